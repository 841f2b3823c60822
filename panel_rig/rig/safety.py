"""Safety limits of the rig and the checks applied to every command (reason string, or None if fine)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

#: Distance (m) from the panel's undeformed plane to the nearer tunnel wall. The paper gives no test-section
#: size; 0.25 m is a panel on the centreline of a ~0.5 m-tall test section (set it to your tunnel).
DEFAULT_WALL_CLEARANCE_M = 0.25


def tip_limit_from_wall_clearance(wall_clearance_m: float, panel_length_m: float) -> float:
    """|tip w/L| at which the trailing edge reaches the tunnel wall: clearance / L, and at most 1 (an
    inextensible panel of length L cannot put its tip farther than L from its plane; with clearance >= L the
    wall cannot be hit and the limit is the geometric one)."""
    if not (math.isfinite(wall_clearance_m) and wall_clearance_m > 0 and math.isfinite(panel_length_m)
            and panel_length_m > 0):
        raise ValueError(f"wall clearance and panel length must be finite and > 0, got {wall_clearance_m!r}, "
                         f"{panel_length_m!r}")
    return min(1.0, wall_clearance_m / panel_length_m)


@dataclass(frozen=True)
class SafetyLimits:
    """Operating envelope; commands outside it are refused, a tip beyond it aborts the run.

    The tip limit has a physical basis: the run aborts when the trailing edge would touch the tunnel wall
    (``wall_clearance_m``) or pass its own length (``max_tip_w_over_L`` = 1: no inextensible panel can),
    whichever comes first (:meth:`tip_limit`; 0.926 for the paper's panel at the default clearance). The cubic
    variants' LCOs (peaks ~1.2 just past flutter) abort there, as a real panel would hit the wall; the ``exact``
    structure stays inside (|w/L| <= 1 by construction)."""

    max_airspeed_mps: float = 30.0
    max_tip_w_over_L: float = 1.0
    wall_clearance_m: float = DEFAULT_WALL_CLEARANCE_M
    max_force_npm: float = 10.0
    max_amplitude_npm: float = 10.0
    max_frequency_hz: float = 200.0

    def tip_limit(self, panel_length_m: float) -> float:
        """|tip w/L| that aborts a run of a panel of this length: wall contact or max_tip_w_over_L, the smaller."""
        return min(self.max_tip_w_over_L, tip_limit_from_wall_clearance(self.wall_clearance_m, panel_length_m))

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
                raise ValueError(f"safety limit {f.name} must be a finite number > 0, got {value!r}")


def _not_finite(name: str, value: float) -> str | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f"{name} must be a number, got {value!r}"
    if not math.isfinite(value):
        return f"{name} must be finite, got {value!r}"
    return None


def _check_range(name: str, value: float, unit: str, limit: float, symmetric: bool = False) -> str | None:
    """A finite number in [0, limit] (or [-limit, limit] if symmetric), else the reason."""
    reason = _not_finite(name, value)
    if reason:
        return reason
    if not symmetric and value < 0:
        return f"{name} must be >= 0 {unit}, got {value:g}"
    if abs(value) > limit:
        bound = f"+-{limit:g}" if symmetric else f"{limit:g}"
        return f"{name} {value:g} {unit} exceeds the limit {bound} {unit}"
    return None


def check_airspeed(airspeed_mps: float, limits: SafetyLimits) -> str | None:
    """Set-point in [0, max_airspeed_mps]."""
    return _check_range("airspeed", airspeed_mps, "m/s", limits.max_airspeed_mps)


def check_force(force_npm: float, limits: SafetyLimits) -> str | None:
    """Held force in [-max_force_npm, max_force_npm]."""
    return _check_range("shaker force", force_npm, "N/m", limits.max_force_npm, symmetric=True)


def check_amplitude(amplitude_npm: float, limits: SafetyLimits) -> str | None:
    """Sine amplitude in [0, max_amplitude_npm]."""
    return _check_range("shaker amplitude", amplitude_npm, "N/m", limits.max_amplitude_npm)


def check_frequency(frequency_hz: float, limits: SafetyLimits, dt_s: float | None = None) -> str | None:
    """Sine frequency in [0, max_frequency_hz] and, given dt, below a quarter of the step rate."""
    reason = _check_range("shaker frequency", frequency_hz, "Hz", limits.max_frequency_hz)
    if reason:
        return reason
    if dt_s is not None and frequency_hz > 0.25 / dt_s:
        return f"shaker frequency {frequency_hz:g} Hz is too high for the physics step ({0.25 / dt_s:g} Hz max)"
    return None


def check_tip(tip_w_over_L: float, limit_w_over_L: float) -> str | None:
    """|w/L| at the tip within the limit (:meth:`SafetyLimits.tip_limit`; a reason here means abort)."""
    if not math.isfinite(tip_w_over_L):
        return f"tip w/L is not finite ({tip_w_over_L!r})"
    if abs(tip_w_over_L) > limit_w_over_L:
        return f"tip |w/L| = {abs(tip_w_over_L):.5g} exceeds the limit {limit_w_over_L:.5g}"
    return None
