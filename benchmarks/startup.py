"""Node start-up: wall time from launching ``panel-rig run`` to its first ``tip_displacement`` message.

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
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def first_tip_s(extra_env: dict[str, str]) -> float:
    """Seconds from process start to the first tip_displacement message received by a subscriber here."""
    import rclpy
    from geometry_msgs.msg import PointStamped
    from rclpy.qos import qos_profile_sensor_data

    domain = random.randint(150, 199)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", **extra_env)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node("startup_probe", context=ctx)
    got: list[float] = []
    node.create_subscription(PointStamped, "/rig/tip_displacement", lambda m: got.append(time.monotonic()),
                             qos_profile_sensor_data)
    exe = rclpy.executors.SingleThreadedExecutor(context=ctx)
    exe.add_node(node)
    panel_rig = Path(sys.executable).parent / "panel-rig"
    with tempfile.TemporaryDirectory() as log_dir:
        env["ROS_LOG_DIR"] = log_dir
        t0 = time.monotonic()
        proc = subprocess.Popen([str(panel_rig), "run", "--ros-args", "-r", "__ns:=/rig"], env=env,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            while not got and proc.poll() is None and time.monotonic() - t0 < 300:
                exe.spin_once(timeout_sec=0.05)
        finally:
            proc.send_signal(signal.SIGINT)
            proc.wait(30)
    exe.shutdown()
    node.destroy_node()
    rclpy.shutdown(context=ctx)
    if not got:
        raise RuntimeError("the node published no tip_displacement")
    return got[0] - t0


def measure() -> dict[str, float]:
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        out["startup_cold_first_tip_s"] = first_tip_s({"NUMBA_CACHE_DIR": cache})
        out["startup_cold_again_same_cache_first_tip_s"] = first_tip_s({"NUMBA_CACHE_DIR": cache})
    first_tip_s({})  # make sure the default cache is filled
    out["startup_warm_first_tip_s"] = min(first_tip_s({}) for _ in range(3))
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
