"""The measurements behind docs/validation.md, section "Flutter-test methods":
``python -m panel_rig.analysis.flutter_study`` prints its tables (markdown, ~45 s on 2 cores).

Stand-ins (this study came before the rig's turbulence and sensor model, issue 9; section 10 of docs/validation.md
measures the methods on those): turbulence = band-limited (0-100 Hz) white
trailing-edge force on the stepper; sensor = white noise of 5 um RMS on the tip (a lab laser displacement sensor),
tip ~0.3 mm RMS under turbulence and ~0.5 mm peak after a tap (the linear stepper's output is scaled to these
levels, exact by linearity).
"""

from __future__ import annotations

import numpy as np
import scipy.signal

from panel_rig.analysis.flutter_margin import (
    damping_trend_speed,
    flutter_margin_speed,
    predict_by_damping_trend,
    predict_by_flutter_margin,
)
from panel_rig.analysis.identification import identify_free_decay, identify_ssi
from panel_rig.analysis.vg import model_flutter_speed, pole_from_modal, vg_diagram
from panel_rig.argparsing import study_parser
from panel_rig.config import load_config
from panel_rig.model.aeroelastic import AeroelasticModel
from panel_rig.model.stepper import Stepper

NOISE_M, TURB_RMS_M, TAP_PEAK_M = 5e-6, 3e-4, 5e-4
CONFIGS = {"paper": [], "thickness 0.40 mm": ["panel.thickness_m=0.0004"],
           "damping 0.01": ["structure.damping_ratio=0.01"], "length 0.22 m": ["panel.length_m=0.22"]}
RATIOS = np.array([0.5, 0.6, 0.7, 0.8, 0.9])


def modal_response(modes, dt, T, rng):
    """Uncoupled modes driven by one white force (exact ZOH), scaled to TURB_RMS_M, plus sensor noise."""
    n = int(T / dt)
    f = rng.standard_normal(n)
    y = np.zeros(n)
    for fr, z in modes:
        w = 2 * np.pi * fr
        b, a, _ = scipy.signal.cont2discrete(([w * w], [1, 2 * z * w, w * w]), dt, method="zoh")
        y += scipy.signal.lfilter(b.ravel(), a, f)
    return y * TURB_RMS_M / np.std(y) + NOISE_M * rng.standard_normal(n)


def stepper_turbulence(cfg, model, u, T, rng, variant="linear"):
    st = Stepper(cfg, variant, "rom", model=model)
    n0, n = int(2.0 / st.dt_s), int(T / st.dt_s)
    sos = scipy.signal.butter(4, 100.0, fs=1 / st.dt_s, output="sos")
    w = st.advance(n0 + n, u, 0.2 * scipy.signal.sosfilt(sos, rng.standard_normal(n0 + n)))[n0:] * cfg.panel_length_m
    return w * TURB_RMS_M / np.std(w) + NOISE_M * rng.standard_normal(n), st.dt_s


def stepper_tap(cfg, model, u, rng, T=8.0):
    st = Stepper(cfg, "linear", "rom", model=model)
    k = int(0.005 / st.dt_s)
    st.advance(k, u, np.sin(np.pi * np.arange(k) / k))
    w = st.advance(int(T / st.dt_s), u) * cfg.panel_length_m
    return w * TAP_PEAK_M / np.max(np.abs(w)) + NOISE_M * rng.standard_normal(w.size), st.dt_s


def synthetic_table() -> str:
    modes = ((5.5, 0.40), (23.0, 0.005), (69.0, 0.009))
    lines = ["| record | mode (f, zeta) | f error, max over seeds | zeta: mean error | zeta: scatter (sd) | "
             "mean jackknife se |", "|---|---|---|---|---|---|"]
    for T in (200.0, 600.0):
        runs = []
        for seed in range(8):
            y = modal_response(modes, 1 / 2048, T, np.random.default_rng(100 + seed))
            e = identify_ssi(y, 1 / 2048, [(20.0, 26.0), (60.0, 80.0)])
            e1 = identify_ssi(y, 1 / 2048, [(3.0, 9.0)], max_rate_hz=320)
            runs.append(e1 + e)
        for m, (f, z) in enumerate(modes):
            got = [r[m] for r in runs if r[m] is not None]
            fe = max(abs(e.frequency_hz / f - 1) for e in got)
            ze = np.array([e.damping_ratio / z - 1 for e in got])
            se = np.mean([e.damping_se / z for e in got])
            scatter = f"{ze.std(ddof=1):.1%}" if ze.size > 1 else "—"  # one record has no scatter
            lines.append(f"| SSI-cov, {T:.0f} s, {len(got)}/8 seeds | {f} Hz, {z} | {fe:.2%} | {ze.mean():+.1%} | "
                         f"{scatter} | {se:.1%} |")
    taps = [identify_free_decay(_decay(modes, np.random.default_rng(200 + k)), 1 / 2048,
                                [(3.0, 9.0), (20.0, 26.0), (60.0, 80.0)], max_rate_hz=400) for k in range(8)]
    for m, (f, z) in enumerate(modes):
        fe = max(abs(t[m].frequency_hz / f - 1) for t in taps)
        ze = np.array([t[m].damping_ratio / z - 1 for t in taps])
        se = np.mean([t[m].damping_se / z for t in taps])
        lines.append(f"| free decay, 8 s, 8 taps | {f} Hz, {z} | {fe:.2%} | {ze.mean():+.2%} | {ze.std(ddof=1):.2%} | "
                     f"{se:.2%} |")
    return "\n".join(lines)


