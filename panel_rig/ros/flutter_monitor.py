"""The flutter monitor's message: one ``diagnostic_msgs/DiagnosticArray`` per test point on ``flutter_monitor``.

Standard type only. Status name ``panel_rig: flutter monitor``; level OK while the predicted margin is at least
the required one, WARN below it (the procedure stops), ERROR if the panel fluttered. Key/values (strings of
numbers, "nan" when unknown; floats written with ``repr`` so a client rebuilds the estimates bit for bit):

- the plateau: ``point_index`` (results published so far, from 1), ``airspeed_mps`` (the commanded set-point),
  ``plateau_start_s`` (simulated time of the command), ``settle_s``, ``dwell_s`` (the monitor's settings,
  simulated seconds: the window identified is from plateau_start_s + settle_s to the earlier of that + dwell_s and
  sim_time_s, which a wind-off or the next command can cut short), ``fluttered`` (``true``/``false``),
  ``sim_time_s``, ``identify_wall_s`` (wall seconds the node spent identifying and predicting: simulated time waits
  meanwhile);
- the flutter mode: ``frequency_hz``, ``frequency_ci_low_hz``/``_high_hz``, ``damping_ratio``,
  ``damping_ci_low``/``_high``, and the estimate itself: ``frequency_se_hz``, ``damping_se``, ``dof``,
  ``estimator``, ``n_stable``; the first mode likewise with the prefix ``first_``; ``method`` (ssi-cov,
  free-decay, fluttered); ``flutter_band_low_hz``/``_high_hz`` (the model's band the flutter mode was sought in);
- the node's own prediction and decision (settings ``flutter_test.*``): ``predicted_flutter_speed_mps``,
  ``predicted_flutter_speed_ci_low_mps``/``_high_mps`` (an open bound: ``inf``), ``margin``, ``required_margin``,
  ``prediction_method``, ``next_airspeed_mps`` (nan: stop), ``decision``.
"""

from __future__ import annotations

import math
from typing import Any

from panel_rig.analysis.flutter_margin import finite_or_none
from panel_rig.analysis.flutter_test import NO_PREDICTION, Decision, TestPoint, flutter_mode_text, prediction_text
from panel_rig.analysis.identification import ModalEstimate
from panel_rig.ros import messages
from panel_rig.topics import FLUTTER_MONITOR_TOPIC

TOPIC = FLUTTER_MONITOR_TOPIC
STATUS_NAME = "panel_rig: flutter monitor"
_ESTIMATE = ("frequency_se_hz", "damping_se", "dof", "estimator", "n_stable")


def _estimate_values(e: ModalEstimate | None, prefix: str) -> dict[str, Any]:
    nan = math.nan
    f_ci = e.frequency_ci_hz() if e is not None else (nan, nan)
    z_ci = e.damping_ci() if e is not None else (nan, nan)
    return {
        f"{prefix}frequency_hz": e.frequency_hz if e is not None else nan,
        f"{prefix}frequency_ci_low_hz": f_ci[0], f"{prefix}frequency_ci_high_hz": f_ci[1],
        f"{prefix}damping_ratio": e.damping_ratio if e is not None else nan,
        f"{prefix}damping_ci_low": z_ci[0], f"{prefix}damping_ci_high": z_ci[1],
        f"{prefix}frequency_se_hz": e.frequency_se_hz if e is not None else nan,
        f"{prefix}damping_se": e.damping_se if e is not None else nan,
        f"{prefix}dof": e.dof if e is not None else -1,
        f"{prefix}estimator": e.method if e is not None else "none",
        f"{prefix}n_stable": e.n_stable if e is not None else 0,
    }


