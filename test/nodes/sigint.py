"""Start a node process, wait for a line it prints, send it SIGINT: its exit code and everything it printed."""

from __future__ import annotations

import os
import signal
import subprocess
import time

ABORT_GRACE_S = 5.0


def interrupt_after(command: list[str], marker: str, *, start_timeout_s: float = 60.0,
                    stop_timeout_s: float = 20.0) -> tuple[int, str]:
    """Run ``command``, send SIGINT once a line holding ``marker`` is printed, and wait for the process to end.

    Fails the test (AssertionError with the output) when the marker never comes or the process does not end within
    ``stop_timeout_s``. A process that hangs is sent SIGABRT first: the child runs with ``PYTHONFAULTHANDLER=1``, so
    every thread's stack is in the failure's output, which says where the stop hangs. The process is killed on any
    error.
    """
    env = dict(os.environ, PYTHONFAULTHANDLER='1')
    proc = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    try:
        deadline = time.monotonic() + start_timeout_s
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            lines.append(line)
            if marker in line or not line:
                break
        assert marker in lines[-1], ''.join(lines)
        proc.send_signal(signal.SIGINT)
        try:
            rc = proc.wait(timeout=stop_timeout_s)
        except subprocess.TimeoutExpired:
            proc.send_signal(signal.SIGABRT)
            try:
                tail, _ = proc.communicate(timeout=ABORT_GRACE_S)
            except subprocess.TimeoutExpired:
                tail = '(no stack: the process did not end on SIGABRT either)'
            raise AssertionError(f'the process did not end within {stop_timeout_s:.0f} s of SIGINT; '
                                 f'its output, then its stacks on SIGABRT:\n{"".join(lines)}{tail}') from None
        lines.append(proc.stdout.read())
    finally:
        if proc.poll() is None:
            proc.kill()
    return rc, ''.join(lines)
