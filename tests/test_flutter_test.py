"""The flutter-test procedure core (panel_rig.analysis.flutter_test): decisions on synthetic test points, and the
whole procedure on the in-process Rig with the default turbulence and sensor (no ROS)."""

import json

import numpy as np
import pytest

from panel_rig import flutter_cli
from panel_rig.analysis.flutter_test import REPEAT, FlutterTestSettings, TestPoint, decide, tap_start, uncertain
from panel_rig.analysis.identification import ModalEstimate
from panel_rig.analysis.vg import vg_diagram
from panel_rig.config import load_config
from panel_rig.rig.flutter_run import default_plan, run_on_rig

UF = 10.0  # synthetic flutter mode (no first mode: damping trend only): damping linear in U^2, zero at UF


def _point(u, se=1e-4):
    z = 0.01 * (1 - (u / UF) ** 2)
    return TestPoint(u, None, ModalEstimate(20.0 - 0.5 * u, z, 0.01, se, 9, "synthetic"), "synthetic")


def test_decide_caps_the_next_airspeed_and_stops_inside_the_margin():
    s = FlutterTestSettings(start_mps=5.0, step_mps=2.0, margin=0.1)
    d = decide([_point(5.0)], s)
    assert d.next_airspeed_mps == pytest.approx(7.0) and d.prediction is None
    pts = [_point(u) for u in (5.0, 6.0, 7.0, 8.0)]
    d = decide(pts, s)
    # a full step would go to 10 m/s (= U_f): capped at (1 - M) x the prediction
    assert d.prediction.speed_mps == pytest.approx(UF, rel=0.02)
    assert d.next_airspeed_mps == pytest.approx(0.9 * d.prediction.speed_mps)
    assert "capped" in d.reason
    d = decide(pts + [_point(9.2)], FlutterTestSettings(start_mps=5.0, step_mps=2.0, margin=0.1, min_damping=0.0))
    assert d.stop and "margin" in d.reason
    low = FlutterTestSettings(start_mps=5.0, step_mps=0.5, min_damping=0.009)
    d = decide([_point(1.0), _point(4.0)], low)
    assert d.stop and "damping" in d.reason


def test_a_margin_stop_on_an_uncertain_prediction_repeats_the_point_first():
    """9 of 32 seeds stopped 7-34 % short of U_f on a margin stop from a prediction whose interval was wide (e.g.
    [6.72 m/s, open] at 0.6 U_f on two points). Now such a stop takes the same airspeed again first (``repeats``
    times, default once): an airspeed already cleared, never a higher one; a prediction with a tight interval
    stops at once, as before, and so does the uncertain one once its repeats are used."""
    from dataclasses import replace

    s = FlutterTestSettings(start_mps=5.0, step_mps=2.0, margin=0.1, min_damping=0.0)
    speeds = (5.0, 6.0, 7.0, 8.0, 9.2)
    d = decide([_point(u) for u in speeds], s)
    assert d.stop and d.reason.startswith("predicted margin") and not uncertain(d.prediction, s.wide_ci), d
    noisy = [_point(u, se=3e-3) for u in speeds]
    d = decide(noisy, s)
    assert uncertain(d.prediction, s.wide_ci) and d.prediction.margin(9.2) < 0.1
    assert d.next_airspeed_mps == 9.2 and d.reason.startswith(f"{REPEAT} the point: predicted margin"), d.reason
    again = noisy + [_point(9.2, se=3e-3)]
    d = decide(again, s)
    assert d.stop and d.reason.startswith("predicted margin"), d.reason
    assert decide(noisy, replace(s, repeats=0)).stop
    assert decide(again, replace(s, repeats=2)).next_airspeed_mps == 9.2
    assert decide(again, replace(s, max_points=6)).stop  # a repeat is a test point: the cap on points holds
    # the repeated airspeed is a sample of the fit, not a point of its curve: 3 points at 2 airspeeds give no trend
    assert decide([_point(5.0), _point(6.0), _point(6.0)], s).trend is None


def test_a_point_without_a_flutter_mode_estimate_clears_nothing():
    """A quiet tunnel (no turbulence, no tap) gave no flutter-mode estimate at any point, and the procedure stepped
    on regardless, to 16.8 m/s (1.6 U_f) with exit 0. Now such a point stops the test, however the points before it
    went; and a first mode identified with damping <= 0 (a failed identification of the heavily damped mode) is no
    ZW point."""
    from panel_rig.analysis.flutter_test import margin_points

    s = FlutterTestSettings(start_mps=5.0, step_mps=1.0, margin=0.1)
    blind = TestPoint(6.0, None, None, "ssi-cov")
    for pts in ([blind], [_point(5.0), blind]):
        d = decide(pts, s)
        assert d.stop and d.unidentified and d.reason.startswith("flutter mode not identified at 6.000 m/s"), d
        assert all(k in d.reason for k in ("tunnel.turbulence.intensity", "sensor.tip_noise_m")), d.reason
    assert not decide([_point(5.0)], s).unidentified

    def with_first(u, zeta_first):
        return TestPoint(u, ModalEstimate(4.5, zeta_first, 0.1, 0.05, 9, "synthetic"), _point(u).flutter, "synthetic")

    pts = [with_first(5.0, 0.45), with_first(6.0, -0.017), with_first(7.0, 0.44)]
    u, f = margin_points(pts)
    assert list(u) == [5.0, 7.0] and np.all(f > 0)


def test_a_quiet_tunnel_s_test_stops_at_its_first_point_and_exits_1(tmp_path, capsys):
    """`panel-rig flutter-test --in-process --set tunnel.turbulence.intensity=0`: nothing excites the panel, the
    flutter mode is not identified, and the test stops at its first airspeed without clearing it (exit 1, one line
    saying so)."""
    import json

    from panel_rig.cli import main

    code = main(["flutter-test", "--in-process", "--set", "tunnel.turbulence.intensity=0", "--dwell", "20", "--json",
                 "--bag-dir", str(tmp_path), "--plot", str(tmp_path / "vg.png")])
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert code == 1 and out["fluttered"] is False and len(out["test_points"]) == 1
    assert out["max_airspeed_mps"] == out["test_points"][0]["airspeed_mps"] < 0.6 * out["model_flutter_speed_mps"]
    assert out["stop_reason"].startswith("flutter mode not identified at ")
    assert captured.err.strip().splitlines()[-1] == (
        f"panel-rig flutter-test: stopped without clearance: {out['stop_reason']}")
    from panel_rig.flutter_cli import format_flutter_test

    head, row = format_flutter_test(out).splitlines()[:2]  # the table named the method of a point it did not identify
    assert row.split()[2:5] == ["-", "-", "-"] and row.endswith("- (ssi-cov: not identified)"), row
    # each "-" under its column's header ("1   5.240 - -                   - -" was misaligned)
    assert row.index("- (ssi") == head.index("method") and row[: head.index("zeta 95% CI") + 11].endswith("-"), row


def test_tap_start_is_the_first_sample_after_the_force():
    f = np.zeros(100)
    assert tap_start(None) is None and tap_start(f) is None
    f[10:15] = 1.0
    assert tap_start(f) == 15


