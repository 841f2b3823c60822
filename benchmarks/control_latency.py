"""Closed-loop latency on loopback: the real-time rig node (in-process, default rates: 500 Hz readings) with the
reference controller attached as a separate process answering every tip reading.

Reports the command ages the node measures (reading stamp -> command arrival, ROS clock: mean, p99, max), how many
readings were answered, the node's overruns and tick jitter, and the closed-loop flutter speed the linear model
predicts with that latency (mean and p99). ``python benchmarks/control_latency.py [duration_s]`` prints JSON.
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from typing import Any


def measure(duration_s: float = 30.0, airspeed_factor: float = 0.9) -> dict[str, Any]:
    """Run the loop for ``duration_s`` of wall time at ``airspeed_factor`` x the open-loop flutter speed (below it,
    so that a slow loop cannot end the run in an abort)."""
    import numpy as np
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from panel_rig.analysis.control import LoopModel, closed_loop_flutter, design_law, effective_delay
    from panel_rig.config import load_config
    from panel_rig.model.aeroelastic import AeroelasticModel
    from panel_rig.ros.node import RigNode
    from panel_rig.ros.rig_node import spin

    cfg = load_config()
    model = AeroelasticModel(cfg)
    design = design_law(model)
    domain = random.randint(201, 230)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    ctl = subprocess.Popen([sys.executable, "-m", "panel_rig.ros.controller", "--ros-args", "-r", "__ns:=/bench",
                            "-p", f"gain_nspm2:={design.law.gain_nspm2}"], env=env,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = RigNode(context=ctx, namespace="/bench",
                   parameter_overrides=[Parameter("tunnel.time_constant_s", value=0.2)])
    try:
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        node.rig.command_airspeed(airspeed_factor * design.open_loop_flutter_mps)
        deadline = time.monotonic() + 60.0
        spin(node, executor, lambda: node.rig.control.commands > 500 or time.monotonic() > deadline)
        c = node.rig.control
        c.ages_s.clear()
        overruns0, commands0, t0 = node.rig.overrun_count, c.commands, node.rig.time_s
        node.tick_intervals_s.clear()
        end = time.monotonic() + duration_s
        spin(node, executor, lambda: time.monotonic() > end)
        stats = node.stats()
        ages = np.asarray(c.ages_s) * 1e3
        readings = (node.rig.time_s - t0) * 500.0
        out = {
            "control_duration_s": duration_s,
            "control_commands_per_reading": round((c.commands - commands0) / readings, 4) if readings else 0.0,
            "control_latency_mean_ms": round(float(ages.mean()), 3) if ages.size else None,
            "control_latency_p50_ms": round(float(np.percentile(ages, 50)), 3) if ages.size else None,
            "control_latency_p99_ms": round(float(np.percentile(ages, 99)), 3) if ages.size else None,
            "control_latency_max_ms": round(float(ages.max()), 3) if ages.size else None,
            "control_overruns": node.rig.overrun_count - overruns0,
            "control_tick_jitter_p99_ms": round(stats["tick_jitter_p99_ms"], 3),
            "control_tick_interval_mean_ms": round(stats["tick_interval_mean_ms"], 3),
            "control_rig_state": node.rig.state,
            "load_average_1min": os.getloadavg()[0],
        }
        executor.shutdown()
    finally:
        node.close()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
        ctl.send_signal(signal.SIGINT)
        try:
            ctl.wait(15)
        except subprocess.TimeoutExpired:
            ctl.kill()
            ctl.wait()
    bw = node.rig.control.settings.bandwidth_hz
    for key in ("mean", "p99"):
        age = out[f"control_latency_{key}_ms"]
        if age is None:
            continue
        cl = closed_loop_flutter(model, design.law, LoopModel(bw, effective_delay(age * 1e-3, 500.0, cfg.dt_s)))
        out[f"closed_loop_flutter_speed_at_{key}_latency_mps"] = (
            None if cl.speed_mps is None else round(cl.speed_mps, 3))
        out[f"closed_loop_unstable_at_low_speed_at_{key}_latency"] = cl.unstable_at_low_speed
    out["open_loop_flutter_speed_mps"] = round(design.open_loop_flutter_mps, 3)
    return out


if __name__ == "__main__":
    print(json.dumps(measure(float(sys.argv[1]) if len(sys.argv) > 1 else 30.0), indent=2))
