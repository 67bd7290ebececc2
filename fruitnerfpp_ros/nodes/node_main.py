"""The ``main()`` shared by the package's node executables: init, spin, one-line errors, clean shutdown."""

from __future__ import annotations

import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node

from fruitnerfpp_ros.errors import FruitNerfError

__all__ = ['DRAIN_TIMEOUT_S', 'SIGNAL_SETTLE_S', 'spin_node']

DRAIN_TIMEOUT_S = 10.0
SIGNAL_SETTLE_S = 2.0


def spin_node(name: str, make_node: Callable[[], Node], make_executor: Callable[[], Executor],
              args: list[str] | None = None, *, on_shutdown: Callable[[Node], None] | None = None) -> int:
    """Create the node, spin it until Ctrl-C / shutdown, and return the process exit code.

    Bad parameters or input (:class:`FruitNerfError`) end the process with one line on stderr and exit code 2;
    Ctrl-C / SIGINT at any point after ``rclpy.init`` is a clean stop (exit code 0).
    ``on_shutdown`` runs before the node is destroyed (e.g. to stop a training thread), after the callbacks still
    running in the executor's threads have finished (at most ``DRAIN_TIMEOUT_S``).
    """
    rclpy.init(args=args)
    node = executor = None
    try:
        # The executor first: one SIGSEGV on SIGINT came from the finaliser of an executor's SIGINT guard condition
        # (SignalHandlerGuardCondition.__del__), likely an executor the KeyboardInterrupt left half-built; the node's
        # construction takes longer and logs, so that is where an early Ctrl-C lands now.
        executor = make_executor()
        node = make_node()
        executor.add_node(node)
        executor.spin()
    except FruitNerfError as err:
        print(f'{name}: error: {err}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        _await_signal_handling(SIGNAL_SETTLE_S)
    except Exception:
        # A SIGINT between node construction and spin() shuts the context down under rclpy's signal handler;
        # whatever then fails (adding the node, starting the executor) is part of a requested stop.
        if rclpy.ok():
            raise
    finally:
        if executor is not None:
            _drain(executor, DRAIN_TIMEOUT_S)
        if node is not None:
            if on_shutdown is not None:
                on_shutdown(node)
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _drain(executor: Executor, timeout_s: float) -> None:
    """Stop ``executor`` and wait up to ``timeout_s`` for the callbacks its threads are still running.

    rclpy Jazzy's ``Executor.shutdown`` does not wait for them, and ``MultiThreadedExecutor`` keeps its threads in a
    ``ThreadPoolExecutor`` (``_executor``) that nothing shuts down: a node destroyed under a running callback is a
    use after free in rcl (the process ended with SIGSEGV on SIGINT). Queued callbacks that have not started are
    cancelled. The pool's threads are found by name as well: a Ctrl-C that lands while the pool starts a thread
    leaves that thread out of the pool's own set. Where the attribute is absent (other rclpy versions),
    ``shutdown`` is all there is.
    """
    deadline = time.monotonic() + timeout_s
    executor.shutdown(timeout_sec=timeout_s)
    pool = getattr(executor, '_executor', None)
    if not isinstance(pool, ThreadPoolExecutor):
        return
    pool.shutdown(wait=False, cancel_futures=True)
    prefix = f'{getattr(pool, "_thread_name_prefix", None)}_'
    workers = set(getattr(pool, '_threads', ())) | {t for t in threading.enumerate() if t.name.startswith(prefix)}
    for worker in workers - {threading.current_thread()}:
        worker.join(max(0.0, deadline - time.monotonic()))
    if any(worker.is_alive() for worker in workers):
        print(f'a callback still runs after {timeout_s:.0f} s; destroying the node anyway', file=sys.stderr)


def _await_signal_handling(timeout_s: float) -> None:
    """After Ctrl-C, wait (at most ``timeout_s``) until rclpy's signal thread has shut the context down.

    The ``KeyboardInterrupt`` reaches the main thread while rclpy's own signal thread may still be triggering the
    executors' SIGINT guard conditions; destroying the executor's in that window freed it under the trigger
    (SIGSEGV in a thread without Python). The context going down is the signal thread's last step.
    """
    deadline = time.monotonic() + timeout_s
    while rclpy.ok() and time.monotonic() < deadline:
        time.sleep(0.01)