@pytest.fixture(scope="module")
def paper_run():
    cfg = load_config()
    return run_on_rig(cfg, variant="full", margin=0.1)


def test_procedure_on_the_rig_stops_short_and_predicts_the_flutter_speed(paper_run):
    """Paper configuration, default turbulence and sensor, full nonlinear variant, dwell 200 s per point: the
    procedure never flutters, never climbs above (1 - M) x the prediction current at the time of each command (a
    repeat takes an airspeed already measured again), stays below 0.95 U_f, and the prediction it stops on (from
    points <= 0.95 U_f) is within 3 % of the model's linear U_f; the identified flutter-mode damping (the mean of a
    repeated airspeed's points) is within 20 % of the model V-g at 0.6-0.9 U_f."""
    res, uf = paper_run
    assert not res.fluttered
    assert res.max_airspeed_mps < 0.95 * uf
    assert len(res.points) >= 4
    for d, before, nxt in zip(res.decisions, res.points, res.points[1:]):
        if d.reason.startswith(REPEAT):
            assert nxt.airspeed_mps == before.airspeed_mps
        elif d.prediction is not None:
            assert nxt.airspeed_mps <= (1 - 0.1) * d.prediction.speed_mps + 1e-9
    pred = res.final.prediction
    assert pred is not None and pred.speed_mps == pytest.approx(uf, rel=0.03)
    assert pred.ci_mps[0] <= pred.speed_mps <= pred.ci_mps[1]
    from panel_rig.model.stepper import Stepper

    model = Stepper(load_config(), variant="full").model
    u = np.unique([p.airspeed_mps for p in res.points])
    vg = vg_diagram(model, u)
    mode = int(np.argmin(np.abs(vg.frequency_hz[0] - res.points[0].flutter.frequency_hz))) + 1
    for k, uk in enumerate(u):  # a repeated airspeed's points by their mean (one dwell reads the V-g +- 10 %)
        if 0.6 * uf <= uk <= 0.9 * uf:
            at = [p.flutter for p in res.points if p.airspeed_mps == uk]
            assert np.mean([e.damping_ratio for e in at]) == pytest.approx(vg.damping_ratio[k, mode - 1], rel=0.2)
            for e in at:
                assert e.frequency_hz == pytest.approx(vg.frequency_hz[k, mode - 1], rel=5e-3)
    d = res.as_dict()
    assert d["fluttered"] is False and d["test_points"][0]["damping_ci"][0] < d["test_points"][0]["damping_ratio"]


def test_replay_skips_a_window_where_the_tunnel_did_not_run_at_the_command():
    """A recorded set-point the tunnel did not follow (a command refused, an aborted rig) is no test point: the
    measured airspeed decides. Synthetic: a 2 %-damped 20 Hz mode driven by noise, commands at 8, 50 (refused:
    the tunnel stays at 8) and 9 m/s."""
    from panel_rig.analysis.flutter_test import replay_points

    dt, n = 1.0 / 500.0, 500 * 90
    t = np.arange(n) * dt
    rng = np.random.default_rng(0)
    omega, zeta = 2 * np.pi * 20.0, 0.02
    a1, a2 = 2 * np.exp(-zeta * omega * dt) * np.cos(omega * dt), -np.exp(-2 * zeta * omega * dt)
    y = np.zeros(n)
    e = rng.normal(size=n)
    for k in range(2, n):
        y[k] = a1 * y[k - 1] + a2 * y[k - 2] + e[k]
    y *= 1e-5 / np.std(y)
    cmds = [(0.0, 8.0), (30.0, 50.0), (60.0, 9.0)]
    measured = np.where(t < 60.0, 8.0, 9.0)
    bands = lambda u: [(3.0, 6.0), (15.0, 25.0)]  # noqa: E731 (first mode, flutter mode)
    without = replay_points(t, y, cmds, bands, 0.27)
    checked = replay_points(t, y, cmds, bands, 0.27, airspeed_mps=measured)
    assert [p.airspeed_mps for p in without] == [8.0, 50.0]  # the refused 50 m/s taken, and it ended the ascent
    assert [p.airspeed_mps for p in checked] == [8.0, 9.0]


def test_default_plan_starts_at_half_the_model_speed():
    s = default_plan(10.0)
    assert s.start_mps == 5.0 and s.step_mps == 1.0 and s.margin == 0.1


def test_cli_flutter_test_json_with_a_set_and_its_replay(tmp_path, capsys):
    """`panel-rig flutter-test --in-process --set panel.thickness_m=0.0004 --json` (short dwell to bound the test):
    the JSON keys of the issue, no flutter, airspeeds below the model's U_f, a bag with the measured tip and the
    monitor. (The default, live path: tests/test_flutter_test_live.py.)"""
    import json

    from panel_rig.cli import main
    from panel_rig.recording.series import load_series

    code = main(["flutter-test", "--in-process", "--set", "panel.thickness_m=0.0004", "--dwell", "30", "--json",
                 "--bag-dir", str(tmp_path), "--plot", str(tmp_path / "vg.png"), "--rerun", str(tmp_path / "t.rrd")])
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert code == 0 and out["fluttered"] is False
    # progress on stderr while the test runs: a line per point with what it found and what comes next
    lines = [ln for ln in captured.err.splitlines() if ln.startswith("point ")]
    assert len(lines) == len(out["test_points"]) >= 2
    for k, (line, p) in enumerate(zip(lines, out["test_points"]), 1):
        assert line.startswith(f"point {k}: {p['airspeed_mps']:.3f} m/s: {p['frequency_hz']:.3f} Hz, zeta "), line
    assert lines[-1].endswith(f"stop ({out['stop_reason']})")
    for key in ("test_points", "predicted_flutter_speed_mps", "predicted_flutter_speed_ci_mps", "max_airspeed_mps",
                "fluttered", "bag"):
        assert key in out
    assert out["rerun"] == str(tmp_path / "t.rrd") and (tmp_path / "t.rrd").stat().st_size > 0  # named, written
    assert set(out["test_points"][0]) >= {"airspeed_mps", "frequency_hz", "damping_ratio", "damping_ci"}
    assert out["model_flutter_speed_mps"] > 11.0  # thicker panel: later flutter than the paper's 10.48 m/s
    assert out["max_airspeed_mps"] < out["model_flutter_speed_mps"]
    assert (tmp_path / "vg.png").stat().st_size > 0
    rec = load_series(out["bag"])
    assert rec.t_s[-1] == pytest.approx(out["simulated_s"], abs=0.1)
    # replay: the same identification on the bag gives the same points (the recorded tip resampled on the
    # recorded stamps), and a prediction
    from panel_rig.analyze_cli import analyze_bag

    result = analyze_bag(out["bag"], plots_dir=tmp_path / "plots")
    ft = result["flutter_test"]
    # with --plots the replay's V-g figure too, as `flutter-test --plot` draws it
    assert str(tmp_path / "plots" / "flutter_test_vg.png") in result["plots"]
    assert (tmp_path / "plots" / "flutter_test_vg.png").stat().st_size > 0
    assert [p["airspeed_mps"] for p in ft["test_points"]] == pytest.approx(
        [p["airspeed_mps"] for p in out["test_points"]])
    # the in-process driver takes the node monitor's window [command + settle, + dwell) and records its window and
    # hold as the node does: the replay is the test's identification (it differed by up to 3e-5 in damping, with a
    # window one sample later and the replay's default window)
    for live, again in zip(out["test_points"], ft["test_points"]):
        assert again["damping_ratio"] == pytest.approx(live["damping_ratio"], abs=1e-9)
        assert again["frequency_hz"] == pytest.approx(live["frequency_hz"], abs=1e-9)
    assert ft["predicted_flutter_speed_mps"] == pytest.approx(out["predicted_flutter_speed_mps"], abs=1e-6)


