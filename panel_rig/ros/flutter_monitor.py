"""The flutter monitor's message: one ``diagnostic_msgs/DiagnosticArray`` per test point on ``flutter_monitor``.

Standard type only. Status name ``panel_rig: flutter monitor``; level OK while the predicted margin is at least
the required one, WARN below it (the procedure stops), ERROR if the panel fluttered. Key/values (strings of
numbers, "nan" when unknown): ``airspeed_mps``, ``frequency_hz``, ``frequency_ci_low_hz``/``_high_hz``,
``damping_ratio``, ``damping_ci_low``/``_high``, ``predicted_flutter_speed_mps``,
``predicted_flutter_speed_ci_low_mps``/``_high_mps``, ``margin``, ``required_margin``, ``method``,
``prediction_method``, ``decision``.
"""

from __future__ import annotations

import math
from typing import Any

from panel_rig.analysis.flutter_test import Decision, TestPoint
from panel_rig.ros import messages

TOPIC = "flutter_monitor"
STATUS_NAME = "panel_rig: flutter monitor"


def monitor_values(point: TestPoint, decision: Decision, required_margin: float) -> dict[str, Any]:
    e, p = point.flutter, decision.prediction
    nan = math.nan
    f_ci = e.frequency_ci_hz() if e is not None else (nan, nan)
    z_ci = e.damping_ci() if e is not None else (nan, nan)
    return {
        "airspeed_mps": point.airspeed_mps,
        "frequency_hz": e.frequency_hz if e is not None else nan,
        "frequency_ci_low_hz": f_ci[0], "frequency_ci_high_hz": f_ci[1],
        "damping_ratio": e.damping_ratio if e is not None else nan,
        "damping_ci_low": z_ci[0], "damping_ci_high": z_ci[1],
        "predicted_flutter_speed_mps": p.speed_mps if p is not None else nan,
        "predicted_flutter_speed_ci_low_mps": p.ci_mps[0] if p is not None else nan,
        "predicted_flutter_speed_ci_high_mps": p.ci_mps[1] if p is not None else nan,
        "margin": decision.margin(point.airspeed_mps) if p is not None else nan,
        "required_margin": required_margin,
        "method": point.method,
        "prediction_method": p.method if p is not None else "none",
        "decision": decision.reason,
    }


def monitor_msg(stamp_ns: int, point: TestPoint, decision: Decision, required_margin: float):
    from diagnostic_msgs.msg import DiagnosticStatus

    values = monitor_values(point, decision, required_margin)
    margin = values["margin"]
    level = DiagnosticStatus.WARN if (not math.isnan(margin) and margin < required_margin) else DiagnosticStatus.OK
    msg = messages.diagnostics_msg(stamp_ns, level, decision.reason, values)
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
