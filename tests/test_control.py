"""Closed-loop control (issue 13): the control actuator against its transfer function, the watchdog, bad commands,
command ages, the reference law's design, and the closed-loop flutter prediction against the emulated tunnel."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from panel_rig.analysis.control import (
    SENSOR_NOISE_M,
    ControlLaw,
    DiscreteLaw,
    LoopModel,
    closed_loop_flutter,
    design_law,
    effective_delay,
    growth_rate,
    noise_force_rms,
    pade_delay,
)
from panel_rig.rig.control import (
    ACTIVE,
    TIMED_OUT,
    ControlActuator,
    ControlSettings,
    envelope_growth_rate,
    run_closed_loop,
)
from panel_rig.rig.rig import Rig
from panel_rig.rig.safety import SafetyLimits

DT = 1.0 / 2048.0


class Recorder:
    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def info(self, m: str) -> None:
        self.lines.append(("info", m))

    def warning(self, m: str) -> None:
        self.lines.append(("warning", m))

    def error(self, m: str) -> None:
        self.lines.append(("error", m))


def drive(act: ControlActuator, target_at: callable, n: int) -> np.ndarray:
    """Per step k: a command of target_at(k) arriving at the step's start; returns the applied forces."""
    out = np.empty(n)
    for k in range(n):
        t = k * DT
        act.command(target_at(k), t, t)
        out[k] = act.step(t)
    return out


def test_actuator_step_response_is_its_first_order_transfer_function() -> None:
    s = ControlSettings(bandwidth_hz=50.0, max_force_npm=5.0, max_rate_npmps=1e6, timeout_s=1.0)
    act = ControlActuator(DT, s)
    n = 400
    f = drive(act, lambda k: 1.0, n)
    t = np.arange(n) * DT  # the force over step k is its value at the step's start
    expected = 1.0 - np.exp(-2 * np.pi * 50.0 * t)
    assert np.max(np.abs(f - expected)) < 1e-12
    assert np.interp(1 / (2 * np.pi * 50.0), t, f) == pytest.approx(1 - math.exp(-1), abs=2e-3)


@pytest.mark.parametrize("f_hz", [10.0, 50.0, 150.0])
def test_actuator_sine_response_matches_gain_and_phase(f_hz: float) -> None:
    bw = 50.0
    s = ControlSettings(bandwidth_hz=bw, max_force_npm=5.0, max_rate_npmps=1e6, timeout_s=1.0)
    act = ControlActuator(DT, s)
    n = int(2.0 / DT)
    f = drive(act, lambda k: math.sin(2 * np.pi * f_hz * k * DT), n)
    t = np.arange(n) * DT
    late = t > 1.0
    basis = np.column_stack([np.sin(2 * np.pi * f_hz * t[late]), np.cos(2 * np.pi * f_hz * t[late])])
    (a, b), *_ = np.linalg.lstsq(basis, f[late], rcond=None)
    # exact discretisation of wa / (s + wa) for an input held over each step, applied one step later:
    # H(z) = (1 - a) z^-1 / (1 - a z^-1), a = exp(-wa dt): the continuous gain (2 %), and its phase less the
    # hold's delay of 0.5 to 1.5 physics steps
    a_ = math.exp(-2 * np.pi * bw * DT)
    z = np.exp(1j * 2 * np.pi * f_hz * DT)
    h = (1 - a_) / z / (1 - a_ / z)
    continuous = 1.0 / (1.0 + 1j * f_hz / bw)
    assert abs(h) == pytest.approx(abs(continuous), rel=0.02)
    extra_steps = -np.angle(h / continuous) / (2 * np.pi * f_hz * DT)
    assert 0.5 <= extra_steps <= 1.5
    assert complex(a, b) == pytest.approx(h, abs=0.005)  # sin and cos parts: |h| cos(phase), |h| sin(phase)


