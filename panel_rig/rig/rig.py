"""The emulated tunnel: commands -> actuator/shaker -> model step -> readings -> sinks. No ROS here."""

from __future__ import annotations

import logging
import math
import traceback
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from panel_rig.rig.actuator import AirspeedActuator
from panel_rig.rig.control import ControlActuator, ControlSettings, check_control_force, check_stamp
from panel_rig.rig.reading import Reading, ReadingBlock, Sink, SinkStop
from panel_rig.rig.safety import (
    SafetyLimits,
    check_airspeed,
    check_amplitude,
    check_force,
    check_frequency,
    check_tip,
)
from panel_rig.rig.sensor import TipSensor
from panel_rig.rig.shaker import Shaker
from panel_rig.rig.turbulence import Turbulence
from panel_rig.topics import CONTROL_TOPIC

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


class EventLogger(Protocol):
    """Where the rig reports events: rclpy's node logger and Python's ``logging.Logger`` both fit."""

    def info(self, message: str) -> Any: ...

    def warning(self, message: str) -> Any: ...

    def error(self, message: str) -> Any: ...


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


def tunnel_extras(cfg: Any, stepper: Any) -> dict[str, Any]:
    """The turbulence and the tip sensor of a PanelConfig (``tunnel.turbulence.*``, ``sensor.*``) for a stepper,
    as keyword arguments of :class:`Rig`; off / perfect when the configuration says so."""
    from panel_rig.rig.sensor import SensorSettings
    from panel_rig.rig.turbulence import TurbulenceSettings

    ts = TurbulenceSettings.from_config(cfg)
    turb = Turbulence(ts, stepper.dt_s, stepper.x_colloc_m, cfg.chord_m) if ts.on else None
    return {"turbulence": turb, "sensor": TipSensor(SensorSettings.from_config(cfg), stepper.dt_s)}


