"""Recorder throughput: JointState messages per wall second into a temporary bag.

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
    }


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 20000
    print(json.dumps(measure(n), indent=2))
