"""``spin_node``'s stop: a callback still running in an executor thread at Ctrl-C finishes before the node goes.

The node process once ended with SIGSEGV on SIGINT (``test_live_nodes``): rclpy Jazzy's ``Executor.shutdown``
does not wait for the callbacks a ``MultiThreadedExecutor``'s threads are running, so the node was destroyed under
one of them. The child below has a timer whose callback sleeps, then publishes; SIGINT arrives during the sleep.
Before the fix the node was destroyed first and the late publish met a destroyed publisher.
"""

from __future__ import annotations

import sys
import textwrap

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
