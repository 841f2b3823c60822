"""Figures: what they draw (not how it looks)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from panel_rig.analysis import plots
from panel_rig.analysis.flutter_test import FlutterTestResult, FlutterTestSettings, TestPoint, decide
from panel_rig.analysis.identification import ModalEstimate
from panel_rig.analysis.lco import LCOResult
from panel_rig.analysis.vg import model_flutter_speed, vg_diagram
from panel_rig.config import PanelConfig
from panel_rig.model.stepper import Stepper


def test_lco_sweep_marks_the_diverged_airspeeds(tmp_path, monkeypatch):
    """Fig. 8 of `lco-sweep --plot` and of the paper report: a diverged run has no metrics (NaN) and its line
    point vanished without a word; it is a cross on the axis now, for both. A run past |w/L| = 1 is circled."""
    figures = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: (figures.append([ln for ax in fig.axes for ln in ax.lines]),
                                                           real_save(fig, path))[1])
    nan = math.nan
    res = [LCOResult(10.0, 0.1, 0.15, 22.0, 3.0, False), LCOResult(12.0, nan, nan, nan, None, True, 4.0),
           LCOResult(14.0, 0.8, 1.2, 20.0, 2.0, False), LCOResult(16.0, nan, nan, nan, None, True, 1.0)]
    path = plots.plot_lco_sweep(tmp_path / "fig8.png", np.array([10.0, 12.0, 14.0, 16.0]), res, "Fig. 8")
    assert path.stat().st_size > 0
    crosses = [ln for ln in figures[0] if ln.get_marker() == "x"]  # on both panels, (a) and (b)
    assert len(crosses) == 2 and all(list(c.get_xdata()) == [12.0, 16.0] for c in crosses)
    assert "diverged" in crosses[0].get_label()
    # a cycle past the panel's length (peak |w/L| 1.2 at 14 m/s) was an ordinary LCO point: circled on both panels
    past = [ln for ln in figures[0] if "past the panel's length" in ln.get_label()]
    assert len(past) == 2 and all(list(c.get_xdata()) == [14.0] for c in past)
    # a frequency only where there is an LCO: the decaying run's (10 m/s, RMS 0) drew a false step into the LCO's
    quiet = [LCOResult(10.0, 0.0, 0.0, 22.9, None, False), LCOResult(11.0, 0.3, 0.4, 17.8, 2.0, False)]
    plots.plot_lco_sweep(tmp_path / "fig8b.png", np.array([10.0, 11.0]), quiet, "Fig. 8")
    freq = next(ln for ln in figures[1] if "frequency" in ln.get_label())
    assert np.isnan(freq.get_ydata()[0]) and freq.get_ydata()[1] == 17.8  # in Hz, on its own panel (b)


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


def test_report_cells_read_as_text_not_python_dicts():
    """report.md's C1, C2 and C5 cells were raw Python dicts ({'airspeed_mps': [...], 'full_rms': [None, ...]});
    a cell now reads "airspeed_mps: 10, 11; full_rms: -, 0.12", and the header names where the paper's values come
    from (published_results.md is not in the repository: its transcription is)."""
    from panel_rig.analysis.report import markdown

    text = markdown([{"id": "C5", "what": "sweep", "paper": "0 -> 0.5", "verdict": "ok", "note": "",
                      "ours": {"airspeed_mps": [10.0, 11.0], "full_rms": [None, 0.1234567]}, "exact": None}], 1.0)
    (row,) = (ln for ln in text.splitlines() if ln.startswith("| C5"))
    assert "airspeed_mps: 10, 11; full_rms: -, 0.123457" in row and "{" not in row and "None" not in row
    assert "panel_rig/analysis/published.py" in text


@pytest.fixture(scope="module")
def panel() -> tuple[Any, float, int]:
    """The paper panel's model, its linear U_f and its flutter mode."""
    model = Stepper(PanelConfig()).model
    uf, mode = model_flutter_speed(model)
    return model, uf, mode


def flutter_result(panel: tuple[Any, float, int], fractions: list[float], damping_se: list[float],
                   shifts: list[float] | None = None, first: bool = True) -> FlutterTestResult:
    """A flutter test whose points identified the model's modes at ``fractions`` x U_f (the flutter mode's damping
    shifted by ``shifts``, its standard error ``damping_se``), with the procedure's decisions."""
    model, uf, mode = panel
    u = np.array(fractions) * uf
    vg = vg_diagram(model, u)
    shifts = shifts or [0.0] * u.size

    def estimate(k: int, m: int, se: float, shift: float = 0.0) -> ModalEstimate:
        return ModalEstimate(vg.frequency_hz[k, m], vg.damping_ratio[k, m] + shift, 0.01, se, 9, "ssi")

    points = [TestPoint(float(x), estimate(k, 0, 0.01) if first else None,
                        estimate(k, mode - 1, damping_se[k], shifts[k]), "ssi-cov") for k, x in enumerate(u)]
    settings = FlutterTestSettings(start_mps=float(u[0]), step_mps=1.0, n_boot=100)
    return FlutterTestResult(points, [decide(points[:k], settings) for k in range(1, len(points) + 1)])


