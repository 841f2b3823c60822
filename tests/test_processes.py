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

