"""Rerun recordings of the flutter test and of a bag analysis: read back, each view has readable data."""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rerun")

from rerun.chunk import RrdReader

from panel_rig.analysis.flutter_test import FlutterTestSettings, TestPoint, decide
from panel_rig.analysis.identification import ModalEstimate
from panel_rig.viz.logger import RerunLogger

ROOT = Path(__file__).resolve().parents[1]
UF = 10.0
SPEEDS = (5.0, 6.0, 7.0, 8.0, 9.2)


def _point(u: float, se: float = 1e-4) -> TestPoint:
    """A synthetic flutter mode: damping linear in U^2, zero at UF (as tests/test_flutter_test.py)."""
    z = 0.01 * (1 - (u / UF) ** 2)
    return TestPoint(u, None, ModalEstimate(20.0 - 0.5 * u, z, 0.01, se, 9, "synthetic"), "synthetic")


def _temporal(path: Path) -> dict[str, list[dict]]:
    """Entity path -> its temporal rows (column name -> value), in file order."""
    out: dict[str, list[dict]] = defaultdict(list)
    for chunk in RrdReader(path).stream().to_chunks():
        if chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        cols = {n: batch.column(n).to_pylist() for n in batch.schema.names}
        for i in range(chunk.num_rows):
            out[str(chunk.entity_path)].append({n: v[i] for n, v in cols.items()})
    return out


def _static_components(path: Path) -> dict[str, set[str]]:
    out: dict[str, set[str]] = defaultdict(set)
    for chunk in RrdReader(path).stream().to_chunks():
        if chunk.is_static:
            out[str(chunk.entity_path)].update(chunk.to_record_batch().schema.names)
    return out


def _views(path: Path) -> dict[str, str]:
    """Blueprint view name -> its space origin."""
    reader = RrdReader(path)
    fields: dict[str, dict[str, object]] = defaultdict(dict)
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        for key, col in (("name", "ViewBlueprint:display_name"), ("origin", "ViewBlueprint:space_origin")):
            if col in batch.schema.names:
                fields[str(chunk.entity_path)][key] = batch.column(col).to_pylist()[-1][0]
    return {f["name"]: "/" + str(f.get("origin", "/")).lstrip("/") for f in fields.values() if "name" in f}


def _scalar(row: dict) -> float:
    return row[next(n for n in row if n.endswith("Scalars:scalars"))][0]


@pytest.fixture(scope="module")
def monitor_rrd(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list]:
    path = tmp_path_factory.mktemp("vg") / "m.rrd"
    s = FlutterTestSettings(start_mps=5.0, step_mps=2.0, margin=0.1, min_damping=0.0)
    pts = [_point(u) for u in SPEEDS]
    decisions = [decide(pts[:k], s) for k in range(1, len(pts) + 1)]
    log = RerunLogger(3, mode="save", target=str(path), views=("flutter", "flutter_uf"))
    for k, d in enumerate(decisions, start=1):
        log.log_flutter_point(10.0 * k, pts[:k], d, 0.1)
    log.close()
    return path, decisions


