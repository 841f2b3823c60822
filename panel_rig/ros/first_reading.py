"""Seconds from this program's first node (its DDS participant) to its first tip reading from a running rig:
what an operator, a controller or a user's subscriber started now waits before it sees the rig.

    python -m panel_rig.ros.first_reading [--namespace /rig] [--timeout 15]

Prints the seconds, or exits 1 with one line if nothing arrived within the timeout. Used by
``benchmarks/startup.py`` and ``tests/test_node.py`` (discovery of a late joiner, panel_rig/ros/discovery.py).
"""

from __future__ import annotations

import math
import sys
import time

from panel_rig.argparsing import OneLineParser


def first_reading_s(namespace: str, timeout_s: float) -> float | None:
    """Seconds from creating a node in ``namespace`` to its first ``tip_displacement`` message (None: none came)."""
    import rclpy
    from geometry_msgs.msg import PointStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data

    rclpy.init()
    try:
        t0 = time.monotonic()
        node = rclpy.create_node("first_reading_probe", namespace=namespace)
        got: list[float] = []
        node.create_subscription(PointStamped, "tip_displacement", lambda _m: got.append(time.monotonic()),
                                 qos_profile_sensor_data)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            while not got and time.monotonic() - t0 < timeout_s:
                executor.spin_once(timeout_sec=0.01)
        finally:  # a Ctrl-C while spinning: the node and executor are released before the context
            executor.shutdown()
            node.destroy_node()
        return got[0] - t0 if got else None
    finally:
        rclpy.shutdown()


def main(argv: list[str] | None = None) -> int:
    ap = OneLineParser(prog="python -m panel_rig.ros.first_reading", description=__doc__.split("\n\n")[0])
    ap.add_argument("--namespace", default="/rig", help="the rig's namespace (default /rig)")
    ap.add_argument("--timeout", type=float, default=15.0, help="seconds to wait (default 15)")
    opts = ap.parse_args(argv)
    if not (math.isfinite(opts.timeout) and opts.timeout > 0):
        ap.error(f"--timeout must be a finite number of seconds > 0, got {opts.timeout:g}")
    seconds = first_reading_s(opts.namespace, opts.timeout)
    if seconds is None:
        print(f"no tip_displacement reading in {opts.namespace} within {opts.timeout:g} s", file=sys.stderr)
        return 1
    print(f"{seconds:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
