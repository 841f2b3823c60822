"""The emulated tunnel: commands -> actuator/shaker -> model step -> readings -> sinks. No ROS here."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from panel_rig.rig.actuator import AirspeedActuator
from panel_rig.rig.reading import Reading, Sink
from panel_rig.rig.safety import (
    SafetyLimits,
    check_airspeed,
    check_amplitude,
    check_force,
    check_frequency,
    check_tip,
)
from panel_rig.rig.shaker import Shaker

log = logging.getLogger(__name__)

RUNNING = "running"
ABORTED = "aborted"


class StepperLike(Protocol):
    """What the rig needs of ``panel_rig.model.stepper.Stepper``."""

    dt_s: float
    time_s: float
    q: np.ndarray
    qdot: np.ndarray
    tip_w_over_L: float
    aero_force_npm: np.ndarray

    def step(self, airspeed_mps: float, tip_force_npm: float) -> None: ...

    def shape_w_over_L(self, x_over_L: np.ndarray) -> np.ndarray: ...

    def reset(self) -> None: ...


def _divergence_types() -> tuple[type[BaseException], ...]:
    """The stepper's typed divergence error (if the model package exists), plus FloatingPointError."""
    try:
        from panel_rig.model.stepper import DivergenceError
    except ImportError:
        return (FloatingPointError,)
    return (DivergenceError, FloatingPointError)


@dataclass(frozen=True)
class CommandResult:
    """Outcome of a command: accepted, or refused with a reason."""

    accepted: bool
    reason: str = ""


@dataclass(frozen=True)
class TunnelSettings:
    """Actuator dynamics: first-order lag tau (s) and optional rate limit (m/s^2, 0 = none)."""

    time_constant_s: float = 1.0
    max_rate_mps2: float = 0.0


