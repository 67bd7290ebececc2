"""The SIGINT harness (sigint.py) says where a process that does not stop hangs."""

from __future__ import annotations

import sys
import textwrap

import pytest

from test.nodes.sigint import interrupt_after

DEAF_CHILD = textwrap.dedent('''
    import signal, threading
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def wait_here_for_ever():
        threading.Event().wait()

    print('ready', flush=True)
    wait_here_for_ever()
''')


def test_a_process_that_ignores_sigint_fails_with_its_stack() -> None:
    with pytest.raises(AssertionError) as failure:
        interrupt_after([sys.executable, '-c', DEAF_CHILD], 'ready', stop_timeout_s=1.0)
    message = str(failure.value)
    assert 'did not end within 1 s of SIGINT' in message
    assert 'in wait_here_for_ever' in message, message