def test_vg_view_draws_positive_damping_up_with_visible_points_and_bars_in_frame(monitor_rrd) -> None:
    """Finding 1: a 2-D view's y axis points down; the damping was logged as +y, so positive damping was drawn
    below zero, the points (radius 0.05 scene units) were invisible and the bars ran off the frame."""
    path, _ = monitor_rrd
    rows = _temporal(path)
    last = rows["/flutter_vg/identified"][-1]
    xy = np.array(last["Points2D:positions"])
    z = np.array([_point(u).flutter.damping_ratio for u in SPEEDS])
    assert np.all(xy[:, 1][z > 0] < 0)  # above the zero line (y = 0): positive damping drawn up
    assert np.all(np.diff(xy[:, 1]) > 0)  # the damping falls with airspeed: each point lower on screen
    assert all(r < 0 for r in last["Points2D:radii"])  # negative radius: UI points, visible at any zoom
    axes = np.concatenate([np.array(s) for s in rows["/flutter_vg/axes/lines"][-1]["LineStrips2D:strips"]])
    y_lo, y_hi = axes[:, 1].min(), axes[:, 1].max()
    for entity in ("/flutter_vg/interval", "/flutter_vg/trend", "/flutter_vg/predicted_uf"):
        strips = np.concatenate([np.array(s) for s in rows[entity][-1]["LineStrips2D:strips"]])
        assert strips[:, 1].min() >= y_lo - 1e-9 and strips[:, 1].max() <= y_hi + 1e-9, entity
    labels = rows["/flutter_vg/axes/y_ticks"][-1]["Points2D:labels"]
    assert "0" in labels  # labelled damping ticks


def test_monitor_series_are_logged_at_every_point_and_the_margin_off_the_mps_axis(monitor_rrd) -> None:
    """Finding 2: estimate, interval and margin drew nothing (a line needs two samples; the required margin, a
    fraction, sat under the m/s entity). Every point logs the required margin and the damping, every decision
    with a prediction the U_f, its interval and the margin, each with markers (one sample shows); the unitless
    margins are under flutter/margin with a view of their own."""
    path, decisions = monitor_rrd
    rows = _temporal(path)
    n_pred = sum(d.prediction is not None for d in decisions)
    assert n_pred >= 2
    assert len(rows["/flutter/predicted_uf_mps/estimate"]) == n_pred
    assert len(rows["/flutter/margin/current"]) == n_pred
    assert len(rows["/flutter/margin/required"]) == len(SPEEDS)
    assert len(rows["/flutter/damping_x1000/identified"]) == len(SPEEDS)
    assert [_scalar(r) for r in rows["/flutter/damping_x1000/identified"]] == pytest.approx(
        [1e3 * _point(u).flutter.damping_ratio for u in SPEEDS])
    assert not [e for e in rows if e.startswith("/flutter/predicted_uf_mps/") and "margin" in e]
    # both predictors' U_f, as the PNG draws them (only the one used was logged)
    for name, attr in (("damping_trend", "trend"), ("zw", "zw")):
        crossing = [getattr(d, attr).speed_mps for d in decisions
                    if getattr(d, attr) is not None and math.isfinite(getattr(d, attr).speed_mps)]
        assert [_scalar(r) for r in rows.get(f"/flutter/predicted_uf_mps/{name}", [])] == pytest.approx(crossing)
    assert any(rows.get(f"/flutter/predicted_uf_mps/{n}") for n in ("damping_trend", "zw"))
    static = _static_components(path)
    assert "SeriesPoints:marker_sizes" in static["/flutter/predicted_uf_mps/estimate"]
    views = _views(path)
    assert views["Flutter monitor: predicted U_f and 95 % interval; each predictor (m/s)"] == "/flutter/predicted_uf_mps"
    assert views["Flutter margin 1 - U/U_f and required (unitless)"] == "/flutter/margin"