def draw_flutter_test(tmp_path, monkeypatch, panel: tuple[Any, float, int], res: FlutterTestResult) -> Any:
    """`plot_flutter_test` of ``res``; returns its figure, drawn (display coordinates valid)."""
    figures = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: (figures.append(fig), real_save(fig, path))[1])
    model, uf, mode = panel
    assert plots.plot_flutter_test(res, model, mode, uf, tmp_path / "vg.png").stat().st_size > 0
    return figures[0]


def bar_extents(ax: Any, res: FlutterTestResult) -> list[Any]:
    """Each identified point's 95 % bar as drawn: its display-coordinate box, cut to the axes."""
    from matplotlib.transforms import Bbox

    boxes = []
    for p in res.points:
        lo, hi = ax.transData.transform([(p.airspeed_mps, y) for y in p.flutter.damping_ci()])
        box = Bbox.intersection(Bbox([lo - [4, 0], hi + [4, 0]]), ax.get_window_extent())
        boxes += [box] if box is not None else []
    return boxes


def test_flutter_test_damping_panel_shows_every_bar(tmp_path, monkeypatch, panel):
    """`flutter-test --plot` (a 20 s dwell): the damping panel's fixed limits (-0.005, 0.03) cut the first
    point's bar [-0.0064, 0.0217]. Every point and its whole bar are inside the limits now."""
    res = flutter_result(panel, [0.5, 0.6, 0.7, 0.73, 0.83], [0.0062, 0.0032, 0.0028, 0.003, 0.0014],
                         [0.0005, 0.002, 0.001, 0.004, -0.001])
    lo, hi = draw_flutter_test(tmp_path, monkeypatch, panel, res).axes[0].get_ylim()
    for p in res.points:
        z_lo, z_hi = p.flutter.damping_ci()
        assert lo < z_lo and z_hi < hi, (p.airspeed_mps, (z_lo, z_hi), (lo, hi))


def test_flutter_test_cuts_a_huge_bar_and_marks_it(tmp_path, monkeypatch, panel):
    """A bar of +-0.45 would flatten the other points to a line: it is cut at a few times their span, the cut
    marked by a triangle at the edge and the bar's end printed."""
    res = flutter_result(panel, [0.5, 0.6, 0.7, 0.8], [0.0005, 0.2, 0.0005, 0.0005])
    ax = draw_flutter_test(tmp_path, monkeypatch, panel, res).axes[0]
    lo, hi = ax.get_ylim()
    assert -0.05 < lo and hi < 0.05
    marks = [ln for ln in ax.lines if ln.get_marker() in ("^", "v")]
    assert sorted(ln.get_marker() for ln in marks) == ["^", "v"]
    assert all(ln.get_xdata()[0] == res.points[1].airspeed_mps for ln in marks)
    ends = [f"{x:.3g}" for x in res.points[1].flutter.damping_ci()]
    assert sorted(t.get_text() for t in ax.texts if t.get_gid() != "airspeed-line") == sorted(ends)


def test_flutter_test_legend_covers_no_bar(tmp_path, monkeypatch, panel):
    """The legend sat in the damping panel's upper left, over the first point's bar (a high damping at the
    lowest airspeed). Its box overlaps no bar now."""
    res = flutter_result(panel, [0.5, 0.6, 0.7, 0.8], [0.0005, 0.008, 0.0005, 0.0005], [0.018, 0.0, 0.0, 0.0])
    fig = draw_flutter_test(tmp_path, monkeypatch, panel, res)
    legend = fig.legends[0] if fig.legends else fig.axes[0].get_legend()
    box = legend.get_window_extent()
    assert not any(box.overlaps(b) for b in bar_extents(fig.axes[0], res))


