"""`panel-rig paper`: every id of published_results.md recomputed, figures 2-8, report.md and results.json."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

import numpy as np

from panel_rig import jsonio
from panel_rig.analysis import plots
from panel_rig.analysis import published as paper
from panel_rig.analysis.flutter import eigenvalues, find_flutter
from panel_rig.analysis.forced import BANDS_HZ, forced_sweep
from panel_rig.analysis.lco import lco_sweep, rms_shape, run_lco
from panel_rig.analysis.signals import rms
from panel_rig.config import PanelConfig
from panel_rig.model.aeroelastic import AeroelasticModel
from panel_rig.model.structure import build_structure

PAPER_UF_MPS = paper.FLUTTER_SPEED_MPS
FORCE_NPM = {0: 0.05, 1: 0.5}  # band -> f0 (N/m); see docs/validation.md, "f0 scaling"


def _verdict(ok: bool | None) -> str:
    return {True: "match", False: "gap", None: "see note"}[ok]


def build_report(cfg: PanelConfig, out: Path, log: Callable[[str], None] = lambda s: None,
                 sweep_s: float = 30.0) -> dict:
    """Recompute every published id; write PNGs, report.md and results.json into out."""
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    model = AeroelasticModel(cfg)
    rows: list[dict] = []

    def add(id_, what, paper, ours, ok, note="", exact=None):
        """ours: the paper's (cubic) model; exact: the same run with the exact (elastica) structure."""
        rows.append({"id": id_, "what": what, "paper": paper, "ours": ours, "verdict": _verdict(ok), "note": note,
                     "exact": exact})

    f = build_structure(cfg).natural_frequencies_hz
    paper_f = np.array(paper.NATURAL_FREQUENCIES_HZ)
    add("N1", "natural frequencies (Hz)", paper_f.tolist(), np.round(f, 3).tolist(),
        bool(np.all(np.abs(f / paper_f - 1) < 0.025)), "tolerance 2.5 %")

    log("flutter (Fig. 3)")
    full = find_flutter(model, aero="full")
    rom = find_flutter(model, aero="rom", rom_modes=cfg.rom_modes)
    add("L1", "linear flutter, all aero modes: U_f (m/s), f_f (Hz), dominant mode",
        [paper.FLUTTER_SPEED_MPS, paper.FLUTTER_FREQUENCY_HZ, paper.FLUTTER_DOMINANT_MODE],
        [round(full.speed_mps, 3), round(full.frequency_hz, 3), full.dominant_mode],
        None, "f_f within 3 %, 2nd mode dominant; U_f 17 % low with the 1/4 load point (docs/validation.md)")
    add("L2", f"ROM Ra = {cfg.rom_modes}: U_f, f_f", "virtually identical to L1",
        [round(rom.speed_mps, 3), round(rom.frequency_hz, 3)],
        abs(rom.speed_mps / full.speed_mps - 1) < 0.01 and abs(rom.frequency_hz / full.frequency_hz - 1) < 0.01,
        "tolerance 1 %")
    speeds = np.linspace(1.0, 20.0, 39)
    curves = {"full (all vortices)": (speeds, [eigenvalues(model, u, aero="full").s for u in speeds]),
              f"ROM Ra={cfg.rom_modes}": (speeds, [eigenvalues(model, u, aero="rom", rom_modes=cfg.rom_modes).s
                                                  for u in speeds])}
    plots.plot_flutter_roots(curves, out / "fig3_flutter.png",
                             {"full (all vortices)": (full.speed_mps, full.frequency_hz),
                              f"ROM Ra={cfg.rom_modes}": (rom.speed_mps, rom.frequency_hz)})

    log("forced response, protocol F0 (Fig. 2)")
    paper_peaks = paper.FORCED_PEAKS_HZ
    forced = {}
    for var in ("linear", "full", "stiffness", "inertia"):
        forced[var] = [forced_sweep(cfg, lo, hi, 0.1, var, FORCE_NPM[b], model=model)
                       for b, (lo, hi) in enumerate(BANDS_HZ)]
    lin = [r.peak_frequency_hz for r in forced["linear"]]
    add("F2", "forced, linear: peaks (Hz)", "natural frequencies, largest amplitudes", lin,
        all(abs(p - fn) <= 0.1 for p, fn in zip(lin, f[:2])),
        "peak frequencies within the 0.1 Hz sweep step; the amplitudes are not compared: the step is wider than the "
        "first mode's half-power band (2 zeta f = 0.04 Hz), so a sampled peak's height depends on where the grid falls")
    for id_, var in (("F1", "full"), ("F3", "stiffness"), ("F4", "inertia")):
        peaks = [r.peak_frequency_hz for r in forced[var]]
        want = paper_peaks[var]
        dirs_paper = [int(np.sign(round(w - fn, 1))) for w, fn in zip(want, paper.NATURAL_FREQUENCIES_HZ[:2])]
        dirs_ours = [int(np.sign(round(p - q, 2))) for p, q in zip(peaks, lin)]
        add(id_, f"forced, {var}: peaks (Hz)", list(want), peaks, dirs_ours[1] == dirs_paper[1],
            f"verdict on the direction of the 2nd-peak shift vs linear (paper {dirs_paper}, ours {dirs_ours}); "
            "band 1 f0 = 0.05 N/m, band 2 f0 = 0.5 N/m")
    for b, (lo, hi) in enumerate(BANDS_HZ):
        r0 = forced["linear"][b]
        plots.plot_series(out / f"fig2{'ab'[b]}_forced.png", r0.frequency_hz,
                          [(forced[v][b].amplitude_tip_w_over_L, v) for v in forced], "frequency, Hz",
                          "tip w/L amplitude", f"Fig. 2({'ab'[b]}): forced response, f0 = {FORCE_NPM[b]} N/m")
    add("F0", "forced-response protocol", "f0 = 0.05, 2-7 and 23-28 Hz, 0.1 Hz, 20 s, last 1 s",
        "as printed; f0 in N/m (band 2 at 0.5 N/m)", None, "f0 units open, docs/validation.md")

    log("LCO runs (Figs. 4-7)")
    ratio = full.speed_mps / PAPER_UF_MPS
    u_c = paper.LCO_AIRSPEED_MPS * ratio
    dt = cfg.dt_s
    c1, tip1, st1 = run_lco(cfg, u_c, 40.0, "full", model=model, keep=True)
    c1p, tip1p, _ = run_lco(cfg, u_c, 40.0, "full", scheme="paper", model=model, keep=True)
    c3, tip3, st3 = run_lco(cfg, u_c, 30.0, "stiffness", model=model, keep=True)
    c1x, tip1x, st1x = run_lco(cfg, u_c, 40.0, "exact", model=model, keep=True)

    def lco_cell(r):
        return "diverged" if r.diverged else [round(r.rms_tip_w_over_L, 4), round(r.dominant_frequency_hz, 2)]

    add("C1", f"LCO full nonlinear at U/U_f = {paper.LCO_AIRSPEED_MPS:g}/{PAPER_UF_MPS:g} (U = {u_c:.2f} m/s): RMS, Hz",
        [paper.C1_FULL_RMS_W_OVER_L, paper.C1_FULL_FREQUENCY_HZ],
        {"implicit": [round(c1.rms_tip_w_over_L, 4), round(c1.dominant_frequency_hz, 2)],
         "paper scheme": [round(c1p.rms_tip_w_over_L, 4), round(c1p.dominant_frequency_hz, 2)]},
        False, "not reproduced by a consistent discretisation: docs/validation.md, item 3", exact=lco_cell(c1x))
    add("C3", f"LCO stiffness only at U = {u_c:.2f} m/s: RMS, Hz", [paper.C3_STIFFNESS_RMS_W_OVER_L, paper.C3_STIFFNESS_FREQUENCY_HZ],
        [round(c3.rms_tip_w_over_L, 4), round(c3.dominant_frequency_hz, 2)],
        abs(c3.rms_tip_w_over_L / paper.C3_STIFFNESS_RMS_W_OVER_L - 1) < 0.25
        and abs(c3.dominant_frequency_hz / paper.C3_STIFFNESS_FREQUENCY_HZ - 1) < 0.05,
        "tolerance 25 % RMS, 5 % frequency", exact="n/a (the exact structure has no stiffness-only form)")
    t1 = np.arange(tip1.size) * dt
    plots.plot_series(out / "fig4a_lco_time.png", t1, [(tip1, "full, implicit")], "time, s", "tip w/L",
                      f"Fig. 4(a): U = {u_c:.2f} m/s", bound=(1.0, "|w/L| = 1: the panel's length"))
    plots.plot_spectrum(out / "fig4b_lco_fft.png", dt, [(tip1[-int(10 / dt):], "full, implicit"),
                                                        (tip1p[-int(10 / dt):], "full, paper scheme"),
                                                        (tip3[-int(10 / dt):], "stiffness only")],
                        marks=[(paper.C1_FULL_FREQUENCY_HZ, "paper C1"), (paper.C3_STIFFNESS_FREQUENCY_HZ, "paper C3"),
                               (full.frequency_hz, "ours f_f")])
    plots.plot_series(out / "fig6_stiffness_time.png", np.arange(tip3.size) * dt, [(tip3, "stiffness only")],
                      "time, s", "tip w/L", f"Fig. 6: U = {u_c:.2f} m/s, stiffness nonlinearity only")
    x = np.linspace(0, 1, 81)
    shapes = {"full": rms_shape(st1, u_c, 2.0, x) if not c1.diverged else None,
              "stiffness": rms_shape(st3, u_c, 2.0, x),
              "exact": rms_shape(st1x, u_c, 2.0, x) if not c1x.diverged else None}
    nodes = {k: node_of(x, v) for k, v in shapes.items() if v is not None}
    main = nodes.get("full")
    add("C2", "LCO RMS shape: node x/L (interior local minimum of RMS w/L)", paper.C2_NODE_X_OVER_L,
        {k: (None if v is None else round(v, 3)) for k, v in nodes.items() if k != "exact"},
        None if main is None else abs(main - paper.C2_NODE_X_OVER_L) <= 0.1, "tolerance 0.1 in x/L, full nonlinear LCO",
        exact=None if nodes.get("exact") is None else round(nodes["exact"], 3))
    plots.plot_series(out / "fig5_lco_shape.png", x, [(v, k) for k, v in shapes.items() if v is not None], "x/L",
                      "RMS of w/L", f"Fig. 5: LCO RMS shape, U = {u_c:.2f} m/s")
    u4 = paper.C4_AIRSPEED_MPS * ratio
    c4, tip4, _ = run_lco(cfg, u4, 10.0, "full", model=model, keep=True)
    c4x, tip4x, _ = run_lco(cfg, u4, 10.0, "exact", model=model, keep=True)

    def c4_cell(r):
        return "diverged (|w/L| > bound)" if r.diverged else [round(r.peak_tip_w_over_L, 3),
                                                              round(r.dominant_frequency_hz, 2)]

    add("C4", f"LCO full at U/U_f = {paper.C4_AIRSPEED_MPS:g}/{PAPER_UF_MPS:g} (U = {u4:.2f} m/s): peak w/L, Hz",
        [paper.C4_PEAK_W_OVER_L, paper.C4_FREQUENCY_HZ], c4_cell(c4),
        None if c4.diverged else abs(c4.dominant_frequency_hz / paper.C4_FREQUENCY_HZ - 1) < 0.05, "", exact=c4_cell(c4x))
    tip4_padded = np.full(tip4x.size, np.nan)
    tip4_padded[: min(tip4.size, tip4x.size)] = tip4[: tip4x.size]
    gone = f", diverged at {c4.diverged_at_s:.2f} s" if c4.diverged and c4.diverged_at_s is not None else ""
    plots.plot_series(out / "fig7_lco_31.png", np.arange(tip4x.size) * dt,
                      [(tip4x, "exact"), (tip4_padded, "full (cubic)" + gone)],
                      "time, s", "tip w/L", f"Fig. 7: U = {u4:.2f} m/s",
                      marks=(np.array([c4.diverged_at_s]), "full (cubic) diverged") if gone else None)

    log("LCO sweep (Fig. 8)")
    us = np.linspace(*paper.C5_AIRSPEEDS_MPS, 21) * ratio
    sweep = {v: lco_sweep(cfg, us, sweep_s, v, model=model) for v in ("full", "stiffness", "exact")}
    for v, res in sweep.items():
        plots.plot_lco_sweep(out / f"fig8_sweep_{v}.png", us, res,
                             f"Fig. 8 ({v} nonlinearity), speeds scaled by U_f ratio")
    ok_full = [r for r in sweep["full"] if not r.diverged]
    add("C5", "LCO vs airspeed (Fig. 8): RMS rises, frequency falls", "0 -> 0.5, 22 -> 16.5 Hz",
        {"airspeed_mps": np.round(us, 2).tolist(),
         "full_rms": [None if r.diverged else round(r.rms_tip_w_over_L, 4) for r in sweep["full"]],
         "full_hz": [None if r.diverged else round(r.dominant_frequency_hz, 2) for r in sweep["full"]],
         "stiffness_rms": [None if r.diverged else round(r.rms_tip_w_over_L, 4) for r in sweep["stiffness"]],
         "stiffness_hz": [None if r.diverged else round(r.dominant_frequency_hz, 2) for r in sweep["stiffness"]]},
        None, f"{len(sweep['full']) - len(ok_full)} of {len(us)} full-nonlinear runs diverge (|w/L| > "
              f"{cfg.max_tip_w_over_L}) and {sum(r.peak_tip_w_over_L > 1.0 for r in ok_full)} more pass |w/L| = 1 "
              "(past the panel's length: the cubic model's numbers there are not physical)",
        exact={"rms": [None if r.diverged else round(r.rms_tip_w_over_L, 4) for r in sweep["exact"]],
               "hz": [None if r.diverged else round(r.dominant_frequency_hz, 2) for r in sweep["exact"]],
               "diverged": sum(r.diverged for r in sweep["exact"])})
    t0 = time.perf_counter()
    run_lco(cfg, u_c, 10.0, "full", model=model)
    rt = 10.0 / (time.perf_counter() - t0)
    add("P1", "cost of the nonlinear march", "full order 'almost impossible' on a Cray T916",
        f"{rt:.0f}x real time on one core: one 10 s full-nonlinear run at U = {u_c:.2f} m/s, its set-up included",
        True, "benchmarks/run.py times the march alone (rom_realtime_factor, a 60 s march) and the other ratios")
    result = {"rows": rows, "wall_s": time.perf_counter() - t_start, "flutter_ratio_to_paper": ratio,
              "tip_rms_check": rms(tip3[-2048:])}
    (out / "results.json").write_text(jsonio.dumps(result, indent=2, default=float))
    (out / "report.md").write_text(markdown(rows, result["wall_s"]))
    return result


