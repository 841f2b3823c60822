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

    A tip limit with a physical basis is the trailing edge touching the tunnel wall: :meth:`for_panel`
    (:func:`tip_limit_from_wall_clearance`; 0.926 for the paper's panel at the default clearance). It suits the
    ``exact`` structure (|w/L| <= 1 by construction); the field default below stays above L for the cubic
    variants, whose LCO peaks exceed L just past flutter."""

    max_airspeed_mps: float = 30.0
    # |w/L| at the tip that aborts: above the largest LCO peaks of the cubic full model just past flutter (~1.2),
    # below the stepper's own divergence bound sim.max_tip_w_over_L = 2.0, so the rig aborts first.
    max_tip_w_over_L: float = 1.5
    max_force_npm: float = 10.0
    max_amplitude_npm: float = 10.0
    max_frequency_hz: float = 200.0

    @classmethod
    def for_panel(cls, panel_length_m: float, wall_clearance_m: float = DEFAULT_WALL_CLEARANCE_M,
                  **others: float) -> "SafetyLimits":
        """Limits whose tip limit is the wall contact of a panel of this length at this clearance."""
        return cls(max_tip_w_over_L=tip_limit_from_wall_clearance(wall_clearance_m, panel_length_m), **others)

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


def check_tip(tip_w_over_L: float, limits: SafetyLimits) -> str | None:
    """|w/L| at the tip within max_tip_w_over_L (a reason here means abort)."""
    if not math.isfinite(tip_w_over_L):
        return f"tip w/L is not finite ({tip_w_over_L!r})"
    if abs(tip_w_over_L) > limits.max_tip_w_over_L:
        return f"tip |w/L| = {abs(tip_w_over_L):.3g} exceeds the limit {limits.max_tip_w_over_L:g}"
    return None
