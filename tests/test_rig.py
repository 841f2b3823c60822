"""The emulated tunnel (panel_rig.rig) against a tiny fake model: lag, shaker, safety, abort/reset."""

from __future__ import annotations

import math

import numpy as np
import pytest

from panel_rig.rig.actuator import AirspeedActuator
from panel_rig.rig.reading import Reading
from panel_rig.rig.rig import ABORTED, RUNNING, Rig, TunnelSettings
from panel_rig.rig.safety import SafetyLimits
from panel_rig.rig.shaker import Shaker

DT = 1.0 / 2048.0


class FakeDivergence(RuntimeError):
    """Stands in for panel_rig.model.stepper.DivergenceError."""


class FakeStepper:
    """A damped linear oscillator with the Stepper interface (one mode, w/L = q).

    ``gain`` scales how strongly the airspeed drives it (negative damping above ``flutter_mps``).
    """

    def __init__(self, dt_s: float = DT, f_hz: float = 10.0, zeta: float = 0.02, flutter_mps: float = 1e9) -> None:
        self.dt_s = dt_s
        self.omega = 2 * math.pi * f_hz
        self.zeta = zeta
        self.flutter_mps = flutter_mps
        self.diverge_next = False
        self.reset()

    def reset(self) -> None:
        self.time_s = 0.0
        self.q = np.zeros(1)
        self.qdot = np.zeros(1)
        self.aero_force_npm = np.zeros(1)

    @property
    def tip_w_over_L(self) -> float:
        return float(self.q[0])

    def shape_w_over_L(self, x_over_L: np.ndarray) -> np.ndarray:
        return self.q[0] * np.asarray(x_over_L) ** 2

    def step(self, airspeed_mps: float, tip_force_npm: float) -> None:
        if self.diverge_next:
            self.q[:] = np.nan
            raise FakeDivergence("state is not finite")
        zeta = self.zeta * (1.0 - airspeed_mps / self.flutter_mps)
        acc = tip_force_npm - 2 * zeta * self.omega * self.qdot - self.omega**2 * self.q
        self.aero_force_npm = np.array([airspeed_mps * 1e-3 * self.q[0]])
        self.qdot = self.qdot + self.dt_s * acc  # semi-implicit Euler
        self.q = self.q + self.dt_s * self.qdot
        self.time_s += self.dt_s


class ListSink:
    def __init__(self) -> None:
        self.readings: list[Reading] = []
        self.commands: list[tuple[str, float, bool, float]] = []
        self.closed = False

    def on_reading(self, reading: Reading) -> None:
        self.readings.append(reading)

    def on_command(self, name: str, value: float, accepted: bool, time_s: float) -> None:
        self.commands.append((name, value, accepted, time_s))

    def close(self) -> None:
        self.closed = True


def make_rig(**kw) -> tuple[Rig, FakeStepper, ListSink]:
    st = FakeStepper(**kw)
    sink = ListSink()
    rig = Rig(st, panel_length_m=0.27, limits=SafetyLimits(max_tip_w_over_L=0.5),
              tunnel=TunnelSettings(time_constant_s=0.5), sinks=[sink], divergence_errors=(FakeDivergence,))
    return rig, st, sink


def test_actuator_lag_one_time_constant():
    tau = 0.5
    act = AirspeedActuator(DT, tau)
    act.setpoint_mps = 10.0
    n = round(tau / DT)
    for _ in range(n):
        act.step()
    assert act.airspeed_mps == pytest.approx(10.0 * (1 - math.exp(-1)), rel=0.005)


def test_actuator_lag_arrives_at_its_set_point():
    """The exact lag stalls ~200 ulp short of its set-point in floating point (the step's change rounds away); it
    then snaps to it, so ``settled`` (the rig's fast path without per-step actuator calls) is reached."""
    tau = 0.2
    act = AirspeedActuator(DT, tau)
    act.setpoint_mps = 10.0
    steps = 0
    while not act.settled and steps < round(40 * tau / DT):
        act.step()
        steps += 1
    assert act.settled and act.airspeed_mps == 10.0
    assert steps > round(25 * tau / DT)  # not before the lag itself is within round-off (e^-25 ~ 1e-11)


def test_actuator_rate_limit_and_zero_tau():
    act = AirspeedActuator(DT, 0.0, max_rate_mps2=2.0)
    act.setpoint_mps = 10.0
    for _ in range(2048):
        act.step()
    assert act.airspeed_mps == pytest.approx(2.0, rel=1e-6)
    act.set_max_rate(0.0)
    act.step()
    assert act.airspeed_mps == 10.0
    with pytest.raises(ValueError):
        act.set_time_constant(-1.0)