def test_monitor_message_and_rerun_drawing_of_synthetic_points(tmp_path):
    """The monitor's DiagnosticArray carries the point, the prediction with its interval and the margin (WARN once
    the margin is below the required one); the Rerun logger draws them (strict mode: a bad call raises)."""
    import rerun as rr

    from panel_rig.ros.flutter_monitor import monitor_msg, parse_monitor
    from panel_rig.viz.logger import RerunLogger

    s = FlutterTestSettings(start_mps=5.0, step_mps=2.0, margin=0.1, min_damping=0.0)
    pts = [_point(u) for u in (5.0, 6.0, 7.0, 8.0, 9.2)]
    d = decide(pts, s)
    msg = monitor_msg(123, pts[-1], d, 0.1)
    v = parse_monitor(msg)
    assert v["airspeed_mps"] == 9.2 and v["damping_ci_low"] < v["damping_ratio"] < v["damping_ci_high"]
    assert v["predicted_flutter_speed_mps"] == pytest.approx(UF, rel=0.02)
    assert v["margin"] == pytest.approx(1 - 9.2 / v["predicted_flutter_speed_mps"])
    assert msg.status[0].level == b"\x01"  # WARN: inside the margin
    was = rr.strict_mode()
    rr.set_strict_mode(True)
    try:
        log = RerunLogger(3, mode="save", target=str(tmp_path / "m.rrd"))
        for k in range(1, len(pts) + 1):
            log.log_flutter_point(10.0 * k, pts[:k], decide(pts[:k], s), 0.1)
        log.close()
    finally:
        rr.set_strict_mode(was)
    assert (tmp_path / "m.rrd").stat().st_size > 0


def test_monitor_identifies_a_dwell_of_exactly_the_minimum_length():
    """A 20 s dwell (the least --dwell accepts) sampled at 512 Hz spans 20 s - 1/512 s from first to last sample;
    measured by that span alone it was never long enough, nothing was published and the flutter test hung."""
    from panel_rig.config import load_config
    from panel_rig.model.aeroelastic import AeroelasticModel
    from panel_rig.rig.flutter_run import MIN_DWELL_S, FlutterMonitorSink

    cfg = load_config()
    published = []
    sink = FlutterMonitorSink(cfg, AeroelasticModel(cfg), lambda *a, **k: published.append(a), settle_s=1.0,
                              dwell_s=MIN_DWELL_S)
    sink.on_command("airspeed_cmd", 5.0, True, 0.0)
    rng = np.random.default_rng(0)
    t = np.arange(0, int(512 * (1.0 + MIN_DWELL_S + 1.0))) / 512.0
    for block in np.array_split(np.arange(t.size), 40):
        sink.on_block(type("Block", (), {"time_s": t[block], "tip_w_m": 1e-6 * rng.standard_normal(block.size),
                                         "state": "running"})())
    assert len(published) == 1 and published[0][1].airspeed_mps == 5.0


def test_the_monitor_takes_a_repeated_airspeed_as_a_point_and_skips_a_step_down():
    """The flutter test repeats a point before an uncertain margin stop: the node's monitor ignored a command at the
    last point's airspeed (it follows the ascent only) and the live test waited for a result that never came."""
    from panel_rig.config import load_config
    from panel_rig.model.aeroelastic import AeroelasticModel
    from panel_rig.rig.flutter_run import MIN_DWELL_S, FlutterMonitorSink

    cfg = load_config()
    published = []
    sink = FlutterMonitorSink(cfg, AeroelasticModel(cfg), lambda *a, **k: published.append(a), settle_s=1.0,
                              dwell_s=MIN_DWELL_S)
    rng = np.random.default_rng(0)
    t0 = 0.0
    for u in (5.0, 5.0, 4.0, 6.0):
        sink.on_command("airspeed_cmd", u, True, t0)
        t = t0 + np.arange(1, int(512 * (1.0 + MIN_DWELL_S + 0.5))) / 512.0
        for block in np.array_split(np.arange(t.size), 20):
            sink.on_block(type("Block", (), {"time_s": t[block], "tip_w_m": 1e-6 * rng.standard_normal(block.size),
                                             "state": "running"})())
        t0 = float(t[-1])
    assert [a[1].airspeed_mps for a in published] == [5.0, 5.0, 6.0]


class _Recorder:
    """A sink keeping what the node's bag keeps: every sample's time and tip, and the accepted airspeed commands."""

    def __init__(self):
        self.t, self.y, self.cmds = [], [], []

    def on_block(self, block):
        self.t.append(np.asarray(block.time_s, float))
        self.y.append(np.asarray(block.tip_w_m, float))

    def on_reading(self, reading):
        self.on_block(type("B", (), {"time_s": [reading.time_s], "tip_w_m": [reading.tip_w_m]})())

    def on_command(self, name, value, accepted, time_s):
        if name == "airspeed_cmd" and accepted:
            self.cmds.append((time_s, value))

    def close(self):
        pass


def test_with_no_run_in_the_monitor_the_driver_and_the_replay_identify_the_same_window():
    """`flutter-test --dwell 20 --settle 0`: the live test hung (no sample is taken at t = 0, so the monitor's first
    window held one sample less than a 20 s dwell and was never identified; the node ran free and filled the disk),
    and the in-process test's replay differed from its points. The node's monitor (a sink of the rig as in the node),
    the in-process driver and the bag's replay now cut each window alike: the same points to 1e-12."""
    from panel_rig.analysis.flutter_test import bands_from_model, identify_point, replay_points
    from panel_rig.analysis.vg import model_flutter_speed
    from panel_rig.model.stepper import Stepper
    from panel_rig.rig.flutter_run import MIN_DWELL_S, FlutterMonitorSink, RigMeasure, node_equivalent_rig

    cfg = load_config()
    st = Stepper(cfg)
    uf, mode = model_flutter_speed(st.model)
    rig = node_equivalent_rig(cfg, st, uf)
    published = []
    monitor = FlutterMonitorSink(cfg, st.model, lambda *a, **k: published.append(a), settle_s=0.0,
                                 dwell_s=MIN_DWELL_S)
    rec = _Recorder()
    rig.sinks += [monitor, rec]
    settings = FlutterTestSettings(start_mps=0.5 * uf, step_mps=0.1 * uf, settle_s=0.0, dwell_s=MIN_DWELL_S)
    measure, bands = RigMeasure(rig, settings), bands_from_model(st.model, mode)
    driven = []
    for k, u in enumerate((0.5 * uf, 0.6 * uf), 1):
        tip, dt, _, fluttered = measure(u)
        assert not fluttered
        assert len(published) == k and published[-1][0] == pytest.approx(rig.time_s)  # at the dwell's end
        assert tip.size == round(MIN_DWELL_S / dt)
        driven.append(identify_point(tip, dt, u, bands(u), ssi=settings.ssi))
    live = [p[1] for p in published]
    replay = replay_points(np.concatenate(rec.t), np.concatenate(rec.y), rec.cmds, bands, cfg.panel_length_m,
                           settle_s=0.0, min_dwell_s=MIN_DWELL_S, ssi=settings.ssi, dwell_s=MIN_DWELL_S)
    assert len(replay) == 2
    for a, b, c in zip(live, driven, replay):
        for p in (b, c):
            assert p.flutter.damping_ratio == pytest.approx(a.flutter.damping_ratio, abs=1e-12)
            assert p.flutter.frequency_hz == pytest.approx(a.flutter.frequency_hz, abs=1e-12)


