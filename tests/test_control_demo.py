"""`panel-rig control-demo`: its summary's numbers."""

from __future__ import annotations

import json

from panel_rig import jsonio


def test_summary_takes_the_diagnostics_as_numbers() -> None:
    """The node's diagnostics are KeyValues (text): the summary had `"control_commands": "1200"`. Counts are
    integers, command ages floats, and a 'nan' (no command yet) is null, not a string or NaN."""
    from panel_rig.control_demo import diagnostics_summary

    d = diagnostics_summary({"control_latency_mean_total_ms": "0.213", "control_latency_p99_total_ms": "nan",
                             "control_commands": "1200", "rejected_commands": "0", "state": "running"})
    assert json.loads(jsonio.dumps(d)) == {"latency_mean_total_ms": 0.213, "latency_p99_total_ms": None,
                                           "rig_state": "running", "control_commands": 1200, "rejected_commands": 0}
    assert isinstance(d["control_commands"], int) and diagnostics_summary({})["control_commands"] is None
