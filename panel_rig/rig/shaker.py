"""The shaker at the trailing edge: a held direct force plus a built-in sine generator (N/m span)."""

from __future__ import annotations

import math

TWO_PI = 2.0 * math.pi


class Shaker:
    """Force ``F = held + A sin(phase)``; the phase integrates ``2 pi f dt`` so it stays continuous
    when the frequency changes."""

    def __init__(self, dt_s: float) -> None:
        if not dt_s > 0:
            raise ValueError(f"dt_s must be > 0, got {dt_s!r}")
        self.dt_s = float(dt_s)
        self.reset()

    def reset(self) -> None:
        """No force, no sine, phase 0."""
        self.held_force_npm = 0.0
        self.amplitude_npm = 0.0
        self.frequency_hz = 0.0
        self.phase_rad = 0.0

    @property
    def force_npm(self) -> float:
        """The force applied now (N/m)."""
        return self.held_force_npm + self.amplitude_npm * math.sin(self.phase_rad)

    def step(self) -> float:
        """The force for the coming step (evaluated at its start), then advance the phase by one dt."""
        force = self.force_npm
        self.phase_rad = (self.phase_rad + TWO_PI * self.frequency_hz * self.dt_s) % TWO_PI
        return force

    def advance_phase(self, n: int) -> None:
        """The phase after n calls of :meth:`step`, bit for bit (for a block in which the sine is off)."""
        inc, phase = TWO_PI * self.frequency_hz * self.dt_s, self.phase_rad
        if inc != 0.0:
            for _ in range(n):
                phase = (phase + inc) % TWO_PI
        self.phase_rad = phase