def test_shaker_phase_continuous_across_frequency_change():
    sh = Shaker(DT)
    sh.amplitude_npm = 1.0
    sh.frequency_hz = 5.0
    forces = [sh.step() for _ in range(300)]
    sh.frequency_hz = 23.0
    forces += [sh.step() for _ in range(300)]
    jumps = np.abs(np.diff(forces))
    # the largest possible change in one step is 2 pi f A dt
    assert jumps.max() <= 2 * math.pi * 23.0 * DT * 1.0001
    sh.held_force_npm = 0.5
    assert sh.force_npm == pytest.approx(0.5 + math.sin(sh.phase_rad))


@pytest.mark.parametrize(
    ("method", "value"),
    [
        ("command_airspeed", math.nan),
        ("command_airspeed", math.inf),
        ("command_airspeed", -1.0),
        ("command_airspeed", 31.0),
        ("command_airspeed", "fast"),
        ("command_force", math.nan),
        ("command_force", 11.0),
        ("command_force", -11.0),
        ("command_amplitude", -0.1),
        ("command_amplitude", math.inf),
        ("command_amplitude", 1e6),
        ("command_frequency", -1.0),
        ("command_frequency", 1e4),
        ("command_frequency", math.nan),
    ],
)
def test_bad_commands_rejected_counted_and_rig_carries_on(method, value):
    rig, _, sink = make_rig()
    result = getattr(rig, method)(value)
    assert not result.accepted and result.reason
    assert rig.rejected_count == 1 and rig.last_rejection
    assert rig.state == RUNNING
    assert sink.commands[-1][2] is False
    assert rig.advance_to(0.01) == math.floor(0.01 / DT + 1e-6)
    assert rig.command_airspeed(5.0).accepted


def test_advance_to_runs_whole_steps():
    rig, _, _ = make_rig()
    assert rig.advance_to(1.0) == 2048
    assert rig.time_s == pytest.approx(1.0)
    assert rig.advance_to(1.0) == 0
    assert rig.advance_to(1.0 + 1.5 * DT) == 1
    assert rig.advance_to(2.0, max_steps=10) == 10


def test_airspeed_follows_command_with_lag():
    rig, _, sink = make_rig()
    assert rig.command_airspeed(12.0).accepted
    rig.advance_to(0.5)
    r = rig.emit()
    assert r.airspeed_mps == pytest.approx(12.0 * (1 - math.exp(-1)), rel=0.005)
    assert sink.readings[-1] is r


def test_negative_zero_airspeed_is_zero():
    """-0.0 passes the airspeed check (it equals 0); taken as it came it showed as "-0.0000" in /diagnostics."""
    rig, _, _ = make_rig()
    assert rig.command_airspeed(-0.0).accepted
    assert math.copysign(1.0, rig.actuator.setpoint_mps) == 1.0


def test_shaker_drives_model_and_reading_is_consistent():
    rig, st, _ = make_rig()
    assert rig.command_amplitude(2.0).accepted
    assert rig.command_frequency(10.0).accepted
    assert rig.command_force(0.1).accepted
    rig.advance_to(1.0)
    r = rig.reading()
    assert r.tip_w_m == pytest.approx(0.27 * r.tip_w_over_L)
    assert abs(r.tip_w_over_L) > 1e-4
    assert r.q.shape == r.qdot_per_s.shape == r.aero_force_npm.shape == (1,)
    assert r.q is not st.q


def test_operator_abort_and_reset():
    rig, _, _ = make_rig()
    rig.command_airspeed(10.0)
    rig.command_amplitude(1.0)
    rig.advance_to(2.0)
    u_before = rig.actuator.airspeed_mps
    rig.abort("test")
    assert rig.state == ABORTED and rig.abort_reason == "test"
    t_abort = rig.abort_time_s
    rig.advance_to(2.1)
    rig.abort("a second press")  # the reason the run stopped for stays (it was replaced)
    assert rig.abort_reason == "test" and rig.abort_time_s == t_abort and rig.abort_count == 1
    assert rig.actuator.setpoint_mps == 0.0 and rig.shaker.amplitude_npm == 0.0
    refused = rig.command_airspeed(5.0)
    assert not refused.accepted and "reset" in refused.reason
    assert rig.rejected_count == 1
    # wind and shaker off are what the abort did: an operator's stop sequence is not logged as refused
    assert rig.command_airspeed(0.0).accepted and rig.command_force(0.0).accepted
    assert rig.command_amplitude(0.0).accepted and rig.rejected_count == 1
    assert not rig.command_control(0.0, rig.time_s).accepted  # the control actuator stays off until reset
    rig.advance_to(2.5)
    assert 0 < rig.actuator.airspeed_mps < u_before  # ramps down, not a jump
    assert rig.reading().state == ABORTED
    rig.reset()
    assert rig.state == RUNNING and rig.actuator.airspeed_mps == 0.0
    assert rig.reading().tip_w_over_L == 0.0
    assert rig.command_airspeed(5.0).accepted
    # the present abort's reason is gone; the last abort's stays with its time (diagnostics: last_abort_reason)
    assert rig.abort_reason == "" and rig.last_abort_reason == "test" and rig.abort_time_s == t_abort


