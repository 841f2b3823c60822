"""The full-nonlinear LCO question (issue 'Physics core II', item 3): figures and numbers for docs/validation.md.

    python -m panel_rig.analysis.scheme_study --out docs/figures

Produces: LCO RMS versus dt for each scheme, tip histories at U/U_f = 13.5/12.5, the bistability below U_f,
and the energy error of the free structure per scheme.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from scipy.integrate import cumulative_simpson, simpson  # noqa: E402

from panel_rig import jsonio
from panel_rig.analysis.flutter import find_flutter  # noqa: E402
from panel_rig.analysis.lco import run_lco  # noqa: E402
from panel_rig.analysis.signals import window_rms  # noqa: E402
from panel_rig.argparsing import study_parser
from panel_rig.config import PanelConfig, load_config  # noqa: E402
from panel_rig.model.aeroelastic import AeroelasticModel  # noqa: E402
from panel_rig.model.options import SCHEMES  # noqa: E402
from panel_rig.model.stepper import Stepper  # noqa: E402
from panel_rig.model.structure import mode_shapes  # noqa: E402

DT_FACTORS = (1, 2, 4)


def field_energy_j(cfg: PanelConfig, q: np.ndarray, qdot: np.ndarray) -> float:
    """T + V from the fields w, u of the full nonlinear panel (Eqs. 7-11), J per metre span."""
    x = np.linspace(0, 1, 1001)
    L, m, D = cfg.panel_length_m, cfg.mass_per_area_kgpm2, cfg.bending_stiffness_nm
    n = q.shape[0]
    w1, w2 = q @ mode_shapes(n, x, 1), q @ mode_shapes(n, x, 2)
    wdot, wdot1 = qdot @ mode_shapes(n, x, 0), qdot @ mode_shapes(n, x, 1)
    udot = -cumulative_simpson(w1 * wdot1, x=x, initial=0.0)
    return 0.5 * m * L**3 * simpson(udot**2 + wdot**2, x=x) + 0.5 * D / L * simpson(w2**2 * (1 + w1**2), x=x)


def study(out: Path) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    cfg = load_config()
    model = AeroelasticModel(cfg)
    u = 13.5 / 12.5 * find_flutter(model, aero="rom", rom_modes=cfg.rom_modes).speed_mps
    numbers: dict = {"airspeed_mps": u, "rms_vs_dt": {}, "hz_vs_dt": {}}
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    for scheme in SCHEMES + ("stiffness",):
        variant, sch = ("stiffness", "implicit") if scheme == "stiffness" else ("full", scheme)
        rows = [run_lco(cfg, u, 40.0, variant, scheme=sch, model=model, dt_s=cfg.dt_s / k)[0] for k in DT_FACTORS]
        numbers["rms_vs_dt"][scheme] = [r.rms_tip_w_over_L for r in rows]
        numbers["hz_vs_dt"][scheme] = [r.dominant_frequency_hz for r in rows]
        dts = [cfg.dt_s / k for k in DT_FACTORS]
        ax[0].loglog(dts, numbers["rms_vs_dt"][scheme], "o-", label=f"full, {scheme}" if scheme != "stiffness"
                     else "stiffness only")
        ax[1].semilogx(dts, numbers["hz_vs_dt"][scheme], "o-")
    ax[0].axhline(0.054, color="k", ls="--", lw=1, label="paper C1 0.054")
    ax[0].axhline(0.093, color="k", ls=":", lw=1, label="paper C3 0.093")
    ax[0].set(xlabel="dt, s", ylabel="RMS tip w/L (last 5 s)", title=f"LCO amplitude vs dt, U = {u:.2f} m/s")
    ax[1].set(xlabel="dt, s", ylabel="dominant frequency, Hz", title="LCO frequency vs dt")
    ax[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "scheme_dt_convergence.png", dpi=100)
    plt.close(fig)

    fig, axes = plt.subplots(4, 1, figsize=(9, 8), sharex=True)
    for a, (variant, sch) in zip(axes, [("full", "implicit"), ("full", "paper"), ("full", "paper_literal"),
                                        ("stiffness", "implicit")]):
        _, tip, _ = run_lco(cfg, u, 30.0, variant, scheme=sch, model=model, keep=True)
        a.plot(np.arange(tip.size) * cfg.dt_s, tip, lw=0.4)
        a.set(ylabel="tip w/L", title=f"{variant}, {sch}")
    axes[-1].set(xlabel="time, s")
    fig.tight_layout()
    fig.savefig(out / "scheme_time_histories.png", dpi=100)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(8, 4))
    numbers["bistability"] = {}
    for variant, ls in (("full", "-"), ("stiffness", "--")):
        for q2 in (0.01, 0.1):
            st = Stepper(cfg, variant, "rom", model=model)
            st.reset(q=[0.0, q2, 0.0])
            env = window_rms(st.advance(int(30 / cfg.dt_s), 0.91 * u / 1.08), int(0.25 / cfg.dt_s))
            numbers["bistability"][f"{variant}_q2_{q2}"] = float(env[-1])
            ax.semilogy(np.arange(env.size) * 0.25, np.maximum(env, 1e-8), ls, label=f"{variant}, q2(0) = {q2}")
    ax.set(xlabel="time, s", ylabel="RMS tip w/L (0.25 s windows)",
           title=f"Below flutter (U = {0.91 * u / 1.08:.2f} m/s = 0.91 U_f): the full model is bistable")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "subcritical_bistability.png", dpi=100)
    plt.close(fig)

    cfg0 = cfg.replace(damping_ratio=0.0)
    fig, ax = plt.subplots(figsize=(8, 4))
    numbers["energy_error"] = {}
    for sch in SCHEMES:
        st = Stepper(cfg0, "full", "none", scheme=sch)
        st.reset(q=[0.05, 0.02, 0.002])
        e0 = field_energy_j(cfg0, st.q, st.qdot)
        err = []
        for _ in range(40):
            st.advance(int(0.05 / cfg.dt_s), 0.0)
            err.append(field_energy_j(cfg0, st.q, st.qdot) / e0 - 1)
        numbers["energy_error"][sch] = float(np.max(np.abs(err)))
        ax.plot(np.arange(1, 41) * 0.05, err, label=sch)
    ax.set(xlabel="time, s", ylabel="(T + V) / (T + V)_0 - 1", title="Free undamped structure, dt = 1/2048 s")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "scheme_energy.png", dpi=100)
    plt.close(fig)
    (out / "scheme_study.json").write_text(jsonio.dumps(numbers, indent=1))
    return numbers


if __name__ == "__main__":
    ap = study_parser(__doc__, "panel_rig.analysis.scheme_study")
    ap.add_argument("--out", default="docs/figures")
    print(jsonio.dumps(study(Path(ap.parse_args().out)), indent=1))
