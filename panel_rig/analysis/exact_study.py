"""LCO of the exact (elastica) structure against airspeed, beside the cubic variants and the paper's Fig. 8, and
the hysteresis of an up-and-down sweep with continuation.

``python -m panel_rig.analysis.exact_study --out docs/figures`` writes exact_fig8.png, exact_hysteresis.png
and exact_study.json and prints the markdown tables of docs/validation.md (section 5).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from panel_rig import jsonio
from panel_rig.analysis.flutter import find_flutter
from panel_rig.analysis.lco import LCOResult, lco_metrics, lco_sweep
from panel_rig.argparsing import study_parser
from panel_rig.config import PanelConfig, load_config
from panel_rig.model.aeroelastic import AeroelasticModel
from panel_rig.model.stepper import DivergenceError, Stepper

#: U / U_f of the Fig. 8 comparison (the paper's 12-32 m/s is 0.96-2.56 U_f); 1.05, 1.5, 2.0, 2.5 included
RATIOS = np.round(np.r_[1.05, np.arange(1.1, 2.61, 0.1)], 2)
#: the paper, read from the text (published_results.md): C1, C3 at 13.5/12.5, C4 at 31/12.5, C5 endpoints
PAPER_POINTS = {"C1 full": (13.5 / 12.5, 0.054, 22.0), "C3 stiffness": (13.5 / 12.5, 0.093, 22.55),
                "C4": (31 / 12.5, None, 16.65)}
PAPER_TREND = ((1.0, 0.0, 22.0), (31 / 12.5, 0.5, 16.5))  # C5: RMS 0 -> ~0.5, frequency ~22 -> ~16.5 Hz
LCO_RMS = 0.01  # RMS tip w/L above which a plateau counts as a limit cycle (hysteresis)


def flutter_speed(model: AeroelasticModel) -> float:
    """The stepper's linear flutter speed (ROM, continuous-time model): the reference of U / U_f."""
    return find_flutter(model, aero="rom", rom_modes=model.cfg.rom_modes, formulation="continuous").speed_mps


def fig8(cfg: PanelConfig, model: AeroelasticModel, variants=("exact", "full", "stiffness"), ratios=RATIOS,
         duration_s: float = 30.0) -> dict[str, list[LCOResult]]:
    """Independent fixed-airspeed runs from the small standard disturbance, per variant."""
    uf = flutter_speed(model)
    return {v: lco_sweep(cfg, uf * np.asarray(ratios), duration_s, v, model=model) for v in variants}


KICK_Q2 = 1e-3  # added to q2 at the start of every plateau: the tunnel's small disturbances


def hysteresis(cfg: PanelConfig, model: AeroelasticModel, variant: str, ratios_up: np.ndarray,
               ratios_down: np.ndarray, dwell_s: float = 15.0, log: Callable[[str], None] = lambda s: None) -> dict:
    """Up through ratios_up then down through ratios_down (x U_f), each plateau continuing from the previous
    one's final state plus a small kick (q2 += 1e-3, so that an instability shows within the dwell rather than
    waiting on round-off); metrics over each plateau's last 5 s. A diverged plateau ends the sweep (the model's
    bound)."""
    uf = flutter_speed(model)
    st = Stepper(cfg, variant=variant, model=model)
    n = int(round(dwell_s / st.dt_s))
    out = {"up": [], "down": []}
    for direction, rs in (("up", list(ratios_up)), ("down", list(ratios_down))):
        for r in rs:
            st.q[1] += KICK_Q2
            try:
                tip = st.advance(n, r * uf)
            except DivergenceError:
                out[direction].append({"ratio": float(r), "rms": None, "hz": None, "diverged": True})
                log(f"{variant} {direction} {r:.2f}: diverged")
                return out
            m = lco_metrics(tip, st.dt_s, r * uf)
            out[direction].append({"ratio": float(r), "rms": m.rms_tip_w_over_L, "hz": m.dominant_frequency_hz,
                                   "peak": m.peak_tip_w_over_L, "diverged": False})
            log(f"{variant} {direction} {r:.2f}: RMS {m.rms_tip_w_over_L:.4f}, {m.dominant_frequency_hz:.2f} Hz")
    return out


def onset_and_stop(h: dict) -> tuple[float | None, float | None]:
    """Onset: first ratio of the up sweep with an LCO; stop: last ratio of the down sweep that still has one."""
    up = [p["ratio"] for p in h["up"] if p["diverged"] or (p["rms"] or 0) > LCO_RMS]
    down = [p["ratio"] for p in h["down"] if not p["diverged"] and (p["rms"] or 0) > LCO_RMS]
    return (up[0] if up else None), (min(down) if down else None)


