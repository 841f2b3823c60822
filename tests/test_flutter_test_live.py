"""`panel-rig flutter-test` end to end on the live node over topics (the default path): the command starts the rig
node in a private ROS domain, commands the airspeed on /rig/airspeed_cmd and takes each test point from the
node's /rig/flutter_monitor. Bounded: a thicker panel (any --set configuration must work), 80 s dwells, three
points from 8.4 m/s (0.7, 0.8, 0.9 U_f), 255 s simulated (~13 s wall). Points at 0.5-0.7 U_f with 40 s dwells
were tried first: the damping estimates (+-0.004) did not fall monotonically and rounding-level changes of the
model decided whether a prediction existed."""

import json
import os
import re
import stat
import subprocess
import sys
from pathlib import Path

import pytest

SETTLE_S, DWELL_S, START_MPS = 5.0, 80.0, 8.4


@pytest.fixture(scope="module")
def live_run(tmp_path_factory):
    pytest.importorskip("rclpy")
    from panel_rig.cli import main

    tmp = tmp_path_factory.mktemp("flutter_live")
    import contextlib
    import io

    buf, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(err):
        code = main(["flutter-test", "--set", "panel.thickness_m=0.0004", "--dwell", str(DWELL_S), "--start-mps",
                     str(START_MPS), "--max-points", "3", "--json", "--bag-dir", str(tmp), "--plot", str(tmp / "vg.png")])
    print(err.getvalue(), file=sys.stderr)  # shown by pytest on a failure
    return code, json.loads(buf.getvalue()), tmp, err.getvalue()


def test_live_flutter_test_json_and_lockstep(live_run):
    """The issue's JSON keys; the node was driven live (its own model, its own bag, its exit code 0); the client's
    prediction equals the node monitor's own (the same points rebuilt bit for bit, the same seeded bootstrap)."""
    code, out, tmp, _ = live_run
    assert code == 0, out
    for key in ("test_points", "predicted_flutter_speed_mps", "predicted_flutter_speed_ci_mps", "max_airspeed_mps",
                "fluttered", "bag"):
        assert key in out
    assert out["live"] is True and out["node_exit_code"] == 0 and out["fluttered"] is False
    assert out["model_flutter_speed_mps"] > 11.0  # thicker panel: later flutter than the paper's 10.48 m/s
    u = [p["airspeed_mps"] for p in out["test_points"]]
    assert len(u) == 3 and u[0] == START_MPS and u == sorted(u)
    assert out["max_airspeed_mps"] == max(u) < out["model_flutter_speed_mps"]
    for p in out["test_points"]:
        lo, hi = p["damping_ci"]
        assert lo < p["damping_ratio"] < hi and 0.0 < p["damping_ratio"] < 0.05
        assert p["method"] == "ssi-cov" and p["first_mode"] is not None
    assert out["predicted_flutter_speed_mps"] is not None
    assert out["node_prediction_mps"] == out["predicted_flutter_speed_mps"]
    # the third point (0.9 U_f) is close enough for the procedure to stop on the margin, or the point budget ends it
    assert out["stop_reason"] == "3 test points done" or out["stop_reason"].startswith("predicted margin")
    assert (tmp / "vg.png").stat().st_size > 0
    # the run directory is made as the user's other directories are (it was 0700) and named as the in-process one
    run_dir = Path(out["bag"]).parent
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(run_dir.stat().st_mode) == 0o777 & ~umask and re.fullmatch(r"flutter_test_\d{8}_\d{6}(_\d+)?",
                                                                                   run_dir.name), run_dir


def test_live_flutter_test_shows_each_point_as_it_is_identified(live_run):
    """A line per test point on stderr while the test runs (a stopped test has shown what it found)."""
    _, out, _, err = live_run
    lines = [ln for ln in err.splitlines() if ln.startswith("point ")]
    assert [ln.split(":")[1].strip() for ln in lines] == [f"{p['airspeed_mps']:.3f} m/s" for p in out["test_points"]]
    assert lines[-1].endswith(f"stop ({out['stop_reason']})")


