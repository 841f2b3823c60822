"""Figures: what they draw (not how it looks)."""

from __future__ import annotations

import math

import numpy as np

from panel_rig.analysis import plots
from panel_rig.analysis.lco import LCOResult


def test_lco_sweep_marks_the_diverged_airspeeds(tmp_path, monkeypatch):
    """Fig. 8 of `lco-sweep --plot` and of the paper report: a diverged run has no metrics (NaN) and its line
    point vanished without a word; it is a cross on the axis now, for both."""
    figures = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: (figures.append(fig.axes[0].lines[:]), real_save(fig, path))[1])
    nan = math.nan
    res = [LCOResult(10.0, 0.1, 0.15, 22.0, 3.0, False), LCOResult(12.0, nan, nan, nan, None, True, 4.0),
           LCOResult(14.0, 0.3, 0.42, 20.0, 2.0, False), LCOResult(16.0, nan, nan, nan, None, True, 1.0)]
    path = plots.plot_lco_sweep(tmp_path / "fig8.png", np.array([10.0, 12.0, 14.0, 16.0]), res, "Fig. 8")
    assert path.stat().st_size > 0
    crosses = [ln for ln in figures[0] if ln.get_marker() == "x"]
    assert len(crosses) == 1 and list(crosses[0].get_xdata()) == [12.0, 16.0]
    assert "diverged" in crosses[0].get_label()


def test_spectrum_names_its_reference_frequencies_in_the_legend(tmp_path, monkeypatch):
    """Fig. 4(b): the paper's and our frequencies are 0.3-0.5 Hz apart; their rotated labels printed over each
    other. Each mark is a line style in the legend now, with its value."""
    legends = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: (
        legends.append([t.get_text() for t in fig.axes[0].get_legend().get_texts()]), real_save(fig, path))[1])
    t = np.arange(4096) / 1024.0
    plots.plot_spectrum(tmp_path / "fig4b.png", 1 / 1024.0, [(np.sin(2 * np.pi * 22.0 * t), "tip")],
                        marks=[(22.0, "paper C1"), (22.55, "paper C3"), (22.83, "ours f_f")])
    assert legends[0] == ["tip", "paper C1: 22.00 Hz", "paper C3: 22.55 Hz", "ours f_f: 22.83 Hz"]