class Rig:
    """A wind tunnel around one stepper, advanced in whole physics steps of ``stepper.dt_s``.

    Bad commands are refused (counted, with a reason) and the rig carries on. A tip beyond
    ``limits.max_tip_w_over_L`` or a diverging model aborts: set-point 0, shaker off, commands refused
    until :meth:`reset`. A diverged model is reset to rest so no NaN ever leaves the rig.
    """

    def __init__(
        self,
        stepper: StepperLike,
        panel_length_m: float,
        limits: SafetyLimits | None = None,
        tunnel: TunnelSettings | None = None,
        sinks: Iterable[Sink] = (),
        divergence_errors: tuple[type[BaseException], ...] | None = None,
    ) -> None:
        self.stepper = stepper
        self.dt_s = float(stepper.dt_s)
        self.panel_length_m = float(panel_length_m)
        self.limits = limits or SafetyLimits()
        tunnel = tunnel or TunnelSettings()
        self.actuator = AirspeedActuator(self.dt_s, tunnel.time_constant_s, tunnel.max_rate_mps2)
        self.shaker = Shaker(self.dt_s)
        self.sinks: list[Sink] = list(sinks)
        self._divergence = divergence_errors or _divergence_types()
        self.state = RUNNING
        self.abort_reason = ""
        self.rejected_count = 0
        self.last_rejection = ""
        self.overrun_count = 0
        self.abort_count = 0
        self.sink_errors = 0
        self.steps = 0
        self._time_s = 0.0
        self._last_force_npm = 0.0

    # ---- time -------------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        """Simulated time (s): whole steps since start (not reset by :meth:`reset`)."""
        return self._time_s

    def step(self) -> None:
        """One physics step with the actuator's airspeed and the shaker's force for that step."""
        airspeed = self.actuator.airspeed_mps
        force = self.shaker.step()
        self._last_force_npm = force
        try:
            self.stepper.step(airspeed, force)
            tip = float(self.stepper.tip_w_over_L)
            if not (math.isfinite(tip) and np.all(np.isfinite(self.stepper.q))):
                raise FloatingPointError("model state is not finite")
        except self._divergence as exc:
            self.stepper.reset()
            self.abort(f"model diverged at U = {airspeed:.3g} m/s: {exc}")
        except Exception as exc:  # noqa: BLE001 (any model failure aborts the run, never the process)
            self.stepper.reset()
            self.abort(f"model error at U = {airspeed:.3g} m/s: {type(exc).__name__}: {exc}")
        else:
            if self.state == RUNNING:
                reason = check_tip(tip, self.limits)
                if reason:
                    self.abort(reason)
        self.actuator.step()
        self.steps += 1
        self._time_s = self.steps * self.dt_s

    def advance_to(self, time_s: float, max_steps: int | None = None) -> int:
        """Run whole steps while the next one ends at or before ``time_s`` (within 1e-9 s).

        Returns the number of steps run (at most ``max_steps`` if given).
        """
        n = math.floor((time_s - self._time_s) / self.dt_s + 1e-6)
        if max_steps is not None:
            n = min(n, max_steps)
        for _ in range(max(n, 0)):
            self.step()
        return max(n, 0)

    def note_overrun(self) -> None:
        """Count a clock tick the rig could not keep up with (the caller decides what that means)."""
        self.overrun_count += 1

    # ---- commands -----------------------------------------------------------------------------
    def _command(self, name: str, value: Any, check: Callable[[], str | None], apply: Callable[[], None]) -> CommandResult:
        if self.state != RUNNING:
            reason = f"rig aborted ({self.abort_reason}); call reset"
        else:
            try:
                reason = check()
            except Exception as exc:  # noqa: BLE001 (a bad value must never stop the rig)
                reason = f"{name}: invalid value {value!r} ({exc})"
        accepted = reason is None
        if accepted:
            apply()
        else:
            self.rejected_count += 1
            self.last_rejection = f"{name}: {reason}"
        self._notify_command(name, value, accepted)
        return CommandResult(accepted, "" if accepted else str(reason))

    def command_airspeed(self, airspeed_mps: float) -> CommandResult:
        """Tunnel set-point (m/s); the actuator follows it with its lag."""
        def apply() -> None:
            self.actuator.setpoint_mps = float(airspeed_mps)
        return self._command("airspeed_cmd", airspeed_mps, lambda: check_airspeed(airspeed_mps, self.limits), apply)

    def command_force(self, force_npm: float) -> CommandResult:
        """Held trailing-edge force (N/m span)."""
        def apply() -> None:
            self.shaker.held_force_npm = float(force_npm)
        return self._command("shaker/force_cmd", force_npm, lambda: check_force(force_npm, self.limits), apply)

    def command_amplitude(self, amplitude_npm: float) -> CommandResult:
        """Sine generator amplitude (N/m span)."""
        def apply() -> None:
            self.shaker.amplitude_npm = float(amplitude_npm)
        return self._command(
            "shaker/amplitude_cmd", amplitude_npm, lambda: check_amplitude(amplitude_npm, self.limits), apply
        )

    def command_frequency(self, frequency_hz: float) -> CommandResult:
        """Sine generator frequency (Hz); the phase stays continuous."""
        def apply() -> None:
            self.shaker.frequency_hz = float(frequency_hz)
        return self._command(
            "shaker/frequency_cmd",
            frequency_hz,
            lambda: check_frequency(frequency_hz, self.limits, self.dt_s),
            apply,
        )

    def abort(self, reason: str = "operator abort") -> None:
        """Emergency stop: set-point 0 (the actuator ramps down), shaker off, state aborted."""
        self.actuator.setpoint_mps = 0.0
        self.shaker.reset()
        if self.state != ABORTED:
            self.abort_count += 1
            log.warning("rig aborted at t = %.3f s: %s", self._time_s, reason)
        self.state = ABORTED
        self.abort_reason = reason

    def reset(self) -> None:
        """Model at rest, airspeed 0, shaker off, state running. Time and counters continue."""
        self.stepper.reset()
        self.actuator.reset()
        self.shaker.reset()
        self._last_force_npm = 0.0
        self.state = RUNNING
        self.abort_reason = ""

    def set_limits(self, **changes: float) -> None:
        """Change safety limits live (validated; raises ValueError)."""
        self.limits = replace(self.limits, **changes)

    # ---- readings ------------------------------------------------------------------------------
    def reading(self) -> Reading:
        """The current sample (copies of the model arrays)."""
        st = self.stepper
        tip = float(st.tip_w_over_L)
        return Reading(
            time_s=self._time_s,
            airspeed_mps=self.actuator.airspeed_mps,
            shaker_force_npm=self._last_force_npm,
            tip_w_m=tip * self.panel_length_m,
            tip_w_over_L=tip,
            q=np.array(st.q, dtype=float),
            qdot_per_s=np.array(st.qdot, dtype=float),
            aero_force_npm=np.array(st.aero_force_npm, dtype=float),
            state=self.state,
        )

    def shape_w_over_L(self, x_over_L: np.ndarray) -> np.ndarray:
        """Panel deflection w/L at the given x/L (0 = clamped edge, 1 = trailing edge)."""
        return np.asarray(self.stepper.shape_w_over_L(np.asarray(x_over_L, dtype=float)), dtype=float)

    def emit(self) -> Reading:
        """Take a reading and hand it to every sink; a failing sink is logged and counted, never fatal."""
        reading = self.reading()
        for sink in list(self.sinks):
            try:
                sink.on_reading(reading)
            except Exception:  # noqa: BLE001 (a sink must never stop the rig)
                self._sink_failed(sink)
        return reading

    def _notify_command(self, name: str, value: Any, accepted: bool) -> None:
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = math.nan
        for sink in list(self.sinks):
            try:
                sink.on_command(name, v, accepted, self._time_s)
            except Exception:  # noqa: BLE001 (a sink must never stop the rig)
                self._sink_failed(sink)

    def _sink_failed(self, sink: Sink) -> None:
        self.sink_errors += 1
        if self.sink_errors <= 5:
            log.exception("sink %r failed", sink)

    def close(self) -> None:
        """Close every sink (errors logged)."""
        for sink in self.sinks:
            try:
                sink.close()
            except Exception:
                log.exception("closing sink %r failed", sink)
        self.sinks.clear()
