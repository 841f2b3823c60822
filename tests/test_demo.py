"""`panel-rig demo` stopped half-way: its node and operator do not outlive it, the wind goes off, the bag closes."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize(("how", "status"), [("sigterm", 143), ("ctrl_c", 130), ("sigkill", -9)])
def test_a_stopped_demo_stops_its_children_and_closes_the_bag(tmp_path: Path, how: str, status: int) -> None:
    """SIGTERM ended the demo at once while its node ran on, recording without limit (106 MB in 15 s); a Ctrl-C
    in the terminal (SIGINT to the whole process group) stopped the node before the operator's wind-off. The
    children now run in their own sessions and the demo stops them in order: operator (0 m/s), then node."""
    psutil = pytest.importorskip("psutil")
    pytest.importorskip("rclpy")
    from panel_rig.recording.reader import read_bag

    out, bags = tmp_path / "out", tmp_path / "bags"
    proc = subprocess.Popen([sys.executable, "-m", "panel_rig.cli", "demo", "--out", str(out), "--bag-dir", str(bags)],
                            cwd=ROOT, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline and proc.poll() is None:  # until the operator's first command is recorded
            if any(b"/rig/airspeed_cmd" in f.read_bytes() for f in bags.glob("rig_*/*.mcap")):
                break
            time.sleep(0.2)  # polling the bag the demo writes (flushed every fraction of a second), bounded
        children = psutil.Process(proc.pid).children(recursive=True)
        assert len(children) >= 2, "no node and operator under the demo"
        if how == "sigterm":
            proc.send_signal(signal.SIGTERM)
        elif how == "sigkill":  # no clean-up in the parent at all: the children follow it (parent-death signal)
            proc.kill()
        else:
            os.killpg(proc.pid, signal.SIGINT)
        out_text, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == status, err[-2000:]
    _, alive = psutil.wait_procs(children, timeout=60)
    assert not alive, f"left running: {[p.cmdline()[:4] for p in alive]}"
    (bag,) = bags.glob("rig_*")
    assert (bag / "metadata.yaml").exists()  # closed, not a recording to recover
    if how != "sigkill":  # there the node and the operator stop at once, each on its own
        assert _commands(read_bag, bags)[-1] == 0.0, "the wind was not turned off"  # the operator's wind-off
        # the steps played before the stop, and one line on the stop (it printed two and lost the operator's table)
        assert "panel-rig demo: operator stopped at step" in err and "panel-rig: interrupted" not in err, err
        at = int(err.split("operator stopped at step ", 1)[1].split()[0])
        if at > 1:  # the steps before it (the stop came once the first command was recorded: mostly in step 2)
            assert "What the operator played before the stop" in out_text and "airspeed 8.0" in out_text, out_text
            # the operator's log of step 1, sent before the fast node's clock ran: no airspeed reading yet (it said
            # "U = nan m/s")
            logs = "".join(f.read_text(errors="replace") for f in (out / "ros_log").rglob("*.log"))
            assert "step 1: airspeed 8.0" in logs and "U = nan" not in logs, logs[-2000:]
        assert err.strip().splitlines()[-1].startswith("panel-rig demo: stopped; the recording so far is in"), err


def _commands(read_bag, bags: Path) -> list[float]:
    (bag,) = bags.glob("rig_*")
    return [m.data for topic, _, _, m in read_bag(bag) if topic.endswith("/airspeed_cmd")]


def test_fast_wait_for_command_starts_the_clock_with_the_first_command(ros_env: dict[str, str]) -> None:
    """The demo's fast node ran ~40 simulated seconds at 0 m/s in a third of the runs while its operator was
    still being discovered; with fast_wait_for_command its simulated time stands until a command arrives."""
    rclpy = pytest.importorskip("rclpy")
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from std_msgs.msg import Float64

    from panel_rig.processes import module_command, stop

    node = subprocess.Popen([*module_command("panel_rig.ros.rig_node"), "--fast", "--ros-args", "-r", "__ns:=/rig",
                             "-p", "fast_wait_for_command:=true", "-p", "diagnostics_rate_hz:=10.0"],
                            env=ros_env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    watcher = rclpy.create_node("clock_watch", context=ctx)
    times: list[float] = []
    watcher.create_subscription(DiagnosticArray, "/diagnostics", lambda m: times.extend(
        float(kv.value) for st in m.status for kv in st.values if kv.key == "sim_time_s"), 10)
    pub = watcher.create_publisher(Float64, "/rig/airspeed_cmd", 10)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(watcher)

    def spin_until(done, what: str, timeout_s: float = 120.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not done():
            assert node.poll() is None and time.monotonic() < deadline, f"waiting for {what}"
            executor.spin_once(timeout_sec=0.1)

    try:
        spin_until(lambda: len(times) >= 5 and pub.get_subscription_count() > 0, "five diagnostics and the node")
        assert max(times) == 0.0, times  # half a second of wall time at least, and the clock has not moved
        pub.publish(Float64(data=0.0))
        spin_until(lambda: times[-1] > 1.0, "the clock to run after the command", 30.0)
    finally:
        executor.shutdown()
        watcher.destroy_node()
        rclpy.shutdown(context=ctx)
        stop(node, 30)


@pytest.mark.parametrize(("args", "said"), [
    (["--max-rtf", "-1"], "panel-rig demo: --max-rtf: must lie in [0, 1e+06], got -1.0"),
    (["--profile", "/nonexistent/profile.yaml"], "panel-rig demo: --profile /nonexistent/profile.yaml: profile not found"),
    (["--profile", "NEG"], "panel-rig demo: --profile NEG: step 1 (airspeed): expected a number in [0, "),
])
def test_arguments_the_node_or_the_operator_would_refuse_are_refused_before_anything_starts(
        tmp_path: Path, capsys, args: list[str], said: str) -> None:
    """`demo --max-rtf -1` started a node that refused its parameter and exited, and the demo waited the rig's
    whole start-up time for it; a missing or bad profile printed a session summary ("Aborts: none (the rig ran the
    whole procedure)") and exit 1. Both now get one line and exit 2, and nothing is made."""
    pytest.importorskip("rclpy")
    from panel_rig.demo import main

    bad = tmp_path / "neg.yaml"
    bad.write_text("- airspeed: -5\n")
    args = [str(bad) if a == "NEG" else a for a in args]
    said = said.replace("NEG", str(bad))
    assert main([*args, "--out", str(tmp_path / "out"), "--bag-dir", str(tmp_path / "bags")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(said) and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists() and not (tmp_path / "bags").exists()


def test_a_node_that_ends_while_the_operator_waits_for_it_ends_the_wait(tmp_path: Path) -> None:
    """The demo waited for its operator alone: a node that had exited left it waiting out the operator's start-up
    timeout (180 s). The wait now ends once the node has, and the node log's problem line says why."""
    from panel_rig.demo import NODE_WATCH_S, _node_failure, _wait_for_operator

    operator = subprocess.Popen([sys.executable, "-c", "import sys, time; print('waiting'); sys.stdout.flush(); "
                                 "time.sleep(60)"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    node = subprocess.Popen([sys.executable, "-c", "import sys; sys.exit(2)"])
    try:
        t0 = time.monotonic()
        out, err, node_ended = _wait_for_operator(operator, node, timeout_s=60.0)
        waited = time.monotonic() - t0
    finally:
        operator.kill()
        operator.wait()
        node.wait()
    assert node_ended and waited < 10 * NODE_WATCH_S + 5, waited
    log = tmp_path / "node.log"
    log.write_text("[INFO] starting\n[ERROR] [rig_node]: invalid parameters: fast_max_realtime_factor: bad\n\n")
    assert _node_failure(2, log) == ("the rig node exited (status 2) before the operator had played the profile: "
                                     "[ERROR] [rig_node]: invalid parameters: fast_max_realtime_factor: bad")
    # an operator that finishes gives its output, and a node still running is no failure
    operator = subprocess.Popen([sys.executable, "-c", "print('played')"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    node = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        out, err, node_ended = _wait_for_operator(operator, node, timeout_s=60.0)
    finally:
        node.kill()
        node.wait()
    assert (out.strip(), node_ended) == ("played", False)
