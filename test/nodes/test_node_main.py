"""``spin_node``'s stop: a callback still running in an executor thread at Ctrl-C finishes before the node goes.

The node process once ended with SIGSEGV on SIGINT (``test_live_nodes``): rclpy Jazzy's ``Executor.shutdown``
does not wait for the callbacks a ``MultiThreadedExecutor``'s threads are running, so the node was destroyed under
one of them. The child below has a timer whose callback sleeps, then publishes; SIGINT arrives during the sleep.
Before the fix the node was destroyed first and the late publish met a destroyed publisher.

A callback that never returns is a hang, not a stop: the process says where it hangs and ends anyway (once the
full-disk node test waited 20 s for a fruit_counter that had printed only "a callback still runs after 10 s").
"""

from __future__ import annotations

import sys
import textwrap
import time

from fruitnerfpp_ros.nodes.node_main import STUCK_EXIT_CODE
from test.nodes.sigint import interrupt_after

CHILD = textwrap.dedent('''
    import sys, time
    from rclpy.callback_groups import ReentrantCallbackGroup
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from std_msgs.msg import String
    from fruitnerfpp_ros.nodes.node_main import spin_node

    class Slow(Node):
        def __init__(self):
            super().__init__('slow_callback')
            self.pub = self.create_publisher(String, '~/out', 1)
            self.calls = 0
            self.timer = self.create_timer(0.05, self.tick, callback_group=ReentrantCallbackGroup())

        def tick(self):
            self.calls += 1
            if self.calls != 1:
                return
            print('callback started', flush=True)
            time.sleep(1.5)
            try:  # SIGINT has shut the context down: publishing fails, but on a publisher that still exists
                self.pub.publish(String(data='late'))
            except Exception as err:
                print('publish refused:', err, flush=True)
            print('callback finished', flush=True)

    def on_shutdown(node):
        print('node destroyed next', flush=True)

    sys.exit(spin_node('slow', Slow, lambda: MultiThreadedExecutor(num_threads=2), on_shutdown=on_shutdown))
''')


def test_a_running_callback_finishes_before_the_node_is_destroyed() -> None:
    rc, printed = interrupt_after([sys.executable, '-c', CHILD], 'callback started')
    said = [s.strip() for s in printed.splitlines() if s.strip() in ('callback finished', 'node destroyed next')]
    assert rc == 0 and said == ['callback finished', 'node destroyed next'], printed
    assert 'destruction was requested' not in printed


STUCK_CHILD = textwrap.dedent('''
    import sys, threading
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node
    from fruitnerfpp_ros.nodes.node_main import spin_node

    class Stuck(Node):
        def __init__(self):
            super().__init__('stuck_callback')
            self.timer = self.create_timer(0.05, self.wait_for_ever)

        def wait_for_ever(self):
            print('callback started', flush=True)
            threading.Event().wait()

    def on_shutdown(node):
        print('shutdown steps ran', flush=True)

    sys.exit(spin_node('stuck', Stuck, lambda: MultiThreadedExecutor(num_threads=2), on_shutdown=on_shutdown,
                       drain_timeout_s=1.0))
''')


def test_a_callback_that_never_returns_is_named_and_the_process_still_ends() -> None:
    started = time.monotonic()
    rc, printed = interrupt_after([sys.executable, '-c', STUCK_CHILD], 'callback started', stop_timeout_s=15.0)
    assert rc == STUCK_EXIT_CODE, printed
    assert 'a callback still runs after 1 s' in printed and 'in wait_for_ever' in printed, printed
    assert 'shutdown steps ran' in printed, printed
    assert time.monotonic() - started < 15.0