def test_flutter_test_draws_both_predictions_and_the_zw_margin(tmp_path, monkeypatch, panel):
    """Only the prediction the decision used had a line, labelled with the method's code name, and the ZW flutter
    margins behind it were not shown. Both predicted U_f are lines now (the ZW one named so) and the margins per
    point are a panel of their own; without a ZW prediction (mode 1 not identified) there is no such panel."""
    res = flutter_result(panel, [0.5, 0.6, 0.7, 0.8, 0.85], [0.0005] * 5)
    fig = draw_flutter_test(tmp_path, monkeypatch, panel, res)
    d = res.final
    assert np.isfinite(d.trend.speed_mps) and np.isfinite(d.zw.speed_mps)
    for pred, name in ((d.trend, "damping trend"), (d.zw, "ZW")):
        lines = [ln for ln in fig.axes[0].lines if list(ln.get_xdata()) == [pred.speed_mps] * 2]  # vertical
        assert len(lines) == 1 and name in lines[0].get_label(), name
    from panel_rig.analysis.flutter_test import margin_points

    margin = next(ax for ax in fig.axes if "ZW" in ax.get_ylabel())
    u, f = margin_points(res.points)
    points = next(ln for ln in margin.lines if ln.get_marker() == "s")
    assert list(points.get_xdata()) == list(u) and np.allclose(points.get_ydata(), f / (2 * np.pi) ** 4)
    fit = next(ln for ln in margin.lines if ln.get_linestyle() == "--")  # the ZW fit, extrapolated to F = 0
    assert fit.get_xdata()[-1] == pytest.approx(d.zw.speed_mps) and abs(fit.get_ydata()[-1]) < 1e-6 * max(f)
    no_zw = flutter_result(panel, [0.5, 0.6, 0.7], [0.001] * 3, first=False)
    fig = draw_flutter_test(tmp_path, monkeypatch, panel, no_zw)
    assert no_zw.final.zw is None and not any("ZW" in ax.get_ylabel() for ax in fig.axes)


def test_each_u_f_line_is_named_beside_it_and_close_ones_stay_readable(tmp_path, monkeypatch, panel):
    """vg.png: the ZW prediction's line sat on the model's U_f line (10.47 against 10.48 m/s) and only the legend,
    below the panels, said which was which. Each line is named at the top of the damping panel now; a label
    whose line is close to the previous one's goes lower, so no two labels overlap."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    ax.set_xlim(3.0, 12.0)
    texts = plots.label_airspeed_lines(ax, [(10.48, "model U_f 10.48", "k"), (10.47, "ZW 10.47", "C2"),
                                            (11.44, "trend 11.44", "C1")])
    fig.canvas.draw()
    boxes = {t.get_text().strip(): t.get_window_extent() for t in texts}
    assert not boxes["ZW 10.47"].overlaps(boxes["model U_f 10.48"])
    assert boxes["trend 11.44"].y1 == pytest.approx(boxes["ZW 10.47"].y1)  # far from its neighbour: at the top
    plt.close(fig)
    res = flutter_result(panel, [0.5, 0.6, 0.7, 0.8, 0.85], [0.0005] * 5)
    ax_z = draw_flutter_test(tmp_path, monkeypatch, panel, res).axes[0]
    named = sorted(t.get_text().split()[-1] for t in ax_z.texts if t.get_gid() == "airspeed-line")
    expected = [res.final.trend.speed_mps, res.final.zw.speed_mps, panel[1]]
    assert named == sorted(f"{x:.2f}" for x in expected)


def test_lco_vs_airspeed_of_a_subcritical_run_says_why_its_frequency_panel_is_empty(tmp_path, monkeypatch):
    """A flutter-test bag has no LCO: its `analyze --plots` frequency panel was an empty 0..1 frame. It shares the
    amplitude panel's airspeed axis now and says why it is empty."""
    figures = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: (figures.append(fig), real_save(fig, path))[1])
    quiet = [{"airspeed_mps": u, "rms_tip_w_over_L": 1e-4 * u, "dominant_frequency_hz": 23.0, "status": "decaying"}
             for u in (5.2, 6.3, 7.3)]
    plots.plot_lco_vs_airspeed(tmp_path / "a.png", quiet)
    ax1, ax2 = figures[0].axes
    assert ax2.get_xlim() == ax1.get_xlim() and not ax2.lines
    assert any("no LCO frequency" in t.get_text() for t in ax2.texts)
    assert ax1.get_title() == "(a) RMS response (no plateau at an LCO)"  # it read "(a) LCO amplitude"
    plots.plot_lco_vs_airspeed(tmp_path / "b.png", [*quiet, {**quiet[0], "airspeed_mps": 11.0, "status": "lco"}])
    assert not figures[1].axes[1].texts and figures[1].axes[1].lines
    assert figures[1].axes[0].get_title() == "(a) LCO amplitude"
    # a wind-off plateau (the demo's first) stretched the airspeed axis down to 0 m/s: left out, and said so
    off = {**quiet[0], "airspeed_mps": 0.0, "status": "quiet"}
    plots.plot_lco_vs_airspeed(tmp_path / "c.png", [off, *quiet])
    ax1 = figures[2].axes[0]
    assert min(x for ln in ax1.lines for x in ln.get_xdata()) == 5.2 and ax1.get_xlim()[0] > 4.0
    assert any("1 wind-off plateau(s)" in t.get_text() for t in ax1.texts)


