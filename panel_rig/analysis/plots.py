"""Report figures (matplotlib, no display): the paper's Figs. 2-8 as PNG."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

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
                ylabel: str, title: str = "", paper: Sequence[tuple[np.ndarray, np.ndarray, str]] = ()) -> Path:
    """Generic line plot with optional paper points."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for y, label in ys:
        ax.plot(x, y, label=label, lw=1.2)
    for px, py, label in paper:
        ax.plot(px, py, "ks", mfc="none", label=label)
    ax.set(xlabel=xlabel, ylabel=ylabel, title=title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
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
    for fr, label in marks:
        ax.axvline(fr, ls=":", lw=1, color="k")
        ax.annotate(label, (fr, ax.get_ylim()[1] * 0.9), fontsize=7, rotation=90)
    ax.set(xlabel="frequency, Hz", ylabel="amplitude of tip w/L", title="Fig. 4(b): spectrum")
    ax.legend(fontsize=8)
    return _save(fig, path)
