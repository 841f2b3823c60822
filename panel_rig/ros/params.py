"""The node's own parameters (beyond the physics in ``panel_rig.config.SCHEMA``): defaults, checks, liveness.

Names form one nested namespace in which no name is also the prefix of another (so ``ros2 param dump``
writes one nested YAML that ``ros2 param load`` takes back). Defaults of the rig's settings come from the
rig's own dataclasses (:class:`SafetyLimits`, :class:`TunnelSettings`, :class:`ControlSettings`); ``config/rig.yaml`` is pinned to
these defaults by a test.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.parameter import Parameter

from panel_rig.analysis.flutter_test import FlutterTestSettings
from panel_rig.config import SCHEMA, PanelConfig, float_from_text, interval_rule
from panel_rig.model.aerodynamics import MAX_AIRSPEED_MPS
from panel_rig.model.options import DEFAULT_AERO, DEFAULT_VARIANT, RIG_AERO_MODELS, VARIANTS
from panel_rig.rig.control import ControlSettings
from panel_rig.rig.flutter_run import DEFAULT_SETTLE_S, MAX_DWELL_S, MAX_REPEATS, MAX_SETTLE_S, MIN_DWELL_S
from panel_rig.rig.rig import TunnelSettings
from panel_rig.rig.safety import SafetyLimits

# "none", not "off": YAML 1.1 (rcl, `ros2 param load`) reads an unquoted off as the boolean false
_RERUN = re.compile(r"^(none|save:.+|connect:.*)$")


@dataclass(frozen=True)
class NodeParam:
    """A node parameter: default (also its type), whether it may change live, a check returning a reason,
    and numeric bounds ``lo``/``hi`` (published as the descriptor's range, which has closed ends: an open end is
    the check's; None: unbounded)."""

    default: Any
    live: bool
    check: Callable[[Any], str | None]
    description: str
    lo: float | None = None
    hi: float | None = None


def _number(default: float, live: bool, description: str, lo: float, hi: float, lo_open: bool = False,
            hi_open: bool = False) -> NodeParam:
    ok, rule = interval_rule(lo, hi, lo_open, hi_open)

    def check(v: Any) -> str | None:
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            return f"expected a finite number, got {v!r}"
        return None if ok(v) else f"{rule}, got {v!r}"

    return NodeParam(float(default), live, check, description, lo, hi)


def _count(default: int, description: str, lo: int, hi: int) -> NodeParam:
    """A read-only integer parameter in [lo, hi]."""
    def check(v: Any) -> str | None:
        if isinstance(v, bool) or not isinstance(v, int):
            return f"expected an integer, got {v!r}"
        return None if lo <= v <= hi else f"must be in [{lo}, {hi}], got {v!r}"

    return NodeParam(int(default), False, check, description, lo, hi)


def _one_of(default: str, choices: tuple[str, ...], description: str) -> NodeParam:
    return NodeParam(default, False, lambda v: None if v in choices else f"must be one of {choices}, got {v!r}",
                     f"{description}: {' | '.join(choices)}")


def _bool(v: Any) -> str | None:
    return None if isinstance(v, bool) else f"expected true/false, got {v!r}"


def _string(v: Any) -> str | None:
    return None if isinstance(v, str) and v else f"expected a non-empty string, got {v!r}"


def _rerun(v: Any) -> str | None:
    return None if isinstance(v, str) and _RERUN.match(v) else f"expected none | save:PATH | connect:URL, got {v!r}"


def _physics_dt(v: Any) -> str | None:
    """0 (sim.dt_s), or a step within sim.dt_s's bounds (a 1 ns step was taken: 1e9 steps a simulated second)."""
    spec = SCHEMA["sim.dt_s"]
    number = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
    if number and (v == 0 or spec.ok(v)):
        return None
    return f"must be 0 (use sim.dt_s) or in [{spec.lo:g}, {spec.hi:g}] s, got {v!r}"


_LIMITS, _TUNNEL, _CONTROL = SafetyLimits(), TunnelSettings(), ControlSettings()

NODE_PARAMS: dict[str, NodeParam] = {
    "physics_dt": NodeParam(0.0, False, _physics_dt, "physics step, s (0: use sim.dt_s; else within sim.dt_s's "
                            "bounds)", 0.0, SCHEMA["sim.dt_s"].hi),
    "publish_rate_hz": _number(500.0, True, "readings and timer tick rate, Hz", 1.0, 5000.0),
    "shape_rate_hz": _number(30.0, True, "panel_shape marker rate (simulated time), Hz", 0.1, 200.0),
    "diagnostics_rate_hz": _number(2.0, True, "/diagnostics rate (wall time), Hz", 0.1, 50.0),
    "max_lag_s": _number(0.05, True, "real-time lag counted as an overrun, s", 0.0, 10.0, lo_open=True),
    "fast": NodeParam(False, False, _bool, "run as fast as possible and publish /clock"),
    "fast_max_realtime_factor": _number(0.0, True, "fast mode: at most this many simulated s per wall s (0: no cap)",
                                        0.0, 1e6),
    "model.variant": _one_of(DEFAULT_VARIANT, tuple(VARIANTS), "structural model variant"),
    "model.aero": _one_of(DEFAULT_AERO, RIG_AERO_MODELS, "aerodynamics: reduced-order or full vortex lattice"),
    "tunnel.time_constant_s": _number(_TUNNEL.time_constant_s, True, "airspeed first-order lag, s", 0.0, 1000.0),
    "tunnel.max_rate_mps2": _number(_TUNNEL.max_rate_mps2, True, "airspeed rate limit, m/s^2 (0: none)", 0.0, 1000.0),
    "safety.max_airspeed_mps": _number(_LIMITS.max_airspeed_mps, True,
                                       "airspeed limit, m/s (lowering it below the set-point ramps the tunnel down; "
                                       "the incompressible lattice holds to about Mach 0.3)",
                                       0.0, MAX_AIRSPEED_MPS, lo_open=True),
    "safety.max_tip_w_over_L": _number(_LIMITS.max_tip_w_over_L, True,
                                       "tip |w/L| that aborts the run (1: the panel's own length; the wall may "
                                       "come first; also when lowered below the present tip)",
                                       0.0, 100.0, lo_open=True),
    "safety.wall_clearance_m": _number(_LIMITS.wall_clearance_m, True,
                                       "distance from the panel's plane to the nearer tunnel wall, m: the tip "
                                       "reaching it aborts the run", 0.0, 100.0, lo_open=True),
    "shaker.max_force_npm": _number(_LIMITS.max_force_npm, True, "held force limit +-, N/m", 0.0, 1e6, lo_open=True),
    "shaker.max_amplitude_npm": _number(_LIMITS.max_amplitude_npm, True, "sine amplitude limit, N/m", 0.0, 1e6,
                                        lo_open=True),
    "shaker.max_frequency_hz": _number(_LIMITS.max_frequency_hz, True, "sine frequency limit, Hz", 0.0, 1e5,
                                       lo_open=True),
    # closed-loop control actuator (control/force_cmd; panel_rig/rig/control.py)
    "control.bandwidth_hz": _number(_CONTROL.bandwidth_hz, True, "control actuator first-order bandwidth, Hz",
                                    0.0, 1e4, lo_open=True),
    "control.max_force_npm": _number(_CONTROL.max_force_npm, True,
                                     "control force saturation +-, N/m (commands beyond it are rejected)",
                                     0.0, 1e6, lo_open=True),
    "control.max_rate_npmps": _number(_CONTROL.max_rate_npmps, True, "control force rate limit, N/m per s",
                                      0.0, 1e9, lo_open=True),
    "control.timeout_s": _number(_CONTROL.timeout_s, True,
                                 "watchdog: no control command for longer -> control force to zero, s",
                                 0.0, 60.0, lo_open=True),
    "control.fast_delay_s": _number(0.002, True, "fast mode (lock-step with the controller): emulated command "
                                    "latency added to each command's arrival, s", 0.0, 1.0),
    "record": NodeParam(False, False, _bool, "record a rosbag2 MCAP of every topic and command"),
    "bag_dir": NodeParam("bags", False, _string, "directory for recordings"),
    "record_min_free_mb": _number(500.0, False, "free space kept under bag_dir: below it the recording stops, its "
                                  "bag closed intact (0: record until the disk is full), MB", 0.0, 1e9),
    "rerun": NodeParam("none", False, _rerun, "Rerun sink: none | save:PATH | connect:URL"),
    "flutter_monitor": NodeParam(False, False, _bool, "identify each airspeed plateau of the measured tip and "
                                 "publish flutter_monitor (DiagnosticArray: damping, predicted U_f, margin)"),
    # the monitor's test-point window and decision (panel_rig/rig/flutter_run.py FlutterMonitorSink), simulated s
    "flutter_test.settle_s": _number(DEFAULT_SETTLE_S, False, "flutter monitor: run-in dropped after each airspeed command, "
                                     "simulated s", 0.0, MAX_SETTLE_S),
    "flutter_test.dwell_s": _number(200.0, False, "flutter monitor: response identified per test point (published "
                                    "as soon as it is complete), simulated s", MIN_DWELL_S, MAX_DWELL_S),
    "flutter_test.margin": _number(0.1, False, "flutter monitor: required speed margin M of its decision "
                                   "(as flutter-test --margin)", 0.0, 1.0, lo_open=True, hi_open=True),
    "flutter_test.repeats": _count(FlutterTestSettings.repeats, "flutter monitor: times its decision takes an "
                                   "airspeed again before a margin stop on an uncertain prediction (as flutter-test "
                                   "--repeats)", 0, MAX_REPEATS),
    "fast_wait_for_command": NodeParam(False, False, _bool, "fast mode: simulated time starts with the first "
                                       "command received (an operator's, a controller's), not at start-up"),
    "flutter_test.hold": NodeParam(False, False, _bool, "fast mode: hold simulated time after each published test "
                                   "point until the next airspeed command (a flutter-test client's lock-step)"),
}

#: node parameter -> field of :class:`panel_rig.rig.safety.SafetyLimits`
LIMIT_FIELDS = {
    "safety.max_airspeed_mps": "max_airspeed_mps",
    "safety.max_tip_w_over_L": "max_tip_w_over_L",
    "safety.wall_clearance_m": "wall_clearance_m",
    "shaker.max_force_npm": "max_force_npm",
    "shaker.max_amplitude_npm": "max_amplitude_npm",
    "shaker.max_frequency_hz": "max_frequency_hz",
}


#: node parameter -> field of :class:`panel_rig.rig.control.ControlSettings`
CONTROL_FIELDS = {f"control.{name}": name for name in ("bandwidth_hz", "max_force_npm", "max_rate_npmps", "timeout_s")}


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
    return problems or combination_problems(values)


def combination_problems(values: Mapping[str, Any]) -> list[str]:
    """Values valid alone but not together (``values``: every parameter's value after the change)."""
    delay, timeout = values.get("control.fast_delay_s"), values.get("control.timeout_s")
    if isinstance(delay, (int, float)) and isinstance(timeout, (int, float)) and delay >= timeout:
        return [f"control.fast_delay_s: {delay:g} s must be below control.timeout_s ({timeout:g} s), else every "
                "control command arrives too old and is refused"]
    return []


def publish_rate_problem(publish_rate_hz: float, physics_dt_s: float) -> str | None:
    """Readings faster than the physics steps repeat the same state under new stamps (a bag at 5000 Hz on 2048 Hz
    physics had dt = 0 between 26449 of 44800 samples, and its spectra showed 2 kHz "frequencies")."""
    step_hz = 1.0 / physics_dt_s
    if publish_rate_hz > step_hz * (1.0 + 1e-9):
        return (f"publish_rate_hz: {publish_rate_hz:g} Hz is above the physics step rate {step_hz:g} Hz "
                f"(dt = {physics_dt_s:g} s): readings would repeat; publish at most once a step")
    return None


#: how alike (difflib's ratio) a declared name must be to be offered for an unknown one: a typo scores 0.9 or more
#: (gian_nspm2 / gain_nspm2 0.90, model.variantt 0.96), an unrelated name less (shape_rate_hz / derivative_hz 0.62)
NEAR_NAME_CUTOFF = 0.8


def undeclared_problem(names: Sequence[str], declared: Sequence[str]) -> str | None:
    """The reason a set of parameters is refused when a name is not one of the node's ``declared`` ones, naming it
    and the nearest declared name (rclpy's own reason listed no name: "undeclared parameter(s): []")."""
    known = set(declared)
    unknown = [name for name in names if name not in known]
    if not unknown:
        return None
    parts = []
    for name in unknown:
        near = difflib.get_close_matches(name, sorted(known), n=1, cutoff=NEAR_NAME_CUTOFF)
        parts.append(f"{name!r}" + (f" (did you mean {near[0]!r}?)" if near else ""))
    return (f"not a parameter of this node: {', '.join(parts)} (the README lists its parameters; so does "
            "`ros2 param list` with a ROS 2 install)")


def as_declared(table: Mapping[str, tuple[Any, ParameterDescriptor]], prm: Parameter) -> Parameter:
    """A value for a float parameter given as an integer (``ros2 param set ... 1``) or as a number in a string
    (rclpy's YAML loader reads ``5e-06``, as ``ros2 param dump`` writes 5.0e-06, back as a string) is taken
    as that float; a boolean for a physics choice with an "off" value is that text (``-p
    tunnel.turbulence.spectrum:=off`` reads as false, see ``_Spec.bool_as_choice``). Every other type mismatch is
    left for rclpy to refuse: types stay static."""
    entry = table.get(prm.name)
    if entry is not None and prm.name in SCHEMA and prm.type_ == Parameter.Type.BOOL:
        text = SCHEMA[prm.name].bool_as_choice(prm.value)
        return Parameter(prm.name, Parameter.Type.STRING, text) if isinstance(text, str) else prm
    if entry is None or not isinstance(entry[0], float):
        return prm
    if prm.type_ == Parameter.Type.INTEGER:
        return Parameter(prm.name, Parameter.Type.DOUBLE, float(prm.value))
    if prm.type_ == Parameter.Type.STRING and (number := float_from_text(prm.value)) is not None:
        return Parameter(prm.name, Parameter.Type.DOUBLE, number)
    return prm


def live_change_problem(params: Sequence[Parameter], current: Callable[[str], Any], physics_dt_s: float
                        ) -> str | None:
    """Why a live change of ``params`` is refused (None: it is not); ``current(name)``: a parameter's value now.
    Physics and structural parameters are read-only (rclpy refuses them); ``use_sim_time`` is read at start."""
    for prm in params:
        if prm.name == "use_sim_time" and prm.value != current("use_sim_time"):
            # rclpy takes it live, and a real-time node then waits for a /clock nobody publishes: frozen
            return ("use_sim_time is read at start: restart the node with -p use_sim_time:=true (a fast node "
                    "publishes /clock itself)")
        spec = NODE_PARAMS.get(prm.name)
        if spec is None:
            continue
        reason = spec.check(prm.value)
        if reason:
            return f"{prm.name}: {reason}"
        if prm.name == "publish_rate_hz":
            reason = publish_rate_problem(float(prm.value), physics_dt_s)
            if reason:
                return reason
    after = {name: current(name) for name in ("control.fast_delay_s", "control.timeout_s")}
    after.update({prm.name: prm.value for prm in params if prm.name in after})
    problems = combination_problems(after)
    return problems[0] if problems else None


def _descriptor(default: Any, description: str, read_only: bool, lo: float | None, hi: float | None
                ) -> ParameterDescriptor:
    """A statically typed descriptor (type of the default) with its range and read-only flag."""
    kind = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
            float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING}[type(default)]
    d = ParameterDescriptor(type=kind, description=description + ("; read-only: restart to change" if read_only else ""),
                            read_only=read_only)
    if kind == ParameterType.PARAMETER_DOUBLE and (lo is not None or hi is not None):
        d.floating_point_range = [FloatingPointRange(from_value=float(-math.inf if lo is None else lo),
                                                     to_value=float(math.inf if hi is None else hi), step=0.0)]
    elif kind == ParameterType.PARAMETER_INTEGER and (lo is not None or hi is not None):
        d.integer_range = [IntegerRange(from_value=int(-(2**63) if lo is None else lo),
                                        to_value=int(2**63 - 1 if hi is None else hi), step=1)]
    return d


def parameter_table() -> dict[str, tuple[Any, ParameterDescriptor]]:
    """Every node parameter, physics and node's own: name -> (default, descriptor)."""
    defaults = PanelConfig()
    table: dict[str, tuple[Any, ParameterDescriptor]] = {}
    for key, spec in SCHEMA.items():
        default = getattr(defaults, spec.field)
        table[key] = (default, _descriptor(default, f"physics ({spec.rule})", True, spec.lo, spec.hi))
    for name, p in NODE_PARAMS.items():
        table[name] = (p.default, _descriptor(p.default, p.description, not p.live, p.lo, p.hi))
    return table
