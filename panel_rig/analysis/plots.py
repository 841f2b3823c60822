"""Report figures (matplotlib, no display): the paper's Figs. 2-8 as PNG."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if fig.get_layout_engine() is None:  # a figure laid out as it was made (constrained) keeps its layout
        fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_flutter_roots(curves: dict[str, tuple[np.ndarray, list[np.ndarray]]], path: str | Path,
                       flutter: dict[str, tuple[float, float]] | None = None,
                       paper: tuple[float, float] | None = (12.5, 22.37)) -> Path:
    """Fig. 3: (a) damping Re s vs airspeed, (b) root locus frequency vs damping.

    curves: label -> (airspeeds, list of eigenvalue arrays per airspeed); flutter: label -> (U_f, f_f).
    """
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    markers = {0: ".", 1: "o"}
    for k, (label, (speeds, roots)) in enumerate(curves.items()):
        for u, s in zip(speeds, roots):
            sel = (s.imag > 0) & (s.imag / (2 * np.pi) < 80) & (s.real > -20)
            kw = dict(marker=markers.get(k, "x"), s=10 if k == 0 else 18,
                      facecolors="none" if k else None, edgecolors=f"C{k}" if k else None,
                      color=None if k else f"C{k}", label=label if u == speeds[0] else None)
            ax1.scatter(np.full(sel.sum(), u), s.real[sel], **kw)
            ax2.scatter(s.real[sel], s.imag[sel] / (2 * np.pi), **kw)
    for k, (label, (uf, ff)) in enumerate((flutter or {}).items()):
        ax1.axvline(uf, color=f"C{k}", ls=":", lw=1, label=f"{label} U_f = {uf:.2f} m/s")
        ax2.annotate(f"{label}: {uf:.2f} m/s, {ff:.2f} Hz", (0, ff), xytext=(-19, 75 - 7 * k), fontsize=8)
    if paper:
        ax1.axvline(paper[0], color="k", ls="--", lw=1, label=f"paper U_f = {paper[0]} m/s")
    ax1.axhline(0, color="k", lw=0.5)
    ax2.axvline(0, color="k", lw=0.5)
    ax1.set(xlabel="flow velocity, m/s", ylabel="damping Re(s), 1/s", ylim=(-20, 10), title="(a) damping")
    ax2.set(xlabel="damping Re(s), 1/s", ylabel="frequency, Hz", xlim=(-20, 10), ylim=(0, 80),
            title="(b) root locus")
    # below the panels: inside, the legend covered the first airspeed's roots; the U_f lines are named in it
    fig.legend(*ax1.get_legend_handles_labels(), fontsize=8, loc="lower center", ncol=3, frameon=False)
    fig.tight_layout(rect=(0, 0.12, 1, 1))
    return _save(fig, path)


def plot_series(path: str | Path, x: np.ndarray, ys: Sequence[tuple[np.ndarray, str]], xlabel: str,
                ylabel: str, title: str = "", paper: Sequence[tuple[np.ndarray, np.ndarray, str]] = (),
                marks: tuple[np.ndarray, str] | None = None, marks_at: float = 0.03,
                bound: tuple[float, str] | None = None) -> Path:
    """Generic line plot with optional paper points; ``marks`` (x values, label): crosses at the height
    ``marks_at`` (a fraction of the axes, bottom edge by default) for points without a value (e.g. the diverged
    airspeeds of a sweep), so the axis spans them too; ``bound`` (value, label): dotted lines at +-value (e.g. the
    panel's length, |w/L| = 1)."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for y, label in ys:
        ax.plot(x, y, label=label, lw=1.2)
    if bound is not None:
        for sign in (1, -1):
            ax.axhline(sign * bound[0], color="0.3", ls=":", lw=1, label=bound[1] if sign > 0 else None)
    for px, py, label in paper:
        ax.plot(px, py, "ks", mfc="none", label=label)
    if marks is not None and len(marks[0]):
        ax.plot(marks[0], np.full(len(marks[0]), marks_at), "x", color="C3", label=marks[1],
                transform=ax.get_xaxis_transform(), clip_on=False)
        ax.set_xlim(min(np.nanmin(x), np.min(marks[0])) - 0.5, max(np.nanmax(x), np.max(marks[0])) + 0.5)
    ax.set(xlabel=xlabel, ylabel=ylabel, title=title)
    ax.grid(alpha=0.3)
    # below the axes: inside, a time history's legend covered its first seconds (Fig. 7's start of the LCO)
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=min(3, len(ys) + len(paper) + 1),
              frameon=False)
    return _save(fig, path)


