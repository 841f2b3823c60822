"""Child processes of the one-command sessions (demo, control demo, live flutter test): stopping them cleanly."""

from __future__ import annotations

import signal
import subprocess


def stop(proc: subprocess.Popen, timeout_s: float) -> int:
    """SIGINT (a node closes its bag and exits 0), wait up to ``timeout_s`` (wall); SIGKILL only if it does not
    stop. Returns the exit code."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()
