"""Wall time of ``panel-rig flutter-test`` (paper configuration, defaults: the live node in fast mode, full variant,
margin 0.1, 200 s per point, bag recorded) as a user runs it: a subprocess, timed from start to exit.

``python benchmarks/flutter_test.py [--in-process] [--set KEY=VALUE ...]`` prints one JSON line: wall_s,
simulated_s, the node's effective real-time factor over the test (identification included) and the wall seconds
its monitor spent identifying, points, predicted and model U_f, error, fluttered, and the load average (the
machine is shared: compare runs with the load beside them). Target: wall_s <= 120.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time


def measure(sets: list[str] | None = None, in_process: bool = False) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "panel_rig.cli", "flutter-test", "--json", "--bag-dir", tmp, "--plot",
               f"{tmp}/vg.png"] + (["--in-process"] if in_process else [])
        for s in sets or []:
            cmd += ["--set", s]
        load0 = os.getloadavg()[0]
        t0 = time.monotonic()
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
        wall = time.monotonic() - t0
    if proc.returncode not in (0, 1):
        raise SystemExit(f"flutter-test failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    out = json.loads(proc.stdout)
    pred, uf = out["predicted_flutter_speed_mps"], out["model_flutter_speed_mps"]
    ident = [x for x in out.get("identify_wall_s") or [] if x == x]
    return {"benchmark": "flutter_test", "live": out.get("live", False), "sets": sets or [], "wall_s": round(wall, 1),
            "simulated_s": round(out["simulated_s"], 1),
            "node_rtf": None if out.get("node_rtf") is None else round(out["node_rtf"], 2),
            "node_identify_wall_s": round(sum(ident), 1) if ident else None,
            "points": len(out["test_points"]), "predicted_flutter_speed_mps": pred, "model_flutter_speed_mps": uf,
            "error": None if pred is None else pred / uf - 1, "max_airspeed_mps": out["max_airspeed_mps"],
            "fluttered": out["fluttered"], "loadavg_1min": [round(load0, 2), round(os.getloadavg()[0], 2)]}


if __name__ == "__main__":
    args = sys.argv[1:]
    sets = [args[i + 1] for i, a in enumerate(args) if a == "--set"]
    print(json.dumps(measure(sets, in_process="--in-process" in args)))
