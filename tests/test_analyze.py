"""`panel-rig analyze`: plateaus, LCO and onset on a synthetic bag, a live node run against
`panel-rig lco`, the reference bag in bags/, and CLI errors."""

from __future__ import annotations

import json
import math
import shutil
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("rclpy")
pytest.importorskip("mcap_ros2")

from geometry_msgs.msg import PointStamped, Vector3Stamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from panel_rig.analyze_cli import analyze_bag
from panel_rig.analyze_cli import analyze_main as main
from panel_rig.recording import BagWriter

ROOT = Path(__file__).resolve().parents[1]


def read_ros2_messages(path: str) -> list:
    """Decoded messages (schema, channel, message, decoded_message) through mcap's make_reader with
    the mcap-ros2 DecoderFactory (mcap_ros2.reader.read_ros2_messages is deprecated)."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, "rb") as f:
        return list(make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages())
REFERENCE = ROOT / "bags" / "stiffness_staircase"

# ------------------------------------------------------------------------------ synthetic bag
FS_HZ = 200.0
TAU_S = 0.3
PLATEAU_S = 8.0
LENGTH_M = 0.3  # not the paper's 0.27: checks that the bag's parameters are used
# (airspeed, decay rate 1/s or None for an LCO of that RMS); rates = 0.8 (U - 10.5)
PLATEAUS = [(8.0, -2.0, None), (9.0, -1.2, None), (10.0, -0.4, None), (11.0, None, 0.05), (12.0, None, 0.08)]
F_HZ = 20.0
TAP_AT_S, TAP_LEN_S = 1.5, 0.5


def _stamp(msg: object, ns: int) -> None:
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)


def _synthetic_series() -> tuple[np.ndarray, np.ndarray, np.ndarray, list[tuple[float, str, float]]]:
    """Time, tip w/L, measured airspeed (first-order lag) and commands of a 5-plateau run."""
    t = np.arange(int(len(PLATEAUS) * PLATEAU_S * FS_HZ)) / FS_HZ
    w = np.zeros_like(t)
    u = np.zeros_like(t)
    cmds: list[tuple[float, str, float]] = []
    u_prev = 0.0
    for k, (u_k, rate, lco_rms) in enumerate(PLATEAUS):
        t0 = k * PLATEAU_S
        sel = (t >= t0) & (t < t0 + PLATEAU_S)
        tl = t[sel] - t0
        u[sel] = u_k + (u_prev - u_k) * np.exp(-tl / TAU_S)
        u_prev = u_k
        cmds.append((t0, "airspeed_cmd", u_k))
        if lco_rms is None:
            tr = tl - (TAP_AT_S + TAP_LEN_S)
            w[sel] = np.where(tr >= 0, 0.01 * np.exp(rate * tr) * np.sin(2 * np.pi * F_HZ * tr), 0.0)
            cmds += [(t0 + TAP_AT_S, "shaker/force_cmd", 0.1), (t0 + TAP_AT_S + TAP_LEN_S, "shaker/force_cmd", 0.0)]
        else:
            w[sel] = lco_rms * math.sqrt(2) * np.sin(2 * np.pi * (F_HZ + k) * tl)
    return t, w, u, cmds


def _write_synthetic(bag_dir: Path, extra: Any = None) -> None:
    """The synthetic run's bag; ``extra(writer)`` writes more messages into it before it is closed."""
    t, w, u, cmds = _synthetic_series()
    with BagWriter(bag_dir) as writer:
        if extra is not None:
            extra(writer)
        writer.write_parameters({"panel.length_m": LENGTH_M, "variant": "synthetic"})
        queue = sorted(cmds)
        for ti, wi, ui in zip(t, w, u):
            ns = int(round(ti * 1e9)) + 1
            while queue and queue[0][0] <= ti:
                tc, name, value = queue.pop(0)
                writer.write(f"/rig/{name}", Float64(data=value), ns, qos="reliable")
            tip = PointStamped()
            _stamp(tip, ns)
            tip.point.z = wi * LENGTH_M
            air = Vector3Stamped()
            _stamp(air, ns)
            air.vector.x = ui
            js = JointState(name=["q1"], position=[wi], velocity=[0.0], effort=[0.0])
            _stamp(js, ns)
            writer.write("/rig/tip_displacement", tip, ns)
            writer.write("/rig/airspeed", air, ns)
            writer.write("/rig/modal_states", js, ns)


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory: pytest.TempPathFactory) -> Path:
    bag = tmp_path_factory.mktemp("syn") / "synthetic"
    _write_synthetic(bag)
    return bag


def test_plateaus_status_and_onset_on_synthetic_bag(synthetic: Path, tmp_path: Path) -> None:
    res = analyze_bag(synthetic, plots_dir=tmp_path / "plots")
    assert res["panel_length_m"] == LENGTH_M and res["panel_length_source"] == "parameters"
    ps = res["plateaus"]
    assert [round(p["airspeed_mps"], 2) for p in ps] == [u for u, _, _ in PLATEAUS]
    assert [p["status"] for p in ps] == ["decaying"] * 3 + ["lco"] * 2
    for k, p in enumerate(ps):
        t0 = k * PLATEAU_S
        assert t0 + 0.5 < p["t_start_s"] < t0 + 2.0  # the lag transient is trimmed off (~1.7 tau)
        assert p["airspeed_std_mps"] < 0.03
    for k, (p, (_, rate, lco_rms)) in enumerate(zip(ps, PLATEAUS)):
        if rate is not None:
            assert p["growth_rate_per_s"] == pytest.approx(rate, abs=0.02)
            assert p["free_from_s"] >= k * PLATEAU_S + TAP_AT_S + TAP_LEN_S  # after the tap
        else:
            assert p["rms_tip_w_over_L"] == pytest.approx(lco_rms, rel=0.01)
            assert p["peak_tip_w_over_L"] == pytest.approx(lco_rms * math.sqrt(2), rel=0.01)
            assert abs(p["late_growth_rate_per_s"]) < 0.01
    assert ps[3]["dominant_frequency_hz"] == pytest.approx(F_HZ + 3, abs=0.05)
    onset = res["onset"]
    assert onset["bracket_low_mps"] == pytest.approx(10.0, abs=0.02)
    assert onset["bracket_high_mps"] == pytest.approx(11.0, abs=0.02)
    assert onset["first_lco_mps"] == pytest.approx(11.0, abs=0.02)
    assert onset["extrapolated_mps"] == pytest.approx(10.5, abs=0.05)
    assert len(onset["extrapolation_points"]) == 3
    assert sorted(Path(p).name for p in res["plots"]) == ["lco_vs_airspeed.png", "spectrogram.png", "time_history.png"]
    assert all(Path(p).stat().st_size > 10_000 for p in res["plots"])


def test_the_time_history_marks_each_shaker_tap(synthetic: Path, tmp_path: Path, monkeypatch) -> None:
    """The time history showed the plateaus but not the taps whose ring-downs it shades: each accepted shaker
    command that drives the panel (held force or sine amplitude not 0) is marked; a command switching it off is
    not."""
    from panel_rig.analysis import plots

    drawn = {}
    real = plots.plot_time_history

    def spy(*args, **kwargs):
        drawn["shaker_on_s"] = list(args[5] if len(args) > 5 else kwargs.get("shaker_on_s", ()))
        return real(*args, **kwargs)

    monkeypatch.setattr(plots, "plot_time_history", spy)
    analyze_bag(synthetic, plots_dir=tmp_path / "plots")
    taps = [k * PLATEAU_S + TAP_AT_S for k, (_, rate, _) in enumerate(PLATEAUS) if rate is not None]
    assert drawn["shaker_on_s"] == pytest.approx(taps, abs=1e-3)


def test_cli_table_and_json(synthetic: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(synthetic), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["plateaus"]) == 5 and doc["criteria"]["tol_mps"] > 0
    assert main([str(synthetic)]) == 0
    out = capsys.readouterr().out
    assert "flutter onset bracket: 10.00 .. 11.00 m/s" in out and out.count("decaying") == 3