def _decay(modes, rng, T=8.0, dt=1 / 2048):
    t = np.arange(int(T / dt)) * dt
    y = sum(a * np.exp(s.real * t) * np.cos(s.imag * t + 0.3)
            for (f, z), a in zip(modes, (1.0, 0.6, 0.2)) for s in [complex(pole_from_modal(f, z))])
    return y * TAP_PEAK_M / np.max(np.abs(y)) + NOISE_M * rng.standard_normal(t.size)


def exact_predictor_table() -> str:
    lines = ["| configuration | U_f (m/s) | zeta-trend, line in U | quadratic in U | quadratic in U^2 (default) | "
             "ZW, line in U^2 (default) | ZW, quadratic in U^2 |", "|---|---|---|---|---|---|---|"]
    for name, sets in CONFIGS.items():
        m = AeroelasticModel(load_config(None, sets))
        uf, mode = model_flutter_speed(m)
        u = uf * RATIOS
        vg = vg_diagram(m, u)
        z, p = vg.damping_ratio[:, mode - 1], vg.poles
        from panel_rig.analysis.flutter_margin import extrapolated_root

        row = [extrapolated_root(u, z, 1), extrapolated_root(u, z, 2), damping_trend_speed(u, z),
               flutter_margin_speed(u, p[:, 0], p[:, 1], 1), flutter_margin_speed(u, p[:, 0], p[:, 1], 2)]
        lines.append(f"| {name} | {uf:.3f} | " + " | ".join(f"{r / uf - 1:+.2%}" for r in row) + " |")
    return "\n".join(lines)


def stepper_tables() -> tuple[str, str, str]:
    id_lines = ["| configuration | U/U_f | U (m/s) | V-g f2 (Hz) | V-g zeta2 | SSI 600 s: zeta2 (95 % CI) | err | "
                "tap: zeta2 | err | V-g zeta1 | tap: zeta1 | SSI 600 s: zeta1 |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    pred_lines = ["| configuration | U_f model (m/s) | excitation | damping trend: U_f (95 % CI) | err | ZW margin: U_f (95 % CI) "
                  "| err |", "|---|---|---|---|---|---|---|"]
    for name, sets in CONFIGS.items():
        cfg = load_config(None, sets)
        model = AeroelasticModel(cfg)
        uf, mode = model_flutter_speed(model)
        speeds = uf * RATIOS
        vg = vg_diagram(model, speeds)
        rng = np.random.default_rng(30)
        tap1, tap2, ssi1, ssi2 = [], [], [], []
        for k, u in enumerate(speeds):
            f1, f2 = vg.frequency_hz[k, 0], vg.frequency_hz[k, mode - 1]
            b1, b2 = (0.6 * f1, 1.5 * f1), (0.85 * f2, 1.15 * f2)
            w, dt = stepper_tap(cfg, model, u, rng)
            e1, e2 = identify_free_decay(w, dt, [b1, b2])
            tap1.append(e1)
            tap2.append(e2)
            w, dt = stepper_turbulence(cfg, model, u, 600.0, rng)
            s2 = identify_ssi(w, dt, [b2])[0]
            s1 = identify_ssi(w, dt, [b1], max_rate_hz=60 * f1)[0]
            ssi1.append(s1)
            ssi2.append(s2)
            z2, z1 = vg.damping_ratio[k, mode - 1], vg.damping_ratio[k, 0]
            lo, hi = s2.damping_ci()
            id_lines.append(
                f"| {name} | {RATIOS[k]:.1f} | {u:.2f} | {f2:.3f} | {z2:.5f} | {s2.damping_ratio:.5f} ({lo:.5f}-{hi:.5f}) | "
                f"{s2.damping_ratio / z2 - 1:+.1%} | {e2.damping_ratio:.5f} | {e2.damping_ratio / z2 - 1:+.2%} | {z1:.3f} | "
                f"{e1.damping_ratio:.3f} | {s1.damping_ratio if s1 else float('nan'):.3f} |")
        for label, m1, m2 in (("taps", tap1, tap2), ("turbulence, SSI 600 s", ssi1, ssi2)):
            tr = predict_by_damping_trend(speeds, m2)
            zw = predict_by_flutter_margin(speeds, m1, m2) if all(m1) else None
            cell = (f"{zw.speed_mps:.3f} ({zw.ci_mps[0]:.2f}-{zw.ci_mps[1]:.2f}) | {zw.speed_mps / uf - 1:+.2%}"
                    if zw else "— | —")
            pred_lines.append(f"| {name} | {uf:.3f} | {label} | {tr.speed_mps:.3f} ({tr.ci_mps[0]:.2f}-{tr.ci_mps[1]:.2f}) | "
                              f"{tr.speed_mps / uf - 1:+.2%} | {cell} |")
    return "\n".join(id_lines), "\n".join(pred_lines), ""


def main(argv: list[str] | None = None) -> None:
    study_parser(__doc__, "panel_rig.analysis.flutter_study").parse_args(argv)
    print("### Synthetic signals\n")
    print(synthetic_table())
    print("\n### Predictors on the model's exact poles (points at 0.5-0.9 U_f)\n")
    print(exact_predictor_table())
    ident, pred, _ = stepper_tables()
    print("\n### Stepper: identification vs V-g\n")
    print(ident)
    print("\n### Stepper: predictions from points <= 0.9 U_f\n")
    print(pred)


if __name__ == "__main__":
    main()