def node_of(x: np.ndarray, rms_w: np.ndarray) -> float | None:
    """x/L of the outermost interior local minimum of an RMS deflection shape (the LCO's node line), or None."""
    d = np.diff(rms_w)
    idx = [i for i in range(1, d.size) if d[i - 1] < 0 <= d[i] and 0.1 < x[i] < 1.0]
    return float(x[idx[-1]]) if idx else None


def _text(value: object) -> str:
    """A value as a reader wants it in a table: a list as "a, b, c" (null as "-"), a dict as "key: value; ..."
    (the C1, C2 and C5 cells were raw Python dicts)."""
    if value is None:
        return "-"
    if isinstance(value, dict):
        return "; ".join(f"{k}: {_text(v)}" for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return ", ".join(_text(v) for v in value)
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def _cell(value: object) -> str:
    """A markdown table cell: a `|` inside (|w/L|) split rows C4 and C5 into more cells than the header has."""
    return _text(value).replace("|", "\\|")


def markdown(rows: list[dict], wall_s: float) -> str:
    lines = ["# panel_rig: Tang & Dowell (2002) reproduced", "",
             "Paper value beside ours for every id of the paper's published figures as numbers "
             "(`published_results.md`, transcribed with its ids in `panel_rig/analysis/published.py`); see "
             "docs/validation.md.", "",
             "`ours` is the paper's (cubic) structure; `exact` the same run with the geometrically exact (elastica) "
             "structure (docs/validation.md, section 5).", "",
             "| id | what | paper | ours | verdict | note | exact |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        ex = "" if r.get("exact") is None else r["exact"]
        cells = (r["id"], r["what"], r["paper"], r["ours"], r["verdict"], r["note"], ex)
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    lines += ["", f"Figures: fig2a/b (forced), fig3 (flutter), fig4a/b (LCO), fig5 (shape), fig6, fig7 (exact), "
                  f"fig8 (full, stiffness, exact). Wall time {wall_s:.0f} s."]
    return "\n".join(lines) + "\n"