def plot_lco_sweep(path: str | Path, airspeed_mps: np.ndarray, results: Sequence[Any], title: str) -> Path:
    """Fig. 8 as the paper draws it: (a) RMS tip w/L and (b) the LCO's frequency against airspeed, each run a marker
    (the frequency only where there is an LCO, RMS at least analyze's ``lco_min_rms``: a decaying run's drew a
    false step into the LCO's); diverged runs (no metrics) crosses at the top of both: beyond the bound, not zero.
    It drew both on one axis before, the frequency as f/50 Hz."""
    from panel_rig.analysis.bag_analysis import Criteria

    u = np.asarray(airspeed_mps, float)
    rms = np.array([r.rms_tip_w_over_L for r in results], dtype=float)
    freq = np.array([r.dominant_frequency_hz for r in results], dtype=float)
    freq[~(rms >= Criteria().lco_min_rms)] = np.nan
    gone = np.array([x for x, r in zip(u, results) if r.diverged])
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.2))
    ax1.plot(u, rms, "o-", ms=3.5, lw=1.2, label="RMS tip w/L")
    ax2.plot(u, freq, "o-", ms=3.5, lw=1.2, color="C1", label="LCO frequency")
    past = np.array([not r.diverged and r.peak_tip_w_over_L > 1.0 for r in results], dtype=bool)
    if past.any():  # the cubic model's cycles past the panel's length: computed, but not a panel's numbers
        for ax, y in ((ax1, rms), (ax2, freq)):
            ax.plot(u[past], y[past], "o", ms=8, mfc="none", color="C3",
                    label="peak |w/L| > 1: past the panel's length, not physical")
    for ax in (ax1, ax2):
        if gone.size:
            ax.plot(gone, np.full(gone.size, 0.97), "x", color="C3", label="diverged (|tip w/L| over the bound)",
                    transform=ax.get_xaxis_transform(), clip_on=False)
            ax.set_xlim(min(np.nanmin(u), gone.min()) - 0.5, max(np.nanmax(u), gone.max()) + 0.5)
            lo, hi = ax.get_ylim()  # the data below the crosses (the last LCO point sat under them)
            ax.set_ylim(lo, lo + (hi - lo) / 0.9)
        ax.set_xlabel("airspeed, m/s")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="lower right")
    ax1.set(ylabel="RMS tip w/L", title="(a) amplitude")
    ax2.set(ylabel="frequency, Hz", title="(b) frequency")
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def plot_spectrum(path: str | Path, dt_s: float, series: Sequence[tuple[np.ndarray, str]],
                  marks: Sequence[tuple[float, str]] = (), f_max_hz: float = 40.0) -> Path:
    """Amplitude spectra (Fig. 4b) with vertical marks at reference frequencies."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for x, label in series:
        x = np.asarray(x) - np.mean(x)
        spec = np.abs(np.fft.rfft(x * np.hanning(x.size))) * 2 / max(1, x.size) * 2
        f = np.fft.rfftfreq(x.size, dt_s)
        sel = f <= f_max_hz
        ax.plot(f[sel], spec[sel], label=label, lw=1)
    # the marks are a few tenths of a hertz apart: named in the legend by style (rotated texts overlapped)
    for (fr, label), ls in zip(marks, [":", "--", "-.", (0, (1, 3))] * len(marks)):
        ax.axvline(fr, ls=ls, lw=1, color="k", label=f"{label}: {fr:.2f} Hz")
    ax.set(xlabel="frequency, Hz", ylabel="amplitude of tip w/L", title="Fig. 4(b): spectrum")
    ax.legend(fontsize=8)
    return _save(fig, path)


_STATUS_STYLE = {"lco": ("C3", "o"), "growing": ("C1", "^"), "decaying": ("C0", "v"), "stationary": ("C7", "D"),
                 "quiet": ("0.6", "s")}


def plot_time_history(path: str | Path, t_s: np.ndarray, tip_w_over_L: np.ndarray, airspeed_mps: np.ndarray,
                      spans: Sequence[tuple[float, float, str]] = (), shaker_on_s: Sequence[float] = ()) -> Path:
    """Recording: tip w/L and measured airspeed versus time, plateaus shaded by status, the times the shaker was
    switched on (``shaker_on_s``) marked above the tip."""
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True, height_ratios=[2, 1])
    ax1.plot(t_s, tip_w_over_L, lw=0.5, color="C0")
    if len(shaker_on_s):
        ax1.plot(shaker_on_s, np.full(len(shaker_on_s), 0.96), "v", color="C3", ms=6,
                 transform=ax1.get_xaxis_transform(), label="shaker on (sine amplitude or held force)")
        ax1.legend(loc="lower left", fontsize=7)
    ax2.plot(t_s, airspeed_mps, lw=1.2, color="C2")
    u_max = float(np.nanmax(airspeed_mps)) if np.any(np.isfinite(airspeed_mps)) else 0.0
    if spans:  # a band below 0 m/s for the status labels: on the curve's level they sat on it (wind off, at 0)
        ax2.set_ylim(-0.3 * max(u_max, 1.0), 1.08 * max(u_max, 1.0))
    for t0, t1, status in spans:
        for ax in (ax1, ax2):
            ax.axvspan(t0, t1, color=_STATUS_STYLE.get(status, ("0.6", ""))[0], alpha=0.12, lw=0)
        ax2.annotate(status, ((t0 + t1) / 2, 0.02), xycoords=ax2.get_xaxis_transform(), ha="center", va="bottom",
                     fontsize=7)
    ax1.set(ylabel="tip w/L", title="Time history (shaded: airspeed plateaus)")
    ax2.set(xlabel="time, s", ylabel="airspeed, m/s")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    return _save(fig, path)


#: the spectrogram's colours start at this percentile of the PSD drawn (a few near-silent cells, e.g. a window
#: whose turbulence happened to cancel, took a third of the scale); the colour bar's extension marks those below
SPECTROGRAM_FLOOR_PERCENTILE = 1.0


def shown_db_limits(psd: np.ndarray, freqs_hz: np.ndarray, f_top_hz: float,
                    floor_percentile: float = SPECTROGRAM_FLOOR_PERCENTILE) -> tuple[float, float] | None:
    """Colour limits of a spectrogram's PSD (rows: ``freqs_hz``) in dB, over the rows up to ``f_top_hz``: from the
    ``floor_percentile`` of its finite values to their maximum; None if none is finite."""
    with np.errstate(divide="ignore"):
        db = 10.0 * np.log10(np.asarray(psd, float)[np.asarray(freqs_hz) <= f_top_hz])
    db = db[np.isfinite(db)]
    return (float(np.percentile(db, floor_percentile)), float(db.max())) if db.size else None


def plot_spectrogram(path: str | Path, t_s: np.ndarray, tip_w_over_L: np.ndarray, airspeed_mps: np.ndarray,
                     window_s: float = 2.0, f_max_hz: float = 60.0) -> Path:
    """Spectrogram of tip w/L (dB) with the measured airspeed on a second axis."""
    dt = float((t_s[-1] - t_s[0]) / (t_s.size - 1))
    nfft = int(2 ** np.ceil(np.log2(max(16, window_s / dt))))
    nfft = min(nfft, max(16, 2 ** int(np.log2(max(16, t_s.size // 4)))))
    fig, ax = plt.subplots(figsize=(9, 4.5))
    x = np.asarray(tip_w_over_L, float) - np.mean(tip_w_over_L)
    f_top_hz = min(f_max_hz, 0.5 / dt)
    with np.errstate(divide="ignore"):  # silent stretches (rig at rest) are -inf dB
        psd, freqs_hz, _, image = ax.specgram(x, NFFT=nfft, Fs=1.0 / dt, noverlap=nfft // 2,
                                              xextent=(t_s[0], t_s[-1]), cmap="viridis", scale="dB")
    limits = shown_db_limits(psd, freqs_hz, f_top_hz)
    if limits is not None:  # the colours span what is drawn, not the band above the plot's top (to 0.5/dt)
        image.set_clim(*limits)
    ax.set(xlabel="time, s", ylabel="frequency, Hz", ylim=(0, f_top_hz),
           title=f"Spectrogram of tip w/L ({nfft * dt:.2f} s windows)")
    # the colour scale, before the twin axis is made (it then takes the plot's narrowed place)
    fig.colorbar(image, ax=ax, pad=0.11, extend="min", label="PSD of tip w/L, dB re 1 (w/L)^2/Hz")
    ax2 = ax.twinx()
    ax2.plot(t_s, airspeed_mps, color="w", lw=1.2)
    ax2.set_ylabel("airspeed, m/s (white)")
    return _save(fig, path)


WIND_OFF_MPS = 0.5  # a plateau below this airspeed is the tunnel off (bag_analysis: no decay rate there either)


def plot_lco_vs_airspeed(path: str | Path, plateaus: Sequence[dict], onset: dict | None = None,
                         onset_loop: str = "open") -> Path:
    """Fig. 8 from a recording: RMS tip w/L and dominant frequency per airspeed plateau; a closed-loop plateau
    (``loop`` "closed") hollow; a wind-off one (U < WIND_OFF_MPS) left out, said in a note (the demo's axis began at
    0 m/s for it). ``onset`` is the ``onset_loop`` loop's ("closed": labelled so)."""
    wind_off = sum(p["airspeed_mps"] < WIND_OFF_MPS for p in plateaus)
    plateaus = [p for p in plateaus if p["airspeed_mps"] >= WIND_OFF_MPS]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4.2), sharex=True)
    if wind_off:
        ax1.text(0.01, 0.99, f"{wind_off} wind-off plateau(s) (U < {WIND_OFF_MPS:g} m/s) not drawn",
                 transform=ax1.transAxes, ha="left", va="top", fontsize=7, color="0.4")
    if not _any_lco(plateaus):  # a subcritical run (a flutter test)
        ax2.text(0.5, 0.5, "no plateau at an LCO or growing:\nno LCO frequency", transform=ax2.transAxes,
                 ha="center", va="center", color="0.4")
    for status, (color, marker) in _STATUS_STYLE.items():
        for loop in ("open", "closed"):
            sel = [p for p in plateaus if p["status"] == status and p.get("loop", "open") == loop]
            if not sel:
                continue
            u = [p["airspeed_mps"] for p in sel]
            style = dict(color=color, label=status if loop == "open" else f"{status}, closed loop")
            if loop == "closed":
                style["markerfacecolor"] = "none"
            ax1.plot(u, [p["rms_tip_w_over_L"] for p in sel], marker, **style)
            if status in ("lco", "growing"):
                ax2.plot(u, [p["dominant_frequency_hz"] for p in sel], marker, **style)
    onset = onset or {}
    lo, hi, ex = onset.get("bracket_low_mps"), onset.get("bracket_high_mps"), onset.get("extrapolated_mps")
    which = " (closed loop)" if onset_loop == "closed" else ""
    for ax in (ax1, ax2):
        if lo is not None and hi is not None:
            ax.axvspan(lo, hi, color="0.8", alpha=0.5, label=f"onset bracket{which}")
        if ex is not None:
            ax.axvline(ex, color="k", ls="--", lw=1, label=f"extrapolated{which} {ex:.2f} m/s")
        ax.grid(alpha=0.3)
        ax.set_xlabel("airspeed, m/s")
    ax1.set(ylabel="RMS tip w/L", title=lco_amplitude_title(plateaus))
    ax2.set(ylabel="dominant frequency, Hz", title="(b) LCO frequency")
    ax1.legend(fontsize=8)
    return _save(fig, path)