def test_actuator_rate_limit_and_saturation() -> None:
    s = ControlSettings(bandwidth_hz=1000.0, max_force_npm=1.0, max_rate_npmps=100.0, timeout_s=1.0)
    act = ControlActuator(DT, s)
    f = drive(act, lambda k: 1.0, 200)
    assert np.max(np.diff(f)) <= 100.0 * DT * (1 + 1e-9)
    assert f[10] == pytest.approx(10 * 100.0 * DT)  # on the rate limit
    assert np.max(f) <= 1.0 and f[-1] == pytest.approx(1.0)


def test_command_acts_from_its_arrival_and_its_age_is_recorded() -> None:
    act = ControlActuator(DT, ControlSettings(bandwidth_hz=1e4, max_rate_npmps=1e9, timeout_s=1.0))
    act.command(1.0, stamp_s=0.0, arrival_s=10 * DT + 1e-5)
    forces = [act.step(k * DT) for k in range(14)]
    assert all(f == 0.0 for f in forces[:12])  # not before the first step starting after the arrival (k = 11)
    assert forces[12] > 0.9
    stats = act.latency_stats_ms()
    assert stats["n"] == 1 and stats["mean"] == pytest.approx((10 * DT + 1e-5) * 1e3)


def test_watchdog_zeroes_the_actuator_logs_and_rearms() -> None:
    log = Recorder()
    s = ControlSettings(bandwidth_hz=200.0, max_force_npm=2.0, max_rate_npmps=1e6, timeout_s=0.05)
    act = ControlActuator(DT, s, logger=log)
    k = 0
    for k in range(100):
        act.command(1.0, k * DT, k * DT)
        act.step(k * DT)
    assert act.state == ACTIVE and act.force_npm > 0.99
    last_arrival = 99 * DT
    trip = None
    for k in range(100, 400):
        f = act.step(k * DT)
        if act.state == TIMED_OUT and trip is None:
            trip = k * DT
        assert math.isfinite(f)
    assert trip is not None and trip - last_arrival <= s.timeout_s + DT
    assert abs(act.force_npm) < 1e-6  # decayed with the actuator lag (tau = 0.8 ms) well within the timeout
    assert act.timeouts == 1
    assert [lvl for lvl, m in log.lines if "watchdog" in m] == ["warning"]
    act.command(0.5, 400 * DT, 400 * DT)
    act.step(400 * DT)
    assert act.state == ACTIVE and any("resumed" in m for _, m in log.lines)


def test_a_controller_slower_than_the_watchdog_logs_one_trip_per_second_not_each() -> None:
    """An 8 Hz controller with the 0.1 s watchdog trips it at every gap: the trip and resume lines came at ~16 per
    second. Now at most one trip (with its resume) per LOG_INTERVAL_S of simulated time, the next one counting
    those left out; every trip is still counted (``timeouts``, /diagnostics)."""
    from panel_rig.rig.control import LOG_INTERVAL_S

    log = Recorder()
    act = ControlActuator(DT, ControlSettings(timeout_s=0.1), logger=log)
    period = round(0.125 / DT)  # 8 Hz
    for k in range(round(3.0 / DT)):
        if k % period == 0:
            act.command(0.1, k * DT, k * DT)
        act.step(k * DT)
    assert act.timeouts == 24
    trips = [m for _, m in log.lines if "watchdog" in m]
    resumes = [m for _, m in log.lines if "resumed" in m]
    assert len(trips) == 3 == round(3.0 / LOG_INTERVAL_S) and len(resumes) == 3, log.lines
    assert "more trip(s)" not in trips[0] and "7 more trip(s)" in trips[1], trips