def monitor_values(point: TestPoint, decision: Decision, required_margin: float, *, fluttered: bool = False,
                   plateau: dict[str, float] | None = None) -> dict[str, Any]:
    """The key/values of one result (see the module docstring); ``plateau``: point_index, plateau_start_s,
    settle_s, dwell_s, sim_time_s, flutter_band_low_hz/_high_hz (nan when not given)."""
    p = decision.prediction
    nan = math.nan
    plat = {"point_index": -1, "plateau_start_s": nan, "settle_s": nan, "dwell_s": nan, "sim_time_s": nan,
            "flutter_band_low_hz": nan, "flutter_band_high_hz": nan, "identify_wall_s": nan, **(plateau or {})}
    return {
        "airspeed_mps": point.airspeed_mps,
        **_estimate_values(point.flutter, ""),
        **_estimate_values(point.first, "first_"),
        "predicted_flutter_speed_mps": p.speed_mps if p is not None else nan,
        "predicted_flutter_speed_ci_low_mps": p.ci_mps[0] if p is not None else nan,
        "predicted_flutter_speed_ci_high_mps": p.ci_mps[1] if p is not None else nan,
        "margin": decision.margin(point.airspeed_mps) if p is not None else nan,
        "required_margin": required_margin,
        "method": point.method,
        "prediction_method": p.method if p is not None else "none",
        "next_airspeed_mps": decision.next_airspeed_mps if decision.next_airspeed_mps is not None else nan,
        "decision": decision.reason,
        "fluttered": "true" if fluttered else "false",
        **plat,
    }


def monitor_msg(stamp_ns: int, point: TestPoint, decision: Decision, required_margin: float, *,
                fluttered: bool = False, plateau: dict[str, float] | None = None):
    from diagnostic_msgs.msg import DiagnosticStatus

    values = monitor_values(point, decision, required_margin, fluttered=fluttered, plateau=plateau)
    margin = values["margin"]
    if fluttered:
        level = DiagnosticStatus.ERROR
    elif not math.isnan(margin) and margin < required_margin:
        level = DiagnosticStatus.WARN
    else:
        level = DiagnosticStatus.OK
    msg = messages.diagnostics_msg(stamp_ns, level, decision.reason,
                                   {k: repr(float(v)) if isinstance(v, float) else v for k, v in values.items()})
    msg.status[0].name = STATUS_NAME
    return msg


def parse_monitor(msg) -> dict[str, Any]:
    """Back from a message (bag replay, tests): numbers as floats, the rest as strings."""
    out: dict[str, Any] = {}
    for kv in msg.status[0].values:
        try:
            out[kv.key] = float(kv.value)
        except ValueError:
            out[kv.key] = kv.value
    return out


def monitor_line(values: dict[str, Any]) -> str:
    """One line of a monitor result (``parse_monitor`` output) for a person watching a run: the plateau, the flutter
    mode identified with its 95 % interval, the prediction and the monitor's advice (a client such as the operator
    need not follow it)."""
    u = values.get("airspeed_mps", math.nan)
    head = f"flutter monitor, point {int(values.get('point_index', -1))}: {u:.3f} m/s"
    if values.get("fluttered") == "true":
        return f"{head}: fluttered (at t = {values.get('sim_time_s', math.nan):.3f} s simulated)"
    found = flutter_mode_text(_estimate_from(values, ""))
    speed = values.get("predicted_flutter_speed_mps", math.nan)
    pred = (NO_PREDICTION if not isinstance(speed, float) or math.isnan(speed) else
            prediction_text(speed, (finite_or_none(values.get("predicted_flutter_speed_ci_low_mps")),
                                    finite_or_none(values.get("predicted_flutter_speed_ci_high_mps"))),
                            values.get("prediction_method")))
    return f"{head}: {found}; {pred}; monitor: {values.get('decision', '')}"


def _estimate_from(values: dict[str, Any], prefix: str) -> ModalEstimate | None:
    f = values.get(f"{prefix}frequency_hz", math.nan)
    if not isinstance(f, float) or math.isnan(f):
        return None
    return ModalEstimate(f, float(values[f"{prefix}damping_ratio"]), float(values[f"{prefix}frequency_se_hz"]),
                         float(values[f"{prefix}damping_se"]), int(values[f"{prefix}dof"]),
                         str(values[f"{prefix}estimator"]), int(values[f"{prefix}n_stable"]))


def point_from_values(values: dict[str, Any]) -> TestPoint:
    """The test point a monitor message carries (``parse_monitor`` output), estimates bit for bit as identified."""
    return TestPoint(float(values["airspeed_mps"]), _estimate_from(values, "first_"), _estimate_from(values, ""),
                     str(values["method"]))