def test_a_start_inside_the_margin_is_warned_of():
    """`--start-mps` at or above (1 - margin) U_f of the pre-test analysis: the test went there without a word."""
    from panel_rig.rig.flutter_run import start_warning

    assert start_warning(None, 10.48, 0.1) is None
    assert start_warning(9.4, 10.48, 0.1) is None
    text = start_warning(10.0, 10.48, 0.1)
    assert text is not None and "9.432 m/s" in text and "may flutter" in text


def test_a_test_stopped_part_way_keeps_its_points_and_their_prediction():
    """Ctrl-C in the third point's dwell: the caller's result holds the two points identified, the airspeed
    commanded for the third, and, made into an interrupted result, the prediction of those points and a stop reason
    that says so. Before, run_points built its result inside and a stop lost it."""
    from panel_rig.analysis.flutter_test import FlutterTestResult, interrupted_result, run_points

    settings = FlutterTestSettings(start_mps=5.0, step_mps=1.0, n_boot=50)

    def next_point(u):
        if u > 6.5:
            raise KeyboardInterrupt
        return _point(u), False

    res = FlutterTestResult()
    with pytest.raises(KeyboardInterrupt):
        run_points(next_point, settings, res=res)
    assert [p.airspeed_mps for p in res.points] == [5.0, 6.0] and res.max_airspeed_mps == 7.0
    out = interrupted_result(res, settings, "SIGINT").as_dict()
    assert out["interrupted"] is True and len(out["test_points"]) == 2
    assert out["stop_reason"] == "interrupted by SIGINT after 2 test point(s)"
    assert out["predicted_flutter_speed_mps"] is None  # two points without a first mode: no predictor yet


def test_an_interrupted_result_takes_the_decision_the_stop_cut_off():
    """A stop between a point's identification and its decision (the bootstrap takes a while): the decision, and so
    the prediction, is taken from all the points identified; a test that had stopped on its own says why too."""
    from panel_rig.analysis.flutter_test import FlutterTestResult, interrupted_result

    settings = FlutterTestSettings(start_mps=5.0, step_mps=1.0, n_boot=50)
    pts = [_point(u) for u in (6.0, 7.0, 8.0, 9.2)]  # 9.2 m/s: inside the 0.1 margin of U_f 10 m/s
    res = FlutterTestResult(points=pts, decisions=[decide(pts[:k], settings) for k in (1, 2, 3)])
    out = interrupted_result(res, settings, "SIGTERM").as_dict()
    assert len(res.decisions) == 4 and out["predicted_flutter_speed_mps"] == pytest.approx(UF, rel=0.05)
    assert out["stop_reason"].startswith("interrupted by SIGTERM after 4 test point(s); the procedure had stopped")
    empty = interrupted_result(FlutterTestResult(), settings, "SIGINT").as_dict()
    assert empty["test_points"] == [] and empty["predicted_flutter_speed_mps"] is None and empty["interrupted"]
    assert FlutterTestResult().as_dict()["interrupted"] is False


def run_thin_test(tmp_path, capsys):
    """`flutter-test --in-process` of a thin panel (0.4 mm: U_f ~2.3 m/s, short dwells), JSON, bag and plot into
    ``tmp_path``: (exit status, the JSON, the captured output)."""
    import json

    from panel_rig.cli import main

    code = main(["flutter-test", "--in-process", "--set", "panel.thickness_m=0.0004", "--dwell", "20",
                 "--settle", "1", "--json", "--bag-dir", str(tmp_path), "--plot", str(tmp_path / "vg.png")])
    captured = capsys.readouterr()
    return code, json.loads(captured.out), captured


def test_cli_flutter_test_stopped_by_sigterm_reports_its_points(tmp_path, capsys, monkeypatch):
    """SIGTERM after the first point of an in-process test: the JSON of the points so far, marked interrupted, the
    plot, and status 143; the line on stderr says how to replay the recording. Before, SIGTERM killed the process
    at once (the test's own handler stands in for that here) and nothing was reported."""
    import json
    import os
    import signal

    from panel_rig import flutter_cli
    from panel_rig.cli import main

    def terminate_after(index, point, decision):  # as `kill` lands just after the first point is identified
        os.kill(os.getpid(), signal.SIGTERM)
        return real(index, point, decision)

    def killed(signum, frame):  # the default action would end pytest: end the command instead
        raise SystemExit(-signal.SIGTERM)

    real = flutter_cli.point_line
    monkeypatch.setattr(flutter_cli, "point_line", terminate_after)
    previous = signal.signal(signal.SIGTERM, killed)
    try:
        code = main(["flutter-test", "--in-process", "--set", "panel.thickness_m=0.0004", "--dwell", "20",
                     "--settle", "1", "--json", "--bag-dir", str(tmp_path), "--plot", str(tmp_path / "vg.png")])
    finally:
        signal.signal(signal.SIGTERM, previous)
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert code == 143 and out["interrupted"] is True, captured.err
    assert len(out["test_points"]) == 1 and out["stop_reason"].startswith("interrupted by SIGTERM after 1 test")
    assert out["max_airspeed_mps"] == out["test_points"][0]["airspeed_mps"]  # stopped before the next command
    assert (tmp_path / "vg.png").stat().st_size > 0 and out["plot"] == str(tmp_path / "vg.png")
    assert f"`panel-rig analyze {out['bag']}` replays the flutter test" in captured.err