def _any_lco(plateaus: Sequence[dict]) -> bool:
    return any(p["status"] in ("lco", "growing") for p in plateaus)


def lco_amplitude_title(plateaus: Sequence[dict]) -> str:
    """Panel (a)'s title: a run with no plateau at an LCO shows random or decaying response, not LCO amplitude."""
    return "(a) LCO amplitude" if _any_lco(plateaus) else "(a) RMS response (no plateau at an LCO)"


def plot_control_damping(speeds: np.ndarray, open_roots: list[np.ndarray], closed_roots: list[np.ndarray],
                         path: str | Path, open_uf: float | None, closed_uf: float | None, title: str = "") -> Path:
    """Open- vs closed-loop damping: Re s of the structural-range roots vs airspeed, flutter speeds marked."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    for k, (label, roots, uf) in enumerate((("open loop", open_roots, open_uf),
                                            ("closed loop", closed_roots, closed_uf))):
        for u, s in zip(speeds, roots):
            sel = s.imag > 1.0
            kw = dict(color=f"C{k}", s=10 if k == 0 else 14, marker="." if k == 0 else "o",
                      label=label if u == speeds[0] else None)
            if k:
                kw.update(facecolors="none", edgecolors=f"C{k}", color=None)
            ax1.scatter(np.full(sel.sum(), u), s.real[sel], **kw)
            ax2.scatter(s.real[sel], s.imag[sel] / (2 * np.pi), **kw)
        if uf is not None:
            ax1.axvline(uf, color=f"C{k}", ls=":", lw=1.2)
            # at the top, on a white ground, the open loop's left of its line and the closed loop's right: over the
            # data they were hard to read
            ax1.annotate(f"{label} U_f = {uf:.2f} m/s", (uf, 0.96 - 0.08 * k), xycoords=ax1.get_xaxis_transform(),
                         xytext=(-3 if k == 0 else 3, 0), textcoords="offset points", ha="right" if k == 0 else "left",
                         va="top", fontsize=8, color=f"C{k}", bbox=dict(fc="white", ec="none", alpha=0.85, pad=1))
    ax1.axhline(0, color="k", lw=0.5)
    ax2.axvline(0, color="k", lw=0.5)
    ax1.set(xlabel="flow velocity, m/s", ylabel="damping Re(s), 1/s", ylim=(-25, 10), title="(a) damping")
    ax2.set(xlabel="damping Re(s), 1/s", ylabel="frequency, Hz", xlim=(-25, 10), ylim=(0, 90), title="(b) root locus")
    ax1.legend(fontsize=8, loc="lower left")
    if title:
        fig.suptitle(title, fontsize=9)
    return _save(fig, path)


#: the flutter-test predictors: their name on the figure, colour (the damping trend's matches its curve) and the
#: short name beside their line
_PREDICTORS = {"damping-trend": ("damping trend", "C1", "trend"), "flutter-margin": ("ZW flutter margin", "C2", "ZW")}


def _predictor_style(method: str) -> tuple[str, str, str]:
    return _PREDICTORS.get(method, (method, "C3", method))


#: a 95 % bar is drawn in full unless it reaches beyond the other data by more than this many times their span
BAR_CAP_SPANS = 3.0


def damping_limits(values: np.ndarray, bars: np.ndarray, others: Sequence[np.ndarray] = (),
                   cap: float = BAR_CAP_SPANS, pad: float = 0.08) -> tuple[float, float]:
    """y-limits that show every value and every bar end, except that a bar end more than ``cap`` x the values'
    span beyond them is cut there (a huge interval would flatten the rest); each of ``others`` (curves) is shown
    whole when it lies within that reach, else left out; ``pad`` of the range either side."""
    lo, hi = float(np.nanmin(values)), float(np.nanmax(values))
    span = max(hi - lo, 1e-3)
    reach = (lo - cap * span, hi + cap * span)
    ends = np.asarray(bars, float).ravel()
    ends = np.clip(ends[np.isfinite(ends)], *reach)
    for y in others:
        if np.size(y) and reach[0] <= np.min(y) and np.max(y) <= reach[1]:
            ends = np.concatenate([ends, [np.min(y), np.max(y)]])
    if ends.size:
        lo, hi = min(lo, ends.min()), max(hi, ends.max())
    return lo - pad * (hi - lo), hi + pad * (hi - lo)


def _mark_clipped(ax, u: np.ndarray, ci: np.ndarray, limits: tuple[float, float]) -> None:
    """A triangle at the panel's edge, with the bar's end value, for every 95 % bar the limits cut."""
    label = "95 % bar cut at the edge (its end printed)"
    for x, (lo, hi) in zip(u, ci):
        for end, edge, marker, va in ((hi, limits[1], "^", "top"), (lo, limits[0], "v", "bottom")):
            if (end > edge) if marker == "^" else (end < edge):
                ax.plot(x, edge, marker, color="C0", clip_on=False, label=label)
                ax.annotate(f"{end:.3g}", (x, edge), xytext=(5, 0), textcoords="offset points", fontsize=7,
                            color="C0", va=va)
                label = None


def _prediction_lines(axes, decision: Any, u_hi: float) -> None:
    """Both predictors of the final decision: a vertical line at each predicted U_f across all panels (solid for
    the one the decision used, its 95 % interval shaded), or a legend note when one does not cross zero."""
    for pred in (decision.trend, decision.zw):
        if pred is None:
            continue
        name, color, _ = _predictor_style(pred.method)
        used = pred is decision.prediction
        lo, hi = pred.ci_mps
        ci = "" if not np.isfinite(lo) else f" (95 % {lo:.2f} .. {f'{hi:.2f}' if np.isfinite(hi) else 'open'})"
        if not np.isfinite(pred.speed_mps):
            axes[0].plot([], [], " ", label=f"{name}: no crossing{ci}")
            continue
        label = f"{name} U_f {pred.speed_mps:.2f} m/s{ci}{', used' if used else ''}"
        for ax in axes:
            ax.axvline(pred.speed_mps, color=color, ls="-" if used else "--", lw=1.2, label=label)
            if used and np.isfinite(lo):
                ax.axvspan(lo, min(hi, u_hi), color=color, alpha=0.12, lw=0)
            label = None


#: vertical-line labels closer than this fraction of the airspeed axis are drawn at alternating heights
LINE_LABEL_GAP = 0.04


def label_airspeed_lines(ax, lines: Sequence[tuple[float, str, str]], gap: float = LINE_LABEL_GAP) -> list[Any]:
    """Name each vertical line (airspeed m/s, text, colour) at the top of ``ax``, beside the line; a line within
    ``gap`` of the axis span of the previous label's line gets its label lower down, so that two close lines
    (a prediction on the model's U_f) keep both labels readable. Returns the texts (gid ``airspeed-line``)."""
    from matplotlib.transforms import blended_transform_factory

    lo, hi = ax.get_xlim()
    where = blended_transform_factory(ax.transData, ax.transAxes)
    texts, last_x, level = [], None, 0
    for x, text, color in sorted(lines):
        level = (level + 1) % 2 if last_x is not None and x - last_x < gap * (hi - lo) else 0
        texts.append(ax.text(x, (0.97, 0.5)[level], f" {text}", transform=where, rotation=90, ha="right",
                             va="top", fontsize=7, color=color, gid="airspeed-line",
                             bbox={"facecolor": "white", "alpha": 0.7, "lw": 0, "pad": 0.5}))
        last_x = x
    return texts


def _prediction_labels(decision: Any) -> list[tuple[float, str, str]]:
    """(U_f, short name, colour) of each predictor of ``decision`` that crossed zero."""
    if decision is None:
        return []
    preds = [p for p in (decision.trend, decision.zw) if p is not None and np.isfinite(p.speed_mps)]
    return [(p.speed_mps, f"{_predictor_style(p.method)[2]} {p.speed_mps:.2f}", _predictor_style(p.method)[1])
            for p in preds]


def _margin_panel(ax, points: Sequence[Any], decision: Any) -> None:
    """The ZW flutter margin F of each point (both modes identified) and its fit in q extrapolated to zero."""
    from panel_rig.analysis.flutter_test import margin_curve, margin_points

    hz4 = (2 * np.pi) ** 4  # F in Hz^4: (rad/s)^4 / (2 pi)^4
    u, f = margin_points(points)
    ax.plot(u, f / hz4, "s", color="C2", label="ZW flutter margin F (modes 1 and flutter)")
    curve = margin_curve(points, decision)
    if curve is not None:
        ax.plot(curve[0], curve[1] / hz4, "--", color="C2", label=f"ZW fit (degree {decision.zw.degree} in q)")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_ylabel("ZW margin F, Hz^4")


def _off_scale_notes(ax, grid: np.ndarray, damping: np.ndarray, mode: int, shown: np.ndarray) -> None:
    """A legend note for each model mode whose damping in the shown airspeeds is entirely off the panel."""
    lo, hi = ax.get_ylim()
    for k in range(damping.shape[1]):
        z = damping[shown, k]
        if k != mode - 1 and z.size and (z.min() > hi or z.max() < lo):
            ax.plot([], [], " ", label=f"model mode {k + 1}: zeta {z.min():.2f}..{z.max():.2f}, off the panel")


def plot_flutter_test(res: Any, model: Any, mode: int, uf: float, path: str | Path, title: str = "") -> Path:
    """The flutter test's V-g: the model's damping and frequency of every mode (solid: the flutter mode), the
    identified points with their 95 % bars, the damping-trend extrapolation, both predicted U_f (damping trend
    and Zimmerman–Weissenburger), and when the result holds a ZW prediction a panel of the ZW flutter margin per
    point with its extrapolation. Damping limits show every point and bar (a huge bar is cut, marked); the
    legend is below the panels, off the data. ``res``: a FlutterTestResult (its points and final decision);
    ``title`` above the panels (what was tested and how it ended)."""
    from panel_rig.analysis.flutter_test import trend_curve
    from panel_rig.analysis.vg import vg_diagram

    d = res.final
    pts = [p for p in res.points if p.flutter is not None]
    tested = [p.airspeed_mps for p in res.points]
    preds = [] if d is None else [p.speed_mps for p in (d.trend, d.zw) if p is not None and np.isfinite(p.speed_mps)]
    flutter_at = [res.max_airspeed_mps] if res.fluttered else []  # where the test fluttered (no point there)
    u_hi = max([uf * 1.1] + tested + preds + flutter_at)  # the model drawn to every predicted U_f
    grid = np.linspace(min([0.3 * uf] + tested), u_hi, 60)
    vg = vg_diagram(model, grid)
    zw = d is not None and d.zw is not None
    fig, axes = plt.subplots(3 if zw else 2, 1, figsize=(7, 10 if zw else 8), sharex=True, layout="constrained",
                             height_ratios=[3, 2, 2] if zw else [3, 2])
    ax_z, ax_f = axes[0], axes[-1]
    for k in range(vg.poles.shape[1]):
        ls, label = ("-", "model V-g, flutter mode") if k == mode - 1 else (":", "model V-g, other modes")
        ax_z.plot(grid, vg.damping_ratio[:, k], ls, color="0.5", lw=1,
                  label=None if label in ax_z.get_legend_handles_labels()[1] else label)
        ax_f.plot(grid, vg.frequency_hz[:, k], ls, color="0.5", lw=1)
    # the damping limits: the points, the model's flutter mode from the first point (or half U_f, where the default
    # plan starts) to U_f (a lone point near U_f was drawn on the scale of its bar alone), the trend and zero, and
    # the bars (cut when huge); the other modes there when they are near
    shown = (grid >= min(tested + [0.5 * uf]) - 1e-9) & (grid <= max(tested + [uf]) + 1e-9)
    values = [0.0, *vg.damping_ratio[shown, mode - 1]]
    u = np.array([p.airspeed_mps for p in pts])
    zci = np.array([p.flutter.damping_ci() for p in pts]).reshape(-1, 2)
    if pts:
        z = np.array([p.flutter.damping_ratio for p in pts])
        ax_z.errorbar(u, z, yerr=[z - zci[:, 0], zci[:, 1] - z], fmt="o", color="C0", capsize=3,
                      label="identified flutter mode (95 %)")
        ax_f.plot(u, [p.flutter.frequency_hz for p in pts], "o", color="C0")
        values += list(z)
    first = [p for p in res.points if p.first is not None]
    if first:
        ax_f.plot([p.airspeed_mps for p in first], [p.first.frequency_hz for p in first], "o", mfc="none",
                  color="C0", label="identified mode 1")
    curve = trend_curve(res.points, d)
    if curve is not None:
        ax_z.plot(*curve, "--", color="C1", label="damping trend (quadratic in q)")
        values += list(curve[1])
    if zw:
        _margin_panel(axes[1], res.points, d)
    if d is not None:
        _prediction_lines(axes, d, u_hi)
    for ax in axes:
        ax.axvline(uf, color="k", lw=0.8, ls="-.", label=f"model linear U_f {uf:.2f} m/s" if ax is ax_z else None)
        ax.grid(alpha=0.3)
    for u_fl in flutter_at:
        for ax in axes:
            ax.axvline(u_fl, color="C3", lw=1.2, label=f"fluttered at {u_fl:.2f} m/s" if ax is ax_z else None)
        ax_z.plot([u_fl], [0.0], "X", color="C3", ms=10, gid="fluttered")
    label_airspeed_lines(ax_z, [(uf, f"model U_f {uf:.2f}", "k"), *_prediction_labels(d),
                                *[(u_fl, f"fluttered {u_fl:.2f}", "C3") for u_fl in flutter_at]])
    ax_z.axhline(0, color="k", lw=0.5)
    others = [vg.damping_ratio[shown, k] for k in range(vg.poles.shape[1]) if k != mode - 1]
    limits = damping_limits(np.array(values), zci, others)
    ax_z.set_ylim(*limits)
    _mark_clipped(ax_z, u, zci, limits)
    _off_scale_notes(ax_z, grid, vg.damping_ratio, mode, shown)
    ax_z.set_ylabel("damping ratio")
    ax_f.set_ylabel("frequency (Hz)")
    ax_f.set_xlabel("airspeed (m/s)")
    fig.legend(loc="outside lower center", ncols=2, fontsize=7)
    if title:
        fig.suptitle(title, fontsize=9)
    return _save(fig, path)