def test_over_limit_tip_aborts():
    rig, _, _ = make_rig(flutter_mps=5.0)  # negative damping above 5 m/s: grows until the limit
    rig.command_airspeed(15.0)
    rig.command_force(1.0)  # a kick off the rest state
    rig.advance_to(30.0)
    assert rig.state == ABORTED and "tip" in rig.abort_reason
    assert rig.abort_count == 1
    assert rig.actuator.setpoint_mps == 0.0


def test_divergence_aborts_and_resets_model_to_rest():
    rig, st, _ = make_rig()
    rig.command_airspeed(10.0)
    rig.command_force(1.0)
    rig.advance_to(0.1)
    st.diverge_next = True
    rig.step()
    st.diverge_next = False
    r = rig.reading()
    assert rig.state == ABORTED and "diverged" in rig.abort_reason
    assert np.all(np.isfinite(r.q)) and np.all(r.q == 0.0) and math.isfinite(r.tip_w_m)
    rig.advance_to(0.2)
    assert np.all(np.isfinite(rig.reading().q))


def test_live_limits_and_sink_failures_are_not_fatal():
    rig, _, sink = make_rig()
    rig.set_limits(max_airspeed_mps=5.0)
    assert not rig.command_airspeed(6.0).accepted
    with pytest.raises(ValueError):
        rig.set_limits(max_airspeed_mps=-1.0)

    class Broken:
        def on_reading(self, reading):
            raise RuntimeError("boom")

        def on_command(self, *a):
            raise RuntimeError("boom")

        def close(self):
            raise RuntimeError("boom")

    rig.sinks.append(Broken())
    rig.emit()
    rig.command_airspeed(1.0)
    assert rig.sink_errors == 2
    rig.close()
    assert sink.closed and not rig.sinks


def test_a_sink_may_stop_the_run_by_raising_sink_stop():
    """The sink contract: SinkStop from a sink ends the caller's run (a flutter test whose recording failed), from a
    reading, a block or a command; the sinks before it got the data, the rig's state is whole (the command applied,
    the time advanced). Before, the flutter test's recorder was a BaseException to get past the rig."""
    from panel_rig.rig.reading import SinkStop

    rig, _, sink = make_rig()

    class Stopping:
        def __init__(self):
            self.calls = 0

        def on_reading(self, reading):
            self.calls += 1
            raise SinkStop("recording failed")

        def on_command(self, *a):
            raise SinkStop("recording failed")

        def close(self):
            pass

    stopping = Stopping()
    rig.sinks.append(stopping)
    with pytest.raises(SinkStop):
        rig.emit()
    with pytest.raises(SinkStop):
        rig.command_airspeed(1.0)
    assert rig.actuator.setpoint_mps == 1.0  # applied before the sinks heard of it
    block = rig.advance_samples([4, 4])
    with pytest.raises(SinkStop):
        rig.emit_block(block)  # a sink without on_block gets each reading: the first one stops it
    assert stopping.calls == 2 and rig.sink_errors == 0
    assert len(sink.readings) == 3  # the sink before it got the reading and the whole block


def test_real_stepper_safety_abort_and_divergence_reset():
    """With panel_rig.model.stepper (if present): above flutter the tip limit aborts; a divergence
    (the model's own bound, set low here) aborts and leaves the model at rest, never NaN."""
    stepper_mod = pytest.importorskip("panel_rig.model.stepper")
    from panel_rig.config import load_config

    cfg = load_config()
    rig = Rig(stepper_mod.Stepper(cfg), cfg.panel_length_m, limits=SafetyLimits(max_tip_w_over_L=0.05),
              tunnel=TunnelSettings(time_constant_s=0.2))
    rig.command_force(0.05)
    rig.command_airspeed(16.0)
    rig.advance_to(20.0)
    assert rig.state == ABORTED and "tip" in rig.abort_reason
    assert rig.actuator.setpoint_mps == 0.0

    low = cfg.replace(max_tip_w_over_L=0.05)
    rig = Rig(stepper_mod.Stepper(low), low.panel_length_m, limits=SafetyLimits(max_tip_w_over_L=1.0),
              tunnel=TunnelSettings(time_constant_s=0.2))
    rig.command_force(0.05)
    rig.command_airspeed(16.0)
    rig.advance_to(20.0)
    assert rig.state == ABORTED and "diverged" in rig.abort_reason
    r = rig.reading()
    assert np.all(np.isfinite(np.r_[r.q, r.qdot_per_s, r.aero_force_npm])) and math.isfinite(r.tip_w_m)


