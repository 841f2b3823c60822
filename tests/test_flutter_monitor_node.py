"""The live flutter monitor in the rig node (``flutter_monitor:=true``, fast mode, turbulence and sensor on): one
``flutter_monitor`` DiagnosticArray per finished airspeed plateau, received over ROS by a subscriber.

``flutter_test.hold`` makes the run deterministic: the node holds simulated time until the first command and after
each published point until the next, so every plateau starts at the same simulated instant and sees the same
turbulence whatever the machine's speed (without it the commands landed at wall-clock-dependent instants and a
realisation now and then gave no prediction from three short plateaus)."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SETTLE_S, DWELL_S = 5.0, 25.0  # simulated: run-in dropped, then the identified window; ~5 s wall a plateau


def test_node_publishes_one_monitor_message_per_plateau(tmp_path, ros_env):
    rclpy = pytest.importorskip("rclpy")
    from diagnostic_msgs.msg import DiagnosticArray

    from panel_rig.ros.flutter_monitor import parse_monitor
    from panel_rig.ros.operator import Operator

    env = ros_env  # this process is on the same private graph: the operator discovers the node
    cmd = [sys.executable, "-m", "panel_rig.ros.rig_node", "--fast", "--params", str(ROOT / "config/tang_dowell_2002.yaml"),
           "--ros-args", "-r", "__ns:=/rig", "--params-file", str(ROOT / "config/rig.yaml"), "-p", "fast:=true",
           "-p", "flutter_monitor:=true", "-p", "model.variant:=full", "-p", "flutter_test.hold:=true",
           "-p", f"flutter_test.settle_s:={SETTLE_S}", "-p", f"flutter_test.dwell_s:={DWELL_S}"]
    with open(tmp_path / "node.log", "w") as log:
        node = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    started_here = not rclpy.ok()
    if started_here:
        rclpy.init(domain_id=int(env["ROS_DOMAIN_ID"]))
    got = []
    try:
        op = Operator("/rig", 30.0)
        sub = op.create_subscription(DiagnosticArray, "flutter_monitor", lambda m: got.append(parse_monitor(m)), 10)
        deadline = time.monotonic() + 60.0  # the node holds (no readings) until the first command: wait for discovery
        while (op.pubs["airspeed"].get_subscription_count() == 0 or sub.get_publisher_count() == 0) \
                and time.monotonic() < deadline:
            op._spin(0.05)
        t_wall = time.monotonic()
        for i, u in enumerate((6.0, 7.0, 8.0)):
            op.send("airspeed", u)
            deadline = time.monotonic() + 60.0  # the node holds after publishing: wait for this point's result,
            # taken by both subscriptions (this test's and the operator's own: one spin may serve only the first)
            while (len(got) <= i or len(op.monitor_lines) <= i) and time.monotonic() < deadline:
                op._spin(0.05)
        wall = time.monotonic() - t_wall
        op.destroy_node()
    finally:
        if started_here:
            rclpy.shutdown()
        if node.poll() is None:
            node.send_signal(signal.SIGINT)
        code = node.wait(20)
    assert code == 0, (tmp_path / "node.log").read_text()[-2000:]
    assert [g["airspeed_mps"] for g in got] == [6.0, 7.0, 8.0], got
    for g in got:
        assert g["damping_ci_low"] < g["damping_ratio"] < g["damping_ci_high"]
        assert 0.0 < g["damping_ratio"] < 0.05 and 20.0 < g["frequency_hz"] < 27.0
    assert got[2]["predicted_flutter_speed_mps"] > 8.0 and got[2]["prediction_method"] != "none"
    starts = [g["plateau_start_s"] for g in got]
    # each plateau begins where the previous one was published (the node stops at the end of a fast block: < 0.13 s)
    assert starts[1:] == pytest.approx([s + SETTLE_S + DWELL_S for s in starts[:-1]], abs=0.13), starts
    assert wall < 90.0
    # the operator shows each result as it comes (the README said it did; it did not subscribe)
    assert [line.split(": ")[1] for line in op.monitor_lines] == ["6.000 m/s", "7.000 m/s", "8.000 m/s"], op.monitor_lines
    assert all("Hz, zeta" in line and "monitor: " in line for line in op.monitor_lines), op.monitor_lines
    assert "predicted U_f" in op.monitor_lines[2], op.monitor_lines