def test_live_dwell_is_in_simulated_time_and_the_node_holds_for_the_client(live_run):
    """From the recorded monitor messages and commands: each result comes one block after settle + dwell of
    simulated time from its command, and the next command arrives at the simulated instant of the previous result
    (the node held while the client decided): the run does not depend on how fast either process is."""
    from panel_rig.recording.reader import read_bag
    from panel_rig.ros.flutter_monitor import parse_monitor

    _, out, _, _ = live_run
    results, cmds = [], []
    for topic, _, stamp_ns, msg in read_bag(out["bag"], topics=["/rig/flutter_monitor", "/rig/airspeed_cmd"]):
        if topic.endswith("flutter_monitor"):
            results.append(parse_monitor(msg))
        else:
            cmds.append((stamp_ns * 1e-9, msg.data))
    assert [r["airspeed_mps"] for r in results] == [p["airspeed_mps"] for p in out["test_points"]]
    assert [c[1] for c in cmds] == [p["airspeed_mps"] for p in out["test_points"]] + [0.0]
    for r, (t_cmd, _) in zip(results, cmds):
        assert r["plateau_start_s"] == pytest.approx(t_cmd, abs=1e-6)
        assert r["settle_s"] == SETTLE_S and r["dwell_s"] == DWELL_S
        assert 0.0 <= r["sim_time_s"] - (t_cmd + SETTLE_S + DWELL_S) < 0.2  # one fast-mode block at most
    for r, (t_next, _) in zip(results, cmds[1:]):
        assert t_next == pytest.approx(r["sim_time_s"], abs=1e-6)
    assert out["simulated_s"] == pytest.approx(results[-1]["sim_time_s"])


def test_analyze_replays_the_live_identification(live_run):
    """`panel-rig analyze BAG` on the node's bag cuts the same windows (the node's flutter_test.* parameters are
    in the bag) and identifies the same points."""
    from panel_rig.analyze_cli import analyze_bag

    _, out, _, _ = live_run
    ft = analyze_bag(out["bag"])["flutter_test"]
    assert [p["airspeed_mps"] for p in ft["test_points"]] == [p["airspeed_mps"] for p in out["test_points"]]
    for live, again in zip(out["test_points"], ft["test_points"]):
        assert again["damping_ratio"] == pytest.approx(live["damping_ratio"], rel=1e-6)
        assert again["frequency_hz"] == pytest.approx(live["frequency_hz"], rel=1e-9)
    assert ft["predicted_flutter_speed_mps"] == pytest.approx(out["predicted_flutter_speed_mps"], rel=1e-6)
    # one meaning per key: the margin reached at the last point, and the one the test required
    assert ft["margin"] == pytest.approx(out["margin"], rel=1e-6) and ft["required_margin"] == out["required_margin"]


def test_live_flutter_test_reports_a_dead_node_in_one_line(tmp_path, capsys, monkeypatch):
    """A node that cannot start (here: a physics value the node refuses) ends the command with one line naming
    the node's log, exit 1, no traceback."""
    pytest.importorskip("rclpy")
    from panel_rig.cli import main
    from panel_rig.ros import flutter_live

    real = flutter_live.node_parameters

    def broken(*a, **k):
        return {**real(*a, **k), "publish_rate_hz": -1.0}

    monkeypatch.setattr(flutter_live, "node_parameters", broken)
    code = main(["flutter-test", "--dwell", "20", "--json", "--bag-dir", str(tmp_path), "--plot",
                 str(tmp_path / "vg.png")])
    err = capsys.readouterr().err
    assert code == 1 and "node log:" in err and len(err.strip().splitlines()) == 1, err


def test_live_flutter_test_reports_a_refused_set_point(tmp_path, capsys, monkeypatch):
    """A first point above the tunnel's limit: refused before the node starts (exit 2, one line, nothing
    recorded); and should the node still refuse a set-point (the check before the start left out here), the
    command says so in one line (exit 1) instead of waiting for a test point that will never come."""
    pytest.importorskip("rclpy")
    from panel_rig.cli import main
    from panel_rig.ros import flutter_live

    args = ["flutter-test", "--start-mps", "50", "--bag-dir", str(tmp_path), "--plot", str(tmp_path / "v.png")]
    code = main(args)
    err = capsys.readouterr().err
    assert code == 2 and len(err.splitlines()) == 1 and "must be at most this test's airspeed limit, 30 m/s" in err, err
    assert not any(tmp_path.iterdir())
    monkeypatch.setattr(flutter_live, "start_problem", lambda settings, limit: None)
    code = main(args)
    err = capsys.readouterr().err
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("warning: --start-mps")]  # the margin's
    assert code == 1 and "rejected" in err and "exceeds the limit" in err and len(lines) == 1, err


