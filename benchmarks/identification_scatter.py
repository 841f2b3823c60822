"""Bias and scatter of the flutter test's damping identification at fixed airspeeds (in-process node rig).

``python benchmarks/identification_scatter.py [N_DWELLS] [--dwell S] [--set KEY=VALUE ...]`` holds the tunnel at 0.5, 0.6,
0.7, 0.8 and 0.88 of the model's linear U_f (after the test's 5 s run-in), cuts N consecutive dwells of S seconds
(default: the test's 200 s) from one long record, identifies each as a test point is identified (`identify_point`:
SSI-cov in the model's bands) and prints one JSON line per airspeed: the model's V-g damping ratio and frequency
of the flutter mode, the identified ones' mean and standard deviation, the median of the standard errors the
identification reported for itself (SSI-cov's jackknife; compare with the standard deviation: is its interval
honest?), and identified / V-g with its standard error. Consecutive dwells of one realisation, unlike
`flutter_coverage.py`'s seeds, hold the airspeed fixed and so separate the estimator's scatter from the
procedure's.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

FRACTIONS = (0.5, 0.6, 0.7, 0.8, 0.88)


def run(n_dwells: int, sets: list[str], dwell_s: float | None = None) -> None:
    from panel_rig.analysis.flutter_test import DEFAULT_SETTLE_S, FlutterTestSettings, bands_from_model, identify_point
    from panel_rig.analysis.vg import model_flutter_speed, vg_diagram
    from panel_rig.config import load_config
    from panel_rig.model.stepper import Stepper
    from panel_rig.rig.flutter_run import node_equivalent_rig

    cfg = load_config(None, sets)
    model = Stepper(cfg, variant="full").model
    uf, mode = model_flutter_speed(model)
    bands = bands_from_model(model, mode)
    dwell_s = dwell_s or FlutterTestSettings(start_mps=0.5 * uf, step_mps=0.1 * uf).dwell_s
    steps_per_sample = 4
    for fraction in FRACTIONS:
        t0, u = time.monotonic(), fraction * uf
        rig = node_equivalent_rig(cfg, Stepper(cfg, variant="full"), uf)
        dt_s = steps_per_sample * rig.dt_s
        rig.command_airspeed(u)
        rig.advance_samples([steps_per_sample] * int(round(DEFAULT_SETTLE_S / dt_s)))
        vg = vg_diagram(model, np.array([u]))
        m = int(np.argmin(np.abs(vg.frequency_hz[0] - np.mean(bands(u)[1]))))
        zeta, freq, se = [], [], []
        for _ in range(n_dwells):
            blk = rig.advance_samples([steps_per_sample] * int(round(dwell_s / dt_s)))
            p = identify_point(np.asarray(blk.tip_w_m, dtype=float), dt_s, u, bands(u))
            zeta.append(p.flutter.damping_ratio)
            freq.append(p.flutter.frequency_hz)
            se.append(p.flutter.damping_se)
        z = np.array(zeta, dtype=float)
        z = z[np.isfinite(z)]
        ratio = z / vg.damping_ratio[0, m]
        print(json.dumps({
            "fraction_of_uf": fraction, "airspeed_mps": round(u, 4), "dwells": n_dwells, "dwell_s": dwell_s, "identified": int(z.size),
            "vg_damping_ratio": round(float(vg.damping_ratio[0, m]), 6),
            "vg_frequency_hz": round(float(vg.frequency_hz[0, m]), 4),
            "damping_ratio_mean": round(float(z.mean()), 6), "damping_ratio_sd": round(float(z.std(ddof=1)), 6),
            "frequency_hz_mean": round(float(np.nanmean(freq)), 4),
            "damping_se_median": round(float(np.nanmedian(se)), 6),
            "over_vg_mean": round(float(ratio.mean()), 4),
            "over_vg_se": round(float(ratio.std(ddof=1) / np.sqrt(ratio.size)), 4),
            "wall_s": round(time.monotonic() - t0, 1)}), flush=True)


if __name__ == "__main__":
    args = sys.argv[1:]
    sets = [args[i + 1] for i, a in enumerate(args) if a == "--set"]
    dwell = [float(args[i + 1]) for i, a in enumerate(args) if a == "--dwell"]
    plain = [a for i, a in enumerate(args) if not a.startswith("--") and (i == 0 or not args[i - 1].startswith("--"))]
    run(int(plain[0]) if plain else 20, sets, dwell[-1] if dwell else None)