def test_cli_makes_the_rerun_file_s_directory_as_it_makes_the_plots(synthetic: Path, tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """`--rerun out/new/x.rrd` refused a missing directory while `--plots` and `flutter-test --rerun` made theirs."""
    rrd = tmp_path / "new" / "deeper" / "replay.rrd"
    assert main([str(synthetic), "--json", "--rerun", str(rrd), "--plots", str(tmp_path / "plots")]) == 0
    assert json.loads(capsys.readouterr().out)["rerun"] == str(rrd)
    assert rrd.stat().st_size > 0


# ------------------------------------------------------------------------------ CLI errors
def _one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_cli_errors(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([str(tmp_path / "nope")]) == 2
    assert "no such bag directory" in _one_error_line(capsys)
    (tmp_path / "empty").mkdir()
    assert main([str(tmp_path / "empty")]) == 2
    assert "expected one .mcap" in _one_error_line(capsys)
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "junk_0.mcap").write_bytes(b"not an mcap file at all")
    assert main([str(junk)]) == 2  # recover cannot use it either: not sent there
    line = _one_error_line(capsys)
    assert "not an MCAP file" in line and "bag recover" not in line
    with BagWriter(tmp_path / "notip") as writer:
        writer.write("/rig/airspeed_cmd", Float64(data=3.0), 1, qos="reliable")
    assert main([str(tmp_path / "notip")]) == 2
    assert "no tip_displacement topic" in _one_error_line(capsys)
    # a node stopped before its first step (the demo's when its operator gave up) leaves a bag without messages:
    # "not a rig recording" was wrong
    with BagWriter(tmp_path / "unrun"):
        pass
    assert main([str(tmp_path / "unrun")]) == 2
    assert "holds no messages: the rig stopped before it ran a step" in _one_error_line(capsys)
    # a recording without summary: still being written (its lock is held): say so; a killed writer's (a copy,
    # whose lock nobody holds): point at `bag recover`
    writer = BagWriter(tmp_path / "live")
    tip = PointStamped()
    for k in range(50):
        writer.write("/rig/tip_displacement", tip, k + 1)
    writer.flush()
    try:
        assert main([str(tmp_path / "live")]) == 2
        line = _one_error_line(capsys)
        assert "still being recorded" in line and "bag recover" not in line
        shutil.copytree(tmp_path / "live", tmp_path / "killed")
    finally:
        writer.close()
    assert main([str(tmp_path / "killed")]) == 2
    assert "panel-rig bag recover" in _one_error_line(capsys)
    # a live flutter test's run directory holds its node's bag: the message said only "found 0"
    run_dir = tmp_path / "flutter_test_run"
    run_dir.mkdir()
    shutil.copytree(tmp_path / "killed", run_dir / "rig_1")
    assert main([str(run_dir)]) == 2
    assert _one_error_line(capsys).endswith("found 0; it holds the bag rig_1: give it")
    # `make run`'s out/demo holds the analysis of the bag (analysis.json names it), not the bag
    out_dir = tmp_path / "demo_out"
    out_dir.mkdir()
    (out_dir / "analysis.json").write_text('{"bag": "bags/rig_1"}')
    assert main([str(out_dir)]) == 2
    assert _one_error_line(capsys).endswith("it holds an analysis's output (analysis.json) of the bag bags/rig_1: "
                                            "give that")
    with pytest.raises(SystemExit) as exc:
        main([])
    assert exc.value.code == 2
    assert "required" in _one_error_line(capsys)


def test_cli_subcommand_wired() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "panel_rig.cli", "analyze", str(ROOT / "no_such_bag")],
        capture_output=True, text=True, timeout=60, cwd=ROOT,
    )
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "no such bag" in proc.stderr


# ------------------------------------------------------------------------------ reference bag
def test_reference_bag_analysis() -> None:
    """The bag shipped in bags/ (default turbulence): plateaus through the flutter speed, bracket and extrapolation
    found; below U_f the turbulence keeps the panel moving (not quiet); above it the flutter starts without a tap;
    the flutter-test replay identifies the flutter mode (SSI) on the long subcritical plateau."""
    if not REFERENCE.is_dir():
        pytest.skip("no reference bag")
    size = sum(p.stat().st_size for p in REFERENCE.rglob("*") if p.is_file())
    assert size <= 2_000_000
    res = analyze_bag(REFERENCE)
    ps = res["plateaus"]
    statuses = [p["status"] for p in ps]
    assert statuses.count("decaying") >= 2 and "lco" in statuses
    for p in ps:
        if p["status"] == "decaying":  # the turbulence-driven response: tens of micrometres, far above the noise
            assert p["airspeed_mps"] < 10.48 and p["rms_tip_w_over_L"] > 5e-5
    onset = res["onset"]
    assert 9.0 <= onset["bracket_low_mps"] < 10.48 < onset["bracket_high_mps"] <= 12.0  # ROM U_f 10.48 m/s
    assert onset["extrapolated_mps"] == pytest.approx(10.48, abs=0.5)
    assert onset["interpolated_mps"] == pytest.approx(10.48, abs=0.2)
    ft = res["flutter_test"]
    assert ft is not None and ft["model_flutter_speed_mps"] == pytest.approx(10.48, abs=0.01)
    flutter = [p for p in ft["test_points"] if p["frequency_hz"] is not None]
    assert flutter and all(abs(p["frequency_hz"] - 22.85) < 0.3 for p in flutter)  # the model's flutter mode
    assert all(abs(p["damping_ratio"]) < 0.01 for p in flutter)  # lightly damped just below U_f
    stored = json.loads((REFERENCE / "analysis.json").read_text())
    assert [p["status"] for p in stored["plateaus"]] == statuses
    assert stored["onset"]["extrapolated_mps"] == pytest.approx(onset["extrapolated_mps"], rel=1e-6)


# ------------------------------------------------------------------------------ a live node run
U_LCO_MPS = 11.3
RUN_S = 30.0  # simulated seconds after the tap
COMMAND_MARGIN_S = 3.0  # simulated: the command latency of a fast node, at most ~1 s seen (failed once at 0.8 s)
TAP_NPM = 0.05  # held trailing-edge force released after TAP_HOLD_S: the disturbance that starts the LCO
TAP_HOLD_S = 1.0
NODE_TAU_S = 0.2
REFUSED_AIRSPEED_MPS = 500.0  # beyond safety.max_airspeed_mps


class _Client:
    """Test-side rclpy node: /clock and command publishers, in its own context and domain."""

    def __init__(self, domain_id: int) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock

        self._rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node("analyze_test_client", namespace="/rig", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.time_s = -1.0
        self.node.create_subscription(Clock, "/clock", self._on_clock, QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE))
        self.pubs = {t: self.node.create_publisher(Float64, t, reliable) for t in ("airspeed_cmd", "shaker/force_cmd")}

    def _on_clock(self, msg: object) -> None:
        self.time_s = msg.clock.sec + msg.clock.nanosec * 1e-9

    def wait(self, cond: object, timeout_s: float, what: str, proc: subprocess.Popen | None = None) -> None:
        deadline = time.monotonic() + timeout_s
        while not cond():
            if proc is not None and proc.poll() is not None:
                raise AssertionError(f"node exited ({proc.returncode}) while waiting for {what}")
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
            self.executor.spin_once(timeout_sec=0.02)

    def publish(self, topic: str, value: float) -> None:
        pub = self.pubs[topic]
        self.wait(lambda: pub.get_subscription_count() > 0, 20.0, f"a subscriber on {topic}")
        pub.publish(Float64(data=value))

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self._rclpy.shutdown(context=self.context)


@pytest.fixture(scope="module")
def node_run(ros_env: dict[str, str], tmp_path_factory: pytest.TempPathFactory) -> dict[str, object]:
    """Node in fast mode (stiffness variant, recording + live Rerun): 11.3 m/s, a tap, 30 s, SIGINT."""
    tmp = tmp_path_factory.mktemp("node_run")
    env = ros_env
    # at most 20x: the run's ~32 simulated s then last >= 1.6 s of wall time, three periods of the node's 2 Hz
    # /diagnostics (uncapped, a fast machine marched them in under 0.5 s wall and the bag held no /diagnostics)
    cmd = [sys.executable, "-m", "panel_rig.ros.rig_node", "--fast", "--ros-args", "-r", "__ns:=/rig",
           "-p", "model.variant:=stiffness", "-p", f"tunnel.time_constant_s:={NODE_TAU_S}", "-p", "record:=true",
           "-p", f"bag_dir:={tmp / 'bags'}", "-p", f"rerun:=save:{tmp / 'x.rrd'}",
           "-p", "fast_max_realtime_factor:=20.0"]
    client = _Client(int(env["ROS_DOMAIN_ID"]))
    t_wall = time.monotonic()
    with open(tmp / "node.log", "w") as log:
        proc = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
    try:
        client.wait(lambda: client.time_s >= 0.0, 60.0, "the first /clock", proc)
        client.publish("airspeed_cmd", U_LCO_MPS)
        client.publish("shaker/force_cmd", TAP_NPM)
        t_on = client.time_s
        client.wait(lambda: client.time_s >= t_on + TAP_HOLD_S, 30.0, "the tap", proc)
        client.publish("shaker/force_cmd", 0.0)
        t_off = client.time_s
        # mid-run, two commands the rig refuses: recorded on <topic>/rejected, they neither end the plateau nor
        # move its free response (the analysis sees the commands that acted)
        client.wait(lambda: client.time_s >= t_off + RUN_S / 2, 60.0, "mid-run", proc)
        client.publish("airspeed_cmd", REFUSED_AIRSPEED_MPS)
        client.publish("shaker/force_cmd", math.nan)
        # the node takes the command a little later in its own time than this client's t_off (fast mode: a few ms of
        # wall time are ~1 s simulated at 80x): RUN_S plus a margin, so the bag's free response is >= RUN_S long
        client.wait(lambda: client.time_s >= t_off + RUN_S + COMMAND_MARGIN_S, 120.0, f"{RUN_S} s of simulated time",
                    proc)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(20) == 0, (tmp / "node.log").read_text()[-2000:]
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        client.close()
    bags = list((tmp / "bags").iterdir())
    assert len(bags) == 1
    print(f"\nnode run: {time.monotonic() - t_wall:.1f} s wall; tap {t_on:.2f}-{t_off:.2f} s simulated")
    return {"bag": bags[0], "rrd": tmp / "x.rrd", "tmp": tmp}