class LinearOscillator:
    """A minimal stepper (w/L = q; the force is in N/m) for the rig-level checks."""

    def __init__(self) -> None:
        self.dt_s = DT
        self.reset()

    def reset(self) -> None:
        self.time_s, self.q, self.qdot, self.aero_force_npm = 0.0, np.zeros(1), np.zeros(1), np.zeros(1)
        self.forces: list[float] = []

    @property
    def tip_w_over_L(self) -> float:
        return float(self.q[0])

    def shape_w_over_L(self, x: np.ndarray) -> np.ndarray:
        return self.q[0] * np.asarray(x)

    def step(self, airspeed_mps: float, tip_force_npm: float) -> None:
        self.forces.append(tip_force_npm)
        self.qdot = self.qdot + DT * (tip_force_npm - 100.0 * self.q)
        self.q = self.q + DT * self.qdot


@pytest.mark.parametrize(
    ("value", "stamp", "why"),
    [(math.nan, 0.0, "finite"), (math.inf, 0.0, "finite"), (-math.inf, 0.0, "finite"),
     (2.5, 0.0, "saturation"), ("x", 0.0, "number"), (0.1, math.nan, "stamp"), (0.1, -1.0, "old"),
     (0.1, 2.0**31 - 1, "answers no reading")],  # a stamp of the future was taken, with a latency of 0 ms
)
def test_bad_control_commands_are_rejected_and_counted(value: object, stamp: float, why: str) -> None:
    rig = Rig(LinearOscillator(), 1.0, control=ControlSettings())
    rig.advance_to(0.01)
    res = rig.command_control(value, stamp)  # type: ignore[arg-type]
    assert not res.accepted and why in res.reason
    assert rig.rejected_count == 1 and "control/force_cmd" in rig.last_rejection
    rig.advance_to(0.05)
    assert rig.state == "running" and np.isfinite(rig.stepper.q).all() and rig.control.force_npm == 0.0


def test_rig_adds_the_control_force_to_the_shaker_force_in_steps_and_blocks() -> None:
    for block in (False, True):
        st = LinearOscillator()
        rig = Rig(st, 1.0, control=ControlSettings(bandwidth_hz=1e4, max_rate_npmps=1e9))
        rig._can_block = block  # noqa: SLF001 (both marching paths)
        rig.command_force(0.3)
        assert rig.command_control(0.5, 0.0).accepted
        rig.advance_to(0.01)
        assert st.forces[-1] == pytest.approx(0.8, rel=1e-6)
        assert rig.reading().shaker_force_npm == pytest.approx(0.3)  # readings: the shaker's own force
        rig.abort("test")
        assert rig.control.force_npm == 0.0


def test_discrete_law_matches_the_continuous_law_in_frequency() -> None:
    law = ControlLaw(0.4, 150.0)
    d = DiscreteLaw(law)
    rate, f_hz = 500.0, 22.0
    t = np.arange(2000) / rate
    y = np.array([d.step(math.sin(2 * np.pi * f_hz * tk), 1 / rate) for tk in t])
    late = t > 1.0
    basis = np.column_stack([np.sin(2 * np.pi * f_hz * t[late]), np.cos(2 * np.pi * f_hz * t[late])])
    (a, b), *_ = np.linalg.lstsq(basis, y[late], rcond=None)
    h = law.state_space().freqresp([f_hz])[0]
    assert complex(a, b) == pytest.approx(h, rel=0.03)


@pytest.mark.parametrize("tau", [0.004, 0.05, 0.1])
def test_pade_delay_phase(tau) -> None:
    """Up to the model's highest frequency, at any delay the CLI takes (one 4th-order Padé of 50 ms was 7 degrees
    off at 25 Hz and 180 off at 70 Hz)."""
    f_hz = np.array([5.0, 25.0, 70.0, 150.0, 200.0])
    h = pade_delay(tau).freqresp(f_hz)
    assert np.allclose(np.abs(h), 1.0)
    assert np.allclose(np.angle(h * np.exp(2j * np.pi * f_hz * tau)), 0.0, atol=2e-3)  # phase error, rad (0.1 deg)


