"""Closed loop over topics: the rig node and the reference controller, each a separate process.

The node runs in fast mode, where an attached controller runs in lock-step with it (the rig waits for each answer
and emulates the transport latency ``control.fast_delay_s``), so the scenario is deterministic whatever the load of
the machine (real-time latency is measured by benchmarks/control_latency.py, not asserted here).
One scenario, bounded in time, every wait on a condition with a timeout: the controller holds the panel quiet
at 1.2 x the open-loop flutter speed, the node measures the command ages, bad control commands are rejected, and
when the controller is killed at 1.1 x U_f the watchdog zeroes the actuator (logged), the panel flutters and the safety
abort acts. No NaN anywhere, and the node exits cleanly.
"""

from __future__ import annotations

import math
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PointStamped, Vector3Stamped, WrenchStamped  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data  # noqa: E402
from std_msgs.msg import Float64  # noqa: E402

from panel_rig.analysis.control import QUIET_FACTOR, SENSOR_NOISE_M  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# the readings' best-effort QoS with a deep history: this client takes one sample per spin_once and falls behind a
# fast node's 500 Hz x 5 bursts; with the sensor profile's depth of 5 it lost most readings (a flaky comparison)
DEEP_BEST_EFFORT = QoSProfile(depth=5000, reliability=ReliabilityPolicy.BEST_EFFORT)
TIP_LIMIT = 0.02  # the node's safety.max_tip_w_over_L: the growing flutter must reach it and abort
TIMEOUT_S = 0.1  # control.timeout_s
FAST_DELAY_S = 0.003  # control.fast_delay_s: the emulated latency the node must report as the commands' age


