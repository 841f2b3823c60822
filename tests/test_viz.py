"""Rerun logger: a saved .rrd holds the expected entities, rows and blueprint."""

from __future__ import annotations

import os
import subprocess
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest

pytest.importorskip("rerun")

from rerun.chunk import RrdReader

from panel_rig.rig.reading import Reading
from panel_rig.viz import RerunLogger, VizError

N_MODES = 3
N_LIVE = 40  # per-sample readings
N_BATCH = 250  # columnar samples
N_SHAPES = 5
SERIES = ["/tip/w_over_L", "/airspeed/mps", "/shaker/force_npm"] + [
    f"/modal/q{i}" for i in range(1, N_MODES + 1)
]


def _reading(k: int) -> Reading:
    t = 0.01 * k
    q = np.array([np.sin(t), 0.1 * np.cos(t), 0.01 * t])
    return Reading(
        time_s=t, airspeed_mps=25.0, shaker_force_npm=0.3 * np.sin(20 * t), tip_w_m=1e-3 * q[0],
        tip_w_over_L=2e-3 * q[0], q=q, qdot_per_s=np.zeros(3), aero_force_npm=np.zeros(3),
    )


def _row_counts(path: Path) -> tuple[Counter, Counter]:
    """(temporal rows, static rows) per entity path in the file's recording store."""
    temporal: Counter = Counter()
    static: Counter = Counter()
    for chunk in RrdReader(path).stream().to_chunks():
        (static if chunk.is_static else temporal)[str(chunk.entity_path)] += chunk.num_rows
    return temporal, static


