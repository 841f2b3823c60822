"""Calibration of the flutter test's prediction over turbulence/sensor seeds (in-process Rig, default plan).

``python benchmarks/flutter_coverage.py [N_SEEDS] [--set KEY=VALUE ...] [--repeats N]`` runs the procedure once per
seed of ``tunnel.turbulence.seed`` (0 .. N-1), with the plan's ``repeats`` if given (0: no repeated point before a
margin stop), and prints one JSON line per seed (the prediction the procedure stopped on, its 95 % interval with an
open bound as null, both predictors, the highest airspeed, fluttered, the stop, the repeats) and a summary:
the error spread and the coverage, i.e. how often the interval contains the model's linear U_f, and how often its
lower bound alone is below it (the one-sided statement a clearance relies on). Each seed's row also holds the
identified flutter-mode damping over the model's V-g damping at each point (``damping_over_vg``), and the summary
their mean, standard deviation and standard error over all points: whether the identification is biased, and how
much one dwell's estimate scatters. Set OPENBLAS_NUM_THREADS=1 on a shared 2-core machine (the SVDs are small).
"""

from __future__ import annotations

import json
import math
import sys
import time

import numpy as np


def damping_over_vg(res, model) -> list[float]:
    """Identified flutter-mode damping ratio / the model's V-g damping ratio of the mode nearest in frequency, at
    each point whose flutter mode was identified."""
    from panel_rig.analysis.vg import vg_diagram

    pts = [p for p in res.points if p.flutter is not None and np.isfinite(p.flutter.damping_ratio)]
    if not pts:
        return []
    vg = vg_diagram(model, np.array([p.airspeed_mps for p in pts]))
    modes = [int(np.argmin(np.abs(vg.frequency_hz[k] - p.flutter.frequency_hz))) for k, p in enumerate(pts)]
    return [float(p.flutter.damping_ratio / vg.damping_ratio[k, m]) for k, (p, m) in enumerate(zip(pts, modes))]


def run(n_seeds: int, sets: list[str], repeats: int | None = None) -> None:
    from panel_rig.analysis.flutter_test import REPEAT
    from panel_rig.config import load_config
    from panel_rig.model.stepper import Stepper
    from panel_rig.rig.flutter_run import run_on_rig

    rows = []
    for seed in range(n_seeds):
        cfg = load_config(None, [*sets, f"tunnel.turbulence.seed={seed}"])
        t0 = time.monotonic()
        res, uf = run_on_rig(cfg, variant="full", margin=0.1, **({} if repeats is None else {"repeats": repeats}))
        d = res.as_dict()
        pred, ci = d["predicted_flutter_speed_mps"], d["predicted_flutter_speed_ci_mps"]
        lo = None if ci is None else ci[0]
        hi = None if ci is None else ci[1]
        row = {"seed": seed, "model_uf_mps": uf, "predicted_mps": pred, "ci_mps": ci,
               "method": d["prediction_method"], "error": None if pred is None else pred / uf - 1,
               "trend_mps": (d["damping_trend"] or {}).get("predicted_flutter_speed_mps"),
               "zw_mps": (d["zimmerman_weissenburger"] or {}).get("predicted_flutter_speed_mps"),
               "points": len(d["test_points"]), "repeats": sum(x.reason.startswith(REPEAT) for x in res.decisions),
               "max_airspeed_mps": d["max_airspeed_mps"], "stop_reason": d["stop_reason"],
               "fluttered": d["fluttered"], "contains": lo is not None and lo <= uf and (hi is None or uf <= hi),
               "lower_below": lo is not None and lo <= uf, "upper_open": ci is not None and hi is None,
               "wall_s": round(time.monotonic() - t0, 1),
               "damping_over_vg": [round(r, 4) for r in damping_over_vg(res, Stepper(cfg, variant="full").model)]}
        rows.append(row)
        print(json.dumps(row), flush=True)
    errs = [r["error"] for r in rows if r["error"] is not None]
    n = len(rows)
    ratios = np.array([x for r in rows for x in r["damping_over_vg"]])
    print(json.dumps({"summary": True, "sets": sets, "seeds": n,
                      "coverage": sum(r["contains"] for r in rows) / n,
                      "lower_bound_below_uf": sum(r["lower_below"] for r in rows) / n,
                      "upper_open": sum(r["upper_open"] for r in rows) / n,
                      "within_3pct": sum(abs(e) <= 0.03 for e in errs) / n,
                      # the low tail: a test that stopped more than 5 % short of the model's U_f
                      "below_minus_5pct": sum(e < -0.05 for e in errs),
                      "highest_point_over_uf_min": min(r["max_airspeed_mps"] / r["model_uf_mps"] for r in rows),
                      "points_mean": sum(r["points"] for r in rows) / n,
                      "repeats": sum(r["repeats"] for r in rows),
                      "wall_s": round(sum(r["wall_s"] for r in rows), 1),
                      "error_mean": sum(errs) / len(errs) if errs else None,
                      "error_sd": (math.sqrt(sum((e - sum(errs) / len(errs)) ** 2 for e in errs) / (len(errs) - 1))
                                   if len(errs) > 1 else None),
                      "fluttered": sum(r["fluttered"] for r in rows),
                      "damping_over_vg_points": int(ratios.size),
                      "damping_over_vg_mean": float(ratios.mean()) if ratios.size else None,
                      "damping_over_vg_sd": float(ratios.std(ddof=1)) if ratios.size > 1 else None,
                      "damping_over_vg_se": float(ratios.std(ddof=1) / np.sqrt(ratios.size)) if ratios.size > 1
                      else None}))


if __name__ == "__main__":
    args = sys.argv[1:]
    sets = [args[i + 1] for i, a in enumerate(args) if a == "--set"]
    repeats = [int(args[i + 1]) for i, a in enumerate(args) if a == "--repeats"]
    plain = [a for i, a in enumerate(args) if a not in ("--set", "--repeats")
             and (i == 0 or args[i - 1] not in ("--set", "--repeats"))]
    run(int(plain[0]) if plain else 8, sets, repeats[-1] if repeats else None)
