"""Recorder throughput: JointState messages per wall second into a temporary bag; and the analysis's reading
(`load_series`, what `panel-rig analyze` spends on a bag: integrity check + read) of a rig bag of tip, airspeed and
modal states, in MB and readings per wall second.

Run: `.venv/bin/python benchmarks/recorder_throughput.py [N]` (prints JSON).
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path


def measure(n_messages: int = 20000) -> dict[str, float]:
    """Write `n_messages` 3-joint JointState messages (all arrays filled) and time it."""
    from sensor_msgs.msg import JointState

    from panel_rig.recording import BagWriter, read_bag

    msg = JointState(
        name=["q1", "q2", "q3"], position=[0.1, 0.2, 0.3], velocity=[1.0, 2.0, 3.0],
        effort=[4.0, 5.0, 6.0],
    )
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "bench"
        t0 = time.perf_counter()
        with BagWriter(bag) as writer:
            for k in range(n_messages):
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(k * 1_000_000, 10**9)
                writer.write("/rig/modal_states", msg, 1 + k * 1_000_000)
        wall_s = time.perf_counter() - t0
        size_bytes = (bag / "bench_0.mcap").stat().st_size
        t1 = time.perf_counter()
        n_read = sum(1 for _ in read_bag(bag))
        read_s = time.perf_counter() - t1
    return {
        "n_messages": n_messages,
        "recorder_msgs_per_s": n_messages / wall_s,
        "recorder_wall_s": wall_s,
        "bag_bytes_per_msg": size_bytes / n_messages,
        "reader_msgs_per_s": n_read / read_s,
        **measure_series(n_messages),
    }


def measure_series(n_readings: int) -> dict[str, float]:
    """Write a rig bag of ``n_readings`` readings (tip, airspeed, modal states: three messages each) and time
    :func:`panel_rig.recording.series.load_series` on it."""
    from geometry_msgs.msg import PointStamped, Vector3Stamped
    from sensor_msgs.msg import JointState

    from panel_rig.recording import BagWriter
    from panel_rig.recording.series import load_series

    tip, air = PointStamped(), Vector3Stamped()
    modal = JointState(name=["q1", "q2", "q3"], position=[0.1, 0.2, 0.3], velocity=[1.0, 2.0, 3.0])
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / "rig"
        with BagWriter(bag) as writer:
            for k in range(n_readings):
                stamp = 1 + k * 2_000_000  # 500 Hz
                tip.point.z, air.vector.x = 1e-5 * (k % 7), 10.0
                writer.write("/rig/tip_displacement", tip, stamp)
                writer.write("/rig/airspeed", air, stamp)
                writer.write("/rig/modal_states", modal, stamp)
        size_mb = sum(f.stat().st_size for f in bag.glob("*.mcap")) / 1e6
        t0 = time.perf_counter()
        rec = load_series(bag)
        read_s = time.perf_counter() - t0
    return {"series_readings_per_s": rec.t_s.size / read_s, "series_mb_per_s": size_mb / read_s,
            "series_bag_mb": size_mb}


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 20000
    print(json.dumps(measure(n), indent=2))
