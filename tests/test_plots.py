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
    # a frequency only where there is an LCO: the decaying run's (10 m/s, RMS 0) drew a false step into the LCO's
    quiet = [LCOResult(10.0, 0.0, 0.0, 22.9, None, False), LCOResult(11.0, 0.3, 0.4, 17.8, 2.0, False)]
    plots.plot_lco_sweep(tmp_path / "fig8b.png", np.array([10.0, 11.0]), quiet, "Fig. 8")
    freq = next(ln for ln in figures[1] if "frequency" in ln.get_label())
    assert np.isnan(freq.get_ydata()[0]) and freq.get_ydata()[1] == 17.8 / 50.0


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


def test_report_rows_have_the_header_s_cells():
    """report.md: `|w/L|` inside rows C4 and C5 split them into 9 cells under a 7-column header."""
    import re

    from panel_rig.analysis.report import markdown

    text = markdown([{"id": "C4", "what": "peak |w/L|, Hz", "paper": [0.9, 20.0], "ours": "diverged (|w/L| > bound)",
                      "verdict": None, "note": "", "exact": [0.8, 19.0]}], 1.0)
    header, row = (ln for ln in text.splitlines() if ln.startswith("| id") or ln.startswith("| C4"))
    cells = lambda line: len(re.split(r"(?<!\\)\|", line)) - 2  # noqa: E731 - unescaped pipes
    assert cells(row) == cells(header) == 7