def stamp_s(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class Client:
    def __init__(self, domain_id: int) -> None:
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node("control_test_client", namespace="/rig", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.got: dict[str, list[Any]] = {"tip": [], "airspeed": [], "diag": [], "rosout": [], "cmd": []}
        for typ, topic, key, qos in ((PointStamped, "tip_displacement", "tip", DEEP_BEST_EFFORT),
                                     (Vector3Stamped, "airspeed", "airspeed", qos_profile_sensor_data),
                                     (DiagnosticArray, "/diagnostics", "diag", RELIABLE),
                                     (Log, "/rosout", "rosout", RELIABLE),
                                     (WrenchStamped, "control/force_cmd", "cmd", RELIABLE)):
            self.node.create_subscription(typ, topic, lambda m, k=key: self.got[k].append(m), qos)
        self.pubs = {t: self.node.create_publisher(Float64, t, RELIABLE) for t in ("airspeed_cmd", "shaker/force_cmd")}
        self.control_pub = self.node.create_publisher(WrenchStamped, "control/force_cmd", RELIABLE)

    def wait(self, cond: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not cond():
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
            self.executor.spin_once(timeout_sec=0.02)

    def diag(self, k: int = -1) -> dict[str, str]:
        """The node's k-th /diagnostics message (default the last) as key -> value; {} before the first."""
        return {kv.key: kv.value for kv in self.got["diag"][k].status[0].values} if self.got["diag"] else {}

    def lockstep_window(self, engaged_s: float) -> dict[str, str] | None:
        """The first diagnostics message whose command window opened after the node marched past ``engaged_s``
        (simulated s, when the lock-step was on): by then every command answering a reading the node published
        before it engaged had arrived (the node marches on only when the reading it waits for is answered, and the
        controller answers in order). Such a window holds lock-step answers only; None while there is none."""
        for k in range(len(self.got["diag"]) - 1):
            prev, d = self.diag(k), self.diag(k + 1)
            if float(prev["sim_time_s"]) > engaged_s and int(d["control_latency_n"]) > 0:
                return d
        return None

    def publish(self, topic: str, value: float) -> None:
        self.wait(lambda: self.pubs[topic].get_subscription_count() > 0, 10.0, f"a subscriber on {topic}")
        self.pubs[topic].publish(Float64(data=value))

    def wait_readings(self, n: int, timeout_s: float = 10.0) -> None:
        k = len(self.got["tip"])
        self.wait(lambda: len(self.got["tip"]) >= k + n, timeout_s, f"{n} tip readings")

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def _stop(proc: subprocess.Popen, sig: int = signal.SIGINT) -> str:
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        out, _ = proc.communicate(timeout=15)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
    return out or ""


def test_closed_loop_over_topics(ros_env: dict[str, str], model: Any, tmp_path: Path) -> None:
    from panel_rig.analysis.control import design_law

    design = design_law(model)
    u_f = design.open_loop_flutter_mps
    client = Client(int(ros_env["ROS_DOMAIN_ID"]))
    node = subprocess.Popen(
        [PYTHON, "-m", "panel_rig.ros.rig_node", "--fast", "--ros-args", "-r", "__ns:=/rig",
         "-p", "fast_max_realtime_factor:=5.0", "-p", f"control.fast_delay_s:={FAST_DELAY_S}",
         "-p", "model.variant:=full", "-p", "tunnel.time_constant_s:=0.3", "-p", "diagnostics_rate_hz:=5.0",
         "-p", f"safety.max_tip_w_over_L:={TIP_LIMIT}", "-p", f"control.timeout_s:={TIMEOUT_S}"],
        env=ros_env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ctl = subprocess.Popen(
        [PYTHON, "-m", "panel_rig.ros.controller", "--ros-args", "-r", "__ns:=/rig",
         "-p", f"gain_nspm2:={design.law.gain_nspm2}", "-p", f"derivative_hz:={design.law.derivative_hz}"],
        env=ros_env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    node_out = ctl_out = ""
    try:
        client.wait(lambda: client.diag().get("control_state") == "active", 60.0, "the controller's commands")
        client.wait(lambda: int(client.diag()["control_commands"]) > 200 and client.diag()["control_lockstep"] == "True",
                    20.0, "the lock-step")
        # the window of that message may still hold the first commands, which answered readings of the node's last
        # free-running 64-period blocks (older than the emulated delay): the ages are measured in a later window
        engaged_s = float(client.diag()["sim_time_s"])
        client.wait(lambda: client.lockstep_window(engaged_s) is not None, 20.0, "a window wholly in lock-step")
        d = client.lockstep_window(engaged_s)
        assert float(d["control_latency_mean_ms"]) == pytest.approx(1e3 * FAST_DELAY_S, abs=1e-3), d
        assert float(d["control_latency_p99_ms"]) == pytest.approx(1e3 * FAST_DELAY_S, abs=1e-3), d
        # every command echoes the stamp of a tip reading: wait until this client has taken the readings the last
        # 50 commands answered (they may still be queued here), then compare
        # (only commands answering readings published after this client's tip subscription matched: discovery can
        # match the controller's command topic here before the node's readings)
        def answered() -> list[Any]:
            tips = client.got["tip"]
            return [m for m in client.got["cmd"] if tips and stamp_s(m) >= stamp_s(tips[0])]

        client.wait(lambda: len(answered()) >= 50, 20.0, "50 commands answering readings this client can see")
        cmds = [(m.header.stamp.sec, m.header.stamp.nanosec) for m in answered()[-50:]]
        client.wait(lambda: client.got["tip"] and stamp_s(client.got["tip"][-1]) >= max(s + n * 1e-9 for s, n in cmds),
                    10.0, "the readings the commands answered")
        tips = {(m.header.stamp.sec, m.header.stamp.nanosec) for m in client.got["tip"]}
        assert sum(c in tips for c in cmds) >= 0.8 * len(cmds)  # (a best-effort reading may not reach this client)

        # quiet at 1.2 x the open-loop flutter speed after a shaker tap
        client.publish("airspeed_cmd", 1.2 * u_f)
        client.wait(lambda: client.got["airspeed"] and client.got["airspeed"][-1].vector.x > 1.19 * u_f, 20.0,
                    "the tunnel at 1.2 U_f")
        client.publish("shaker/force_cmd", 0.05)
        client.wait_readings(10)
        client.publish("shaker/force_cmd", 0.0)
        t_tap = stamp_s(client.got["tip"][-1])
        client.wait(lambda: stamp_s(client.got["tip"][-1]) > t_tap + 6.0, 30.0, "6 s after the tap")
        tw = np.array([(stamp_s(m), m.point.z) for m in client.got["tip"]])
        assert np.all(np.isfinite(tw))
        late = tw[tw[:, 0] > t_tap + 4.0, 1]
        rms = float(np.sqrt(np.mean(late**2)))
        assert rms < QUIET_FACTOR * SENSOR_NOISE_M, f"tip RMS {rms * 1e6:.1f} um at 1.2 U_f"
        assert client.diag()["state"] == "running"

        # bad control commands: rejected with a reason, counted, the rig carries on
        for value in (math.nan, math.inf, 10.0):
            before = int(client.diag()["rejected_commands"])
            msg = WrenchStamped()
            msg.header.stamp = client.got["tip"][-1].header.stamp
            msg.wrench.force.z = value
            client.control_pub.publish(msg)
            client.wait(lambda b=before: int(client.diag()["rejected_commands"]) > b, 10.0, f"rejection of {value}")
            assert "control/force_cmd" in client.diag()["last_rejection"]
        assert client.diag()["state"] == "running"

        # watchdog: kill the controller at 1.1 U_f
        client.publish("airspeed_cmd", 1.1 * u_f)
        client.wait(lambda: client.got["airspeed"][-1].vector.x < 1.11 * u_f, 20.0, "the tunnel at 1.1 U_f")
        ctl.kill()
        ctl.wait(10)
        client.wait(lambda: any("control watchdog" in m.msg for m in client.got["rosout"]), 10.0,
                    "the watchdog on /rosout")
        trip = next(m for m in client.got["rosout"] if "control watchdog" in m.msg)
        assert trip.level == Log.WARN and trip.name.endswith("panel_rig")
        t_last, t_trip = (float(x) for x in _between(trip.msg))
        assert 0 < t_trip - t_last <= TIMEOUT_S + 1e-3, trip.msg
        client.wait(lambda: client.diag()["control_state"] == "timed_out", 5.0, "control state timed out")
        assert abs(float(client.diag()["control_force_npm"])) < 1e-6
        # unprotected now: a tap starts the flutter, which grows until the safety abort acts
        client.publish("shaker/force_cmd", 0.5)
        client.wait_readings(10)
        client.publish("shaker/force_cmd", 0.0)
        client.wait(lambda: client.diag()["state"] == "aborted", 45.0, "the abort as the flutter grows")
        assert "exceeds the limit" in client.diag()["abort_reason"]
        assert all(math.isfinite(m.point.z) for m in client.got["tip"])
        assert node.poll() is None
    finally:
        ctl_out = _stop(ctl)
        node_out = _stop(node)
        client.close()
    assert node.returncode == 0, node_out[-3000:]
    assert "Traceback" not in node_out and "Traceback" not in ctl_out, (node_out[-2000:], ctl_out[-2000:])


def _between(text: str) -> tuple[str, str]:
    """(last command time, trip time) from the watchdog's log line."""
    import re

    m = re.search(r"last command at t = ([0-9.]+) s.*at t = ([0-9.]+) s", text)
    assert m, text
    return m.group(1), m.group(2)


def test_controller_bad_parameters_exit_code_2(ros_env: dict[str, str]) -> None:
    proc = subprocess.run([PYTHON, "-m", "panel_rig.ros.controller", "--params", "/nonexistent.yaml",
                           "--ros-args", "-r", "__ns:=/rig"], env=ros_env, cwd=ROOT, capture_output=True, text=True,
                          timeout=60, check=False)
    assert proc.returncode == 2 and "nonexistent" in proc.stderr



def test_controller_follows_a_restarted_rig_and_takes_live_parameters(ros_env: dict[str, str]) -> None:
    """In-process: a rig whose clock starts again (a restarted fast node) is served at once; live parameters act
    or are refused with a reason; bad start values stop the start."""
    from rclpy.parameter import Parameter

    from panel_rig.ros.controller import Controller

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    node = Controller(context=ctx, parameter_overrides=[Parameter("gain_nspm2", value=0.4)])

    def reading(t_s: float, z_m: float = 1e-4) -> None:
        msg = PointStamped()
        msg.header.stamp.sec, msg.header.stamp.nanosec = int(t_s), int(round((t_s % 1.0) * 1e9))
        msg.point.z = z_m
        node._on_tip(msg)

    try:
        for k in range(5):
            reading(100.0 + 0.002 * k, 1e-4 * k)
        assert node.sent == 5
        reading(100.001)  # late (best effort): the answer to a newer reading is out already
        assert node.sent == 5
        reading(0.002)  # the rig restarted: its time begins again
        assert node.sent == 6
        assert node.set_parameters([Parameter("enabled", value=False)])[0].successful
        reading(0.004)
        assert node.sent == 6
        for name, value in (("gain_nspm2", math.nan), ("max_force_npm", -1.0), ("design_delay_ms", 5.0)):
            result = node.set_parameters([Parameter(name, value=value)])[0]
            assert not result.successful and name in result.reason, (name, result.reason)
        assert node.set_parameters([Parameter("gain_nspm2", value=0.8)])[0].successful
        assert node.law.gain_nspm2 == 0.8
        # an integer for a float parameter is that float, live and at start (as the rig node takes it; rclpy
        # refused `-p gain_nspm2:=1` with "expecting type 'DOUBLE'")
        assert node.set_parameters([Parameter("gain_nspm2", value=2)])[0].successful
        assert node.law.gain_nspm2 == 2.0 and node.get_parameter("gain_nspm2").value == 2.0
        # a misspelt name (the parameter service calls set_parameters_atomically): refused, named, the nearest
        # name offered (rclpy's own reason was "Invalid access to undeclared parameter(s): []")
        typo = node.set_parameters_atomically([Parameter("gain_nspm", value=1.0)])
        assert not typo.successful and "'gain_nspm'" in typo.reason and "'gain_nspm2'" in typo.reason, typo.reason
        assert node.law.gain_nspm2 == 2.0
        clock = node.set_parameters_atomically([Parameter("use_sim_time", value=True)])  # rclpy's: not a design input
        assert not clock.successful and "use_sim_time is read at start" in clock.reason, clock.reason
        other = Controller(context=ctx, parameter_overrides=[Parameter("gain_nspm2", value=1),
                                                             Parameter("max_force_npm", value=3)])
        assert (other.law.gain_nspm2, other.max_force) == (1.0, 3.0)
        other.destroy_node()
        for name, value in (("max_force_npm", -1.0), ("derivative_hz", 0.0), ("design_delay_ms", -3.0)):
            with pytest.raises(ValueError, match=name):
                Controller(context=ctx, parameter_overrides=[Parameter("gain_nspm2", value=0.4),
                                                             Parameter(name, value=value)])
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def test_an_uncapped_fast_rig_engages_the_lock_step_with_a_command_it_refused_as_too_old(
        ros_env: dict[str, str]) -> None:
    """Fast mode without a cap runs free at hundreds of times real time: a controller's answer arrived 0.1 s of
    simulated time or more after its reading and was refused as too old, every one of them, so the lock-step (which
    an accepted command engaged) never engaged and the loop never closed (a review's rig aborted at flutter with every
    command refused). Any command from a controller now engages it: the next answers are taken."""
    client = Client(int(ros_env["ROS_DOMAIN_ID"]))
    node = subprocess.Popen(
        [PYTHON, "-m", "panel_rig.ros.rig_node", "--fast", "--ros-args", "-r", "__ns:=/rig",
         "-p", "fast_max_realtime_factor:=0.0", "-p", f"control.fast_delay_s:={FAST_DELAY_S}",
         "-p", "diagnostics_rate_hz:=5.0", "-p", "control.timeout_s:=0.02"],
        env=ros_env, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    ctl = subprocess.Popen([PYTHON, "-m", "panel_rig.ros.controller", "--ros-args", "-r", "__ns:=/rig",
                            "-p", "gain_nspm2:=0.4"], env=ros_env, cwd=ROOT, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True)
    node_out = ""
    try:
        client.wait(lambda: client.diag().get("control_lockstep") == "True"
                    and int(client.diag().get("control_commands", 0)) > 100, 60.0, "the lock-step and taken commands")
        engaged_s = float(client.diag()["sim_time_s"])
        client.wait(lambda: client.lockstep_window(engaged_s) is not None, 20.0, "a window wholly in lock-step")
        assert float(client.lockstep_window(engaged_s)["control_latency_p99_ms"]) == pytest.approx(
            1e3 * FAST_DELAY_S, abs=1e-3)
    finally:
        _stop(ctl)
        node_out = _stop(node)
        client.close()
    assert node.returncode == 0, node_out[-3000:]


def test_real_time_ages_on_the_ros_clock_and_watchdog(ros_env: dict[str, str]) -> None:
    """Real time: commands echo ROS-clock stamps, the node measures their ages on the ROS clock (reported, not
    asserted against a target: the machine's load decides them; benchmarks/control_latency.py measures them), and
    killing the controller trips the watchdog. The tunnel is off: this checks the plumbing, not the suppression."""
    client = Client(int(ros_env["ROS_DOMAIN_ID"]))
    node = subprocess.Popen(
        [PYTHON, "-m", "panel_rig.ros.rig_node", "--ros-args", "-r", "__ns:=/rig", "-p", "diagnostics_rate_hz:=5.0",
         "-p", f"control.timeout_s:={TIMEOUT_S}"], env=ros_env, cwd=ROOT, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)
    ctl = subprocess.Popen([PYTHON, "-m", "panel_rig.ros.controller", "--ros-args", "-r", "__ns:=/rig",
                            "-p", "gain_nspm2:=0.4"], env=ros_env, cwd=ROOT, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True)
    node_out = ""
    try:
        client.wait(lambda: client.diag().get("mode") == "real-time" and client.diag().get("control_state") == "active"
                    and int(client.diag()["control_latency_n"]) > 0 and bool(client.got["cmd"]), 60.0,
                    "real-time control commands")
        d = client.diag()
        assert client.got["cmd"] and stamp_s(client.got["cmd"][-1]) > 1e9  # the ROS clock, not simulated time
        assert 0 < float(d["control_latency_mean_ms"]) < 1e3 * TIMEOUT_S, d
        assert d["control_lockstep"] == "False"
        ctl.kill()
        ctl.wait(10)
        client.wait(lambda: any("control watchdog" in m.msg for m in client.got["rosout"]), 10.0, "the watchdog")
        client.wait(lambda: client.diag()["control_state"] == "timed_out", 5.0, "control state timed out")
        # a stale command is refused with the rig's times and the stamp as it was sent (the rig's seconds alone did
        # not match anything the controller knew)
        stale = WrenchStamped()
        stale.header.stamp = client.got["tip"][-1].header.stamp
        stale.header.stamp.sec -= 1
        client.control_pub.publish(stale)
        sent = f"header.stamp was {stale.header.stamp.sec}.{stale.header.stamp.nanosec:09d} s"
        client.wait(lambda: any(sent in m.msg for m in client.got["rosout"]), 10.0, "the stale command's warning")
        assert any("ms old" in m.msg and sent in m.msg for m in client.got["rosout"])
    finally:
        _stop(ctl)
        node_out = _stop(node)
        client.close()
    assert node.returncode == 0, node_out[-3000:]


def test_controller_report_says_when_no_rig_is_heard():
    """The periodic log line read "airspeed nan m/s" when no rig node answered on the namespace / domain."""
    pytest.importorskip("rclpy")
    from panel_rig.ros.controller import report_line

    quiet = report_line(0, 0, 0, float("nan"), "/rig")
    assert "no tip readings" in quiet and "/rig" in quiet and "nan" not in quiet
    assert report_line(250, 240, 3, 10.5, "/rig") == "commands sent 240, clipped 3, airspeed 10.50 m/s"
