"""What the rig node says on ``/diagnostics`` and in its stopping log line, as pure functions of the rig's state.

:func:`diagnostic_values` assembles the key/value pairs of one status (the rig's state and counters, the run's pace,
the recording, the closed-loop control: :func:`control_values`), :func:`diagnostic_level` its level and message
(ERROR while aborted or while the recording fails, WARN for commands rejected since the last status, else OK), and
:func:`run_stats` the real-time factor, overruns and tick jitter of a whole run. The node keeps the windows (wall
and simulated time at the last status, counts then) and publishes.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus

from panel_rig.rig.control import ControlActuator
from panel_rig.rig.rig import ABORTED, Rig

if TYPE_CHECKING:
    from panel_rig.ros.publishing import Recording


def jitter_p99_ms(intervals_s: Iterable[float], period_s: float) -> float:
    """The 99th percentile of |tick interval - publish period|, ms (0 without intervals)."""
    window = np.asarray(intervals_s, dtype=float)
    return float(np.percentile(np.abs(window - period_s), 99) * 1e3) if window.size else 0.0


def control_values(c: ControlActuator, lockstep: bool) -> dict[str, Any]:
    """Control actuator state and command ages (mean, p99, max over this diagnostics period; mean, p99 over the
    last 100 000 commands). Takes the control loop's latency window."""
    window = c.latency_stats_ms(c.take_window())
    total = c.latency_stats_ms()

    def ms(x: float) -> str:
        return f"{x:.3f}" if math.isfinite(x) else "nan"

    return {
        "control_state": c.state,
        "control_lockstep": lockstep,
        "control_force_npm": f"{c.force_npm:.6f}",
        "control_commands": c.commands,
        "control_timeouts": c.timeouts,
        "control_latency_mean_ms": ms(window["mean"]),
        "control_latency_p99_ms": ms(window["p99"]),
        "control_latency_max_ms": ms(window["max"]),
        "control_latency_n": window["n"],
        "control_latency_mean_total_ms": ms(total["mean"]),
        "control_latency_p99_total_ms": ms(total["p99"]),
    }


def diagnostic_values(rig: Rig, recording: Recording, *, fast: bool, rtf: float, jitter_ms: float,
                      lockstep: bool) -> dict[str, Any]:
    """State, real-time factor (last window), overruns, rejected commands, last rejection, aborts, airspeed, the
    recording and the control loop's values."""
    return {
        "state": rig.state,
        "mode": "fast" if fast else "real-time",
        "sim_time_s": f"{rig.time_s:.6f}",
        "real_time_factor": f"{rtf:.4f}",
        "overruns": rig.overrun_count,
        "rejected_commands": rig.rejected_count,
        "last_rejection": rig.last_rejection,
        "abort_reason": rig.abort_reason,
        "aborts": rig.abort_count,
        "last_abort_time_s": f"{rig.abort_time_s:.6f}" if rig.abort_count else "",
        # with the time it belongs to (after a reset abort_reason was '' beside the last abort's time)
        "last_abort_reason": rig.last_abort_reason,
        "airspeed_setpoint_mps": f"{rig.actuator.setpoint_mps:.4f}",
        "airspeed_mps": f"{rig.actuator.airspeed_mps:.4f}",
        "tick_jitter_p99_ms": f"{jitter_ms:.3f}",
        "physics_dt_s": f"{rig.dt_s:.9g}",
        "sink_errors": rig.sink_errors,
        "recording": recording.state,
        "recording_errors": recording.errors,
        "last_recording_error": recording.last_error,
        **control_values(rig.control, lockstep),
    }


def diagnostic_level(rig: Rig, rejected_now: int, record_errors_now: int, last_record_error: str,
                     recording_stopped: str = "") -> tuple[bytes, str]:
    """(level, message): aborted, else the recording failing since the last status, else the recording stopped at
    the free-space reserve, else commands rejected since then, else OK with the rig's state."""
    if rig.state == ABORTED:
        return DiagnosticStatus.ERROR, f"aborted: {rig.abort_reason}"
    if record_errors_now:
        return DiagnosticStatus.ERROR, f"recording failed: {last_record_error}"
    if recording_stopped:
        return DiagnosticStatus.ERROR, f"recording stopped: {recording_stopped}"
    if rejected_now:
        return DiagnosticStatus.WARN, f"{rejected_now} command(s) rejected: {rig.last_rejection}"
    return DiagnosticStatus.OK, rig.state


def run_stats(rig: Rig, wall_s: float, intervals_s: Iterable[float], period_s: float,
              ticks: int | None = None) -> dict[str, float]:
    """Real-time factor since start, overruns, ``ticks`` (all of them; default: as many as ``intervals_s``) and the
    tick jitter over ``intervals_s`` (p99 of |interval - period|, ms)."""
    intervals = np.asarray(intervals_s, dtype=float)
    jitter = np.abs(intervals - period_s) * 1e3 if intervals.size else np.zeros(1)
    return {
        "sim_time_s": rig.time_s,
        "wall_time_s": wall_s,
        "realtime_factor": rig.time_s / wall_s if wall_s > 0 else 0.0,
        "overruns": rig.overrun_count,
        "ticks": int(intervals.size if ticks is None else ticks),
        "tick_jitter_p99_ms": float(np.percentile(jitter, 99)),
        "tick_interval_mean_ms": float(intervals.mean() * 1e3) if intervals.size else 0.0,
    }