@pytest.mark.parametrize(("start_mps", "message"), [
    ("150", "--start-mps must be in (0, 100] m/s, got 150"),
    ("40", "--start-mps must be at most this test's airspeed limit, 30 m/s (the node's limit or 1.2 x the model's "
           "U_f, the larger), got 40"),
    ("0", "--start-mps must be in (0, 100] m/s, got 0"),
    ("nan", "--start-mps must be in (0, 100] m/s, got nan"),
])
def test_a_start_the_rig_would_refuse_exits_2_before_anything_is_recorded(tmp_path, capsys, start_mps, message):
    """--start-mps 150 printed the margin warning, ran the pre-test analysis, left a bag in --bag-dir and only then
    failed on the rig's refusal; the README promises one line and status 2 before any work."""
    from panel_rig.cli import main

    code = main(["flutter-test", "--in-process", "--start-mps", start_mps, "--bag-dir", str(tmp_path / "bags"),
                 "--plot", str(tmp_path / "vg.png")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.splitlines()) == 1 and message in err, err
    assert not (tmp_path / "bags").exists() or not any((tmp_path / "bags").iterdir())


@pytest.mark.parametrize("damping_ratio", ["0.002", "0"])
def test_a_rom_window_at_low_airspeed_is_no_flutter_speed_to_plan_from(tmp_path, capsys, damping_ratio):
    """With structure.damping_ratio 0.002 the ROM's second mode is unstable from 1.05 to ~1.9 m/s only (stable again
    up to 9.6 m/s): the test took 1.05 m/s as the model's U_f, started at 0.53 m/s and ended "flutter mode not
    identified" (exit 1); with no damping it ran a point at 0.000 m/s. Now: status 2, one line, nothing recorded."""
    from panel_rig.cli import main

    code = main(["flutter-test", "--in-process", "--set", f"structure.damping_ratio={damping_ratio}", "--dwell", "20",
                 "--bag-dir", str(tmp_path / "bags"), "--plot", str(tmp_path / "vg.png")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "stable again at" in err and "not a flutter boundary" in err, err
    assert not (tmp_path / "bags").exists() or not any((tmp_path / "bags").iterdir())


def test_a_flutter_boundary_is_not_a_window():
    """The configurations of the validation stay unstable above their U_f up to 60 m/s (no false refusal)."""
    from panel_rig.analysis.vg import model_flutter_speed, stable_again_mps
    from panel_rig.model.stepper import Stepper

    for changes in ({}, {"damping_ratio": 0.01}, {"panel_thickness_m": 0.0004}):
        model = Stepper(load_config(None).replace(**changes)).model
        uf, mode = model_flutter_speed(model)
        assert stable_again_mps(model, mode, uf) is None, changes


def test_the_flutter_watch_is_an_rms_not_one_noisy_sample_and_does_not_depend_on_the_blocks():
    """Sensor noise of 2 mm RMS (accepted: sensor.tip_noise_m <= 0.1 m) put single samples past 0.02 L = 5.4 mm and
    a subcritical point was reported as flutter; the watch takes a 0.25 s RMS. A growing oscillation is caught
    at the same sample however the samples arrive (one block, blocks, one reading at a time)."""
    from panel_rig.analysis.flutter_test import FLUTTER_TIP_FRACTION, FlutterWatch

    L = 0.27
    t = np.arange(0.0, 205.0, 1 / 512)
    noise = 0.002 * np.random.default_rng(3).standard_normal(t.size)
    assert np.max(np.abs(noise)) > FLUTTER_TIP_FRACTION * L  # the old test's peak: "fluttered"
    assert not FlutterWatch(L).take(t, noise)
    tt = t[t < 20.0]
    growing = 1e-4 * np.exp(0.5 * tt) * np.sin(2 * np.pi * 23.0 * tt)  # reaches 0.02 L after ~7.9 s

    def first_hit(chunks):
        watch = FlutterWatch(L)
        for idx in chunks:
            if watch.take(tt[idx], growing[idx]):
                return int(idx[-1])
        return None

    whole = first_hit([np.arange(tt.size)])
    blocks = first_hit(np.array_split(np.arange(tt.size), 37))
    one_by_one = first_hit([np.array([k]) for k in range(tt.size)])
    assert whole is not None and 7.0 < tt[one_by_one] < 9.0, tt[one_by_one]
    assert tt[one_by_one] <= tt[blocks]  # a block ends after the sample that fluttered
    blocks_idx = np.array_split(np.arange(tt.size), 37)
    assert any(one_by_one in b for b in blocks_idx if b[-1] == blocks)  # caught in the block holding that sample


def test_a_sensor_whose_noise_reads_as_flutter_is_refused(tmp_path, capsys):
    """With 4 mm of tip noise (over the flutter monitor's level) the test stopped 0.4 s after its first command:
    "fluttered at 5.24 m/s", the tunnel still at ~2 m/s. Now: status 2, one line, before anything is recorded."""
    from panel_rig.cli import main

    code = main(["flutter-test", "--in-process", "--set", "sensor.tip_noise_m=0.004", "--bag-dir", str(tmp_path / "b"),
                 "--plot", str(tmp_path / "vg.png")])
    err = capsys.readouterr().err
    assert code == 2 and len(err.splitlines()) == 1 and "reads as flutter" in err and "quieter" in err, err
    assert not (tmp_path / "b").exists() or not any((tmp_path / "b").iterdir())


def test_noisy_sensor_is_no_flutter_and_is_warned_of(tmp_path, capsys):
    """`flutter-test --in-process --dwell 20 --max-points 2 --set sensor.tip_noise_m=0.002` printed "point 1:
    5.240 m/s: fluttered at 5.240 m/s" (exit 1) from the noise's peaks; the true tip was ~1e-4 L. The noise (400
    times the turbulence response) hides the flutter mode: the test stops without clearance, and says why."""
    from panel_rig.cli import main

    code = main(["flutter-test", "--in-process", "--dwell", "20", "--max-points", "2", "--set",
                 "sensor.tip_noise_m=0.002", "--json", "--bag-dir", str(tmp_path), "--plot", str(tmp_path / "vg.png")])
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    assert code == 1 and not out["fluttered"] and len(out["test_points"]) == 1, captured.err
    assert out["stop_reason"].startswith("flutter mode not identified at 5.240 m/s"), out["stop_reason"]
    assert "warning: sensor.tip_noise_m 0.002 m is over half the flutter monitor's level" in captured.err


def test_a_ctrl_c_during_a_dwell_leaves_a_whole_bag_whose_replay_is_the_test_s(tmp_path, capsys, monkeypatch):
    """Ctrl-C landing while a block of readings is handed to the recording (here: as the block is emitted, in the
    second point's dwell). Before, the KeyboardInterrupt cut the hand-over: one such bag's summary counted a message
    its data section did not hold (`analyze` refused it as corrupt), the rig's time ran ahead of the last recorded
    reading (the wind-off stamped 68 s after it), and the replay identified the cut dwell as a point the test never
    took. Now the stop waits for the block's end: the bag holds every reading marched, and its replay gives the
    test's one point."""
    import os
    import signal

    from panel_rig.analyze_cli import analyze_bag
    from panel_rig.recording.series import load_series
    from panel_rig.rig.rig import Rig

    emitted_after_point: list[int] = []
    real_emit, real_line = Rig.emit_block, flutter_cli.point_line

    def point_line(index, point, decision):
        emitted_after_point.append(0)
        return real_line(index, point, decision)

    def emit_block(self, block):
        if emitted_after_point:
            emitted_after_point[0] += 1
            if emitted_after_point[0] == 5:  # 5 s into the second point's dwell (settle 1 s, blocks of 1 s)
                os.kill(os.getpid(), signal.SIGINT)
        return real_emit(self, block)

    monkeypatch.setattr(flutter_cli, "point_line", point_line)
    monkeypatch.setattr(Rig, "emit_block", emit_block)
    code, out, captured = run_thin_test(tmp_path, capsys)
    assert code == 130 and out["interrupted"] is True and len(out["test_points"]) == 1, captured.err
    rec = load_series(out["bag"])
    assert rec.t_s[-1] == pytest.approx(out["simulated_s"], abs=1e-9)  # nothing marched went unrecorded
    replay = analyze_bag(out["bag"])["flutter_test"]["test_points"]
    assert [p["damping_ratio"] for p in replay] == pytest.approx([out["test_points"][0]["damping_ratio"]], abs=1e-9)


def test_a_ctrl_c_during_a_point_s_identification_still_takes_the_point_its_bag_holds(tmp_path, capsys,
                                                                                      monkeypatch):
    """A stop after the second dwell was recorded whole, while it was being identified: the test reported one point
    where its bag held two complete dwells (the replay found two). The point is now taken as the live client takes
    the node's late result: identified, recorded with its decision, and the replay agrees."""
    import os
    import signal

    import panel_rig.analysis.flutter_test as procedure
    from panel_rig.analyze_cli import analyze_bag

    calls: list[int] = []
    real = procedure.identify_point

    def identify_point(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGINT)
        return real(*args, **kwargs)

    monkeypatch.setattr(procedure, "identify_point", identify_point)
    code, out, captured = run_thin_test(tmp_path, capsys)
    assert code == 130 and len(out["test_points"]) == 2 and len(out["monitor_times_s"]) == 2, captured.err
    replay = analyze_bag(out["bag"])["flutter_test"]["test_points"]
    assert [p["damping_ratio"] for p in replay] == pytest.approx([p["damping_ratio"] for p in out["test_points"]],
                                                                abs=1e-9)


def test_a_stopped_live_test_counts_the_point_the_node_identified_last():
    """The node's result for the point under way can arrive while the stopped client turns the wind off (seen in a
    run stopped 0.6 s after the first point: 170 s simulated, two monitor results, one point reported). The node
    identified that point on the whole dwell, so it is counted, bit for bit; a result already taken, for another
    airspeed, or of a plateau the wind-off cut short, is not."""
    pytest.importorskip("diagnostic_msgs")
    from panel_rig.analysis.flutter_test import FlutterTestResult
    from panel_rig.ros.flutter_live import take_late_result
    from panel_rig.ros.flutter_monitor import monitor_msg, parse_monitor

    s = FlutterTestSettings(start_mps=5.0, step_mps=1.0, n_boot=50)
    pts = [_point(5.0), _point(6.0)]

    def result(k, end_s):  # the k-th point's result, identified at end_s on a plateau from 100 s (5 + 80 s dwell)
        plateau = {"point_index": k, "plateau_start_s": 100.0, "settle_s": 5.0, "dwell_s": 80.0, "sim_time_s": end_s}
        return parse_monitor(monitor_msg(k, pts[k - 1], decide(pts[:k], s), 0.1, plateau=plateau))

    res = FlutterTestResult(points=pts[:1], decisions=[decide(pts[:1], s)], max_airspeed_mps=6.0)
    # "point": the caller prints its line (a review's SIGTERM run printed two point lines, then "after 3 points")
    assert take_late_result(res, [result(1, 50.0), result(2, 185.0)]) == "point"
    assert res.points[-1] == pts[1] and len(res.points) == 2
    assert take_late_result(res, [result(1, 50.0), result(2, 185.0)]) is None  # taken: not twice
    assert len(res.points) == 2
    cut = FlutterTestResult(points=pts[:1], max_airspeed_mps=6.0)  # the wind-off cut the plateau after 30 s
    assert take_late_result(cut, [result(1, 50.0), result(2, 135.0)]) is None
    ahead = FlutterTestResult(points=pts[:1], max_airspeed_mps=7.0)  # the 7 m/s point's result never came
    assert take_late_result(ahead, [result(1, 50.0), result(2, 185.0)]) is None
    assert len(cut.points) == len(ahead.points) == 1
    # a repeated airspeed is a result of its own: the 5 m/s point taken again is counted (it was taken for the first)
    again = FlutterTestResult(points=pts[:1], max_airspeed_mps=5.0)
    repeat = parse_monitor(monitor_msg(2, pts[0], decide(pts[:1], s), 0.1, plateau={
        "point_index": 2, "plateau_start_s": 100.0, "settle_s": 5.0, "dwell_s": 80.0, "sim_time_s": 185.0}))
    assert take_late_result(again, [result(1, 50.0), repeat]) == "point" and len(again.points) == 2
    assert take_late_result(again, [result(1, 50.0), repeat]) is None


def test_a_test_that_flutters_at_its_first_point_says_so(tmp_path, capsys):
    """`flutter-test --start-mps 12` (1.15 U_f): the first point fluttered. The test printed no line for it, its
    stop reason was null and its plot ended below 12 m/s without the point. Now the point's line, the stop reason
    (the node monitor's text) and a mark on the plot say where it fluttered."""
    import json

    from panel_rig.cli import main

    png = tmp_path / "vg.png"
    code = main(["flutter-test", "--in-process", "--start-mps", "12", "--dwell", "20", "--json",
                 "--bag-dir", str(tmp_path / "bags"), "--plot", str(png)])
    out, err = capsys.readouterr()
    d = json.loads(out)
    assert code == 1 and d["fluttered"] and d["test_points"] == []
    assert d["stop_reason"] == "fluttered at 12.000 m/s"
    assert "point 1: 12.000 m/s: fluttered at 12.000 m/s; stop" in err, err
    assert png.stat().st_size > 0 and d["plot"] == str(png)
    # as the live node's monitor reports the flutter at once and the client winds off: the in-process rig marched
    # the whole 25 s plateau and recorded no monitor result for it; `analyze` of a live bag, whose plateau the
    # flutter cut too short to be one, said only "stable up to 0.00 m/s" (its wind-off plateau)
    assert d["simulated_s"] < 5 + 20 - 1, d["simulated_s"]
    capsys.readouterr()
    assert main(["analyze", d["bag"]]) == 0
    text = capsys.readouterr().out
    assert "flutter monitor: the panel fluttered at 12.000 m/s (reported at t = " in text, text
    assert "stable up to 0.00" not in text


def test_a_second_ctrl_c_while_a_stopped_test_winds_up_keeps_its_report(tmp_path, capsys, monkeypatch):
    """Ctrl-C after the first point, then Ctrl-C again while the stopped test closes its recording and draws its
    plot (an impatient operator): the second one raised KeyboardInterrupt there and the whole report was lost
    ("panel-rig: interrupted", no table, no plot). Now it is ignored until the report is made."""
    import os
    import signal

    from panel_rig import flutter_cli
    from panel_rig.analysis import plots

    def interrupt_after(index, point, decision):  # the first Ctrl-C, just after the first point
        os.kill(os.getpid(), signal.SIGINT)
        return real_line(index, point, decision)

    def interrupt_while_drawing(*args, **kwargs):  # the second, while the plot is drawn
        os.kill(os.getpid(), signal.SIGINT)
        return real_plot(*args, **kwargs)

    real_line, real_plot = flutter_cli.point_line, plots.plot_flutter_test
    monkeypatch.setattr(flutter_cli, "point_line", interrupt_after)
    monkeypatch.setattr(plots, "plot_flutter_test", interrupt_while_drawing)
    code, out, captured = run_thin_test(tmp_path, capsys)
    assert code == 130 and out["interrupted"] is True, captured.err
    assert len(out["test_points"]) == 1 and out["stop_reason"].startswith("interrupted by SIGINT after 1 test")
    assert (tmp_path / "vg.png").stat().st_size > 0


def test_a_window_of_exactly_the_minimum_dwell_is_a_test_point(monkeypatch):
    """A `--dwell 20` test's 8.384 m/s point, commanded at 63.00000000000001 s (a sum of simulated seconds), had a
    replay window of 19.999999999999993 s, under the 20 s minimum: `analyze` dropped it without a word and its
    prediction differed from the test's."""
    import numpy as np

    from panel_rig.analysis import flutter_test

    monkeypatch.setattr(flutter_test, "identify_point",
                        lambda y, dt, u, bands, force=None, ssi=None: flutter_test.TestPoint(u, None, None, "stub"))
    t = np.arange(0.0, 90.0, 1.0 / 512.0)
    tip = 1e-6 * np.sin(2 * np.pi * 23.0 * t)
    cmds = [(42.0, 5.0), (63.00000000000001, 6.0), (84.0, 0.0)]
    points = flutter_test.replay_points(t, tip, cmds, lambda u: [], 0.27, settle_s=1.0, min_dwell_s=20.0,
                                        dwell_s=20.0)
    assert [p.airspeed_mps for p in points] == [5.0, 6.0]


def test_a_refused_rerun_path_makes_no_bag_directory(tmp_path, capsys):
    """`flutter-test --rerun x.txt --bag-dir NEW`: refused (exit 2, one line), but NEW had been made first."""
    from panel_rig.cli import main

    assert main(["flutter-test", "--in-process", "--rerun", str(tmp_path / "x.txt"),
                 "--bag-dir", str(tmp_path / "bags")]) == 2
    assert "--rerun: a Rerun recording is saved to a .rrd file" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_the_replay_skips_a_step_down_as_the_live_monitor_does(monkeypatch):
    """6, 7, 8 m/s, down to 5, then 9 m/s: the live monitor skips the step down and takes 9 m/s; the replay stopped
    at the step down, so a bag's replay lost the test's later points (a user's 10.2 m/s point and its prediction)."""
    import numpy as np

    from panel_rig.analysis import flutter_test

    monkeypatch.setattr(flutter_test, "identify_point",
                        lambda y, dt, u, bands, force=None, ssi=None: flutter_test.TestPoint(u, None, None, "stub"))
    t = np.arange(0.0, 130.0, 1.0 / 512.0)
    cmds = [(0.0, 6.0), (25.0, 7.0), (50.0, 8.0), (75.0, 5.0), (100.0, 9.0)]
    points = flutter_test.replay_points(t, 1e-6 * np.sin(2 * np.pi * 23.0 * t), cmds, lambda u: [], 0.27,
                                        settle_s=1.0, min_dwell_s=20.0, dwell_s=20.0)
    assert [p.airspeed_mps for p in points] == [6.0, 7.0, 8.0, 9.0]
    # the same airspeed commanded again (a repeated point of the flutter test) is a point of its own
    cmds = [(0.0, 6.0), (25.0, 7.0), (50.0, 7.0), (75.0, 5.0), (100.0, 9.0)]
    ends: list[float] = []  # when each was identified (the Rerun replay logs it there)
    points = flutter_test.replay_points(t, 1e-6 * np.sin(2 * np.pi * 23.0 * t), cmds, lambda u: [], 0.27,
                                        settle_s=1.0, min_dwell_s=20.0, dwell_s=20.0, ends_s=ends)
    assert [p.airspeed_mps for p in points] == [6.0, 7.0, 7.0, 9.0]
    assert ends == [21.0, 46.0, 71.0, 121.0]


def test_the_replay_takes_no_test_point_where_a_controller_closed_the_loop(monkeypatch):
    """6, 7, 8, 9 m/s with a controller on from 60 to 80 s (the 8 m/s window): that window's damping is the
    controlled panel's, so it is no test point, and the replay says why; the open-loop points before and after
    are kept. Before, the replay took it as the panel's own."""
    import numpy as np

    from panel_rig.analysis import flutter_test

    monkeypatch.setattr(flutter_test, "identify_point",
                        lambda y, dt, u, bands, force=None, ssi=None: flutter_test.TestPoint(u, None, None, "stub"))
    t = np.arange(0.0, 105.0, 1.0 / 512.0)
    cmds = [(0.0, 6.0), (25.0, 7.0), (50.0, 8.0), (80.0, 9.0)]
    skipped: list[str] = []
    points = flutter_test.replay_points(t, 1e-6 * np.sin(2 * np.pi * 23.0 * t), cmds, lambda u: [], 0.27,
                                        settle_s=1.0, min_dwell_s=20.0, skipped=skipped,
                                        closed_loop_s=[(60.0, 79.5)])
    assert [p.airspeed_mps for p in points] == [6.0, 7.0, 9.0]
    assert skipped == ["8.00 m/s: a controller closed the loop"]


def test_the_v_g_figure_says_what_was_tested_and_how_it_ended():
    """The flutter-test figure had no title: an interrupted test's one-point plot read as a finished result, and
    neither the variant nor the tunnel was on it."""
    from panel_rig.analysis.flutter_test import FlutterTestResult, figure_title

    cfg = load_config()
    res = FlutterTestResult(points=[_point(5.0)], decisions=[decide([_point(5.0)], FlutterTestSettings(5.0, 1.0))],
                            interrupted="SIGINT")
    title = figure_title(res, cfg, "full", 200.0, "in-process")
    assert title.startswith("flutter test (in-process): variant full, turbulence 0.1 % (seed 0), dwell 200 s")
    assert "stop: interrupted by SIGINT after 1 test point(s)" in title
    quiet = figure_title(FlutterTestResult(), cfg.replace(turbulence_intensity=0.0), "exact", 20.0, "live node")
    assert "no turbulence" in quiet and "0 point(s); stop: none" in quiet
    # a long stop reason is wrapped to the figure's width (a review's plot cut one 200-character line at both edges)
    unidentified = FlutterTestResult(points=[TestPoint(5.24, None, None, "ssi-cov")])
    unidentified.decisions = [decide(unidentified.points, FlutterTestSettings(5.0, 1.0))]
    long = figure_title(unidentified, cfg, "full", 200.0, "in-process")
    assert len(long.splitlines()) >= 3 and max(len(line) for line in long.splitlines()) <= 100, long
    assert "tunnel.turbulence.intensity" in long


def test_a_full_disk_stops_the_in_process_test_with_the_bag_written_so_far(tmp_path, capsys, monkeypatch):
    """A full disk under --bag-dir (a 3 MB tmpfs, 2026-12-05): the bag sink's traceback was printed five times, the
    test marched on to its end with nothing recorded, and it died on 'cannot finish'. Now the first failed write
    stops the test: one line says where and how to get the bag back, and what was written is readable. The points
    identified before it are reported as an interrupted test's (they were in the progress lines only)."""
    import errno
    import json

    from panel_rig.analyze_cli import analyze_bag
    from panel_rig.cli import main
    from panel_rig.recording import BagWriter

    real_write, calls = BagWriter.write, []

    def write_until_full(self, *args, **kwargs):
        calls.append(1)
        if len(calls) > 120_000:  # about 78 s of readings (3 topics at 512 samples/s): three 20 s dwells and more
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(self, *args, **kwargs)

    monkeypatch.setattr(BagWriter, "write", write_until_full)
    code = main(["flutter-test", "--in-process", "--dwell", "20", "--bag-dir", str(tmp_path), "--json",
                 "--plot", str(tmp_path / "vg.png")])
    captured = capsys.readouterr()
    err, out = captured.err, json.loads(captured.out)
    last = err.strip().splitlines()[-1]
    assert code == 1 and "Traceback" not in err, err
    assert last.startswith("panel-rig flutter-test: the recording failed after 3 test point(s), at t = 7"), last
    assert "No space left on device; the test stopped there" in last and "bag recover" in last
    assert len(out["test_points"]) == 3 and out["interrupted"] and out["fluttered"] is False
    assert out["stop_reason"] == "interrupted by a failed recording after 3 test point(s)"
    # `margin` is the predicted margin at the last point, as the monitor's; `required_margin` is --margin
    assert out["required_margin"] == 0.1 and out["predicted_flutter_speed_mps"] is not None
    assert out["margin"] == pytest.approx(1 - out["test_points"][-1]["airspeed_mps"] / out["predicted_flutter_speed_mps"])
    assert (tmp_path / "vg.png").is_file() and out["plot"] == str(tmp_path / "vg.png")
    (bag,) = [p for p in tmp_path.iterdir() if p.is_dir()]
    assert out["bag"] == str(bag)
    monkeypatch.setattr(BagWriter, "write", real_write)
    assert out["simulated_s"] - 1.0 < analyze_bag(bag)["duration_s"] < out["simulated_s"] + 0.1


def test_a_full_disk_before_any_point_says_so_in_the_table(tmp_path, capsys, monkeypatch):
    """The same stop 8 s into the first dwell: the table says no point was identified and why the test ended."""
    import errno

    from panel_rig.cli import main
    from panel_rig.recording import BagWriter

    real_write, calls = BagWriter.write, []

    def write_until_full(self, *args, **kwargs):
        calls.append(1)
        if len(calls) > 12_000:
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(self, *args, **kwargs)

    monkeypatch.setattr(BagWriter, "write", write_until_full)
    code = main(["flutter-test", "--in-process", "--dwell", "20", "--bag-dir", str(tmp_path),
                 "--plot", str(tmp_path / "vg.png")])
    captured = capsys.readouterr()
    assert code == 1 and "Traceback" not in captured.err, captured.err
    assert captured.err.strip().splitlines()[-1].startswith(
        "panel-rig flutter-test: the recording failed after 0 test point(s), at t = 8.0 s")
    assert "no test point identified (see stop)" in captured.out
    assert "stop: interrupted by a failed recording after 0 test point(s)" in captured.out
    assert not (tmp_path / "vg.png").exists()  # a figure of nothing is not drawn


def test_a_test_that_could_outgrow_the_disk_is_warned_before_it_starts(tmp_path, monkeypatch):
    """--dwell 1000 could record 1.9 GB (12 points); nothing said so before the disk filled."""
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    settings = default_plan(10.0, 0.1, None, dwell_s=1000.0)
    n = settings.max_points
    need_mb = 300 * n * 1005 * 512 / 1e6
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(1e13, 0, 1e6 * need_mb * 1.01))
    assert flutter_cli.disk_warning(tmp_path, settings, 1 / 512) is None
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(1e13, 0, 3e6))
    text = flutter_cli.disk_warning(tmp_path, settings, 1 / 512)
    assert text == (f"warning: {n} test points of 1005 s could record about {need_mb:.0f} MB; "
                    f"{tmp_path} has 3 MB free (a full disk stops the test, the bag written so far kept)")
    # the live node stops recording at its record_min_free_mb: that much of the free space is not the test's
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(1e13, 0, 1e6 * need_mb * 1.01))
    text = flutter_cli.disk_warning(tmp_path, settings, 1 / 512, reserve_bytes=500e6)
    assert text is not None and text.endswith("(the node stops recording, and the test, with 500 MB left, the bag "
                                              "written so far kept)"), text