def test_time_history_status_labels_sit_below_the_airspeed_curve(tmp_path, monkeypatch):
    """The demo's time history wrote each plateau's status at the airspeed panel's bottom, on the curve where the
    wind was off (0 m/s). The labels sit in a band below 0 m/s now."""
    figures = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: (figures.append(fig), real_save(fig, path))[1])
    t = np.linspace(0.0, 30.0, 3001)
    u = np.where(t < 20.0, 10.0, 0.0)
    plots.plot_time_history(tmp_path / "th.png", t, 1e-3 * np.sin(t), u,
                            [(2.0, 18.0, "decaying"), (22.0, 30.0, "decaying")])
    ax2 = figures[0].axes[1]
    for text in ax2.texts:
        bottom, top = ax2.transData.inverted().transform(text.get_window_extent().get_points())[:, 1]
        assert top < 0.0, (text.get_text(), bottom, top)  # below every airspeed the run had


def test_spectrogram_has_its_colour_scale(tmp_path, monkeypatch):
    """The spectrogram's colours had no scale: a colour bar in dB now, the airspeed axis still beside the plot."""
    figures = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: (figures.append(fig), real_save(fig, path))[1])
    t = np.arange(0.0, 20.0, 1 / 200)
    plots.plot_spectrogram(tmp_path / "sg.png", t, 1e-3 * np.sin(2 * np.pi * 22 * t), np.full(t.size, 10.0))
    labels = [ax.get_ylabel() for ax in figures[0].axes]
    assert any(label.startswith("PSD of tip w/L, dB") for label in labels), labels
    spec, speed = figures[0].axes[0], next(ax for ax in figures[0].axes if ax.get_ylabel().startswith("airspeed"))
    assert speed.get_position().bounds == pytest.approx(spec.get_position().bounds)  # the twin on the plot


def test_spectrogram_colours_span_the_band_drawn(tmp_path, monkeypatch):
    """The colour bar ran over the whole band to 0.5/dt (-150 .. -10 dB in the demo) while the plot shows 0..60 Hz:
    a strong 90 Hz tone and the empty band above it set the colours. They now span the PSD drawn, from its 1st
    percentile (a near-silent cell took a third of the scale) to its maximum."""
    figures = []
    real_save = plots._save
    monkeypatch.setattr(plots, "_save", lambda fig, path: (figures.append(fig), real_save(fig, path))[1])
    t = np.arange(0.0, 20.0, 1 / 512)
    tip = 1e-4 * np.sin(2 * np.pi * 22 * t) + 1e-1 * np.sin(2 * np.pi * 90 * t)
    plots.plot_spectrogram(tmp_path / "sg.png", t, tip, np.full(t.size, 10.0), f_max_hz=60.0)
    image = figures[0].axes[0].images[0]
    drawn = image.get_array()  # dB, rows from 256 Hz (top) down to 0 Hz
    freqs = np.linspace(256.0, 0.0, drawn.shape[0])
    shown = np.asarray(drawn)[freqs <= 60.0]
    assert image.get_clim() == pytest.approx((np.percentile(shown, plots.SPECTROGRAM_FLOOR_PERCENTILE),
                                              shown.max()), abs=1e-6)
    assert shown.min() < image.get_clim()[0]  # the few cells below the floor take the bottom colour
    assert image.get_clim()[1] < np.asarray(drawn).max() - 20.0  # the 90 Hz tone is not the top colour


def test_flutter_test_plot_marks_where_the_test_fluttered(tmp_path, monkeypatch, panel):
    """A test that fluttered at 1.15 U_f (no point identified there): the plot ended at 1.1 U_f and showed nothing
    of it. The airspeed is drawn and named in every panel."""
    _, uf, _ = panel
    res = flutter_result(panel, [0.5, 0.6], [0.0062, 0.0032], [0.0005, 0.002])
    res.fluttered, res.max_airspeed_mps = True, 1.15 * uf
    fig = draw_flutter_test(tmp_path, monkeypatch, panel, res)
    ax = fig.axes[0]
    assert ax.get_xlim()[1] >= 1.15 * uf
    marks = [a for a in ax.lines if a.get_gid() == "fluttered"]
    assert len(marks) == 1 and marks[0].get_xdata()[0] == pytest.approx(1.15 * uf)
    labels = [t.get_text() for t in ax.texts if t.get_gid() == "airspeed-line"]
    assert f" fluttered {1.15 * uf:.2f}" in labels
