"""The live flutter monitor in the rig node (``flutter_monitor:=true``, fast mode, turbulence and sensor on): one
``flutter_monitor`` DiagnosticArray per finished airspeed plateau, received over ROS by a subscriber."""

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PLATEAU_S = 30.0  # simulated (5 s run-in + >= 20 s identified); ~5 s wall each at the node's fast-mode speed here


def test_node_publishes_one_monitor_message_per_plateau(tmp_path, monkeypatch):
    rclpy = pytest.importorskip("rclpy")
    from diagnostic_msgs.msg import DiagnosticArray

    from panel_rig.ros.flutter_monitor import parse_monitor
    from panel_rig.ros.operator import Operator

    env = dict(os.environ, ROS_DOMAIN_ID=str(random.randint(100, 200)), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_LOG_DIR=str(tmp_path))
    cmd = [sys.executable, "-m", "panel_rig.ros.node", "--fast", "--params", str(ROOT / "config/tang_dowell_2002.yaml"),
           "--ros-args", "-r", "__ns:=/rig", "--params-file", str(ROOT / "config/rig.yaml"), "-p", "fast:=true",
           "-p", "flutter_monitor:=true", "-p", "model.variant:=full"]
    with open(tmp_path / "node.log", "w") as log:
        node = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):  # discover the node as it discovers us
        monkeypatch.setenv(key, env[key])
    started_here = not rclpy.ok()
    if started_here:
        rclpy.init(domain_id=int(env["ROS_DOMAIN_ID"]))
    got = []
    try:
        op = Operator("/rig", 30.0)
        op.create_subscription(DiagnosticArray, "flutter_monitor", lambda m: got.append(parse_monitor(m)), 10)
        op.wait_for_rig()
        t_wall = time.monotonic()
        for u in (6.0, 7.0, 8.0, 0.0):
            op.send("airspeed", u)
            op.wait_until(op.time_s + PLATEAU_S)
        deadline = time.monotonic() + 10.0
        while len(got) < 3 and time.monotonic() < deadline:
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
    assert wall < 90.0

