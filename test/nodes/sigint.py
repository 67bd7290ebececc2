"""Start a node process, wait for a line it prints, send it SIGINT: its exit code and everything it printed."""

from __future__ import annotations

import os
import signal
import subprocess
import time


def interrupt_after(command: list[str], marker: str, *, start_timeout_s: float = 60.0,
                    stop_timeout_s: float = 20.0) -> tuple[int, str]:
    """Run ``command``, send SIGINT once a line holding ``marker`` is printed, and wait for the process to end.

    Fails the test (AssertionError with the output) when the marker never comes; the process is killed on any error.
    """
    proc = subprocess.Popen(command, env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
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
        rc = proc.wait(timeout=stop_timeout_s)
        lines.append(proc.stdout.read())
    finally:
        if proc.poll() is None:
            proc.kill()
    return rc, ''.join(lines)