@pytest.fixture(scope="module")
def rrd(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rrd") / "run.rrd"
    logger = RerunLogger(N_MODES, mode="save", target=str(path), recording_name="test run")
    for k in range(N_LIVE):
        logger.log_reading(_reading(k))
    t = 1.0 + np.arange(N_BATCH) / 500.0
    q = np.column_stack([np.sin(t), np.cos(t), t])
    logger.log_batch(t, 0.01 * np.sin(t), q, np.full(N_BATCH, 30.0), np.zeros(N_BATCH))
    x = np.linspace(-0.2, 1.0, 30)
    for k in range(N_SHAPES):
        logger.log_shape(0.1 * k, x, 1e-3 * k * np.clip(x, 0.0, None) ** 2)
    logger.close()
    logger.close()  # idempotent
    return path


def test_entities_and_row_counts(rrd: Path) -> None:
    temporal, static = _row_counts(rrd)
    for entity in SERIES:
        assert temporal[entity] == N_LIVE + N_BATCH, entity
        assert static[entity] == 1, entity  # SeriesLines style
    assert temporal["/panel/shape"] == N_SHAPES


def test_values_timeline_and_blueprint(rrd: Path) -> None:
    reader = RrdReader(rrd)
    assert len(reader.recordings()) == 1 and len(reader.blueprints()) == 1
    store = reader.store()
    schema = str(store.schema())
    assert "timeline:sim_time" in schema
    assert "/panel/shape:LineStrips3D:strips" in schema
    assert "/modal/q2:SeriesLines:names" in schema
    batch_chunks = [
        c for c in reader.stream().to_chunks()
        if str(c.entity_path) == "/modal/q3" and c.num_rows == N_BATCH
    ]
    assert len(batch_chunks) == 1
    batch = batch_chunks[0].to_record_batch()
    name = next(n for n in batch.schema.names if "scalars" in n.lower())
    scalars = [row[0] for row in batch.column(name).to_pylist()]
    assert scalars[:3] == pytest.approx(1.0 + np.arange(3) / 500.0)
    times_ns = next(batch.column(n) for n in batch.schema.names if "sim_time" in n)
    assert times_ns.cast("int64").to_pylist()[-1] == pytest.approx((1.0 + 249 / 500.0) * 1e9, abs=2)


def _static_aggregation(path: Path) -> dict[str, list]:
    """Entity path -> the static `SeriesLines:aggregation_policy` values (enum ints) in the file."""
    out: dict[str, list] = {}
    for chunk in RrdReader(path).stream().to_chunks():
        if not chunk.is_static:
            continue
        batch = chunk.to_record_batch()
        if "SeriesLines:aggregation_policy" in batch.schema.names:
            rows = batch.column("SeriesLines:aggregation_policy").to_pylist()
            out.setdefault(str(chunk.entity_path), []).extend(v for row in rows for v in row)
    return out


def test_series_keep_their_envelope_when_zoomed_out(rrd: Path) -> None:
    """Finding 10: Rerun's default zoom aggregation (average) flattens an LCO; the oscillating series use MinMax."""
    import rerun as rr

    minmax = rr.components.AggregationPolicy.MinMax.value
    policies = _static_aggregation(rrd)
    for entity in ["/tip/w_over_L", "/shaker/force_npm"] + [f"/modal/q{i}" for i in range(1, N_MODES + 1)]:
        assert policies.get(entity) == [minmax], entity


def test_rrd_verify_cli(rrd: Path) -> None:
    rerun_bin = Path(sys.executable).with_name("rerun")
    if not rerun_bin.exists():
        pytest.skip("rerun CLI not installed")
    proc = subprocess.run(
        [str(rerun_bin), "rrd", "verify", str(rrd)],
        check=False, capture_output=True, text=True, timeout=60,
    )
    assert proc.returncode == 0, proc.stderr


def test_off_mode_writes_nothing(tmp_path: Path) -> None:
    target = tmp_path / "never.rrd"
    logger = RerunLogger(N_MODES, mode="off", target=str(target))
    assert not logger.enabled
    logger.log_reading(_reading(1))
    logger.log_batch(np.arange(3.0), np.zeros(3), np.zeros((3, 3)), np.zeros(3), np.zeros(3))
    logger.log_shape(0.0, np.arange(3.0), np.zeros(3))
    logger.close()
    assert list(tmp_path.iterdir()) == []


def test_bad_configuration_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(VizError, match="mode"):
        RerunLogger(N_MODES, mode="live", target=None)
    with pytest.raises(VizError, match="target"):
        RerunLogger(N_MODES, mode="save", target=None)
    (tmp_path / "a_file").write_text("")
    with pytest.raises(VizError, match="a_file is a file"):
        RerunLogger(N_MODES, mode="save", target=str(tmp_path / "a_file" / "x.rrd"))
    logger = RerunLogger(N_MODES, mode="save", target=str(tmp_path / "new" / "ok.rrd"))  # its directory is made
    try:
        with pytest.raises(VizError, match="samples"):
            logger.log_batch(np.arange(3.0), np.zeros(2), np.zeros((3, 3)), np.zeros(3), np.zeros(3))
        with pytest.raises(VizError, match="points"):
            logger.log_shape(0.0, np.arange(3.0), np.zeros(4))
    finally:
        logger.close()
    assert (tmp_path / "new" / "ok.rrd").stat().st_size > 0


def _blueprints(path: Path) -> list[list[tuple[str, dict[str, Any]]]]:
    """Each blueprint the file holds, as (entity path without the leading "/", {component: its last value})
    per chunk."""
    reader = RrdReader(path)
    out = []
    for store in reader.blueprints():
        rows = []
        for chunk in reader.stream(store=store).to_chunks():
            batch = chunk.to_record_batch()
            rows.append((str(chunk.entity_path).lstrip("/"),
                         {n: batch.column(n).to_pylist()[-1] for n in batch.schema.names if ":" in n}))
        out.append(rows)
    return out


def _view_names(blueprint: list[tuple[str, dict[str, Any]]]) -> dict[str, str]:
    """View entity path -> display name, in one blueprint of :func:`_blueprints`."""
    return {entity: values["ViewBlueprint:display_name"][0] for entity, values in blueprint
            if "ViewBlueprint:display_name" in values}


def _blueprint_views(path: Path) -> list[set[str]]:
    """The view names of each blueprint the file holds."""
    return [set(_view_names(bp).values()) for bp in _blueprints(path)]


@pytest.mark.parametrize("controlled", [False, True], ids=["no controller", "controller"])
def test_control_views_join_the_layout_with_the_first_command(tmp_path: Path, controlled: bool) -> None:
    """A node's file showed two empty control plots when no controller ran (most runs); they now join the layout
    (a second, active blueprint) when the first control command is logged, and only then."""
    path = tmp_path / "run.rrd"
    logger = RerunLogger(N_MODES, mode="save", target=str(path), views=(), control_views_on_data=True)
    for k in range(N_LIVE):
        logger.log_reading(_reading(k))
        if controlled and k >= 10:
            logger.log_control(0.01 * k, 0.1, 2.0)
        logger.flush_blocks()
    logger.close()
    control = {"Control command (N/m)", "Control command age (ms)"}
    layouts = _blueprint_views(path)
    assert all("Tip deflection w/L" in names for names in layouts)
    assert len(layouts) == (2 if controlled else 1)
    assert sum(control <= names for names in layouts) == (1 if controlled else 0)
    temporal, _ = _row_counts(path)
    assert temporal["/control/command_npm"] == (N_LIVE - 10 if controlled else 0)


def _left_column_shares(path: Path) -> list[dict[str, float]]:
    """Per blueprint in the file: time-series view name -> its row share in the layout's left column."""
    out = []
    for bp in _blueprints(path):
        names = _view_names(bp)
        columns = [(v["ContainerBlueprint:contents"], v["ContainerBlueprint:row_shares"]) for _, v in bp
                   if "ContainerBlueprint:row_shares" in v and "ContainerBlueprint:contents" in v]
        left = [(ids, shares) for ids, shares in columns if any("Tip" in names.get(i, "") for i in ids)]
        assert len(left) == 1, columns
        ids, shares = left[0]
        out.append({names[i]: s for i, s in zip(ids, shares)})
    return out


def test_the_tip_plot_is_twice_as_tall_as_each_other_plot(tmp_path: Path) -> None:
    """The viewer labels a plot's y axis only at powers of ten far enough apart on screen: the demo's LCO (tip w/L
    +-0.65) in a third of a 720-pixel window showed the label "0" alone. The tip gets two shares of the left
    column, in the first layout and in the one the control views join."""
    path = tmp_path / "run.rrd"
    logger = RerunLogger(N_MODES, mode="save", target=str(path), views=(), control_views_on_data=True)
    for k in range(N_LIVE):
        logger.log_reading(_reading(k))
        if k >= 10:
            logger.log_control(0.01 * k, 0.1, 2.0)
        logger.flush_blocks()
    logger.close()
    layouts = _left_column_shares(path)
    assert sorted(len(shares) for shares in layouts) == [4, 6]  # the file's blueprints come in no fixed order
    for shares in layouts:
        assert shares.pop("Tip deflection w/L") == 2.0
        assert set(shares.values()) == {1.0}, shares


def test_operator_commands_are_markers_beside_what_they_set(tmp_path: Path) -> None:
    """A bag's replay draws the held shaker force only (the sine generator's output is not recorded): a shaker tap
    showed nowhere. The accepted set-point, sine amplitude and held-force commands are markers in the airspeed's
    and the shaker's views, live and replayed; a refused command is not drawn. The two views are apart: on one y
    axis a tap's 0.05 N/m markers lay flat under the 5-12 m/s airspeed."""
    path = tmp_path / "run.rrd"
    logger = RerunLogger(N_MODES, mode="save", target=str(path), views=())
    logger.log_reading(_reading(0))
    logger.on_command("airspeed_cmd", 9.0, True, 0.5)
    logger.on_command("shaker/amplitude_cmd", 0.3, True, 1.0)
    logger.on_command("shaker/amplitude_cmd", 0.0, True, 1.5)
    logger.on_command("shaker/force_cmd", 1e9, False, 1.6)
    logger.close()
    temporal, _ = _row_counts(path)
    assert temporal["/commands/airspeed_cmd"] == 1 and temporal["/commands/shaker/amplitude_cmd"] == 2
    assert temporal["/commands/shaker/force_cmd"] == 0
    markers = {str(c.entity_path) for c in RrdReader(path).stream().to_chunks()
               if c.is_static and "SeriesPoints:names" in c.to_record_batch().schema.names}
    assert {"/commands/airspeed_cmd", "/commands/shaker/amplitude_cmd", "/commands/shaker/force_cmd"} <= markers
    (blueprint,) = _blueprints(path)
    air = next(v["ViewContents:query"] for _, v in blueprint if "airspeed/**" in v.get("ViewContents:query", []))
    shaker = next(v["ViewContents:query"] for _, v in blueprint if "shaker/**" in v.get("ViewContents:query", []))
    assert "commands/airspeed_cmd" in air and not any(q.startswith(("shaker", "commands/shaker")) for q in air)
    assert {"commands/shaker/amplitude_cmd", "commands/shaker/force_cmd"} <= set(shaker)
    assert not any(q.startswith(("airspeed", "commands/airspeed")) for q in shaker)


def _columns(path: Path) -> list[list[set[str]]]:
    """Per blueprint in the file: the view names of each container that holds views directly."""
    out = []
    for bp in _blueprints(path):
        names = _view_names(bp)
        out.append([{names[i] for i in v["ContainerBlueprint:contents"] if i in names} for _, v in bp
                    if "ContainerBlueprint:contents" in v])
    return [[c for c in columns if c] for columns in out]


def test_the_flutter_monitor_has_a_column_of_its_own(tmp_path: Path) -> None:
    """Below the readings, seven plots shared one column: a flutter test's tip response (~1e-4 L) and its damping
    per point got no y-axis numbers (the viewer's labels need room). The monitor's plots now stand in a column of
    their own, the readings keep theirs (tip twice as tall), and a run without the monitor keeps two columns."""
    with_monitor = tmp_path / "flutter.rrd"
    logger = RerunLogger(N_MODES, mode="save", target=str(with_monitor), views=("flutter", "flutter_uf",
                                                                                "flutter_zw"))
    logger.close()
    columns = _columns(with_monitor)[0]
    readings = next(c for c in columns if "Tip deflection w/L" in c)
    monitor = next(c for c in columns if any(name.startswith("Flutter margin") for name in c))
    assert len(readings) == 4 and not any("lutter" in name or "ZW" in name for name in readings), readings
    assert len(monitor) == 4 and all("lutter" in name or "ZW" in name for name in monitor), monitor
    assert _left_column_shares(with_monitor)[0]["Tip deflection w/L"] == 2.0
    without = tmp_path / "run.rrd"
    RerunLogger(N_MODES, mode="save", target=str(without), views=()).close()
    assert len(_columns(without)[0]) == 2


def test_a_live_viewer_that_is_absent_is_refused_at_the_start() -> None:
    """rerun connects lazily: `rerun:=connect:URL` with no viewer there started, then held the node's stop forever
    (its flush timeout is not kept when the stream cannot deliver). The viewer's port is tried first."""
    import socket

    from panel_rig.viz.logger import viewer_problem

    with socket.socket() as listening:
        listening.bind(("127.0.0.1", 0))
        listening.listen(1)
        port = listening.getsockname()[1]
        assert viewer_problem(f"rerun+http://127.0.0.1:{port}/proxy") is None
    said = viewer_problem(f"rerun+http://127.0.0.1:{port}/proxy")  # closed now: refused
    assert said is not None and said.startswith(f"no Rerun viewer at rerun+http://127.0.0.1:{port}/proxy (")
    assert "save:PATH.rrd" in said
    with pytest.raises(VizError, match="no Rerun viewer at"):
        RerunLogger(N_MODES, mode="connect", target=f"rerun+http://127.0.0.1:{port}/proxy")


HUNG_VIEWER = """
import socket, sys, threading, time
import numpy as np
from panel_rig.viz import RerunLogger, VizError
from panel_rig.viz import logger
logger.FLUSH_TIMEOUT_S["connect"], logger.DISCONNECT_GRACE_S = 1.0, 1.0
srv = socket.socket(); srv.bind(("127.0.0.1", 0)); srv.listen(8)
held = []
threading.Thread(target=lambda: [held.append(srv.accept()[0]) for _ in iter(int, 1)], daemon=True).start()
lg = RerunLogger(3, mode="connect", target=f"rerun+http://127.0.0.1:{srv.getsockname()[1]}/proxy")
t0, slowest, k = time.monotonic(), 0.0, 0
while lg.dropped_batches == 0 and time.monotonic() - t0 < 90:  # until rerun's buffers are full and the queue too
    t = 10 * k + np.arange(10000) * 1e-3
    t1 = time.monotonic()
    lg.log_batch(t, np.sin(t), np.zeros((t.size, 3)), np.ones(t.size), np.zeros(t.size))
    slowest, k = max(slowest, time.monotonic() - t1), k + 1
print("slowest", slowest, flush=True)
print("logged", k, lg.dropped_batches, flush=True)
try:
    lg.close()
except VizError as exc:
    print("close:", exc, flush=True)
print("closed", time.monotonic() - t0, flush=True)
"""


def test_a_viewer_that_takes_no_data_neither_stops_the_logging_nor_the_exit() -> None:
    """A viewer that accepted the connection and then took no data (frozen, suspended) froze a fast node 30 s into
    its run inside rerun's send_columns: no Ctrl-C, no closed bag. The calls now go through a queue to a thread of
    their own: logging goes on (what does not fit is dropped, and counted), the close gives up after its timeout
    with one error, and the process exits."""
    proc = subprocess.run([sys.executable, "-c", HUNG_VIEWER], capture_output=True, text=True, timeout=120,
                          cwd=Path(__file__).resolve().parents[1])
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = dict(line.split(" ", 1) for line in proc.stdout.splitlines() if " " in line)
    assert int(lines["logged"].split()[1]) > 0, proc.stdout  # the viewer stopped taking data: jobs were dropped
    assert float(lines["slowest"]) < 2.0, proc.stdout  # no call waited for it (rerun's own wait is forever)
    said = lines["close:"]
    assert "took no data for 2 s; gave up" in said and "batches dropped while the viewer took no data" in said, said
    assert float(lines["closed"].split()[-1]) < 120, proc.stdout


def test_rerun_s_own_log_lines_have_no_colour_codes_off_a_terminal(monkeypatch) -> None:
    """A node's log file had rerun's Rust warnings as escape sequences (ESC[33m WARN ESC[0m): off a terminal the
    standard NO_COLOR is set before rerun logs; a user's own NO_COLOR is kept."""
    from panel_rig.viz.logger import plain_rust_logs

    class Pipe:
        def isatty(self) -> bool:
            return False

    monkeypatch.delenv("NO_COLOR", raising=False)
    monkeypatch.setattr(sys, "stderr", Pipe())
    plain_rust_logs()
    assert os.environ["NO_COLOR"] == "1"
    monkeypatch.setenv("NO_COLOR", "yes")
    plain_rust_logs()
    assert os.environ["NO_COLOR"] == "yes"