def test_long_loop_delay_prediction_is_converged_and_unstable_at_50_ms(model, design) -> None:
    """The closed-loop prediction at long delays: with a 50 ms command age the control demo's rig aborted (tip past
    its limit at 1.2 U_f) where the single Padé approximant predicted a closed-loop U_f of 13.7 m/s. The loop is
    unstable from the lowest speeds; the prediction does not change when the delay's model is accurate to twice
    the frequency."""
    u_max = 2.5 * design.open_loop_flutter_mps
    at_50 = closed_loop_flutter(model, design.law, LoopModel(100.0, 0.05), u_max=u_max)
    assert at_50.unstable_at_low_speed or at_50.speed_mps < 1.0
    # and it is a band: stable again above ~2.4 m/s up to a flutter speed above the open loop's (the CLI reported
    # the band's 0.552 m/s as "the closed-loop flutter speed" alone, not unstable at low speed)
    ranges = closed_loop_flutter(model, design.law, LoopModel(100.0, 0.05), u_max=u_max, n_scan=40,
                                 all_ranges=True).unstable_ranges_mps
    assert len(ranges) == 2 and ranges[0][0] < 1.0 and 1.0 < ranges[0][1] < 5.0, ranges
    assert ranges[1][0] > design.open_loop_flutter_mps and ranges[1][1] is None, ranges
    for u, unstable in ((0.5 * (ranges[0][0] + ranges[0][1]), True), (0.5 * (ranges[0][1] + ranges[1][0]), False)):
        assert (growth_rate(model, u, design.law, LoopModel(100.0, 0.05)) > 0) == unstable, u
    for tau in (0.03, 0.04, 0.075):
        a = closed_loop_flutter(model, design.law, LoopModel(100.0, tau), u_max=u_max)
        b = closed_loop_flutter(model, design.law, LoopModel(100.0, tau, delay_accurate_hz=400.0), u_max=u_max)
        assert a.unstable_at_low_speed == b.unstable_at_low_speed
        assert a.speed_mps == pytest.approx(b.speed_mps, rel=1e-3)


@pytest.fixture(scope="module")
def design(model):
    return design_law(model)


def test_design_raises_the_flutter_speed_robustly(model, design) -> None:
    assert design.closed_loop_flutter_mps is not None
    assert design.closed_loop_flutter_mps > 1.25 * design.open_loop_flutter_mps
    # robust: with double the design delay the law still does not make things worse
    twice = closed_loop_flutter(model, design.law, LoopModel(design.loop.actuator_bandwidth_hz,
                                                             2 * design.loop.delay_s))
    assert not twice.unstable_at_low_speed and twice.speed_mps > design.open_loop_flutter_mps
    # no gain at all: the open-loop flutter speed
    none = closed_loop_flutter(model, ControlLaw(0.0), design.loop)
    assert none.speed_mps == pytest.approx(design.open_loop_flutter_mps, rel=1e-6)
    # the command noise the assumed sensor noise makes is far below the saturation
    assert noise_force_rms(design.law, 500.0) < 0.01 * ControlSettings().max_force_npm


def test_prediction_agrees_with_the_emulated_onset_within_5_percent(cfg, model, design) -> None:
    """The closed-loop flutter speed of the linear model (controller, actuator, Padé loop delay) brackets the onset
    in the emulated tunnel (Rig + Stepper + the discrete law, commands acting after their age): decaying at
    0.95 x the prediction, growing at 1.05 x."""
    from panel_rig.model.stepper import Stepper

    age, rate = 0.002, 500.0
    loop = LoopModel(ControlSettings().bandwidth_hz, effective_delay(age, rate, cfg.dt_s))
    pred = closed_loop_flutter(model, design.law, loop).speed_mps
    rates = {}
    for factor in (0.95, 1.05):
        rig = Rig(Stepper(cfg, variant="linear", model=model), cfg.panel_length_m,
                  limits=SafetyLimits(max_tip_w_over_L=1.9, wall_clearance_m=10.0))
        run = run_closed_loop(rig, DiscreteLaw(design.law), factor * pred, 5.0, age, rate)
        assert run.state == "running"
        late = run.time_s > 1.0
        rates[factor] = envelope_growth_rate(run.time_s[late], run.tip_w_m[late])
    assert rates[0.95] < -0.1 and rates[1.05] > 0.1, rates


