"""Signals deferred over work that must not be cut in the middle (a block of readings handed to the recording)."""

from __future__ import annotations

import os
import signal

import pytest

from panel_rig.processes import TERMINATED_STATUS, signals_deferred, sigterm_exits


def test_a_ctrl_c_inside_a_deferred_block_is_raised_at_its_end():
    done = []
    before = signal.getsignal(signal.SIGINT)
    with pytest.raises(KeyboardInterrupt):
        with signals_deferred():
            os.kill(os.getpid(), signal.SIGINT)  # Python runs the handler at once: without the deferral, not past here
            done.append("the rest of the block")
    assert done == ["the rest of the block"]
    assert signal.getsignal(signal.SIGINT) is before


def test_a_sigterm_inside_a_deferred_block_leaves_through_the_handler_before_it():
    done = []
    with pytest.raises(SystemExit) as stopped:
        with sigterm_exits(), signals_deferred():
            os.kill(os.getpid(), signal.SIGTERM)
            done.append("the rest of the block")
    assert done == ["the rest of the block"] and stopped.value.code == TERMINATED_STATUS



def test_a_stopped_ros_program_keeps_taking_signals_as_stop_requests_until_it_exits():
    """A node stopped by Ctrl-C, then sent a SIGTERM after its ROS session had ended (closing its bag and shutting
    rclpy down take moments in which an operator presses again): the restored default handler killed it, status
    143, though it had stopped cleanly. Now a stopped session leaves both signals ignored (the interpreter's
    finalisation resets a Python handler, not an ignored signal); one that was not stopped gives the handlers back."""
    import subprocess
    import sys

    pytest.importorskip("rclpy")
    script = (
        "import os, signal, sys\n"
        "from panel_rig.processes import StopRequest\n"
        "from panel_rig.ros.session import ros_session\n"
        "before = signal.getsignal(signal.SIGTERM)\n"
        "with ros_session([], StopRequest()):\n"
        "    pass\n"
        "assert signal.getsignal(signal.SIGTERM) is before, 'a session not stopped keeps its handlers'\n"
        "with ros_session([], StopRequest()):\n"
        "    os.kill(os.getpid(), signal.SIGINT)\n"
        "assert signal.getsignal(signal.SIGTERM) is signal.SIG_IGN is signal.getsignal(signal.SIGINT)\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "os.kill(os.getpid(), signal.SIGINT)\n"
        "print('exited on its own')\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "exited on its own" in out.stdout, (out.returncode, out.stderr[-2000:])


def test_a_stopped_run_carries_its_exit_status_and_what_catches_it():
    """A signal's stop (Interrupted) passes any ``except Exception`` and exits 128 + the signal; a failure's (Aborted)
    is an error a caller that does not report its payload still catches, and exits 1. One ``except StoppedRun``
    reports both."""
    from panel_rig.processes import Aborted, Interrupted, StoppedRun

    caught = []
    for stop in (Interrupted(signal.SIGTERM, {"points": 2}, "stopped"), Aborted({"points": 1}, "disk full")):
        try:
            try:
                raise stop
            except Exception as exc:  # noqa: BLE001 - what a generic error handler on the way would do
                caught.append(("error", exc.exit_status))
                raise
        except StoppedRun as stopped:
            caught.append((stopped.message, stopped.payload["points"], stopped.exit_status))
    assert caught == [("stopped", 2, 143), ("error", 1), ("disk full", 1, 1)]
