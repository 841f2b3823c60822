"""The node's own parameters (beyond the physics in ``panel_rig.config.SCHEMA``): defaults, checks, liveness."""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from panel_rig.model.options import DEFAULT_AERO, DEFAULT_VARIANT, RIG_AERO_MODELS, VARIANTS

_RERUN = re.compile(r"^(off|save:.+|connect:.*)$")


@dataclass(frozen=True)
class NodeParam:
    """A node parameter: default (also its type), whether it may change live, a check returning a reason."""

    default: Any
    live: bool
    check: Callable[[Any], str | None]
    description: str


def _number(lo: float, hi: float, lo_open: bool = False) -> Callable[[Any], str | None]:
    def check(v: Any) -> str | None:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            return f"expected a finite number, got {v!r}"
        if (v <= lo if lo_open else v < lo) or v > hi:
            return f"must lie in {'(' if lo_open else '['}{lo:g}, {hi:g}], got {v!r}"
        return None

    return check


def _one_of(choices: tuple[str, ...]) -> Callable[[Any], str | None]:
    return lambda v: None if v in choices else f"must be one of {choices}, got {v!r}"


def _bool(v: Any) -> str | None:
    return None if isinstance(v, bool) else f"expected true/false, got {v!r}"


def _string(v: Any) -> str | None:
    return None if isinstance(v, str) and v else f"expected a non-empty string, got {v!r}"


def _rerun(v: Any) -> str | None:
    return None if isinstance(v, str) and _RERUN.match(v) else f"expected off | save:PATH | connect:URL, got {v!r}"


NODE_PARAMS: dict[str, NodeParam] = {
    "physics_dt": NodeParam(0.0, False, _number(0.0, 0.01), "physics step, s (0: use sim.dt_s)"),
    "publish_rate_hz": NodeParam(500.0, True, _number(1.0, 5000.0), "readings and timer tick rate, Hz"),
    "shape_rate_hz": NodeParam(30.0, True, _number(0.1, 200.0), "panel_shape marker rate (simulated time), Hz"),
    "diagnostics_rate_hz": NodeParam(2.0, True, _number(0.1, 50.0), "/diagnostics rate (wall time), Hz"),
    "max_lag_s": NodeParam(0.05, True, _number(0.0, 10.0, lo_open=True), "real-time lag counted as an overrun, s"),
    "fast": NodeParam(False, False, _bool, "run as fast as possible and publish /clock"),
    "fast_max_realtime_factor": NodeParam(0.0, True, _number(0.0, 1e6),
                                          "fast mode: at most this many simulated s per wall s (0: no cap)"),
    "variant": NodeParam(DEFAULT_VARIANT, False, _one_of(tuple(VARIANTS)), "model variant"),
    "aero": NodeParam(DEFAULT_AERO, False, _one_of(RIG_AERO_MODELS), "aerodynamics: reduced-order or full vortex lattice"),
    "tunnel.time_constant_s": NodeParam(1.0, True, _number(0.0, 1000.0), "airspeed first-order lag, s"),
    "tunnel.max_rate_mps2": NodeParam(0.0, True, _number(0.0, 1000.0), "airspeed rate limit, m/s^2 (0: none)"),
    "safety.max_airspeed_mps": NodeParam(30.0, True, _number(0.0, 1000.0, lo_open=True), "airspeed command limit"),
    "safety.max_tip_w_over_L": NodeParam(1.5, True, _number(0.0, 100.0, lo_open=True), "tip |w/L| that aborts"),
    "shaker.max_force_npm": NodeParam(10.0, True, _number(0.0, 1e6, lo_open=True), "held force limit, N/m"),
    "shaker.max_amplitude_npm": NodeParam(10.0, True, _number(0.0, 1e6, lo_open=True), "sine amplitude limit, N/m"),
    "shaker.max_frequency_hz": NodeParam(200.0, True, _number(0.0, 1e5, lo_open=True), "sine frequency limit, Hz"),
    "record": NodeParam(False, False, _bool, "record a rosbag2 MCAP of every topic and command"),
    "bag_dir": NodeParam("bags", False, _string, "directory for recordings"),
    "rerun": NodeParam("off", False, _rerun, "Rerun sink: off | save:PATH | connect:URL"),
}

#: node parameter -> field of :class:`panel_rig.rig.safety.SafetyLimits`
LIMIT_FIELDS = {
    "safety.max_airspeed_mps": "max_airspeed_mps",
    "safety.max_tip_w_over_L": "max_tip_w_over_L",
    "shaker.max_force_npm": "max_force_npm",
    "shaker.max_amplitude_npm": "max_amplitude_npm",
    "shaker.max_frequency_hz": "max_frequency_hz",
}


def check_node_params(values: Mapping[str, Any]) -> list[str]:
    """Every problem with a set of node parameter values, as ``name: reason`` strings."""
    problems = []
    for name, value in values.items():
        spec = NODE_PARAMS.get(name)
        if spec is None:
            continue
        reason = spec.check(value)
        if reason:
            problems.append(f"{name}: {reason}")
    return problems


def coerce(name: str, value: Any) -> Any:
    """Ints given for float parameters become floats (after the check)."""
    default = NODE_PARAMS[name].default
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value