def test_node_bag_reads_identically_in_three_readers(node_run: dict[str, object]) -> None:
    from rerun.chunk import RrdReader
    from rosbags.highlevel import AnyReader

    bag = node_run["bag"]
    mcap = next(bag.glob("*.mcap"))
    ours = Counter(m.channel.topic for m in read_ros2_messages(str(mcap)))
    with AnyReader([bag]) as reader:
        theirs: Counter = Counter()
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            theirs[conn.topic] += 1
    assert theirs == ours
    for topic in ("/rig/tip_displacement", "/rig/modal_states", "/rig/airspeed", "/rig/panel_shape",
                  "/rig/airspeed_cmd", "/rig/shaker/force_cmd", "/diagnostics"):
        assert ours[topic] > 0, topic
    assert ours["/rig/shaker/force_cmd"] == 2 and ours["/rig/airspeed_cmd"] == 1
    assert ours["/rig/shaker/force_cmd/rejected"] == 1 and ours["/rig/airspeed_cmd/rejected"] == 1
    out = node_run["tmp"] / "bag.rrd"
    proc = subprocess.run([str(Path(sys.executable).with_name("rerun")), "mcap", "convert", str(mcap), "-o", str(out)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    rows: Counter = Counter()
    for chunk in RrdReader(out).stream().to_chunks():
        if not chunk.is_static:
            rows[str(chunk.entity_path)] += chunk.num_rows
    for field in ("position", "velocity", "effort"):  # JointState becomes plots
        assert rows[f"/rig/modal_states/{field}"] == ours["/rig/modal_states"]
    for topic, n in ours.items():
        assert rows[topic] == n, topic
    print(f"message counts (mcap-ros2 = rosbags = rerun): {dict(ours)}")


def test_node_bag_records_the_sensor_reading_and_the_truth(node_run: dict[str, object]) -> None:
    """tip_displacement (through the sensor model) and tip_displacement/truth (the model's tip) are both recorded,
    with the same stamps; the reading follows the truth (latency + bandwidth lag < half a 2 ms sample) and differs
    from it (noise, resolution, lag)."""
    from mcap_ros2.reader import read_ros2_messages

    mcap = next(node_run["bag"].glob("*.mcap"))
    series: dict[str, list[tuple[int, float]]] = {"/rig/tip_displacement": [], "/rig/tip_displacement/truth": []}
    for m in read_ros2_messages(str(mcap), topics=list(series)):
        stamp = m.ros_msg.header.stamp
        series[m.channel.topic].append((stamp.sec * 1_000_000_000 + stamp.nanosec, m.ros_msg.point.z))
    meas, truth = (np.array(series[t]) for t in series)
    assert len(meas) == len(truth) > 1000
    assert np.array_equal(meas[:, 0], truth[:, 0])
    assert np.corrcoef(meas[:, 1], truth[:, 1])[0, 1] > 0.99
    assert not np.array_equal(meas[:, 1], truth[:, 1])


def test_node_bag_analysis_matches_lco(node_run: dict[str, object], cfg: object) -> None:
    """The plateau's metrics window (last 5 s of the free response, as `lco`) against `panel-rig lco`."""
    from panel_rig.analysis.lco import run_lco

    res = analyze_bag(node_run["bag"])
    assert res["panel_length_source"] == "parameters" and res["variant"] == "stiffness"
    assert res["refused_commands"] == {"/rig/airspeed_cmd": 1, "/rig/shaker/force_cmd": 1}
    lco_plateaus = [p for p in res["plateaus"] if abs(p["airspeed_mps"] - U_LCO_MPS) < 0.05]
    assert len(lco_plateaus) == 1
    p = lco_plateaus[0]
    assert p["status"] == "lco" and p["t_end_s"] - p["free_from_s"] >= RUN_S - 0.5
    ref, _, _ = run_lco(cfg, U_LCO_MPS, RUN_S, variant="stiffness")
    d_rms = p["rms_tip_w_over_L"] / ref.rms_tip_w_over_L - 1
    d_f = p["dominant_frequency_hz"] / ref.dominant_frequency_hz - 1
    print(f"\nanalyze: rms {p['rms_tip_w_over_L']:.5f}, f {p['dominant_frequency_hz']:.3f} Hz; lco: rms "
          f"{ref.rms_tip_w_over_L:.5f}, f {ref.dominant_frequency_hz:.3f} Hz; diff {d_rms:+.2%}, {d_f:+.2%}")
    assert abs(d_rms) < 0.02 and abs(d_f) < 0.02


def test_live_rrd_entities_and_rows(node_run: dict[str, object]) -> None:
    from rerun.chunk import RrdReader

    counts = Counter(m.channel.topic for m in read_ros2_messages(str(next(node_run["bag"].glob("*.mcap")))))
    temporal: Counter = Counter()
    for chunk in RrdReader(node_run["rrd"]).stream().to_chunks():
        if not chunk.is_static:
            temporal[str(chunk.entity_path)] += chunk.num_rows
    n = counts["/rig/tip_displacement"]
    for entity in ("/tip/w_over_L", "/airspeed/mps", "/shaker/force_npm", "/modal/q1", "/modal/q2", "/modal/q3"):
        assert temporal[entity] == n, entity
    assert temporal["/panel/shape"] == counts["/rig/panel_shape"]
    assert temporal["/commands/airspeed_cmd"] == 1 and temporal["/commands/shaker/force_cmd"] == 2


def test_analyze_writes_rrd_from_bag(node_run: dict[str, object], tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    res = analyze_bag(node_run["bag"], rerun_path=tmp_path / "replay.rrd")
    temporal: Counter = Counter()
    policy: dict[str, list] = {}
    for chunk in RrdReader(res["rerun"]).stream().to_chunks():
        if not chunk.is_static:
            temporal[str(chunk.entity_path)] += chunk.num_rows
        elif "SeriesLines:aggregation_policy" in (batch := chunk.to_record_batch()).schema.names:
            policy[str(chunk.entity_path)] = batch.column("SeriesLines:aggregation_policy").to_pylist()
    assert temporal["/tip/w_over_L"] == res["samples"] == temporal["/modal/q3"]
    assert policy["/tip/w_over_L"] == policy["/modal/q3"] == [[5]]  # MinMax: the replay keeps the LCO envelope
    assert temporal["/panel/shape"] > 0 and temporal["/commands/shaker/force_cmd"] == 2


def test_irregular_lco_and_exponential_decay_are_told_apart() -> None:
    """A large bursting oscillation (non-exponential envelope) is an LCO; a clean exponential decay is not."""
    from panel_rig.analysis.bag_analysis import Criteria, _status

    c = Criteria()
    assert _status(0.2, 0.8, -0.2, -0.2, sustain=0.3, r2=0.4, crit=c) == "lco"
    assert _status(0.2, 0.8, -0.2, -0.2, sustain=1.1, r2=0.95, crit=c) == "lco"
    assert _status(0.2, 0.8, -0.2, -0.2, sustain=0.3, r2=0.98, crit=c) == "decaying"
    assert _status(0.01, 0.8, -0.2, -0.2, sustain=0.9, r2=0.2, crit=c) == "decaying"  # too small to be irregular LCO


def test_onset_ignores_plateaus_after_the_first_lco() -> None:
    """Hysteresis: plateaus back below the flutter speed that stay in LCO, or decay later, do not move the bracket."""
    from panel_rig.analysis.bag_analysis import estimate_onset

    def p(u, status, t0, rate=0.0):
        return {"airspeed_mps": u, "status": status, "t_start_s": t0, "t_end_s": t0 + 8.0, "growth_rate_per_s": rate}

    plateaus = [p(8.0, "quiet", 0), p(10.0, "quiet", 10), p(10.8, "lco", 20), p(11.2, "lco", 30),
                p(10.0, "lco", 40), p(9.0, "lco", 50), p(8.0, "decaying", 60, -0.3)]
    onset = estimate_onset(plateaus)
    assert onset["bracket_low_mps"] == 10.0 and onset["bracket_high_mps"] == 10.8
    assert onset["extrapolated_mps"] is None and onset["extrapolation_points"] == []


def test_onset_interpolates_only_from_a_measured_decay() -> None:
    """The rate of a quiet plateau (a response that never rose, e.g. the tunnel off) is noise: no interpolation
    from it (it gave 0.05 m/s for a bracket 0 .. 11 m/s); from a decaying one, the straight line."""
    from panel_rig.analysis.bag_analysis import estimate_onset

    def p(u, status, t0, rate):
        return {"airspeed_mps": u, "status": status, "t_start_s": t0, "t_end_s": t0 + 8.0, "growth_rate_per_s": rate}

    quiet = estimate_onset([p(0.0, "quiet", 0, -0.001), p(11.0, "growing", 10, 0.3)])
    # nor is the tunnel at rest a lower bound of the onset (the table said "bracket 0.00 .. 11.00 m/s")
    assert quiet["bracket_low_mps"] is None and quiet["bracket_high_mps"] == 11.0 and quiet["interpolated_mps"] is None
    from panel_rig.analyze_cli import onset_line

    assert onset_line(quiet, {}).startswith(
        "flutter onset: at or below 11.00 m/s (no stable plateau with the wind on before it); extrapolated")
    decaying = estimate_onset([p(10.0, "decaying", 0, -0.1), p(11.0, "growing", 10, 0.3)])
    assert decaying["interpolated_mps"] == pytest.approx(10.25)


def test_an_lco_plateau_gives_the_growth_before_it_saturated_to_the_onset_interpolation() -> None:
    """`make run`'s onset read "interpolated across the bracket: none": the turbulence grew the flutter into an LCO
    within the 11.2 m/s plateau, and only a plateau still "growing" gave a rate. The LCO plateau's growth below
    0.2 of its final envelope is the linear growth rate (here 0.5 1/s, within 5 %); an LCO carried over from an
    earlier plateau has none, and a "quiet" or absent rate interpolates nothing."""
    from panel_rig.analysis.bag_analysis import analyze_plateau, estimate_onset

    dt, n = 1.0 / 500.0, 15000  # 30 s at 500 Hz
    t = np.arange(n) * dt
    u = np.full(n, 11.2)
    rng = np.random.default_rng(3)
    a_lco, a0, sigma = 0.35, 0.35 * 0.01, 0.5
    amplitude = a_lco / np.sqrt(1 + (a_lco**2 / a0**2 - 1) * np.exp(-2 * sigma * t))  # logistic: exp, then LCO
    w = amplitude * np.sin(2 * np.pi * 17.0 * t) + 1e-5 * rng.normal(size=n)
    grown = analyze_plateau(t, w, u, {}, 0, n)
    assert grown["status"] == "lco" and grown["onset_growth_rate_per_s"] == pytest.approx(sigma, rel=0.05)
    carried = analyze_plateau(t, a_lco * np.sin(2 * np.pi * 17.0 * t), u, {}, 0, n)
    assert carried["status"] == "lco" and carried["onset_growth_rate_per_s"] is None

    def p(u_mps, status, t0, rate, onset=None):
        return {"airspeed_mps": u_mps, "status": status, "t_start_s": t0, "t_end_s": t0 + 8.0,
                "growth_rate_per_s": rate, "onset_growth_rate_per_s": onset}

    lco = p(11.2, "lco", 10, 0.08, onset=0.5)
    assert estimate_onset([p(10.0, "decaying", 0, -0.25), lco])["interpolated_mps"] == pytest.approx(10.4)
    assert estimate_onset([p(10.0, "decaying", 0, -0.25), p(11.2, "lco", 10, 0.08)])["interpolated_mps"] is None
    assert estimate_onset([p(10.0, "quiet", 0, -0.25), lco])["interpolated_mps"] is None


def test_random_response_in_turbulence_is_not_growth() -> None:
    """A stationary random response (a lightly damped mode driven by white noise, as the tunnel's turbulence drives
    the panel below flutter) wanders in level over a few seconds; it is not "growing" (the demo's 8 m/s plateau
    was, at +0.08 1/s, which put the onset bracket at 0-8 m/s). A noisy exponential growth still is."""
    from panel_rig.analysis.bag_analysis import analyze_plateau

    dt, n = 1.0 / 500.0, 2500  # a 5 s plateau at 500 Hz
    t = np.arange(n) * dt
    u = np.full(n, 8.0)
    omega, zeta = 2 * np.pi * 4.2, 0.05  # the first mode
    a1, a2 = 2 * np.exp(-zeta * omega * dt) * np.cos(omega * dt), -np.exp(-2 * zeta * omega * dt)
    statuses = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        e = rng.normal(size=n + 2000)
        y = np.zeros(n + 2000)
        for k in range(2, y.size):
            y[k] = a1 * y[k - 1] + a2 * y[k - 2] + e[k]
        w = 1e-4 * y[2000:] / np.std(y[2000:])  # stationary (2000 samples of start-up dropped)
        statuses.append(analyze_plateau(t, w, u, {}, 0, n)["status"])
    assert "growing" not in statuses, statuses
    # nor a decay: its envelope drifts (the demo's 8 m/s plateau was "decaying" at -0.125 1/s and stopped the
    # onset extrapolation); a panel that moves but neither decays nor grows is stationary
    assert set(statuses) == {"stationary"}, statuses
    rng = np.random.default_rng(1)
    growth = 1e-4 * np.exp(0.5 * t) * np.sin(2 * np.pi * 22.8 * t) + 2e-6 * rng.normal(size=n)
    assert analyze_plateau(t, growth, u, {}, 0, n)["status"] == "growing"


def test_a_decay_is_measured_after_a_tap_or_along_a_line() -> None:
    """decaying needs a measured decay: the free response after a shaker tap, or without a tap an envelope that
    falls along a line (R^2 >= 0.98); the noisy drift of an untapped random response is stationary, a panel that
    never moved quiet; a stationary plateau brackets the onset like a decaying one but gives no rate."""
    from panel_rig.analysis.bag_analysis import Criteria, _status, estimate_onset

    c = Criteria()
    assert _status(1e-3, 2e-3, -0.05, -0.05, sustain=0.8, r2=0.99, crit=c, tapped=False) == "decaying"
    assert _status(1e-3, 2e-3, -0.5, -0.5, sustain=0.1, r2=0.6, crit=c, tapped=True) == "decaying"
    assert _status(1e-4, 2e-4, -0.215, 0.1, sustain=1.1, r2=0.92, crit=c, tapped=False) == "stationary"
    assert _status(0.0, 0.0, 0.0, 0.0, sustain=1.0, r2=1.0, crit=c, tapped=False) == "quiet"

    def p(u, status, t0, rate):
        return {"airspeed_mps": u, "status": status, "t_start_s": t0, "t_end_s": t0 + 8.0, "growth_rate_per_s": rate}

    onset = estimate_onset([p(8.0, "stationary", 0, -0.125), p(10.0, "decaying", 10, -0.25), p(11.0, "growing", 20, 0.5)])
    assert onset["bracket_low_mps"] == 10.0 and onset["extrapolated_mps"] is None
    assert onset["extrapolation_points"] == [] and onset["interpolated_mps"] == pytest.approx(10 + 1 / 3)
    assert estimate_onset([p(8.0, "stationary", 0, -0.125), p(11.0, "growing", 20, 0.5)])["bracket_low_mps"] == 8.0


def test_a_long_dwell_after_a_tap_keeps_its_decay() -> None:
    """A tap at 9 m/s, then 16 s of dwell: the turbulence's response in the last 5 s peaked at 0.43 Hz, the envelope
    window (4 periods) became 9.4 s, under 3 of them fitted the free response, and its rate was 0 ("stationary";
    with a 6 s dwell the same tap read -0.626 1/s). The windows are now at most an eighth of the free response."""
    from panel_rig.analysis.bag_analysis import analyze_series

    t = np.arange(0.0, 18.5, 1.0 / 500.0)
    tap = np.where(t >= 2.0, 1e-3 * np.exp(-0.63 * (t - 2.0)) * np.sin(2 * np.pi * 23.0 * t), 0.0)
    w = tap + 3e-5 * np.sin(2 * np.pi * 0.43 * t)
    (p,) = analyze_series(t, w, np.full(t.size, 9.0), {"shaker/amplitude_cmd": [(1.5, 0.3), (2.0, 0.0)]})["plateaus"]
    # the late window's peak, 0.43 Hz as in the bag, is 2 periods of that 5 s window: no resolved frequency
    assert np.isnan(p["dominant_frequency_hz"])
    # the tap's band (15-35 Hz) leaves the 0.43 Hz floor out: the rate is the tap's (a line through the whole
    # log-envelope read -0.18)
    assert p["status"] == "decaying" and p["growth_rate_per_s"] == pytest.approx(-0.63, rel=0.02), p


def test_a_panel_at_rest_under_the_sensor_s_noise_is_quiet() -> None:
    """A panel at rest read the default sensor's 5 um of noise: RMS 1.9e-5 L, 185 times the fixed quiet threshold,
    so it was "stationary" at 100-240 Hz. `panel-rig analyze` puts the threshold at twice the run's sensor noise
    (from the bag's parameters); a quiet plateau has no frequency. The turbulence's response at 8 m/s (27 um) and a
    ring-down are still moving."""
    import dataclasses

    from panel_rig.analysis.bag_analysis import Criteria, analyze_series
    from panel_rig.analyze_cli import quiet_rms_of

    length_m = 0.27
    params = {"sensor.tip_noise_m": 5e-6, "sensor.resolution_m": 3e-6}
    crit = dataclasses.replace(Criteria(), quiet_rms=quiet_rms_of(params, length_m, Criteria().quiet_rms))
    assert crit.quiet_rms == pytest.approx(2 * np.hypot(5e-6, 3e-6 / np.sqrt(12)) / length_m)
    assert quiet_rms_of({}, length_m, 1e-7) == 1e-7  # no sensor in the parameters: the fixed floor
    rng = np.random.default_rng(5)
    t = np.arange(0.0, 12.0, 1.0 / 500.0)
    noise = 5e-6 / length_m * rng.standard_normal(t.size)
    (rest,) = analyze_series(t, noise, np.zeros(t.size), {}, crit)["plateaus"]
    assert rest["status"] == "quiet" and np.isnan(rest["dominant_frequency_hz"]), rest
    moving = noise + 1e-4 * np.sin(2 * np.pi * 4.0 * t)  # the random response's size at 8 m/s
    (wind,) = analyze_series(t, moving, np.full(t.size, 8.0), {}, crit)["plateaus"]
    assert wind["status"] != "quiet" and wind["dominant_frequency_hz"] == pytest.approx(4.0, abs=0.2)
    # a noisy sensor (2 mm, RMS 0.0073 L, above the LCO rule's 0.005) with the wind on: quiet, not an "lco" whose
    # airspeed became the flutter onset (a review's flutter-test bag at 5.24 m/s)
    loud = dataclasses.replace(Criteria(), quiet_rms=quiet_rms_of({"sensor.tip_noise_m": 2e-3}, length_m, 1e-7))
    din = 2e-3 / length_m * rng.standard_normal(t.size)
    result = analyze_series(t, din, np.full(t.size, 5.24), {}, loud)
    assert result["plateaus"][0]["status"] == "quiet" and result["onset"]["first_lco_mps"] is None, result["plateaus"]


def test_a_free_decay_with_the_wind_off_is_no_lco() -> None:
    """After an abort at 12 m/s the panel rang down at 0 m/s from 0.8 L at -0.1 1/s: the irregular-LCO rule (a
    5 s window, its thirds within 0.5-2 of each other) called that plateau an LCO at 0.00 m/s. With the wind off
    nothing feeds an oscillation."""
    from panel_rig.analysis.bag_analysis import analyze_series

    t = np.arange(0.0, 40.0, 1.0 / 500.0)
    u = np.where(t < 20.0, 12.0, 0.0)
    w = np.where(t < 20.0, 1e-4 * np.exp(0.4 * t) * np.sin(2 * np.pi * 22.0 * t),
                 0.8 * np.exp(-0.1 * (t - 20.0)) * np.sin(2 * np.pi * 4.0 * t))
    statuses = [(round(p["airspeed_mps"]), p["status"]) for p in analyze_series(t, w, u, {})["plateaus"]]
    assert statuses == [(12, "growing"), (0, "decaying")], statuses


def test_a_held_force_s_static_deflection_is_no_lco() -> None:
    """A force held on the shaker bends the panel to a static deflection: the plateau's RMS included that mean
    (0.01 L), above the LCO threshold, and a panel at rest under the force was "lco". The RMS, the envelope and
    the status are now those of the motion about the mean (as the operator's table has them); the mean is
    reported beside them."""
    from panel_rig.analysis.bag_analysis import analyze_series

    t = np.arange(0.0, 20.0, 1.0 / 500.0)
    u = np.full(t.size, 8.0)
    rng = np.random.default_rng(3)
    w = np.where(t < 5.0, 0.0, 0.01 * (1.0 - np.exp(-3.0 * (t - 5.0)) * np.cos(2 * np.pi * 17.0 * (t - 5.0))))
    w = w + 1e-5 * rng.standard_normal(t.size)  # the turbulence's small random response about it
    (held,) = analyze_series(t, w, u, {"shaker/force_cmd": [(5.0, 0.3)]})["plateaus"]
    assert held["status"] in ("decaying", "stationary"), held
    assert held["mean_tip_w_over_L"] == pytest.approx(0.01, rel=1e-3)
    assert held["rms_tip_w_over_L"] == pytest.approx(1e-5, rel=0.1)  # about the mean
    assert held["peak_tip_w_over_L"] == pytest.approx(0.01, rel=1e-2)  # the largest deflection, mean included
    # an LCO about a held deflection is still one, its RMS that of the cycle
    lco = 0.01 + 0.05 * np.sin(2 * np.pi * 17.0 * t)
    (cycle,) = analyze_series(t, lco, u, {"shaker/force_cmd": [(0.5, 0.3)]})["plateaus"]
    assert cycle["status"] == "lco" and cycle["rms_tip_w_over_L"] == pytest.approx(0.05 / np.sqrt(2), rel=1e-2)
    # the table names the held deflection (its rms_w/L column is the motion about it); and a bracket between two
    # plateaus at one nominal airspeed shows the digits that tell them apart ("9.00 .. 9.00")
    from panel_rig.analyze_cli import format_table

    onset = {"bracket_low_mps": 8.996, "bracket_high_mps": 9.004, "extrapolated_mps": None,
             "extrapolation_points": [], "interpolated_mps": None}
    table = format_table({"bag": "b", "duration_s": 20.0, "samples": t.size, "panel_length_m": 0.27,
                          "panel_length_source": "parameters", "plateaus": [{**held, "index": 1},
                                                                             {**cycle, "index": 2}], "onset": onset})
    assert "plateau 1: the tip is held at w/L = 0.01 on average" in table, table
    assert "plateau 2:" not in table  # an LCO about a small mean: no line
    assert "flutter onset bracket: 8.996 .. 9.004 m/s" in table, table


def test_instantaneous_airspeed_steps_are_separate_plateaus() -> None:
    """tunnel.time_constant_s = 0 (allowed): the steady windows on both sides of each step joined 5, 6 and 7 m/s
    into one run, of which only the last level survived."""
    from panel_rig.analysis.bag_analysis import find_plateaus

    t = np.arange(0.0, 45.0, 1.0 / 500.0)
    u = np.select([t < 10, t < 20, t < 30], [5.0, 6.0, 7.0], 0.0)
    ranges = find_plateaus(t, u)
    assert [float(u[i0]) for i0, _ in ranges] == [5.0, 6.0, 7.0, 0.0]
    assert [(round(t[i0], 3), round(t[i1 - 1], 3)) for i0, i1 in ranges] == [
        (0.0, 9.998), (10.0, 19.998), (20.0, 29.998), (30.0, 44.998)]


def test_a_step_smaller_than_the_tunnel_s_lag_still_separates_plateaus() -> None:
    """The flutter test's capped step from 9.222 to 9.337 m/s (0.115 m/s, the tunnel's 1 s lag): every 1 s window
    stayed within the 0.05 m/s tolerance, the two levels made one run, and only the 9.337 m/s part was kept: the
    whole 9.222 m/s plateau (410 s of a real test) was missing from analyze's table. The set-point commands cut."""
    from panel_rig.analysis.bag_analysis import analyze_series, find_plateaus, setpoint_change_times_s

    t = np.arange(0.0, 60.0, 1.0 / 500.0)
    u = np.where(t < 30.0, 9.222, 9.337 - 0.115 * np.exp(-np.clip(t - 30.0, 0.0, None) / 1.0))
    cmds = [(0.0, 9.222), (20.0, 9.222), (30.0, 9.337)]  # a repeat of a set-point is no change
    assert setpoint_change_times_s(cmds) == [0.0, 30.0]
    assert len(find_plateaus(t, u)) == 1  # the steady windows alone
    ranges = find_plateaus(t, u, setpoint_changes_s=setpoint_change_times_s(cmds))
    assert [round(float(np.median(u[i0:i1])), 3) for i0, i1 in ranges] == [9.222, 9.337]
    assert round(t[ranges[0][1] - 1], 3) == 29.998 and 30.0 < t[ranges[1][0]] < 32.0  # the lag's transient left out
    result = analyze_series(t, 1e-4 * np.sin(2 * np.pi * 23.0 * t), u, {"airspeed_cmd": cmds})
    assert [p["airspeed_mps"] for p in result["plateaus"]] == [pytest.approx(9.222, abs=1e-9),
                                                              pytest.approx(9.337, abs=0.005)]  # the lag's tail


def test_a_gap_in_the_recording_splits_plateaus_and_is_reported() -> None:
    """A recovered bag that lost a chunk (t 12-14 s here): the plateau bridged it, and the gap, counted in the mean
    sample interval, changed every window of the analysis, far from the gap too."""
    from panel_rig.analysis.bag_analysis import analyze_series, find_plateaus, mean_dt

    t = np.arange(0.0, 30.0, 1.0 / 500.0)
    keep = (t < 12.0) | (t >= 14.0)
    t, u = t[keep], np.full(np.count_nonzero(keep), 8.0)
    assert mean_dt(t) == pytest.approx(1.0 / 500.0, rel=1e-9)
    ranges = find_plateaus(t, u)
    assert [(round(t[i0], 3), round(t[i1 - 1], 3)) for i0, i1 in ranges] == [(0.0, 11.998), (14.0, 29.998)]
    result = analyze_series(t, 1e-4 * np.sin(2 * np.pi * 5.0 * t), u, {})
    assert result["gaps"] == [{"from_s": pytest.approx(11.998), "to_s": pytest.approx(14.0)}]
    assert result["sample_rate_hz"] == pytest.approx(500.0)
    # publish_rate_hz set from 500 to 1 Hz and back, live: every slow interval was a "gap" (thousands, an 80 kB
    # line); a gap is an interval over 3x both of its neighbours now
    from panel_rig.analysis.bag_analysis import recording_gaps
    from panel_rig.analyze_cli import MAX_GAPS_SHOWN, format_table

    slow = np.r_[np.arange(0.0, 10.0, 1 / 500), np.arange(10.0, 40.0, 1.0), np.arange(40.0, 50.0, 1 / 500)]
    assert recording_gaps(slow) == []
    many = np.cumsum(np.where(np.arange(5000) % 200 == 199, 0.5, 1 / 500))  # a jump every 200 samples
    gaps = recording_gaps(many)
    assert len(gaps) == 25
    text = format_table({**result, "bag": "b", "panel_length_m": 0.27, "panel_length_source": "bag", "gaps": gaps})
    assert f"and {25 - MAX_GAPS_SHOWN} more (JSON: gaps)" in text and max(map(len, text.splitlines())) < 400


def test_an_intact_mcap_of_other_messages_is_not_sent_to_recover(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """A valid MCAP with JSON messages: analyze said "run `panel-rig bag recover`", recover said "already complete",
    and analyze said it again. It is not a ROS 2 recording, and the line says so."""
    from mcap.writer import Writer

    bag = tmp_path / "foreign"
    bag.mkdir()
    with open(bag / "foreign_0.mcap", "wb") as f:
        writer = Writer(f)
        writer.start()
        channel = writer.register_channel("/rig/tip_displacement", "json", writer.register_schema("p", "jsonschema", b"{}"))
        for k in range(10):
            writer.add_message(channel, k, json.dumps({"z": 0.1}).encode(), k)
        writer.finish()
    assert main([str(bag)]) == 2
    line = _one_error_line(capsys)
    assert "not a ROS 2 recording (messages in json, not cdr)" in line and "recover" not in line


def test_a_run_without_an_unstable_plateau_reports_no_onset() -> None:
    """A run that stays stable printed "flutter onset bracket: 0.00 .. - m/s", read as an onset found."""
    from panel_rig.analysis.bag_analysis import estimate_onset
    from panel_rig.analyze_cli import format_table

    plateau = {"index": 1, "t_start_s": 0.0, "t_end_s": 10.0, "airspeed_mps": 6.0, "rms_tip_w_over_L": 1e-5,
               "peak_tip_w_over_L": 3e-5, "dominant_frequency_hz": 26.0, "growth_rate_per_s": -0.5,
               "status": "decaying"}
    result = {"bag": "b", "duration_s": 10.0, "samples": 5000, "panel_length_m": 0.27, "panel_length_source": "bag",
              "plateaus": [plateau], "onset": estimate_onset([plateau])}
    last = format_table(result).splitlines()[-1]
    assert last.startswith("flutter onset: no plateau was unstable (stable up to 6.00 m/s)"), last
    # the wind-off plateau of a test whose first point fluttered (cut too short to be a plateau) is no evidence
    wind_off = {**plateau, "airspeed_mps": 0.002, "status": "stationary"}
    last = format_table({**result, "plateaus": [wind_off], "onset": estimate_onset([wind_off])}).splitlines()[-1]
    assert last.startswith("flutter onset: no plateau was unstable; extrapolated"), last


def test_a_bag_without_test_points_says_why() -> None:
    """`analyze` on a demo bag printed no flutter-test replay and did not say why (no plateau had 20 s after its
    5 s run-in). The replay now names the reason, in the table and the JSON."""
    from panel_rig.analysis.bag_analysis import estimate_onset
    from panel_rig.analysis.flutter_test import no_point_reason, replay_points
    from panel_rig.analyze_cli import format_table

    t = np.arange(0, 60.0, 1 / 512)
    y = 1e-6 * np.random.default_rng(0).standard_normal(t.size)
    y[t >= 35.0] = 0.05 * np.sin(2 * np.pi * 20 * t[t >= 35.0])  # the last plateau flutters (past 2 % of L)
    skipped = []
    # plateaus: 5 m/s for 10 s (5 s after the run-in), 6 m/s for 20 s (15 s), 7 m/s for 30 s (25 s, fluttered)
    assert replay_points(t, y, [(0.0, 5.0), (10.0, 6.0), (30.0, 7.0)], lambda u: [(3, 6), (20, 26)], 0.27,
                         skipped=skipped) == []
    short = no_point_reason(skipped)
    assert short == ("a test point needs 20 s of an ascending plateau after its 5 s run-in, below flutter: 5.00 m/s "
                     "has 5.0 s; 6.00 m/s has 15.0 s; 7.00 m/s fluttered")
    assert no_point_reason([]) == "no airspeed plateau above 0 m/s"
    plateau = {"index": 1, "t_start_s": 0.0, "t_end_s": 30.0, "airspeed_mps": 6.0, "rms_tip_w_over_L": 1e-5,
               "peak_tip_w_over_L": 3e-5, "dominant_frequency_hz": 26.0, "growth_rate_per_s": -0.5,
               "status": "decaying"}
    result = {"bag": "b", "duration_s": 30.0, "samples": 15000, "panel_length_m": 0.27, "panel_length_source": "bag",
              "plateaus": [plateau], "onset": estimate_onset([plateau]),
              "flutter_test": {"test_points": [], "no_test_point_reason": short}}
    assert f"flutter-test replay: no test point ({short})" in format_table(result).splitlines()


def test_a_replay_without_a_prediction_says_why_not_none() -> None:
    """One identified point gives no prediction: the table printed "predicted U_f - m/s [None]"."""
    from panel_rig.analysis.bag_analysis import estimate_onset
    from panel_rig.analysis.flutter_test import NO_PREDICTION
    from panel_rig.analyze_cli import format_table
    from panel_rig.flutter_cli import format_flutter_test

    plateau = {"index": 1, "t_start_s": 0.0, "t_end_s": 30.0, "airspeed_mps": 10.2, "rms_tip_w_over_L": 2e-4,
               "peak_tip_w_over_L": 5e-4, "dominant_frequency_hz": 22.8, "growth_rate_per_s": -0.1,
               "status": "decaying"}
    point = {"airspeed_mps": 10.2, "frequency_hz": 22.84, "damping_ratio": 2e-4, "damping_ci": [-1e-4, 5e-4],
             "method": "ssi-cov"}
    ft = {"test_points": [point], "model_flutter_speed_mps": 10.48, "predicted_flutter_speed_mps": None,
          "predicted_flutter_speed_ci_mps": None, "prediction_method": None}
    result = {"bag": "b", "duration_s": 30.0, "samples": 15000, "panel_length_m": 0.27,
              "panel_length_source": "bag", "plateaus": [plateau], "onset": estimate_onset([plateau]),
              "flutter_test": ft}
    text = format_table(result)
    assert "None" not in text and f"   {NO_PREDICTION}; model linear U_f 10.48 m/s" in text.splitlines()
    run = {**ft, "max_airspeed_mps": 10.2, "fluttered": False, "stop_reason": "max points", "bag": None,
           "simulated_s": 30.0, "wall_s": 3.0}
    text = format_flutter_test(run)
    assert "None" not in text and "bag: -; plot: -;" in text and f"{NO_PREDICTION}; model linear U_f 10.480 m/s" in text
    assert text.splitlines()[0].split() == ["#", "U_mps", "f_Hz", "zeta", "zeta", "95%", "CI", "method"]
    # a test whose first point fluttered printed the header over no rows
    none = format_flutter_test({**run, "test_points": [], "fluttered": True})
    assert none.splitlines()[0] == "no test point identified (see stop)", none
    with_one = format_flutter_test({**run, "predicted_flutter_speed_mps": 10.4, "prediction_method": "damping-trend",
                                    "predicted_flutter_speed_ci_mps": [10.1, None]})
    assert "predicted U_f 10.400 m/s (95 % 10.100 .. open) [damping-trend]; model linear U_f 10.480 m/s" in with_one
    assert "predicted margin" not in with_one  # no margin key: none printed
    margin = format_flutter_test({**run, "margin": 0.0192, "required_margin": 0.1})
    assert "max airspeed 10.200 m/s; predicted margin 0.019 at the last point (required 0.1); fluttered" in margin
    # a live test's wall time includes the node's start ("7 s simulated in 4.9 s wall ... RTF 79.7" looked wrong)
    live = format_flutter_test({**run, "simulated_s": 7.0, "wall_s": 4.9, "live": True, "ros_domain_id": 80,
                                "node_startup_wall_s": 4.7, "test_wall_s": 0.088, "node_rtf": 79.7})
    assert ("7 s simulated in 4.9 s wall on the live node (ROS_DOMAIN_ID 80; its start took 4.7 s, the test 0.1 s: "
            "RTF 79.7)") in live, live


def test_onset_estimates_that_could_not_be_made_say_why() -> None:
    """`make run`'s table said "extrapolated from decay rates: - m/s; interpolated across the bracket: - m/s"
    (the turbulence-driven decay rates fell with airspeed; the bracket's top was an LCO): read as figures lost."""
    from panel_rig.analysis.bag_analysis import estimate_onset
    from panel_rig.analyze_cli import format_table

    def plateau(i: int, u: float, rate: float, status: str) -> dict:
        return {"index": i, "t_start_s": 10.0 * i, "t_end_s": 10.0 * i + 9, "airspeed_mps": u,
                "rms_tip_w_over_L": 1e-4, "peak_tip_w_over_L": 3e-4, "dominant_frequency_hz": 22.0,
                "growth_rate_per_s": rate, "status": status}

    ps = [plateau(1, 8.0, -0.14, "decaying"), plateau(2, 10.0, -0.25, "decaying"), plateau(3, 11.2, 0.09, "lco")]
    result = {"bag": "b", "duration_s": 40.0, "samples": 20000, "panel_length_m": 0.27,
              "panel_length_source": "bag", "plateaus": ps, "onset": estimate_onset(ps)}
    onset = next(ln for ln in format_table(result).splitlines() if ln.startswith("flutter onset"))
    assert onset == ("flutter onset bracket: 10.00 .. 11.20 m/s; extrapolated from decay rates: none (the rates do "
                     "not rise towards 0); interpolated across the bracket: none (needs a measured growth at the "
                     "bracket's top and a decay at its bottom)")
    one = [ps[1], plateau(3, 11.2, 0.5, "growing")]
    onset = next(ln for ln in format_table({**result, "plateaus": one, "onset": estimate_onset(one)}).splitlines()
                 if ln.startswith("flutter onset"))
    assert "extrapolated from decay rates: none (needs two plateaus with a measured decay)" in onset
    assert "interpolated across the bracket: 10.40 m/s" in onset  # 10 + 0.25 x 1.2 / 0.75


def test_signal_metrics_of_a_response_decayed_to_denormals_and_of_too_few_samples() -> None:
    """`lco --duration 3600 --json` gave RMS 0.0 beside a peak of 5.5e-322 (the squares underflowed), and
    `lco --duration 0.001` a dominant frequency of 0.0 Hz for two samples."""
    from panel_rig.analysis.signals import dominant_frequency_hz, rms

    t = np.arange(4096) / 2048.0
    wave = np.sin(2 * np.pi * 23.0 * t)
    for scale in (1.0, 1e-200, 1e-310):
        assert rms(scale * wave) == pytest.approx(scale * rms(wave), rel=1e-6 if scale > 1e-300 else 1e-3)
        assert dominant_frequency_hz(scale * wave, 1 / 2048.0) == pytest.approx(23.0, abs=0.05)
    assert rms(np.zeros(5)) == 0.0
    assert np.isnan(dominant_frequency_hz(np.array([0.0, 1e-3]), 1e-3))
    assert np.isnan(dominant_frequency_hz(np.zeros(64), 1e-3))


def test_analyze_on_a_terminal_shows_its_stages(tmp_path: Path) -> None:
    """A 153 MB flutter-test bag took 60 s with no output at all (reading it is most of that). On a terminal the
    stages are named on stderr as they start; piped or logged, stderr keeps to one line per error."""
    import os
    import pty

    master, slave = pty.openpty()
    proc = subprocess.Popen([sys.executable, "-m", "panel_rig.cli", "analyze", str(REFERENCE), "--plots",
                             str(tmp_path / "plots")], stdout=subprocess.PIPE, stderr=slave, text=True)
    os.close(slave)
    chunks = []
    while True:
        try:
            chunk = os.read(master, 4096)
        except OSError:  # the pty's other end closed: the command ended
            break
        if not chunk:
            break
        chunks.append(chunk)
    out, _ = proc.communicate(timeout=120)
    os.close(master)
    err = b"".join(chunks).decode()
    assert proc.returncode == 0 and "flutter onset" in out
    assert f"checking and reading {REFERENCE} (" in err and "readings (51.0 s) in" in err, err
    assert f"writing the plots to {tmp_path / 'plots'}" in err
    piped = subprocess.run([sys.executable, "-m", "panel_rig.cli", "analyze", str(REFERENCE)], capture_output=True,
                           text=True, timeout=120)
    assert piped.returncode == 0 and piped.stderr == ""


def test_analyze_names_the_aborts_the_bag_recorded(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A run that ended in an abort showed only its plateaus: the abort was in the recorded /diagnostics but not in
    the analysis. Each abort (a new last_abort_time_s) is now named with its time and reason, once."""
    from diagnostic_msgs.msg import DiagnosticStatus

    from panel_rig.ros.messages import diagnostics_msg

    reason = "tip |w/L| = 0.9304 exceeds the limit 0.92593"

    def diagnostics(writer: BagWriter) -> None:
        for t_s, aborts, last in [(1.0, 0, ""), (20.0, 1, "12.5"), (21.0, 1, "12.5"), (30.0, 2, "29.0")]:
            values = {"state": "aborted" if aborts else "running", "aborts": aborts, "last_abort_time_s": last,
                      "abort_reason": reason if aborts else ""}
            writer.write("/diagnostics", diagnostics_msg(int(t_s * 1e9), DiagnosticStatus.OK, "", values, "/rig"),
                         int(t_s * 1e9))

    _write_synthetic(tmp_path / "aborted", extra=diagnostics)
    res = analyze_bag(tmp_path / "aborted")
    assert res["aborts"] == [{"time_s": 12.5, "reason": reason}, {"time_s": 29.0, "reason": reason}]
    assert main([str(tmp_path / "aborted")]) == 0
    assert f"rig aborted at t = 12.500 s (rig time): {reason}" in capsys.readouterr().out
    _write_synthetic(tmp_path / "plain")
    assert analyze_bag(tmp_path / "plain")["aborts"] == []  # no /diagnostics recorded (the in-process rig's bags)


@pytest.mark.parametrize("rate_hz", [500.0, 64.0])
def test_a_tap_s_decay_is_fitted_above_its_floor_and_apart_from_faster_modes(rate_hz: float) -> None:
    """A tap's free response: the 23 Hz mode decaying at -0.8 1/s from 1e-3, a 69 Hz mode at -4 1/s from 1e-3 and a
    random response of the 23 Hz mode (a resonator at 10 % damping driven by white noise, RMS 4e-5) that it sinks
    into; twelve noise seeds. The band-limited floor fit gives the mode's rate within 5 % on average and 30 % each
    (measured -0.827 and -0.830 mean, worst 16 % and 22 %: the random response interferes with the decay), and finds
    the floor; a line through the whole log-envelope reads -0.35. Read at 64 Hz (the reference bag's rate) the
    band's top would pass the Nyquist frequency and the 69 Hz mode aliases to 5 Hz: a high-pass above it does."""
    from scipy.signal import lfilter

    from panel_rig.analysis.bag_analysis import envelope_rate_per_s
    from panel_rig.analysis.decay import tap_decay

    dt, f, sigma = 1.0 / rate_hz, 23.0, -0.8
    t = np.arange(0.0, 8.0, dt)
    free = 1e-3 * np.exp(sigma * t) * np.sin(2 * np.pi * f * t) + 1e-3 * np.exp(-4.0 * t) * np.sin(2 * np.pi * 69 * t)
    r = np.exp(-2 * np.pi * f * 0.1 * dt)  # the resonator's pole radius
    rates, plain = [], []
    for seed in range(12):
        drive = np.random.default_rng(seed).standard_normal(t.size + 2000)
        noise = lfilter([1.0], [1.0, -2 * r * np.cos(2 * np.pi * f * dt), r * r], drive)[2000:]
        floor = 4e-5 * noise / np.std(noise)
        fit, band = tap_decay(free + floor, dt, 0.5)
        assert 5.0 < band[0] < f and (band[1] is None if rate_hz == 64.0 else f < band[1] < 69.0)
        assert 1e-5 < fit.floor < 6e-5
        rates.append(fit.rate_per_s)
        plain.append(envelope_rate_per_s(free + floor, dt, 0.5))
        none = tap_decay(floor, dt, 0.5)  # no tap: no decay worth the name
        assert none is None or abs(none[0].rate_per_s) < 0.1, none
    assert np.mean(rates) == pytest.approx(sigma, rel=0.05)
    assert np.all(np.abs(np.array(rates) / sigma - 1) < 0.3), rates
    assert np.mean(plain) > 0.6 * sigma


def test_a_rate_that_rounds_to_zero_has_no_minus_sign_and_a_stationary_plateau_has_none() -> None:
    """A stationary plateau's fitted rate of -0.0001 1/s printed as '-0.000' in the table; a stationary plateau has
    no measured rate (an audit read '0.000' and '0.001' as rates), so it reads '-'; a decay's rounds without a sign."""
    from panel_rig.analysis.bag_analysis import estimate_onset
    from panel_rig.analyze_cli import format_table

    plateau = {"index": 1, "t_start_s": 0.0, "t_end_s": 10.0, "airspeed_mps": 6.0, "rms_tip_w_over_L": 1e-5,
               "peak_tip_w_over_L": 3e-5, "dominant_frequency_hz": 26.0, "growth_rate_per_s": -1e-4,
               "status": "stationary"}
    result = {"bag": "b", "duration_s": 10.0, "samples": 5000, "panel_length_m": 0.27, "panel_length_source": "bag",
              "plateaus": [plateau], "onset": estimate_onset([plateau])}
    row = next(line for line in format_table(result).splitlines() if line.endswith("stationary"))
    assert row.split()[-2:] == ["-", "stationary"], row
    decay = {**plateau, "status": "decaying"}
    row = next(line for line in format_table({**result, "plateaus": [decay]}).splitlines() if line.endswith("decaying"))
    assert " 0.000 decaying" in row and "-0.000" not in row, row


@pytest.mark.parametrize("n", [10, 27, 28, 60])
def test_a_tap_s_free_response_too_short_to_fit_gives_no_rate_not_an_error(n: int) -> None:
    """A free response of 10 samples (a tap just before a plateau's end) made the band-pass filter raise (its
    padding needs 27 samples). Too short for the filter or for the fit's windows is no fit now."""
    from panel_rig.analysis.decay import tap_decay

    t = np.arange(n) / 500.0
    x = np.exp(-t) * np.sin(2 * np.pi * 23.0 * t)
    assert tap_decay(x, 1 / 500.0, 0.1) is None  # 4 windows of 50 samples needed
    fit = tap_decay(x, 1 / 500.0, 0.002)  # windows of 2 samples: only the filter's padding limits it
    assert (fit is None) == (n <= 27)


def test_a_plateau_whose_measuring_window_holds_only_the_sensor_s_noise_has_no_frequency() -> None:
    """A wind-off plateau after a run: the panel rings down in its first seconds, so its envelope rose above the
    quiet threshold and it is not "quiet", but its last 5 s (the measuring window) hold only the sensor's 5 um of
    noise, whose spectral peak was read as the panel's frequency (161 Hz, above every structural mode)."""
    import dataclasses

    from panel_rig.analysis.bag_analysis import Criteria, analyze_series
    from panel_rig.analyze_cli import quiet_rms_of

    length_m, rng = 0.27, np.random.default_rng(3)
    crit = dataclasses.replace(Criteria(), quiet_rms=quiet_rms_of({"sensor.tip_noise_m": 5e-6}, length_m, 1e-7))
    t = np.arange(0.0, 40.0, 1.0 / 500.0)
    ring = 2e-3 * np.exp(-1.5 * t) * np.sin(2 * np.pi * 23.0 * t)
    noise = 5e-6 / length_m * rng.standard_normal(t.size)
    (p,) = analyze_series(t, ring + noise, np.zeros(t.size), {}, crit)["plateaus"]
    assert p["status"] != "quiet" and p["rms_tip_w_over_L"] == pytest.approx(5e-6 / length_m, rel=0.1), p
    assert np.isnan(p["dominant_frequency_hz"]), p
    # a slower ring-down, still moving in the measuring window, has its frequency
    slow = 2e-3 * np.exp(-0.3 * t) * np.sin(2 * np.pi * 23.0 * t)
    (p,) = analyze_series(t[t < 8.0], (slow + noise)[t < 8.0], np.zeros(int(np.sum(t < 8.0))), {}, crit)["plateaus"]
    assert p["dominant_frequency_hz"] == pytest.approx(23.0, abs=0.3), p


def test_a_bag_without_a_plateau_says_so_instead_of_an_empty_table(tmp_path: Path) -> None:
    """A 1.7 s bag (the first chunk of a recording, rebuilt) printed the table's head alone and "flutter onset: no
    plateau was unstable", as if the panel had been stable somewhere. It now says there is no plateau, and why."""
    from panel_rig.analyze_cli import format_table

    bag = tmp_path / "short"
    with BagWriter(bag) as writer:
        writer.write_parameters({"panel.length_m": LENGTH_M})
        for k in range(int(1.7 * FS_HZ)):
            ns = int(round(k / FS_HZ * 1e9)) + 1
            tip, air = PointStamped(), Vector3Stamped()
            _stamp(tip, ns)
            _stamp(air, ns)
            air.vector.x = 8.0
            writer.write("/rig/tip_displacement", tip, ns)
            writer.write("/rig/airspeed", air, ns)
    res = analyze_bag(bag)
    assert res["plateaus"] == []
    text = format_table(res)
    assert "no plateau: the airspeed stays within 0.05 m/s for 3 s nowhere in this 1.7 s" in text, text
    assert "flutter onset:" not in text and "flutter onset bracket" not in text and " t_s " not in text, text


def test_a_plateau_still_growing_when_the_rig_aborted_is_growing_not_lco() -> None:
    """A closed loop held the panel quiet at 1.2 U_f, then was switched off: the panel grew (+1.8 1/s over its last
    5 s) until the rig aborted at its tip limit, and the irregular-LCO rule (RMS >= 0.05, an envelope that is not
    one exponential) called the plateau "lco". A plateau the rig's abort ended while it still grew is "growing";
    without the abort the same record stays as it was."""
    from panel_rig.analysis.bag_analysis import analyze_series

    t = np.arange(0.0, 18.1, 1.0 / 500.0)
    u = np.where(t < 2.0, 12.58 * (1 - np.exp(-t / 0.2)), 12.58)
    rng = np.random.default_rng(0)
    quiet = 5e-4 * np.sin(2 * np.pi * 22.0 * t) * (1 + 0.3 * rng.standard_normal(t.size))
    a_lco, a0, sigma = 1.2, 5e-4, 1.8  # growing towards a cycle beyond the wall
    amp = a_lco / np.sqrt(1 + (a_lco**2 / a0**2 - 1) * np.exp(-2 * sigma * np.clip(t - 12.0, 0, None)))
    w = np.where(t >= 12.0, amp * np.sin(2 * np.pi * 22.0 * t), quiet)
    (p,) = analyze_series(t, w, u, {}, abort_times_s=[18.08])["plateaus"]
    assert p["status"] == "growing" and p["late_growth_rate_per_s"] > 1.0, p
    (p,) = analyze_series(t, w, u, {})["plateaus"]
    assert p["status"] == "lco"  # (the irregular rule, unchanged without an abort)


def test_control_spans_end_a_watchdog_timeout_after_the_last_command() -> None:
    from panel_rig.analysis.bag_analysis import control_spans

    cmds = {"control/force_cmd": [(1.0, 0.1), (1.05, 0.2), (1.1, 0.0), (2.0, 0.3)]}
    assert control_spans(cmds, 0.1) == [(1.0, pytest.approx(1.2)), (2.0, pytest.approx(2.1))]
    assert control_spans({}, 0.1) == []


@pytest.mark.parametrize("period_ms", [5, 125], ids=["200 Hz", "8 Hz, slower than the watchdog"])
def test_a_plateau_is_cut_where_a_controller_closes_the_loop(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                             period_ms: int) -> None:
    """A controller switched on in the middle of the 11 m/s LCO plateau (t = 28 s) and left on: the plateau is cut
    there, the parts after it are 'closed', and the open loop's onset comes from the open plateaus alone (as without
    a controller), the closed loop's from the closed ones, on a line of its own. Before, the controller's commands
    were not read from the bag and every plateau spoke of the open loop. A controller slower than the watchdog
    (8 Hz, 0.1 s) trips it at every gap: the loop opens for 25 ms each time, which does not cut the plateau (it cut
    it into pieces too short to be plateaus, and the closed loop's plateaus vanished)."""
    from geometry_msgs.msg import WrenchStamped

    def control(writer: BagWriter) -> None:
        for ns in range(28_000_000_000, 40_000_000_000, period_ms * 1_000_000):
            msg = WrenchStamped()
            _stamp(msg, ns)
            msg.wrench.force.z = 0.01
            writer.write("/rig/control/force_cmd", msg, ns, qos="reliable")

    _write_synthetic(tmp_path / "closed", extra=control)
    res = analyze_bag(tmp_path / "closed")
    loops = [(round(p["airspeed_mps"]), p["loop"]) for p in res["plateaus"]]
    assert loops == [(8, "open"), (9, "open"), (10, "open"), (11, "open"), (11, "closed"), (12, "closed")], loops
    assert res["plateaus"][3]["t_end_s"] <= 28.0 <= res["plateaus"][4]["t_start_s"] < 28.01
    _write_synthetic(tmp_path / "plain")
    plain = analyze_bag(tmp_path / "plain")
    assert all(p["loop"] == "open" for p in plain["plateaus"]) and plain["closed_loop_onset"] is None
    assert res["onset"]["bracket_low_mps"] == pytest.approx(plain["onset"]["bracket_low_mps"])
    assert res["onset"]["bracket_high_mps"] == pytest.approx(plain["onset"]["bracket_high_mps"], abs=0.01)  # 4 s of 8
    closed = res["closed_loop_onset"]
    assert closed["bracket_low_mps"] is None and closed["bracket_high_mps"] == pytest.approx(11.0, abs=0.05)
    assert main([str(tmp_path / "closed")]) == 0
    out = capsys.readouterr().out
    assert "loop   status" in out and " closed lco" in out, out
    assert "\nflutter onset bracket: " in out and "\nclosed loop: flutter onset: at or below 11.00 m/s" in out, out
