"""The ``main()`` shared by the package's node executables: init, spin, one-line errors, clean shutdown."""

from __future__ import annotations

import sys
from typing import Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node

from fruitnerfpp_ros.errors import FruitNerfError

__all__ = ['spin_node']


def spin_node(name: str, make_node: Callable[[], Node], make_executor: Callable[[], Executor],
              args: list[str] | None = None, *, on_shutdown: Callable[[Node], None] | None = None) -> int:
    """Create the node, spin it until Ctrl-C / shutdown, and return the process exit code.

    Bad parameters or input (:class:`FruitNerfError`) end the process with one line on stderr and exit code 2;
    Ctrl-C / SIGINT at any point after ``rclpy.init`` is a clean stop (exit code 0).
    ``on_shutdown`` runs before the node is destroyed (e.g. to stop a training thread).
    """
    rclpy.init(args=args)
    node = None
    try:
        node = make_node()
        executor = make_executor()
        executor.add_node(node)
        executor.spin()
    except FruitNerfError as err:
        print(f'{name}: error: {err}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # A SIGINT between node construction and spin() shuts the context down under rclpy's signal handler;
        # whatever then fails (adding the node, starting the executor) is part of a requested stop.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            if on_shutdown is not None:
                on_shutdown(node)
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