def test_a_terminated_flutter_test_turns_the_wind_off_and_stops_its_node(ros_env, tmp_path):
    """SIGTERM (a `kill`, a job scheduler) during a test point: the same clean stop as Ctrl-C. Before, the client
    died at once and its rig node ran on as an orphan, recording, with the wind on. The table of what was measured
    (nothing yet: the first point was under way) is printed all the same."""
    import signal
    import subprocess
    import sys
    import time

    import psutil

    rclpy = pytest.importorskip("rclpy")
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from panel_rig.recording.series import load_series
    from panel_rig.ros.messages import rig_status

    domain = int(ros_env["ROS_DOMAIN_ID"])
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    watcher = rclpy.create_node("airspeed_watch", namespace="/rig", context=ctx)
    commands: list[float] = []

    def on_diagnostics(msg: DiagnosticArray) -> None:  # the node's set-point (a second airspeed_cmd subscriber
        values = rig_status(msg, "/rig")  # would make the test refuse to run: it cannot tell it from another rig)
        if values is not None and float(values.get("airspeed_setpoint_mps", "0")) > 0:
            commands.append(float(values["airspeed_setpoint_mps"]))

    watcher.create_subscription(DiagnosticArray, "/diagnostics", on_diagnostics,
                                QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE))
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(watcher)
    proc = subprocess.Popen([sys.executable, "-m", "panel_rig.cli", "flutter-test", "--domain-id", str(domain),
                             "--dwell", "400", "--max-points", "2", "--bag-dir", str(tmp_path),
                             "--plot", str(tmp_path / "vg.png")], env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 240
        while not commands and proc.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        assert commands and commands[0] > 0, "the test never commanded a test point"
        node_procs = psutil.Process(proc.pid).children(recursive=True)
        assert node_procs, "no rig node under the flutter test"
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        executor.shutdown()
        watcher.destroy_node()
        rclpy.shutdown(context=ctx)
    assert proc.returncode == 143, err[-2000:]
    assert "flutter-test stopped by SIGTERM after 0 identified test point(s)" in err, err[-2000:]
    assert "stop: interrupted by SIGTERM after 0 test point(s)" in out, out
    assert f"max airspeed {commands[0]:.3f} m/s" in out, out  # the point under way was commanded
    # no result yet: the simulated time is the node's last reported one (it read "nan s simulated ... RTF nan")
    assert "nan" not in out and int(re.search(r"; (\d+) s simulated in ", out).group(1)) > 0, out
    gone, alive = psutil.wait_procs(node_procs, timeout=10)
    assert not alive, f"left running: {alive}"
    bag = load_series(next(tmp_path.glob("flutter_test_*/rig_*")))
    assert bag.commands["airspeed_cmd"][-1][1] == 0.0, bag.commands["airspeed_cmd"]  # the wind off, recorded


def test_a_flutter_test_stopped_with_ctrl_c_reports_the_points_it_identified(ros_env, tmp_path, stderr_lines):
    """Ctrl-C after the first test point (during the second, or just before its command): the JSON of the first
    point, marked interrupted, its plot, the wind off recorded, the node stopped (exit 0), status 130, and a line
    naming the replay of the recording. Before, only the progress lines showed what had been found."""
    import signal
    import subprocess
    import sys

    pytest.importorskip("rclpy")
    from panel_rig.recording.series import load_series

    proc = subprocess.Popen([sys.executable, "-m", "panel_rig.cli", "flutter-test", "--domain-id",
                             ros_env["ROS_DOMAIN_ID"], "--set", "panel.thickness_m=0.0004", "--start-mps",
                             str(START_MPS), "--dwell", str(DWELL_S), "--max-points", "3", "--json", "--bag-dir",
                             str(tmp_path), "--plot", str(tmp_path / "vg.png")], env=ros_env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    err = stderr_lines(proc)
    try:
        err.wait_for("point 1:", 240)  # the first point identified and decided: the second is under way
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
        out = json.loads(proc.stdout.read())
    finally:
        err.close()
    text = err.text
    assert proc.returncode == 130, text[-2000:]
    n = len(out["test_points"])  # 2 only if the second point's whole dwell ended before the signal (~0.7 s wall)
    assert out["interrupted"] is True and out["stop_reason"] == f"interrupted by SIGINT after {n} test point(s)"
    assert n in (1, 2) and out["test_points"][0]["airspeed_mps"] == START_MPS and out["node_exit_code"] == 0
    assert out["plot"] == str(tmp_path / "vg.png") and (tmp_path / "vg.png").stat().st_size > 0
    assert f"`panel-rig analyze {out['bag']}` replays the flutter test" in text, text[-2000:]
    assert load_series(out["bag"]).commands["airspeed_cmd"][-1][1] == 0.0  # the wind off, recorded


def test_flutter_test_refuses_a_domain_where_another_rig_takes_its_commands(ros_env, tmp_path):
    """`--domain-id` of a domain where somebody's rig node runs: the test's commands went to that node too, and the
    test hung. Now it stops before the first command, naming the reason."""
    import subprocess
    import sys
    import time

    rclpy = pytest.importorskip("rclpy")
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor

    from panel_rig.processes import module_command, stop

    other = subprocess.Popen([*module_command("panel_rig.ros.rig_node"), "--fast", "--ros-args", "-r", "__ns:=/rig",
                              "-p", "fast_max_realtime_factor:=1.0"], env=ros_env, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    watcher = rclpy.create_node("rig_watch", context=ctx)
    heard: list[int] = []
    watcher.create_subscription(DiagnosticArray, "/diagnostics", lambda m: heard.append(1), 10)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(watcher)
    try:
        deadline = time.monotonic() + 120  # the other rig is up (and discoverable) before the test starts
        while not heard and other.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        assert heard, "the other rig node did not come up"
        out = subprocess.run([sys.executable, "-m", "panel_rig.cli", "flutter-test", "--domain-id",
                              ros_env["ROS_DOMAIN_ID"], "--max-points", "1", "--dwell", "20", "--bag-dir",
                              str(tmp_path), "--plot", str(tmp_path / "vg.png")], env=ros_env, capture_output=True,
                             text=True, timeout=300)
    finally:
        executor.shutdown()
        watcher.destroy_node()
        rclpy.shutdown(context=ctx)
        stop(other, 60)
    assert out.returncode == 1 and "choose another --domain-id" in out.stderr, out.stderr[-2000:]


def test_a_node_whose_recording_failed_stops_the_live_test():
    """A full disk under --bag-dir (a 4 MB tmpfs, 2026-12-05): the node ran on with its recording failed (it says
    so in /diagnostics), and the live test would have gone on recording nothing. The client stops on that status
    with the node's reason and how to get the bag back (the whole run, measured by hand: exit 1 after 52 s
    simulated, the bag recovered)."""
    pytest.importorskip("rclpy")
    from panel_rig.ros.flutter_client import recording_failure

    assert recording_failure({}) is None and recording_failure({"recording": "on"}) is None
    why = recording_failure({"recording": "failed", "last_recording_error": "cannot write b.mcap: No space left"})
    assert why.startswith("the rig node's recording failed (cannot write b.mcap: No space left); the test stopped")
    assert "`panel-rig bag recover` on the run's rig_* bag" in why


def test_a_point_the_node_never_reports_stops_the_test_in_simulated_time():
    """A window the node's monitor never identified (`--dwell 20 --settle 0`, 2026-12-05) left the client waiting
    while the fast node ran free: 269,000 simulated s, a 76 GB bag, a full disk. The client now bounds each point in
    the node's simulated time (run-in + dwell + slack, from the first diagnostics report after the command) and
    stops with a line that says so. The whole run, measured by hand with the monitor's finish disabled: exit 1 when
    the first 20 s point was 81 simulated s overdue (2 Hz diagnostics at the fast node's RTF ~100), the node stopped
    at 240 simulated s, its bag 70 MB, 7 s wall."""
    pytest.importorskip("rclpy")
    from panel_rig.ros.flutter_client import PointWatchdog, RigGone

    dog = PointWatchdog(8.4, 20.0)  # slack max(10 s, 10 %): overdue past 30 s after the first report
    for t in (float("nan"), 100.0, 110.0, 129.9, 130.0):
        dog.check(t)
    with pytest.raises(RigGone, match=r"no result for 8.4 m/s in 31 s \(simulated\) after the command, where run-in "
                                      r"\+ dwell take 20 s"):
        dog.check(131.0)
    long = PointWatchdog(8.4, 200.0)  # 10 % slack for a long point
    long.check(0.0)
    long.check(220.0)
    with pytest.raises(RigGone):
        long.check(220.5)
    restarted = PointWatchdog(8.4, 20.0)  # a clock that starts again (a restarted node) is a new reference
    restarted.check(500.0)
    restarted.check(1.0)
    restarted.check(30.0)
    with pytest.raises(RigGone):
        restarted.check(31.5)


def test_a_live_test_whose_node_failed_after_points_reports_them(tmp_path, capsys, monkeypatch):
    """The node's recording failed (or the node was lost) after two test points: the command said why in one line
    and the two points were in its progress lines only. Now they are reported as an interrupted test's (table or
    JSON, figure), with the line why, exit 1. The client's side is stood in for (the failure itself: the test
    above, and the full-disk run measured by hand)."""
    pytest.importorskip("rclpy")
    from panel_rig.analysis.flutter_test import FlutterTestSettings, TestPoint, decide
    from panel_rig.analysis.identification import ModalEstimate
    from panel_rig.cli import main
    from panel_rig.processes import spawn
    from panel_rig.ros import flutter_live
    from panel_rig.ros.flutter_client import RigGone

    def fake_node(cmd, **kwargs):  # a child that lives until it is stopped, as the node does
        return spawn([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE,
                     **{k: v for k, v in kwargs.items() if k != "stdin"})

    def two_points_then_gone(node, domain_id, settings, startup_s, drive, on_point, stop_request, on_flutter):
        for u in (5.0, 6.0):
            drive.res.points.append(TestPoint(u, None, ModalEstimate(22.0, 0.01 - 0.001 * u, 0.01, 1e-4, 9, "ssi-cov"),
                                              "ssi-cov"))
            drive.res.decisions.append(decide(drive.res.points, FlutterTestSettings(5.0, 1.0)))
            on_point(drive.res.points[-1], drive.res.decisions[-1])
        drive.startup_s, drive.test_s = 1.0, 2.0
        raise RigGone("the rig node's recording failed (cannot write b.mcap: No space left); the test stopped")

    import shutil
    from collections import namedtuple

    monkeypatch.setattr(flutter_live, "spawn", fake_node)
    monkeypatch.setattr(flutter_live, "_drive", two_points_then_gone)
    # and a disk too small for the test's longest course: warned of before the node starts (as in-process)
    monkeypatch.setattr(shutil, "disk_usage", lambda path: namedtuple("usage", "total used free")(1e13, 0, 3e6))
    code = main(["flutter-test", "--dwell", "20", "--json", "--bag-dir", str(tmp_path), "--plot",
                 str(tmp_path / "vg.png")])
    captured = capsys.readouterr()
    out = json.loads(captured.out)
    lines = [ln for ln in captured.err.strip().splitlines() if not ln.startswith("point ")]
    assert code == 1 and len(lines) == 2, captured.err
    assert lines[0].startswith("warning: 12 test points of 25 s could record about 92 MB; ") and "3 MB free" in lines[0]
    lines = lines[1:]
    assert lines[0].startswith("panel-rig flutter-test: the rig node's recording failed (cannot write b.mcap")
    assert "node log:" in lines[0]
    assert [p["airspeed_mps"] for p in out["test_points"]] == [5.0, 6.0] and out["interrupted"]
    assert out["stop_reason"] == "interrupted by the rig node's failure after 2 test point(s)"
    assert out["live"] and (tmp_path / "vg.png").is_file()
    assert out["margin"] is None and out["required_margin"] == 0.1  # no prediction from these two points
