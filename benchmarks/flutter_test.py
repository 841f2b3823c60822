"""Wall time of ``panel-rig flutter-test`` (paper configuration, defaults: full variant, margin 0.1, 200 s per
point, bag recorded) as a user runs it: a subprocess, timed from start to exit.

``python benchmarks/flutter_test.py [--set KEY=VALUE ...]`` prints one JSON line: wall_s, simulated_s, points,
predicted and model U_f, error, fluttered.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time


def measure(sets: list[str] | None = None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "panel_rig.cli", "flutter-test", "--json", "--bag-dir", tmp, "--plot",
               f"{tmp}/vg.png"]
        for s in sets or []:
            cmd += ["--set", s]
        t0 = time.monotonic()
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        wall = time.monotonic() - t0
    out = json.loads(proc.stdout)
    pred, uf = out["predicted_flutter_speed_mps"], out["model_flutter_speed_mps"]
    return {"benchmark": "flutter_test", "sets": sets or [], "wall_s": round(wall, 1),
            "simulated_s": round(out["simulated_s"], 1), "points": len(out["test_points"]),
            "predicted_flutter_speed_mps": pred, "model_flutter_speed_mps": uf,
            "error": None if pred is None else pred / uf - 1, "max_airspeed_mps": out["max_airspeed_mps"],
            "fluttered": out["fluttered"]}


if __name__ == "__main__":
    args = sys.argv[1:]
    sets = [args[i + 1] for i, a in enumerate(args) if a == "--set"]
    print(json.dumps(measure(sets)))