class Rig:
    """A wind tunnel around one stepper, advanced in whole physics steps of ``stepper.dt_s``.

    Bad commands are refused (counted, with a reason) and the rig carries on. A tip beyond
    ``limits.tip_limit(L)`` (wall contact) or a diverging model aborts: set-point 0, shaker off, commands refused
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
        logger: EventLogger | None = None,
        control: ControlSettings | None = None,
        turbulence: Turbulence | None = None,
        sensor: TipSensor | None = None,
    ) -> None:
        """``logger``: where rig events (aborts, limits acting) go; anything with ``info``/``warning``/``error``
        taking one string (the ROS node's logger, or by default this module's Python logger). ``control``: the
        control actuator's settings (its force adds to the shaker's at the trailing edge)."""
        self.log: EventLogger = logger if logger is not None else log
        self.stepper = stepper
        self.dt_s = float(stepper.dt_s)
        self.panel_length_m = float(panel_length_m)
        self.limits = limits or SafetyLimits()
        tunnel = tunnel or TunnelSettings()
        self.actuator = AirspeedActuator(self.dt_s, tunnel.time_constant_s, tunnel.max_rate_mps2)
        self.shaker = Shaker(self.dt_s)
        self.control = ControlActuator(self.dt_s, control, logger=self.log)  # closed-loop control (issue 13)
        self.sinks: list[Sink] = list(sinks)
        self._divergence = divergence_errors or _divergence_types()
        self.state = RUNNING
        self.abort_reason = ""
        self.abort_time_s = math.nan  # simulated time of the last abort
        self.last_abort_reason = ""  # the last abort's reason, kept after a reset (abort_reason is the present one)
        self.rejected_count = 0
        self.last_rejection = ""
        self.overrun_count = 0
        self.abort_count = 0
        self.sink_errors = 0
        self.steps = 0
        self._time_s = 0.0
        self._last_force_npm = 0.0
        self._can_block = callable(getattr(stepper, "advance_sampled", None))
        # the tunnel's turbulence (u' adds to the airspeed of the step, w' is the gust upwash along the chord) and
        # the tip sensor between the model's truth and the reading; None: a quiet tunnel, a perfect sensor
        self.turbulence = turbulence if turbulence is not None and turbulence.on else None
        self.sensor = sensor if sensor is not None and not sensor.settings.perfect else None
        self._sensed_tip_m = 0.0  # the sensor's filtered, delayed tip after the last step

    # ---- time -------------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        """Simulated time (s): whole steps since start (not reset by :meth:`reset`)."""
        return self._time_s

    def step(self) -> None:
        """One physics step with the actuator's airspeed and the shaker's force for that step."""
        airspeed = self.actuator.airspeed_mps
        shaker = self.shaker.step()
        self._last_force_npm = shaker
        force = shaker + self.control.step(self._time_s)
        try:
            if self.turbulence is not None:
                u, w = self.turbulence.block(np.array([airspeed]))
                self.stepper.step(max(airspeed + float(u[0]), 0.0), force, w[0])  # type: ignore[call-arg]
            else:
                self.stepper.step(airspeed, force)
            tip = float(self.stepper.tip_w_over_L)
            if self.sensor is not None:
                self._sensed_tip_m = float(self.sensor.push([tip * self.panel_length_m])[0])
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
                reason = check_tip(tip, self.limits.tip_limit(self.panel_length_m))
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
        if n > 0:
            self.advance_samples([n])
        return max(n, 0)

    def advance_samples(self, counts: Sequence[int]) -> ReadingBlock:
        """Run ``counts[i]`` steps, then take sample i; all samples in one block.

        The same as :meth:`step` per step and :meth:`reading` per sample, but the model marches the whole
        block in one compiled call (if the stepper has ``advance_sampled``). An abort or divergence inside
        the block is replayed step by step, so safety behaves exactly as in :meth:`step`.
        """
        counts = [max(int(c), 0) for c in counts]
        if not self._can_block:
            return ReadingBlock.of([self._steps_then_reading(c) for c in counts])
        parts: list[ReadingBlock] = []
        i = 0
        while i < len(counts):
            if counts[i] == 0:
                parts.append(ReadingBlock.of([self.reading()]))
                i += 1
                continue
            j = i
            while j < len(counts) and counts[j] > 0:
                j += 1
            block, consumed = self._march_block(counts[i:j])
            parts.append(block)
            i += len(block)
            if i < j:  # interrupted inside sample i: finish it step by step (the event happens there)
                parts.append(ReadingBlock.of([self._steps_then_reading(counts[i] - consumed)]))
                i += 1
        if len(parts) == 1:
            return parts[0]
        return ReadingBlock(*(np.concatenate([getattr(p, f) for p in parts]) for f in (
            "time_s", "airspeed_mps", "shaker_force_npm", "tip_w_m", "tip_w_over_L", "q", "qdot_per_s",
            "aero_force_npm")), state=self.state)

    def _steps_then_reading(self, n: int) -> Reading:
        for _ in range(n):
            self.step()
        return self.reading()

    def _inputs(self, n: int) -> tuple[list[float], list[float], list[float], list[float]]:
        """Per-step airspeed (at the start of each step), total force (shaker + control), airspeed after it and
        the shaker's own force; advances the actuator, the shaker and the control actuator by n steps (exactly
        as :meth:`step` does)."""
        act, shaker, control = self.actuator, self.shaker, self.control
        if control.quiet and shaker.amplitude_npm == 0.0:  # constant forces: no per-step calls (fast mode's common case)
            held = shaker.force_npm
            shaker.advance_phase(n)
            if act.settled:
                u_in = u_out = [act.airspeed_mps] * n
            else:
                u_in, u_out = [0.0] * n, [0.0] * n
                for k in range(n):
                    u_in[k] = act.airspeed_mps
                    u_out[k] = act.step()
            return u_in, [held + 0.0] * n, u_out, [held] * n
        u_in, force, u_out, shaken = [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n
        for k in range(n):
            u_in[k] = act.airspeed_mps
            shaken[k] = shaker.step()
            force[k] = shaken[k] + control.step((self.steps + k) * self.dt_s)
            u_out[k] = act.step()
        return u_in, force, u_out, shaken

    def _march_block(self, counts: list[int]) -> tuple[ReadingBlock, int]:
        """March sum(counts) steps (every count >= 1) in one call; stops before an event (tip over the limit,
        divergence, model error). Returns the completed samples and the steps taken into the next one."""
        ends = np.cumsum(counts)
        n = int(ends[-1])
        u0, phase0, control0 = self.actuator.airspeed_mps, self.shaker.phase_rad, self.control.snapshot()
        u_in, force, u_out, shaken = self._inputs(n)
        bound = self.limits.tip_limit(self.panel_length_m) if self.state == RUNNING else math.inf
        u_model, gust, snap = np.array(u_in), None, None
        if self.turbulence is not None:
            snap = self.turbulence.snapshot()
            u_prime, gust = self.turbulence.block(u_model)
            u_model = np.maximum(u_model + u_prime, 0.0)
        try:
            kw = {} if gust is None else {"gust_upwash_mps": gust}
            run = self.stepper.advance_sampled(u_model, np.array(force), ends, bound, **kw)  # type: ignore[attr-defined]
            done, samples = run.steps_done, run.samples_done
        except Exception:  # noqa: BLE001 (replayed step by step, where step() turns it into an abort)
            run, done, samples = None, 0, 0
        if done < n:  # rewind the actuator, the shaker and the turbulence to the event
            self.actuator.airspeed_mps, self.shaker.phase_rad = u0, phase0
            self.control.restore(control0)
            self._inputs(done)
            if snap is not None:
                self.turbulence.restore(snap)  # type: ignore[union-attr]
                self.turbulence.block(np.array(u_in[:done]))  # type: ignore[union-attr]
        measured = None
        if self.sensor is not None and run is not None and done:
            sensed = self.sensor.push(run.tip_w_over_L[:done] * self.panel_length_m)
            self._sensed_tip_m = float(sensed[-1])
            measured = self.sensor.measure(sensed[ends[:samples] - 1])
        if done:
            self._last_force_npm = shaken[done - 1]
        start = self.steps
        self.steps += done
        self._time_s = self.steps * self.dt_s
        idx = ends[:samples] - 1
        if run is None or samples == 0:
            empty = np.zeros(0)
            nm = len(np.atleast_1d(self.stepper.q))
            return ReadingBlock(empty, empty, empty, empty, empty, *(np.zeros((0, nm)),) * 3, state=self.state), done
        tip = run.tip_w_over_L[idx]
        block = ReadingBlock((start + ends[:samples]) * self.dt_s, np.asarray(u_out)[idx], np.asarray(shaken)[idx],
                             tip * self.panel_length_m if measured is None else measured, tip, run.q, run.qdot_per_s,
                             run.aero_force_npm, self.state)
        consumed = done - (int(ends[samples - 1]) if samples else 0)
        return block, consumed

    def note_overrun(self) -> None:
        """Count a clock tick the rig could not keep up with (the caller decides what that means)."""
        self.overrun_count += 1

    # ---- commands -----------------------------------------------------------------------------
    def _command(self, name: str, value: Any, check: Callable[[], str | None], apply: Callable[[], None],
                 zero_when_aborted: bool = True) -> CommandResult:
        """Check and apply one command. An aborted rig refuses all but 0 for the tunnel and the shaker (wind or
        shaker off is what the abort did already: an operator's stop sequence is not refused)."""
        if self.state != RUNNING and not (zero_when_aborted and _is_zero(value)):
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
            self.actuator.setpoint_mps = float(airspeed_mps) + 0.0  # -0.0 is 0 (it showed as "-0.0000")
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

    # ---- closed-loop control (issue 13; logic in panel_rig.rig.control) ------------------------------------
    def command_control(self, force_npm: float, stamp_s: float, arrival_s: float | None = None) -> CommandResult:
        """Control force (N/m) answering the reading of simulated time ``stamp_s``, received at simulated time
        ``arrival_s`` (default: now). Acts from the first step starting at or after its arrival; its age is
        recorded. Rejected if not finite, beyond the saturation, or older than the watchdog timeout."""
        arrival = self._time_s if arrival_s is None else float(arrival_s)

        def check() -> str | None:
            return check_control_force(force_npm, self.control.settings) or check_stamp(
                stamp_s, arrival, self.control.settings)

        return self._command(CONTROL_TOPIC, force_npm, check,
                             lambda: self.control.command(float(force_npm), float(stamp_s), arrival),
                             zero_when_aborted=False)

    def set_control(self, **changes: float) -> None:
        """Change the control actuator's settings live (validated; raises ValueError)."""
        self.control.configure(replace(self.control.settings, **changes))

    # ---- emergency stop and reset ----------------------------------------------------------------------------
    def abort(self, reason: str = "operator abort") -> None:
        """Emergency stop: set-point 0 (the actuator ramps down), shaker and control actuator off, state aborted.
        An aborted rig keeps the first abort's reason and time (an operator's abort after a tip-limit abort
        replaced the reason the run stopped for)."""
        self.actuator.setpoint_mps = 0.0
        self.shaker.reset()
        self.control.reset()
        if self.state == ABORTED:
            return
        self.abort_count += 1
        self.abort_time_s = self._time_s
        self.log.error(f"rig aborted at t = {self._time_s:.3f} s: {reason}")
        self.state = ABORTED
        self.abort_reason = self.last_abort_reason = reason

    def reset(self) -> None:
        """Model at rest, airspeed 0, shaker off, state running. Time and counters continue."""
        self.stepper.reset()
        self.actuator.reset()
        self.shaker.reset()
        self.control.reset()
        self._last_force_npm = 0.0
        self.state = RUNNING
        self.abort_reason = ""

    def set_limits(self, **changes: float) -> None:
        """Change safety limits live (validated; raises ValueError). They act on the present state: an airspeed
        set-point above a lowered airspeed limit is brought down to it (the tunnel ramps down with its lag), and a
        tip already beyond a lowered tip limit aborts the run; a shaker force, amplitude or frequency above its
        lowered limit is brought down to it at once. All are logged."""
        self.limits = replace(self.limits, **changes)
        lim, act, sh = self.limits, self.actuator, self.shaker
        if act.setpoint_mps > lim.max_airspeed_mps:
            self.log.warning(f"airspeed limit lowered to {lim.max_airspeed_mps:g} m/s: set-point "
                             f"{act.setpoint_mps:g} -> {lim.max_airspeed_mps:g} m/s, tunnel ramping down")
            act.setpoint_mps = lim.max_airspeed_mps
        if abs(sh.held_force_npm) > lim.max_force_npm:
            held = math.copysign(lim.max_force_npm, sh.held_force_npm)
            self.log.warning(f"shaker force limit lowered to {lim.max_force_npm:g} N/m: held force "
                             f"{sh.held_force_npm:g} -> {held:g} N/m")
            sh.held_force_npm = held
        if sh.amplitude_npm > lim.max_amplitude_npm:
            self.log.warning(f"shaker amplitude limit lowered to {lim.max_amplitude_npm:g} N/m: amplitude "
                             f"{sh.amplitude_npm:g} -> {lim.max_amplitude_npm:g} N/m")
            sh.amplitude_npm = lim.max_amplitude_npm
        if sh.frequency_hz > lim.max_frequency_hz:
            self.log.warning(f"shaker frequency limit lowered to {lim.max_frequency_hz:g} Hz: frequency "
                             f"{sh.frequency_hz:g} -> {lim.max_frequency_hz:g} Hz")
            sh.frequency_hz = lim.max_frequency_hz
        if self.state == RUNNING:
            reason = check_tip(float(self.stepper.tip_w_over_L), self.limits.tip_limit(self.panel_length_m))
            if reason:
                self.abort(f"tip limit lowered below the present tip: {reason}")

    # ---- readings ------------------------------------------------------------------------------
    def reading(self) -> Reading:
        """The current sample (copies of the model arrays); ``tip_w_m`` is the sensor's reading, ``tip_w_over_L``
        the model's truth."""
        st = self.stepper
        tip = float(st.tip_w_over_L)
        measured = tip * self.panel_length_m
        if self.sensor is not None:
            measured = float(self.sensor.measure(np.array([self._sensed_tip_m]))[0])
        return Reading(
            time_s=self._time_s,
            airspeed_mps=self.actuator.airspeed_mps,
            shaker_force_npm=self._last_force_npm,
            tip_w_m=measured,
            tip_w_over_L=tip,
            q=np.array(st.q, dtype=float),
            qdot_per_s=np.array(st.qdot, dtype=float),
            aero_force_npm=np.array(st.aero_force_npm, dtype=float),
            state=self.state,
        )

    def shape_w_over_L(self, x_over_L: np.ndarray, q: np.ndarray | None = None) -> np.ndarray:
        """Panel deflection w/L at the given x/L (0 = clamped edge, 1 = trailing edge); of the present state, or
        of the modal coordinates ``q`` of a sample (steppers whose ``shape_w_over_L`` takes ``q``)."""
        x = np.asarray(x_over_L, dtype=float)
        if q is None:
            return np.asarray(self.stepper.shape_w_over_L(x), dtype=float)
        return np.asarray(self.stepper.shape_w_over_L(x, q=q), dtype=float)  # type: ignore[call-arg]

    def emit(self) -> Reading:
        """Take a reading and hand it to every sink; a failing sink is logged and counted, never fatal (but a
        :class:`~panel_rig.rig.reading.SinkStop`, which ends the caller's run)."""
        reading = self.reading()
        for sink in list(self.sinks):
            try:
                sink.on_reading(reading)
            except SinkStop:
                raise
            except Exception:  # noqa: BLE001 (a sink must never stop the rig)
                self._sink_failed(sink)
        return reading

    def emit_block(self, block: ReadingBlock) -> None:
        """Hand a block of samples to every sink (``on_block`` if it has one, else ``on_reading`` each)."""
        if not len(block) or not self.sinks:
            return
        singles: list[Reading] | None = None
        for sink in list(self.sinks):
            try:
                on_block = getattr(sink, "on_block", None)
                if on_block is not None:
                    on_block(block)
                else:
                    singles = singles if singles is not None else block.readings()
                    for r in singles:
                        sink.on_reading(r)
            except SinkStop:
                raise
            except Exception:  # noqa: BLE001 (a sink must never stop the rig)
                self._sink_failed(sink)

    def _notify_command(self, name: str, value: Any, accepted: bool) -> None:
        try:
            v = float(value)
        except (TypeError, ValueError):
            v = math.nan
        for sink in list(self.sinks):
            try:
                sink.on_command(name, v, accepted, self._time_s)
            except SinkStop:
                raise
            except Exception:  # noqa: BLE001 (a sink must never stop the rig)
                self._sink_failed(sink)

    def _sink_failed(self, sink: Sink) -> None:
        self.sink_errors += 1
        if self.sink_errors <= 5:
            self.log.error(f"sink {sink!r} failed: {traceback.format_exc(limit=3)}")

    def close(self) -> None:
        """Close every sink (errors logged)."""
        for sink in self.sinks:
            try:
                sink.close()
            except Exception as exc:  # noqa: BLE001 (every other sink still gets closed)
                self.log.error(f"closing sink {type(sink).__name__} failed: {type(exc).__name__}: {exc}")
        self.sinks.clear()


def _is_zero(value: Any) -> bool:
    """A command value of exactly 0 (a number; anything else is checked as usual)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and value == 0.0