def plot_fig8(path: Path, ratios, res: dict[str, list[LCOResult]], uf: float) -> Path:
    from panel_rig.analysis.plots import _save, plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    for k, (v, rr) in enumerate(res.items()):
        rms_ = np.array([np.nan if r.diverged else r.rms_tip_w_over_L for r in rr])
        hz = np.array([np.nan if r.diverged else r.dominant_frequency_hz for r in rr])
        ax1.plot(ratios, rms_, "o-", color=f"C{k}", ms=4, label=v)
        ax2.plot(ratios, hz, "o-", color=f"C{k}", ms=4, label=v)
        div = [r0 for r0, r in zip(ratios, rr) if r.diverged]
        if div:
            ax1.plot(div, np.zeros(len(div)), "x", color=f"C{k}", ms=8, label=f"{v}: diverged (|w/L| > bound)")
    (r0, a0, f0), (r1, a1, f1) = PAPER_TREND
    ax1.plot([r0, r1], [a0, a1], "k--", lw=1, label="paper Fig. 8 trend (C5, from the text)")
    ax2.plot([r0, r1], [f0, f1], "k--", lw=1, label="paper Fig. 8 trend (C5)")
    for label, (r, a, f) in PAPER_POINTS.items():
        if a is not None:
            ax1.plot(r, a, "ks", mfc="none")
            ax1.annotate(label, (r, a), fontsize=7, xytext=(4, 4), textcoords="offset points")
        ax2.plot(r, f, "ks", mfc="none")
        ax2.annotate(label, (r, f), fontsize=7, xytext=(4, 4), textcoords="offset points")
    ax1.set(xlabel=f"U / U_f (U_f = {uf:.2f} m/s; paper 12.5)", ylabel="RMS tip w/L", title="(a) LCO amplitude")
    ax2.set(xlabel="U / U_f", ylabel="dominant frequency, Hz", title="(b) LCO frequency")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    return _save(fig, path)


def plot_hysteresis(path: Path, hyst: dict[str, dict]) -> Path:
    from panel_rig.analysis.plots import _save, plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for k, (v, h) in enumerate(hyst.items()):
        for direction, style in (("up", "^-"), ("down", "v--")):
            pts = [p for p in h[direction] if not p["diverged"]]
            ax.plot([p["ratio"] for p in pts], [p["rms"] for p in pts], style, color=f"C{k}", ms=5,
                    label=f"{v}, {direction}")
            div = [p["ratio"] for p in h[direction] if p["diverged"]]
            if div:
                ax.plot(div, [0] * len(div), "x", color=f"C{k}", ms=9, label=f"{v}: diverged")
    ax.set(xlabel="U / U_f", ylabel="RMS tip w/L", title="Up-and-down sweep with continuation")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, path)


def main(argv=None) -> int:
    ap = study_parser(__doc__, "panel_rig.analysis.exact_study")
    ap.add_argument("--out", default="docs/figures")
    ap.add_argument("--duration", type=float, default=30.0)
    ap.add_argument("--dwell", type=float, default=15.0)
    ap.add_argument("--skip-fig8", action="store_true", help="only the hysteresis sweep")
    args = ap.parse_args(argv)
    out = Path(args.out)
    cfg = load_config()
    model = AeroelasticModel(cfg)
    uf = flutter_speed(model)
    print(f"U_f = {uf:.3f} m/s\n")
    payload = {"flutter_speed_mps": uf, "ratios": RATIOS.tolist()}
    res = {} if args.skip_fig8 else fig8(cfg, model, duration_s=args.duration)
    if res:
        plot_fig8(out / "exact_fig8.png", RATIOS, res, uf)
        payload["fig8"] = {v: [r.as_dict() for r in rr] for v, rr in res.items()}
    print("| U/U_f | U (m/s) | " + " | ".join(f"{v}: RMS, peak, Hz" for v in res) + " |")
    print("|---|---|" + "---|" * len(res))
    for i, r in enumerate(RATIOS if res else []):
        cells = []
        for v in res:
            x = res[v][i]
            cells.append(f"diverged at {x.diverged_at_s:.1f} s" if x.diverged else
                         f"{x.rms_tip_w_over_L:.3f}, {x.peak_tip_w_over_L:.3f}, {x.dominant_frequency_hz:.2f}")
        print(f"| {r:.2f} | {r * uf:.2f} | " + " | ".join(cells) + " |")
    up = np.round(np.arange(0.8, 1.151, 0.05), 2)
    down = np.round(np.arange(1.1, 0.249, -0.05), 2)
    hyst = {v: hysteresis(cfg, model, v, up, down, args.dwell) for v in ("exact", "full")}
    plot_hysteresis(out / "exact_hysteresis.png", hyst)
    print()
    for v, h in hyst.items():
        on, stop = onset_and_stop(h)
        print(f"{v}: onset {on} U_f, LCO persists down to {stop} U_f")
        for d in ("up", "down"):
            print(f"  {d}: " + ", ".join(f"{p['ratio']:.2f}:" + ("div" if p["diverged"] else f"{p['rms']:.3f}")
                                         for p in h[d]))
    payload.update(hysteresis=hyst, onset_stop={v: onset_and_stop(h) for v, h in hyst.items()})
    path = out / ("exact_hysteresis.json" if args.skip_fig8 else "exact_study.json")
    path.write_text(jsonio.dumps(payload, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