@pytest.mark.parametrize(("option", "value", "message"), [
    ("--margin", "nan", "--margin must be in (0, 1), got nan"),
    ("--margin", "1", "--margin must be in (0, 1), got 1.0"),
    ("--max-points", "0", "--max-points must be >= 1, got 0"),
    ("--repeats", "-1", "--repeats must be in [0, 12], got -1"),
])
def test_a_bad_margin_or_point_count_is_named_with_its_value(tmp_path, capsys, option, value, message):
    from panel_rig.cli import main

    assert main(["flutter-test", "--in-process", option, value, "--bag-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith(message) and "\n" not in err, err


def test_a_repeated_point_is_taken_recorded_and_replayed(tmp_path, capsys):
    """`flutter-test --in-process --dwell 20`: at 8.968 m/s the prediction (9.47 m/s, interval [9.06, open]) leaves
    a margin of 0.053; the test takes that airspeed again before it stops, prints why, records the repeated
    set-point, and `analyze` replays both points from the bag. With `--repeats 0` it stops there at once."""
    import json

    from panel_rig.analyze_cli import analyze_bag
    from panel_rig.cli import main

    def run(*extra):
        code = main(["flutter-test", "--in-process", "--dwell", "20", "--json", "--bag-dir", str(tmp_path),
                     "--plot", str(tmp_path / "vg.png"), *extra])
        captured = capsys.readouterr()
        return code, json.loads(captured.out), captured.err

    code, out, err = run()
    u = [p["airspeed_mps"] for p in out["test_points"]]
    assert code == 0 and len(u) == 6 and u[4] == u[5] and len(set(u)) == 5, u
    assert f"point 5: {u[4]:.3f} m/s" in err and f"next {u[4]:.3f} m/s (repeat the point: predicted margin" in err
    assert out["stop_reason"].startswith("predicted margin") and not out["fluttered"]
    replay = analyze_bag(out["bag"])["flutter_test"]
    assert [p["airspeed_mps"] for p in replay["test_points"]] == u
    for live, again in zip(out["test_points"], replay["test_points"]):
        assert again["damping_ratio"] == pytest.approx(live["damping_ratio"], abs=1e-9)
    assert replay["predicted_flutter_speed_mps"] == pytest.approx(out["predicted_flutter_speed_mps"], rel=1e-9)
    code, once, _ = run("--repeats", "0")
    assert code == 0 and [p["airspeed_mps"] for p in once["test_points"]] == u[:5]
    assert once["stop_reason"] == "predicted margin 0.053 < 0.1"
