"""Node timing: real-time factor, overruns and tick jitter at the default rates; fast-mode speed.

Runs the rig node in-process (its own rclpy context and a private ROS domain; no subscribers).
``python benchmarks/node_realtime.py [duration_s]`` prints JSON. The fast-mode turbulence comparisons
(``fast_*quiet_tunnel*``, ``fast_*turbulence_cost_fraction``) are in simulated seconds per second of CPU time, best
of 5 interleaved runs.
"""

from __future__ import annotations

import json
import os
import random
import sys
import tempfile
import time
from typing import Any

SUBCRITICAL_MPS = 10.0  # below the default model's flutter speed (ROM U_f = 10.48 m/s)


def _run(fast: bool, duration_s: float, airspeed_mps: float, sinks_dir: str | None = None,
         variant: str = "full", rerun: bool = True, turbulence: bool = True) -> dict[str, float]:
    """One in-process node run; ``sinks_dir``: record a bag there (and a Rerun .rrd if ``rerun``); ``turbulence``
    False: a quiet tunnel (tunnel.turbulence.intensity 0)."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter

    from panel_rig.ros.node import RigNode
    from panel_rig.ros.rig_node import spin

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random.randint(201, 230))
    node = RigNode(
        context=ctx,
        parameter_overrides=[
            Parameter("fast", value=fast),
            Parameter("model.variant", value=variant),
            Parameter("tunnel.time_constant_s", value=0.2),
            Parameter("safety.max_tip_w_over_L", value=1.9),
            Parameter("safety.wall_clearance_m", value=10.0),
        ] + ([] if turbulence else [Parameter("tunnel.turbulence.intensity", value=0.0)]) + ([] if sinks_dir is None else [
            Parameter("record", value=True),
            Parameter("bag_dir", value=os.path.join(sinks_dir, "bags")),
        ] + ([Parameter("rerun", value=f"save:{os.path.join(sinks_dir, 'bench.rrd')}")] if rerun else [])),
    )
    try:
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        node.rig.command_force(0.05)  # a small held force: a perturbation off the rest state
        node.rig.command_airspeed(airspeed_mps)
        end = time.monotonic() + duration_s
        cpu0, sim0 = time.process_time(), node.rig.time_s
        spin(node, executor, lambda: time.monotonic() > end)
        stats = node.stats()
        # simulated seconds per second of this process's CPU time (the node, its executor and DDS threads): for the
        # fast-mode comparisons, where the machine's other load moved wall-time factors by up to 1.7x between runs
        stats["cpu_realtime_factor"] = (node.rig.time_s - sim0) / max(time.process_time() - cpu0, 1e-9)
        stats["state"] = node.rig.state
        stats["tip_w_over_L"] = node.rig.stepper.tip_w_over_L
        executor.shutdown()
    finally:
        node.close()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    return stats


def measure(duration_s: float = 60.0, airspeed_mps: float = 11.0, fast_duration_s: float = 5.0) -> dict[str, Any]:
    """Real-time run of ``duration_s`` (default rates: 500 Hz publish, 2048 Hz physics) at ``airspeed_mps``
    (above flutter: the exact panel's LCO, the whole run; the cubic `full` panel's LCO at 11 m/s passes |w/L| = 1
    and the rig aborts after ~19 s, leaving an idle tunnel for the rest), then fast-mode runs of
    ``fast_duration_s``."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rt = _run(False, duration_s, airspeed_mps, variant="exact")
    fast = _run(True, fast_duration_s, airspeed_mps)
    with tempfile.TemporaryDirectory() as tmp:  # recording (rosbag2 MCAP) and Rerun (.rrd) both on
        fast_sinks = _run(True, fast_duration_s, airspeed_mps, sinks_dir=tmp)
    with tempfile.TemporaryDirectory() as tmp:  # the exact (elastica) structure, recording and Rerun on
        exact_sinks = _run(True, fast_duration_s, airspeed_mps, sinks_dir=tmp, variant="exact")
    with tempfile.TemporaryDirectory() as tmp:  # exact, recording (the bag) only: issue 8's "with recording on"
        exact_rec = _run(True, fast_duration_s, airspeed_mps, sinks_dir=tmp, variant="exact", rerun=False)
    # issue 9: what the turbulence costs the fast node (no sinks), below flutter (10 m/s: no LCO reaching the tip
    # limit, so both runs march the same state the whole time): interleaved runs, best of 5 each in CPU time (the
    # least disturbed by other load on the machine)
    quiet, windy = [], []
    for _ in range(5):
        quiet.append(_run(True, fast_duration_s, SUBCRITICAL_MPS, turbulence=False)["cpu_realtime_factor"])
        windy.append(_run(True, fast_duration_s, SUBCRITICAL_MPS)["cpu_realtime_factor"])
    # the same in the LCO (exact structure at airspeed_mps, above flutter): both panels move, so the difference is
    # the turbulence's own work; below flutter the quiet panel comes to rest, and a step at rest converges in one
    # Newton iteration where a moving panel's needs two (docs/validation.md, section 7)
    quiet_lco, windy_lco = [], []
    for _ in range(5):
        quiet_lco.append(_run(True, fast_duration_s, airspeed_mps, variant="exact", turbulence=False)[
            "cpu_realtime_factor"])
        windy_lco.append(_run(True, fast_duration_s, airspeed_mps, variant="exact")["cpu_realtime_factor"])
    return {
        "airspeed_mps": airspeed_mps,
        "duration_s": duration_s,
        "realtime_factor": round(rt["realtime_factor"], 4),
        "overruns": rt["overruns"],
        "ticks": rt["ticks"],
        "tick_interval_mean_ms": round(rt["tick_interval_mean_ms"], 3),
        "p99_tick_jitter_ms": round(rt["tick_jitter_p99_ms"], 3),
        "state_after_realtime": rt["state"],
        "fast_realtime_factor": round(fast["realtime_factor"], 2),
        "fast_sim_s": round(fast["sim_time_s"], 2),
        "fast_realtime_factor_all_sinks": round(fast_sinks["realtime_factor"], 2),
        "fast_exact_realtime_factor_all_sinks": round(exact_sinks["realtime_factor"], 2),
        "fast_exact_realtime_factor_recording": round(exact_rec["realtime_factor"], 2),
        "fast_quiet_tunnel_realtime_factor": round(max(quiet), 2),
        "fast_turbulence_cost_fraction": round(max(quiet) / max(windy) - 1.0, 3),
        "fast_exact_lco_quiet_tunnel_realtime_factor": round(max(quiet_lco), 2),
        "fast_exact_lco_turbulence_cost_fraction": round(max(quiet_lco) / max(windy_lco) - 1.0, 3),
    }


if __name__ == "__main__":
    print(json.dumps(measure(float(sys.argv[1]) if len(sys.argv) > 1 else 60.0), indent=2))