def test_analyze_rerun_logs_the_replay_plateaus_and_onset_and_only_views_with_data(tmp_path: Path) -> None:
    """Finding 3: `analyze bags/stiffness_staircase --rerun` left the flutter-mode view empty though the replay
    identified a point at 10.2 m/s, logged no plateau status or onset, and had three empty views."""
    from panel_rig.analyze_cli import analyze_bag

    res = analyze_bag(ROOT / "bags" / "stiffness_staircase", rerun_path=tmp_path / "ref.rrd")
    rows = _temporal(tmp_path / "ref.rrd")
    ft = res["flutter_test"]["test_points"]
    assert [p["airspeed_mps"] for p in ft] == pytest.approx([10.2])
    assert np.array(rows["/flutter_vg/identified"][-1]["Points2D:positions"])[:, 0] == pytest.approx([10.2])
    assert _scalar(rows["/flutter/damping_x1000/identified"][0]) == pytest.approx(1e3 * ft[0]["damping_ratio"])
    texts = [r["TextLog:text"][0] for r in rows["/analysis/plateaus"]]
    assert len(texts) == len(res["plateaus"]) == 4
    assert all(f"{p['airspeed_mps']:.2f} m/s {p['status']}" in t for t, p in zip(texts, res["plateaus"]))
    onset = rows["/analysis/onset"][0]["TextLog:text"][0]
    assert "10.20 .. 11.30" in onset
    views = _views(tmp_path / "ref.rrd")
    assert not any(name.startswith("Control") for name in views)  # no control commands in this bag
    assert not any(name.startswith("Flutter monitor") for name in views)  # one point: no prediction
    for name, origin in views.items():
        if origin != "/":
            assert any(e == origin or e.startswith(origin + "/") for e in rows), name


def test_in_process_flutter_test_records_the_panel_shape(tmp_path: Path) -> None:
    """Finding 4: the in-process flutter test's recording had no panel shape (only the node drew it)."""
    from panel_rig.config import load_config
    from panel_rig.flutter_cli import run_in_process

    cfg = load_config()
    out = run_in_process(cfg, bag_dir=None, rerun=str(tmp_path / "ft.rrd"), dwell_s=20.0, settle_s=1.0,
                         max_points=1)
    rows = _temporal(tmp_path / "ft.rrd")
    shapes = rows["/panel/shape"]
    assert len(shapes) >= 9 * out["simulated_s"]  # about 10 per simulated second
    strip = np.array(shapes[-1]["LineStrips3D:strips"][0])
    assert strip.shape == (5 + 31, 3) and np.all(np.isfinite(strip))
    assert strip[-1, 0] == pytest.approx(cfg.airfoil_length_m + cfg.panel_length_m)


def test_a_flutter_test_s_bag_replays_without_modal_or_shape_views_it_has_no_data_for(tmp_path: Path) -> None:
    """A flutter test records what a tunnel measures (tip, airspeed, commands, the monitor), no modal states and no
    panel shapes. Its `analyze --rerun` drew a modal coordinate "q1" at exactly zero (made up by the replay) and
    an empty panel-shape view; both views are now left out, and no modal entity is logged."""
    from panel_rig.analyze_cli import analyze_bag
    from panel_rig.config import load_config
    from panel_rig.flutter_cli import run_in_process

    run_in_process(load_config(), bag_dir=tmp_path / "bags", dwell_s=20.0, settle_s=1.0, max_points=1)
    (bag,) = (tmp_path / "bags").iterdir()
    analyze_bag(bag, rerun_path=tmp_path / "replay.rrd")
    rows = _temporal(tmp_path / "replay.rrd")
    views = _views(tmp_path / "replay.rrd")
    assert rows["/tip/w_over_L"] and rows["/airspeed/mps"]
    assert not any(entity.startswith("/modal") for entity in rows), sorted(rows)
    assert not any(name.startswith(("Modal", "Panel shape")) for name in views), sorted(views)
    assert "Tip deflection w/L" in views


