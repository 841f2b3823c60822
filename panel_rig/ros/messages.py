"""Readings to standard ROS messages (pure functions; SI units; stamps in the rig's simulated time)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PointStamped, Vector3Stamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker

from panel_rig.rig.reading import Reading

FRAME_ID = "panel_rig"


def stamp(time_s: float) -> Time:
    """Simulated seconds to builtin_interfaces/Time."""
    ns = max(0, round(time_s * 1e9))
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def stamp_ns(time_s: float) -> int:
    """Simulated seconds to integer nanoseconds."""
    return max(0, round(time_s * 1e9))


def header(time_s: float, frame_id: str = FRAME_ID) -> Header:
    """A header stamped with simulated time."""
    return Header(stamp=stamp(time_s), frame_id=frame_id)


def _finite(values: np.ndarray) -> list[float]:
    """Never put NaN/inf on a topic (the rig guarantees it; this is the last line of defence)."""
    arr = np.asarray(values, dtype=float)
    return np.where(np.isfinite(arr), arr, 0.0).tolist()


def _f(x: float) -> float:
    return float(x) if math.isfinite(x) else 0.0


def tip_msg(r: Reading, trailing_edge_x_m: float) -> PointStamped:
    """Trailing-edge position: x along the chord (m), z = transverse deflection w (m)."""
    return PointStamped(header=header(r.time_s), point=Point(x=float(trailing_edge_x_m), y=0.0, z=_f(r.tip_w_m)))


def modal_msg(r: Reading, names: Sequence[str]) -> JointState:
    """q_i (w/L), dq_i/dt (1/s), generalised aero force per mode."""
    return JointState(
        header=header(r.time_s),
        name=list(names),
        position=_finite(r.q),
        velocity=_finite(r.qdot_per_s),
        effort=_finite(r.aero_force_npm),
    )


def airspeed_msg(r: Reading) -> Vector3Stamped:
    """Measured tunnel airspeed in vector.x, m/s."""
    msg = Vector3Stamped(header=header(r.time_s))
    msg.vector.x = _f(r.airspeed_mps)
    return msg


def clock_msg(time_s: float) -> Clock:
    """/clock in simulated time."""
    return Clock(clock=stamp(time_s))


GREY = ColorRGBA(r=0.6, g=0.6, b=0.6, a=1.0)
BLUE = ColorRGBA(r=0.1, g=0.4, b=0.9, a=1.0)
RED = ColorRGBA(r=0.9, g=0.1, b=0.1, a=1.0)


def shape_msg(
    time_s: float,
    airfoil_length_m: float,
    panel_length_m: float,
    w_over_L: np.ndarray,
    x_over_L: np.ndarray,
    aborted: bool = False,
    n_airfoil: int = 5,
) -> Marker:
    """LINE_STRIP of the rigid airfoil (z = 0) followed by the deflected panel; one colour per point."""
    m = Marker(header=header(time_s), ns="panel", id=0, type=Marker.LINE_STRIP, action=Marker.ADD)
    m.pose.orientation.w = 1.0
    m.scale.x = 0.002
    m.color = RED if aborted else BLUE
    pts: list[Point] = []
    cols: list[ColorRGBA] = []
    for x in np.linspace(0.0, airfoil_length_m, n_airfoil, endpoint=False):
        pts.append(Point(x=float(x), y=0.0, z=0.0))
        cols.append(GREY)
    w = _finite(np.asarray(w_over_L) * panel_length_m)
    panel_col = RED if aborted else BLUE
    for xl, z in zip(np.asarray(x_over_L, dtype=float), w):
        pts.append(Point(x=float(airfoil_length_m + xl * panel_length_m), y=0.0, z=z))
        cols.append(panel_col)
    m.points = pts
    m.colors = cols
    return m


def diagnostics_msg(time_s: float, aborted: bool, message: str, values: Mapping[str, object]) -> DiagnosticArray:
    """One DiagnosticStatus for the rig: OK while running, ERROR when aborted."""
    status = DiagnosticStatus(
        level=DiagnosticStatus.ERROR if aborted else DiagnosticStatus.OK,
        name="panel_rig: tunnel",
        message=message,
        hardware_id="panel_rig",
        values=[KeyValue(key=k, value=str(v)) for k, v in values.items()],
    )
    return DiagnosticArray(header=header(time_s, ""), status=[status])