def test_law_with_sensor_noise_keeps_the_panel_quiet_above_open_loop_flutter(cfg, model, design) -> None:
    """At 1.2 x the open-loop U_f, with the assumed sensor noise on the controller's readings, the full nonlinear
    panel stays quiet: tip RMS below the threshold (10 x the sensor noise) after the tap has decayed."""
    from panel_rig.analysis.control import QUIET_FACTOR
    from panel_rig.model.stepper import Stepper

    rig = Rig(Stepper(cfg, variant="full", model=model), cfg.panel_length_m)
    run = run_closed_loop(rig, DiscreteLaw(design.law), 1.2 * design.open_loop_flutter_mps, 8.0, 0.002,
                          noise_m=SENSOR_NOISE_M, seed=3)
    assert run.state == "running"
    true_tip = run.tip_w_m  # includes the noise the controller saw: the true tip is quieter still
    late = run.time_s > 6.0
    assert np.sqrt(np.mean(true_tip[late] ** 2)) < QUIET_FACTOR * SENSOR_NOISE_M
    assert np.max(np.abs(run.command_npm)) < ControlSettings().max_force_npm


def test_cli_flutter_control_json_and_bad_input(capsys, tmp_path) -> None:
    import json

    from panel_rig.cli import main

    assert main(["flutter", "--control", "--json", "--delay-ms", "3", "--plot", str(tmp_path / "d.png")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["closed_loop_flutter_speed_mps"] > 1.25 * out["flutter_speed_mps"]
    assert out["loop_delay_s"] == pytest.approx(0.003) and (tmp_path / "d.png").stat().st_size > 10_000
    assert out["closed_loop_unstable_ranges_mps"] == [[out["closed_loop_flutter_speed_mps"], None]]
    # a band of low speeds unstable (50 ms): the table names it beside the first crossing
    assert main(["flutter", "--control", "--delay-ms", "50"]) == 0
    line = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("closed loop unstable")]
    assert len(line) == 1 and re.fullmatch(r"closed loop unstable +0\.\d{3}-[1-4]\.\d{3} m/s, from 1\d\.\d{3} m/s",
                                            line[0]), line
    assert main(["flutter", "--control", "--plot", str(tmp_path / "e.png")]) == 0
    assert capsys.readouterr().out.splitlines()[-1].split() == ["plot", str(tmp_path / "e.png")]  # named, as --json
    assert main(["flutter", "--control", "--delay-ms", "nan"]) == 2
    assert main(["flutter", "--control", "--delay-ms", "1", "--command-age-ms", "1"]) == 2
    assert "error" in capsys.readouterr().err


def test_rerun_logs_control_command_and_age_in_batches(tmp_path) -> None:
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from panel_rig.viz import RerunLogger

    path = tmp_path / "c.rrd"
    logger = RerunLogger(3, mode="save", target=str(path))
    for k in range(300):
        logger.log_control(k / 500.0, 0.1 * math.sin(k / 10), 2.0 + (k % 7) * 0.1)
        logger.on_command("control/force_cmd", 0.1, True, k / 500.0)  # not logged one by one
    logger.close()
    rows: dict[str, int] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        if not chunk.is_static:
            rows[str(chunk.entity_path)] = rows.get(str(chunk.entity_path), 0) + chunk.num_rows
    assert rows.get("/control/command_npm") == 300 and rows.get("/control/latency_ms") == 300
    assert "/commands/control/force_cmd" not in rows