class ListLogger:
    """Collects rig events (the node passes its ROS logger here)."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def info(self, message: str) -> None:
        self.lines.append(("info", message))

    def warning(self, message: str) -> None:
        self.lines.append(("warning", message))

    def error(self, message: str) -> None:
        self.lines.append(("error", message))


def test_lowered_limits_act_on_the_present_and_are_logged():
    """A lowered airspeed limit brings the set-point down (the tunnel ramps with its lag); a lowered tip limit
    below the present tip aborts; both, and the abort, go to the rig's logger."""
    log = ListLogger()
    st = FakeStepper()
    rig = Rig(st, 0.27, limits=SafetyLimits(max_tip_w_over_L=0.5), tunnel=TunnelSettings(0.5), logger=log)
    rig.command_airspeed(10.0)
    rig.advance_to(3.0)
    assert rig.actuator.airspeed_mps > 9.0
    rig.set_limits(max_airspeed_mps=4.0)
    assert rig.actuator.setpoint_mps == 4.0 and rig.state == RUNNING
    assert any(level == "warning" and "airspeed limit lowered" in text for level, text in log.lines)
    rig.advance_to(3.1)
    assert 4.0 < rig.actuator.airspeed_mps < 10.0  # a ramp, not a jump
    rig.advance_to(8.0)
    assert rig.actuator.airspeed_mps == pytest.approx(4.0, abs=1e-3)
    st.q[:] = 0.2  # the panel is deflected now
    rig.set_limits(max_tip_w_over_L=0.3)
    assert rig.state == RUNNING  # still inside
    rig.set_limits(max_tip_w_over_L=0.1)
    assert rig.state == ABORTED and "tip limit lowered" in rig.abort_reason
    assert any(level == "error" and "rig aborted" in text for level, text in log.lines)


def test_lowered_shaker_limits_act_on_the_present_force_and_are_logged():
    """A lowered shaker force limit left a larger held force acting (only new commands were refused): the force,
    the sine's amplitude and frequency above their lowered limits come down to them at once."""
    log = ListLogger()
    rig = Rig(FakeStepper(), 0.27, tunnel=TunnelSettings(0.5), logger=log)
    assert rig.command_force(-0.3).accepted and rig.command_amplitude(0.2).accepted
    assert rig.command_frequency(20.0).accepted
    rig.set_limits(max_force_npm=0.01, max_amplitude_npm=0.05, max_frequency_hz=10.0)
    assert (rig.shaker.held_force_npm, rig.shaker.amplitude_npm, rig.shaker.frequency_hz) == (-0.01, 0.05, 10.0)
    warned = [text for level, text in log.lines if level == "warning"]
    assert [w.split(" limit")[0] for w in warned] == ["shaker force", "shaker amplitude", "shaker frequency"]
    rig.set_limits(max_force_npm=1.0)  # raising a limit changes nothing
    assert rig.shaker.held_force_npm == -0.01 and len(log.lines) == len(warned)


@pytest.mark.parametrize("scene", ["settled", "lagging", "sine_on", "control_pending"])
def test_block_inputs_equal_the_per_step_inputs_bit_for_bit(scene: str) -> None:
    """The block march's inputs (airspeed before and after each step, total and shaker force) skip the per-step
    calls when the forces are constant; they and the actuator, shaker and control states after the block equal
    the per-step path's exactly, whatever is on."""
    import copy

    rig, _, _ = make_rig()
    rig.command_airspeed(7.0)
    rig.command_force(0.05)
    rig.shaker.frequency_hz = 13.0  # the phase runs on while the sine is off
    rig.advance_to(0.3)
    if scene == "settled":
        rig.actuator.airspeed_mps = rig.actuator.setpoint_mps
    if scene == "sine_on":
        rig.shaker.amplitude_npm = 0.2
    if scene == "control_pending":
        rig.control.command(0.01, rig.time_s, rig.time_s + 0.01)
    twin = copy.deepcopy(rig)
    n = 700
    got = rig._inputs(n)
    act, shaker, control = twin.actuator, twin.shaker, twin.control
    expected: tuple[list[float], ...] = ([], [], [], [])
    for k in range(n):
        expected[0].append(act.airspeed_mps)
        expected[3].append(shaker.step())
        expected[1].append(expected[3][-1] + control.step((twin.steps + k) * twin.dt_s))
        expected[2].append(act.step())
    for a, b in zip(got, expected):
        assert np.array_equal(np.asarray(a), np.asarray(b))
    assert (rig.actuator.airspeed_mps, rig.shaker.phase_rad, rig.control.snapshot()) == \
        (act.airspeed_mps, shaker.phase_rad, control.snapshot())
    assert (scene == "settled") == rig.actuator.settled
