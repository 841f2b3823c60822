"""Safety limits of the rig and the checks applied to every command (reason string, or None if fine)."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


@dataclass(frozen=True)
class SafetyLimits:
    """Operating envelope; commands outside it are refused, a tip beyond it aborts the run."""

    max_airspeed_mps: float = 30.0
    max_tip_w_over_L: float = 1.0
    max_force_npm: float = 10.0
    max_amplitude_npm: float = 10.0
    max_frequency_hz: float = 200.0

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


def check_airspeed(airspeed_mps: float, limits: SafetyLimits) -> str | None:
    """Set-point in [0, max_airspeed_mps]."""
    reason = _not_finite("airspeed", airspeed_mps)
    if reason:
        return reason
    if airspeed_mps < 0:
        return f"airspeed must be >= 0 m/s, got {airspeed_mps:g}"
    if airspeed_mps > limits.max_airspeed_mps:
        return f"airspeed {airspeed_mps:g} m/s exceeds the limit {limits.max_airspeed_mps:g} m/s"
    return None


def check_force(force_npm: float, limits: SafetyLimits) -> str | None:
    """Held force in [-max_force_npm, max_force_npm]."""
    reason = _not_finite("shaker force", force_npm)
    if reason:
        return reason
    if abs(force_npm) > limits.max_force_npm:
        return f"shaker force {force_npm:g} N/m exceeds the limit +-{limits.max_force_npm:g} N/m"
    return None


def check_amplitude(amplitude_npm: float, limits: SafetyLimits) -> str | None:
    """Sine amplitude in [0, max_amplitude_npm]."""
    reason = _not_finite("shaker amplitude", amplitude_npm)
    if reason:
        return reason
    if amplitude_npm < 0:
        return f"shaker amplitude must be >= 0 N/m, got {amplitude_npm:g}"
    if amplitude_npm > limits.max_amplitude_npm:
        return f"shaker amplitude {amplitude_npm:g} N/m exceeds the limit {limits.max_amplitude_npm:g} N/m"
    return None


def check_frequency(frequency_hz: float, limits: SafetyLimits, dt_s: float | None = None) -> str | None:
    """Sine frequency in [0, max_frequency_hz] and, given dt, below a quarter of the step rate."""
    reason = _not_finite("shaker frequency", frequency_hz)
    if reason:
        return reason
    if frequency_hz < 0:
        return f"shaker frequency must be >= 0 Hz, got {frequency_hz:g}"
    if frequency_hz > limits.max_frequency_hz:
        return f"shaker frequency {frequency_hz:g} Hz exceeds the limit {limits.max_frequency_hz:g} Hz"
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
