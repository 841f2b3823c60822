"""The tunnel's airspeed actuator: a first-order lag towards the set-point, optionally rate limited."""

from __future__ import annotations

import math


class AirspeedActuator:
    """First-order lag ``tau dU/dt = U_set - U``, discretised exactly: ``a = exp(-dt/tau)``.

    ``time_constant_s = 0`` follows the set-point at once; ``max_rate_mps2 = 0`` means no rate limit.
    """

    def __init__(self, dt_s: float, time_constant_s: float = 1.0, max_rate_mps2: float = 0.0) -> None:
        if not dt_s > 0:
            raise ValueError(f"dt_s must be > 0, got {dt_s!r}")
        self.dt_s = float(dt_s)
        self.setpoint_mps = 0.0
        self.airspeed_mps = 0.0
        self.set_time_constant(time_constant_s)
        self.set_max_rate(max_rate_mps2)

    def set_time_constant(self, time_constant_s: float) -> None:
        """Change tau (s, >= 0); takes effect at the next step."""
        if not (math.isfinite(time_constant_s) and time_constant_s >= 0):
            raise ValueError(f"time constant must be finite and >= 0, got {time_constant_s!r}")
        self.time_constant_s = float(time_constant_s)
        self._decay = math.exp(-self.dt_s / time_constant_s) if time_constant_s > 0 else 0.0

    def set_max_rate(self, max_rate_mps2: float) -> None:
        """Limit |dU/dt| (m/s^2); 0 disables the limit."""
        if not (math.isfinite(max_rate_mps2) and max_rate_mps2 >= 0):
            raise ValueError(f"max rate must be finite and >= 0, got {max_rate_mps2!r}")
        self.max_rate_mps2 = float(max_rate_mps2)

    def step(self) -> float:
        """Advance one dt; returns the airspeed at the end of the step (m/s)."""
        target = self.setpoint_mps + (self.airspeed_mps - self.setpoint_mps) * self._decay
        if self.max_rate_mps2 > 0:
            dmax = self.max_rate_mps2 * self.dt_s
            target = min(max(target, self.airspeed_mps - dmax), self.airspeed_mps + dmax)
        if target == self.airspeed_mps:  # the lag can no longer move in floating point (it stalls ~200 ulp short,
            target = self.setpoint_mps  # ~4e-13 m/s at 10 m/s): it has arrived, and the rig skips its per-step calls
        self.airspeed_mps = max(0.0, target)
        return self.airspeed_mps

    @property
    def settled(self) -> bool:
        """At its set-point (>= 0): :meth:`step` leaves the airspeed as it is, bit for bit."""
        return self.airspeed_mps == self.setpoint_mps and self.setpoint_mps >= 0.0

    def reset(self) -> None:
        """Tunnel at rest, set-point 0."""
        self.setpoint_mps = 0.0
        self.airspeed_mps = 0.0
