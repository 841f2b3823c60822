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
        ax1.axvline(uf, color=f"C{k}", ls=":", lw=1)
        ax2.annotate(f"{label}: {uf:.2f} m/s, {ff:.2f} Hz", (0, ff), xytext=(-19, 75 - 7 * k), fontsize=8)
    if paper:
        ax1.axvline(paper[0], color="k", ls="--", lw=1, label=f"paper U_f = {paper[0]} m/s")
    ax1.axhline(0, color="k", lw=0.5)
    ax2.axvline(0, color="k", lw=0.5)
    ax1.set(xlabel="flow velocity, m/s", ylabel="damping Re(s), 1/s", ylim=(-20, 10), title="(a) damping")
    ax2.set(xlabel="damping Re(s), 1/s", ylabel="frequency, Hz", xlim=(-20, 10), ylim=(0, 80),
            title="(b) root locus")
    ax1.legend(fontsize=8, loc="lower left")
    return _save(fig, path)


def plot_series(path: str | Path, x: np.ndarray, ys: Sequence[tuple[np.ndarray, str]], xlabel: str,
                ylabel: str, title: str = "", paper: Sequence[tuple[np.ndarray, np.ndarray, str]] = (),
                marks: tuple[np.ndarray, str] | None = None, marks_at: float = 0.03) -> Path:
    """Generic line plot with optional paper points; ``marks`` (x values, label): crosses at the height
    ``marks_at`` (a fraction of the axes, bottom edge by default) for points without a value (e.g. the diverged
    airspeeds of a sweep), so the axis spans them too."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for y, label in ys:
        ax.plot(x, y, label=label, lw=1.2)
    for px, py, label in paper:
        ax.plot(px, py, "ks", mfc="none", label=label)
    if marks is not None and len(marks[0]):
        ax.plot(marks[0], np.full(len(marks[0]), marks_at), "x", color="C3", label=marks[1],
                transform=ax.get_xaxis_transform(), clip_on=False)
        ax.set_xlim(min(np.nanmin(x), np.min(marks[0])) - 0.5, max(np.nanmax(x), np.max(marks[0])) + 0.5)
    ax.set(xlabel=xlabel, ylabel=ylabel, title=title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_lco_sweep(path: str | Path, airspeed_mps: np.ndarray, results: Sequence[Any], title: str) -> Path:
    """Fig. 8: RMS tip w/L and, where there is an LCO (RMS at least analyze's ``lco_min_rms``), its frequency / 50
    Hz against airspeed (a decaying run's frequency drew a false step into the LCO's); diverged runs (no metrics)
    marked by crosses at the top: beyond the bound, not zero."""
    from panel_rig.analysis.bag_analysis import Criteria

    rms = np.array([r.rms_tip_w_over_L for r in results], dtype=float)
    freq = np.array([r.dominant_frequency_hz for r in results], dtype=float)
    freq[~(rms >= Criteria().lco_min_rms)] = np.nan
    return plot_series(path, airspeed_mps, [(rms, "RMS tip w/L"), (freq / 50.0, "LCO frequency / 50 Hz")],
                       "airspeed, m/s", "RMS w/L ; f/50 Hz", title,
                       marks=(np.array([u for u, r in zip(airspeed_mps, results) if r.diverged]),
                              "diverged (|tip w/L| over the bound)"), marks_at=0.97)


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


_STATUS_STYLE = {"lco": ("C3", "o"), "growing": ("C1", "^"), "decaying": ("C0", "v"), "quiet": ("0.6", "s")}


def plot_time_history(path: str | Path, t_s: np.ndarray, tip_w_over_L: np.ndarray, airspeed_mps: np.ndarray,
                      spans: Sequence[tuple[float, float, str]] = ()) -> Path:
    """Recording: tip w/L and measured airspeed versus time, plateaus shaded by status."""
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(9, 5.5), sharex=True, height_ratios=[2, 1])
    ax1.plot(t_s, tip_w_over_L, lw=0.5, color="C0")
    ax2.plot(t_s, airspeed_mps, lw=1.2, color="C2")
    for t0, t1, status in spans:
        for ax in (ax1, ax2):
            ax.axvspan(t0, t1, color=_STATUS_STYLE.get(status, ("0.6", ""))[0], alpha=0.12, lw=0)
        ax2.annotate(status, ((t0 + t1) / 2, ax2.get_ylim()[0]), ha="center", va="bottom", fontsize=7)
    ax1.set(ylabel="tip w/L", title="Time history (shaded: airspeed plateaus)")
    ax2.set(xlabel="time, s", ylabel="airspeed, m/s")
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    return _save(fig, path)


def plot_spectrogram(path: str | Path, t_s: np.ndarray, tip_w_over_L: np.ndarray, airspeed_mps: np.ndarray,
                     window_s: float = 2.0, f_max_hz: float = 60.0) -> Path:
    """Spectrogram of tip w/L (dB) with the measured airspeed on a second axis."""
    dt = float((t_s[-1] - t_s[0]) / (t_s.size - 1))
    nfft = int(2 ** np.ceil(np.log2(max(16, window_s / dt))))
    nfft = min(nfft, max(16, 2 ** int(np.log2(max(16, t_s.size // 4)))))
    fig, ax = plt.subplots(figsize=(9, 4.5))
    x = np.asarray(tip_w_over_L, float) - np.mean(tip_w_over_L)
    with np.errstate(divide="ignore"):  # silent stretches (rig at rest) are -inf dB
        ax.specgram(x, NFFT=nfft, Fs=1.0 / dt, noverlap=nfft // 2, xextent=(t_s[0], t_s[-1]), cmap="viridis",
                    scale="dB")
    ax.set(xlabel="time, s", ylabel="frequency, Hz", ylim=(0, min(f_max_hz, 0.5 / dt)),
           title=f"Spectrogram of tip w/L ({nfft * dt:.2f} s windows)")
    ax2 = ax.twinx()
    ax2.plot(t_s, airspeed_mps, color="w", lw=1.2)
    ax2.set_ylabel("airspeed, m/s (white)")
    return _save(fig, path)


def plot_lco_vs_airspeed(path: str | Path, plateaus: Sequence[dict], onset: dict | None = None) -> Path:
    """Fig. 8 from a recording: RMS tip w/L and dominant frequency per airspeed plateau."""
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4.2))
    for status, (color, marker) in _STATUS_STYLE.items():
        sel = [p for p in plateaus if p["status"] == status]
        if not sel:
            continue
        u = [p["airspeed_mps"] for p in sel]
        ax1.plot(u, [p["rms_tip_w_over_L"] for p in sel], marker, color=color, label=status)
        if status in ("lco", "growing"):
            ax2.plot(u, [p["dominant_frequency_hz"] for p in sel], marker, color=color, label=status)
    onset = onset or {}
    lo, hi, ex = onset.get("bracket_low_mps"), onset.get("bracket_high_mps"), onset.get("extrapolated_mps")
    for ax in (ax1, ax2):
        if lo is not None and hi is not None:
            ax.axvspan(lo, hi, color="0.8", alpha=0.5, label="onset bracket")
        if ex is not None:
            ax.axvline(ex, color="k", ls="--", lw=1, label=f"extrapolated {ex:.2f} m/s")
        ax.grid(alpha=0.3)
        ax.set_xlabel("airspeed, m/s")
    ax1.set(ylabel="RMS tip w/L", title="(a) LCO amplitude")
    ax2.set(ylabel="dominant frequency, Hz", title="(b) LCO frequency")
    ax1.legend(fontsize=8)
    return _save(fig, path)


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
            ax1.annotate(f"{label} U_f = {uf:.2f} m/s", (uf, 6 - 4 * k), fontsize=8, color=f"C{k}")
    ax1.axhline(0, color="k", lw=0.5)
    ax2.axvline(0, color="k", lw=0.5)
    ax1.set(xlabel="flow velocity, m/s", ylabel="damping Re(s), 1/s", ylim=(-25, 10), title="(a) damping")
    ax2.set(xlabel="damping Re(s), 1/s", ylabel="frequency, Hz", xlim=(-25, 10), ylim=(0, 90), title="(b) root locus")
    ax1.legend(fontsize=8, loc="lower left")
    if title:
        fig.suptitle(title, fontsize=9)
    return _save(fig, path)
