"""Node start-up: wall time from launching ``panel-rig run`` to its first ``tip_displacement`` message (and to its
"panel_rig up" log line, when it starts publishing: the gap between the two is DDS discovery), and from starting a
program once the node is up to its first reading (``late_client``: the usual order, an operator joining a running
rig).

    python benchmarks/startup.py [--json]

warm: the compiled kernels are in numba's cache (the normal case after the first start of an install);
cold: an empty ``NUMBA_CACHE_DIR``, so every kernel the node uses is compiled, as at the very first start of a
fresh install (numba keys its cache by the source file's path and stamp, so each install path compiles once).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

WARM_STARTS = 9


UP_LINE = re.compile(r"\[(\d+\.\d+)\] \[[\w.]*panel_rig\]: panel_rig up")


def _node_env(extra_env: dict[str, str] | None = None) -> tuple[int, dict[str, str], list[str]]:
    """A private ROS domain for one node and its probes: (domain id, the environment, the node's command line)."""
    domain = random.randint(150, 199)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", **(extra_env or {}))
    return domain, env, [str(Path(sys.executable).parent / "panel-rig"), "run", "--ros-args", "-r", "__ns:=/rig"]


def start_times_s(extra_env: dict[str, str]) -> tuple[float, float]:
    """(seconds from process start to the first tip_displacement message received by a subscriber here, seconds to
    the node's own "panel_rig up" log line): the difference is DDS discovery between the two processes."""
    import rclpy
    from geometry_msgs.msg import PointStamped
    from rclpy.qos import qos_profile_sensor_data

    domain, env, node_cmd = _node_env(extra_env)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("startup_probe", context=ctx)
    got: list[float] = []
    node.create_subscription(PointStamped, "/rig/tip_displacement", lambda m: got.append(time.monotonic()),
                             qos_profile_sensor_data)
    exe = rclpy.executors.SingleThreadedExecutor(context=ctx)
    exe.add_node(node)
    with tempfile.TemporaryDirectory() as log_dir:
        env["ROS_LOG_DIR"] = log_dir
        log = Path(log_dir) / "console.txt"
        t0, t0_wall = time.monotonic(), time.time()
        with log.open("w") as console:
            proc = subprocess.Popen(node_cmd, env=env, stdout=console, stderr=subprocess.STDOUT)
        try:
            while not got and proc.poll() is None and time.monotonic() - t0 < 300:
                exe.spin_once(timeout_sec=0.05)
        finally:
            proc.send_signal(signal.SIGINT)
            proc.wait(30)
        up = UP_LINE.search(log.read_text())
    exe.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=ctx)
    if not got:
        raise RuntimeError("the node published no tip_displacement")
    return got[0] - t0, (float(up.group(1)) - t0_wall if up else float("nan"))


def late_client_times_s(n: int) -> list[float]:
    """Seconds to the first tip reading for ``n`` programs started one after another once the node is up (the usual
    order: the rig runs, then an operator or a subscriber joins), each a process of its own
    (``python -m panel_rig.ros.first_reading``)."""
    _, env, node_cmd = _node_env()
    times = []
    with tempfile.TemporaryDirectory() as log_dir:
        env["ROS_LOG_DIR"] = log_dir
        proc = subprocess.Popen(node_cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            for line in proc.stdout:
                if "panel_rig up" in line:
                    break
            for _ in range(n):
                out = subprocess.run([sys.executable, "-m", "panel_rig.ros.first_reading", "--namespace", "/rig"],
                                     env=env, capture_output=True, text=True, timeout=60, check=True)
                times.append(float(out.stdout))
        finally:
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=30)
    return times


def measure() -> dict[str, float]:
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        out["startup_cold_first_tip_s"] = start_times_s({"NUMBA_CACHE_DIR": cache})[0]
        out["startup_cold_again_same_cache_first_tip_s"] = start_times_s({"NUMBA_CACHE_DIR": cache})[0]
    start_times_s({})  # make sure the default cache is filled
    # the spread matters: some starts' first reading arrives seconds later, while the node itself was up as early
    starts = [start_times_s({}) for _ in range(WARM_STARTS)]
    for name, values in (("first_tip", sorted(s[0] for s in starts)), ("node_up", sorted(s[1] for s in starts))):
        out[f"startup_warm_{name}_min_s"] = values[0]
        out[f"startup_warm_{name}_median_s"] = values[len(values) // 2]
        out[f"startup_warm_{name}_max_s"] = values[-1]
    late = sorted(late_client_times_s(WARM_STARTS))
    out["late_client_first_tip_min_s"] = late[0]
    out["late_client_first_tip_median_s"] = late[len(late) // 2]
    out["late_client_first_tip_max_s"] = late[-1]
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--json", action="store_true")
    result = measure()
    if ap.parse_args().json:
        print(json.dumps(result))
    else:
        for k, v in result.items():
            print(f"{k:45s} {v:8.2f}")
