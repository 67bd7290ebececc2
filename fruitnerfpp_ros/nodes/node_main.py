"""The ``main()`` shared by the package's node executables: init, spin, one-line errors, clean shutdown."""

from __future__ import annotations

import os
import sys
import threading
import time
import traceback
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node

from fruitnerfpp_ros.errors import FruitNerfError

__all__ = ['DRAIN_TIMEOUT_S', 'SIGNAL_SETTLE_S', 'STUCK_EXIT_CODE', 'spin_node']

DRAIN_TIMEOUT_S = 10.0
SIGNAL_SETTLE_S = 2.0
STUCK_EXIT_CODE = 3  # 2 is a bad parameter or input


def spin_node(name: str, make_node: Callable[[], Node], make_executor: Callable[[], Executor],
              args: list[str] | None = None, *, on_shutdown: Callable[[Node], None] | None = None,
              drain_timeout_s: float = DRAIN_TIMEOUT_S) -> int:
    """Create the node, spin it until Ctrl-C / shutdown, and return the process exit code.

    Bad parameters or input (:class:`FruitNerfError`) end the process with one line on stderr and exit code 2;
    Ctrl-C / SIGINT at any point after ``rclpy.init`` is a clean stop (exit code 0).
    ``on_shutdown`` runs before the node is destroyed (e.g. to stop a training thread), after the callbacks still
    running in the executor's threads have finished (at most ``drain_timeout_s``).

    A callback still running after ``drain_timeout_s`` is a hang: its thread's stack goes to stderr, the node is
    not destroyed under it (a use after free in rcl), ``on_shutdown`` gets another ``drain_timeout_s`` (it may wait
    for a lock the callback holds), and the process ends at once with exit code ``STUCK_EXIT_CODE``, before
    ``rclpy.try_shutdown``: the interpreter's exit would otherwise join the executor's threads and wait for the stuck
    one for ever.
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
        stuck = _drain(executor, drain_timeout_s) if executor is not None else False
        if node is not None and on_shutdown is not None:
            if stuck:  # on_shutdown may wait for a lock the stuck callback holds
                _call_within(on_shutdown, node, drain_timeout_s)
            else:
                on_shutdown(node)
        if stuck:  # no rcl teardown under the stuck thread's handles: the process ends here
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(STUCK_EXIT_CODE)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


def _call_within(function: Callable[[Node], None], node: Node, timeout_s: float) -> None:
    """Call ``function(node)`` in a daemon thread and wait at most ``timeout_s`` for it."""
    thread = threading.Thread(target=function, args=(node,), name='on_shutdown', daemon=True)
    thread.start()
    thread.join(timeout_s)
    if thread.is_alive():
        print(f'the shutdown steps did not finish within {timeout_s:.0f} s', file=sys.stderr, flush=True)


def _drain(executor: Executor, timeout_s: float) -> bool:
    """Stop ``executor`` and wait up to ``timeout_s`` for the callbacks its threads are still running; returns
    whether one still runs (its stack is printed).

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
        return False
    pool.shutdown(wait=False, cancel_futures=True)
    prefix = f'{getattr(pool, "_thread_name_prefix", None)}_'
    workers = set(getattr(pool, '_threads', ())) | {t for t in threading.enumerate() if t.name.startswith(prefix)}
    for worker in workers - {threading.current_thread()}:
        worker.join(max(0.0, deadline - time.monotonic()))
    stuck = sorted((w for w in workers if w.is_alive()), key=lambda w: w.name)
    if stuck:
        frames = sys._current_frames()
        where = ''.join(f'{w.name}:\n' + ''.join(traceback.format_stack(frames[w.ident]))
                        for w in stuck if w.ident in frames)
        print(f'a callback still runs after {timeout_s:.0f} s; stopping without it\n{where}', file=sys.stderr,
              flush=True)
    return bool(stuck)


def _await_signal_handling(timeout_s: float) -> None:
    """After Ctrl-C, wait (at most ``timeout_s``) until rclpy's signal thread has shut the context down.

    The ``KeyboardInterrupt`` reaches the main thread while rclpy's own signal thread may still be triggering the
    executors' SIGINT guard conditions; destroying the executor's in that window freed it under the trigger
    (SIGSEGV in a thread without Python). The context going down is the signal thread's last step.
    """
    deadline = time.monotonic() + timeout_s
    while rclpy.ok() and time.monotonic() < deadline:
        time.sleep(0.01)