def test_monitor_logs_the_zw_flutter_margin_of_each_point_with_both_modes(tmp_path: Path) -> None:
    """The PNG's ZW panel (flutter margin F per point) had no Rerun counterpart: a point with both modes
    identified logs its F in Hz^4 under flutter/zw_margin_hz4 in a view of its own; a point without the first
    mode logs none, nor one whose first mode was identified with damping <= 0 (a failed identification the ZW
    predictor leaves out: the view showed F = -2700 Hz^4, "fluttering", at a stable point of the reference bag)."""
    from panel_rig.analysis.flutter_margin import flutter_margins

    s = FlutterTestSettings(start_mps=5.0, step_mps=2.0, margin=0.1, min_damping=0.0)
    pts = []
    for u in SPEEDS:
        p = _point(u)
        first = None if u == SPEEDS[1] else ModalEstimate(5.0 + 0.8 * u, 0.05, 0.01, 1e-3, 9, "synthetic")
        if u == SPEEDS[2]:
            first = ModalEstimate(5.0 + 0.8 * u, -0.02, 0.01, 1e-3, 9, "synthetic")
        pts.append(TestPoint(u, first, p.flutter, p.method))
    path = tmp_path / "zw.rrd"
    log = RerunLogger(3, mode="save", target=str(path), views=("flutter", "flutter_uf", "flutter_zw"))
    for k in range(1, len(pts) + 1):
        log.log_flutter_point(10.0 * k, pts[:k], decide(pts[:k], s), 0.1)
    log.close()
    both = [p for p in pts if p.first is not None and p.first.damping_ratio > 0]
    expected = flutter_margins([p.first for p in both], [p.flutter for p in both]) / (2 * np.pi) ** 4
    rows = _temporal(path)["/flutter/zw_margin_hz4/point"]
    assert [_scalar(r) for r in rows] == pytest.approx(expected, rel=1e-12)
    assert len(rows) == len(SPEEDS) - 2 and np.all(np.diff(expected) < 0)  # F falls toward flutter
    assert _views(path)["ZW flutter margin F per point (Hz^4; flutter where it reaches 0)"] == "/flutter/zw_margin_hz4"


def _time_axes(path: Path) -> dict[str, bool]:
    """Time-series view name -> whether the blueprint sets its time axis to the whole recording."""
    reader = RrdReader(path)
    names: dict[str, str] = {}
    whole: set[str] = set()
    for chunk in reader.stream(store=reader.blueprints()[0]).to_chunks():
        batch = chunk.to_record_batch()
        entity = str(chunk.entity_path)
        if "ViewBlueprint:class_identifier" in batch.schema.names:
            if batch.column("ViewBlueprint:class_identifier").to_pylist()[-1][0] != "TimeSeries":
                continue
        if "ViewBlueprint:display_name" in batch.schema.names:
            names[entity] = batch.column("ViewBlueprint:display_name").to_pylist()[-1][0]
        if "TimeAxis:view_range" in batch.schema.names:
            whole.add(entity.rsplit("/TimeAxis", 1)[0])
    return {name: entity in whole for entity, name in names.items()}


READINGS_VIEWS = ("Tip deflection w/L", "Modal coordinates q1..q3", "Airspeed (m/s)", "Shaker force (N/m)")
MONITOR_VIEWS = ("Flutter monitor", "Flutter margin", "Flutter mode: damping ratio x 1000 (95 %)")


def test_a_saved_file_shows_the_whole_test_and_a_live_stream_follows_the_cursor(monitor_rrd, tmp_path) -> None:
    """One sample per test point, minutes apart: in the viewer's default window at the time cursor the monitor's
    views showed the last point or two (the whole test is ~20 simulated minutes), and a saved run's readings only
    its last minute. In a saved file every time-series view is set to the whole recording; in a live stream the
    readings' views keep the viewer's window at the cursor, the monitor's views still show the whole test."""
    from panel_rig.viz.logger import blueprint

    saved = _time_axes(monitor_rrd[0])
    assert sorted(saved) == sorted([*READINGS_VIEWS, *(n for n in saved if n.startswith(MONITOR_VIEWS))])
    assert len(saved) == 7 and all(saved.values()), saved  # U_f, margin, damping (no ZW view asked for)
    blueprint(3, ("flutter", "flutter_uf", "control")).save("panel_rig", tmp_path / "live.rbl")
    live = _time_axes(tmp_path / "live.rbl")
    assert len(live) == 9, live  # the readings' four, the control's two, the monitor's three
    assert {n for n, w in live.items() if w} == {n for n in live if n.startswith(MONITOR_VIEWS)}
