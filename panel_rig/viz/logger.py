"""`RerunLogger`: the rig's time series and panel shape in Rerun (live viewer or `.rrd` file).

Uses its own `rr.RecordingStream` (never the global one), so several loggers can coexist.
All data is on the duration timeline `sim_time` (simulated seconds).
"""

from __future__ import annotations

import os
import socket
import sys
import threading
import time
from collections.abc import Collection
from typing import TYPE_CHECKING, Any

import numpy as np

from panel_rig.paths import prepare_rrd_path
from panel_rig.topics import CONTROL_TOPIC
from panel_rig.viz.sender import QueuedStream, one_job

if TYPE_CHECKING:
    from panel_rig.rig.reading import Reading, ReadingBlock

MODES = ("off", "save", "connect")
TIMELINE = "sim_time"
TIP = "tip/w_over_L"
AIRSPEED = "airspeed/mps"
FORCE = "shaker/force_npm"
SHAPE = "panel/shape"
CONTROL_CMD = "control/command_npm"
CONTROL_AGE = "control/latency_ms"
#: the accepted operator commands drawn as markers beside the airspeed and shaker force they set (N/m, m/s): in a
#: bag's replay the force line is only the held force (the sine generator's output is not recorded), so the
#: amplitude markers are what shows a shaker tap there
COMMAND_MARKERS = {
    "commands/airspeed_cmd": ("airspeed set-point m/s", [0, 90, 0]),
    "commands/shaker/amplitude_cmd": ("shaker sine amplitude N/m", [255, 127, 14]),
    "commands/shaker/force_cmd": ("shaker held force N/m", [140, 86, 75]),
}
AIRSPEED_MARKERS = [k for k in COMMAND_MARKERS if not k.startswith("commands/shaker/")]
SHAKER_MARKERS = [k for k in COMMAND_MARKERS if k.startswith("commands/shaker/")]
# the flutter monitor: predicted U_f (and its interval, m/s), the margin (unitless: its own view) and the
# identified damping (x 1000, 95 % interval) vs time, one sample per test point; damping vs airspeed (2-D)
FLUTTER_UF = "flutter/predicted_uf_mps"
FLUTTER_MARGIN = "flutter/margin"
FLUTTER_DAMPING = "flutter/damping_x1000"
# the Zimmerman-Weissenburger flutter margin F of each point with both modes identified, Hz^4 (flutter at F = 0)
FLUTTER_ZW = "flutter/zw_margin_hz4"
FLUTTER_VG = "flutter_vg"
# an analysis of a recording (`panel-rig analyze --rerun`): plateau status and the flutter onset as text logs
ANALYSIS = "analysis"
#: the optional views; a recording's blueprint shows only those it has data for
OPTIONAL_VIEWS = ("control", "flutter", "flutter_uf", "flutter_zw", "analysis")
DEFAULT_GRPC_URL = "rerun+http://127.0.0.1:9876/proxy"
#: how long close() waits for the last data to reach the viewer or the .rrd file (s)
FLUSH_TIMEOUT_S = {"connect": 5.0, "save": 60.0}
DISCONNECT_GRACE_S = 6.0  # beyond the flush's timeout: rerun's own 5 s for a last connection attempt
VIEWER_PROBE_TIMEOUT_S = 2.0  # a viewer's gRPC port must accept a connection within this at the start
_ABANDONED: list[Any] = []  # recording streams whose flush never returned (see RerunLogger.close)
# How a time-series view draws the samples that share a pixel when zoomed out. Rerun's default is the
# average, which flattens an oscillation (an LCO of tip w/L +-1.2 shows as about +-0.2); min/max keeps
# its envelope at any zoom.
AGGREGATION = "MinMax"
#: the tip plot's height against each other time-series plot of the layout
TIP_ROW_SHARE = 2


#: name and colour of the flutter monitor's series; each sample (one per test point) is a marker too, so a
#: series with a single sample so far is drawn
FLUTTER_STYLES = {
    f"{FLUTTER_UF}/estimate": ("predicted U_f m/s", [214, 39, 40]),
    f"{FLUTTER_UF}/ci_low": ("95 % low m/s", [255, 152, 150]),
    f"{FLUTTER_UF}/ci_high": ("95 % high m/s", [255, 152, 150]),
    f"{FLUTTER_UF}/damping_trend": ("damping trend U_f m/s", [255, 127, 14]),
    f"{FLUTTER_UF}/zw": ("ZW flutter margin U_f m/s", [44, 160, 44]),
    f"{FLUTTER_MARGIN}/current": ("margin 1 - U/U_f", [31, 119, 180]),
    f"{FLUTTER_MARGIN}/required": ("required margin", [0, 0, 0]),
    f"{FLUTTER_DAMPING}/identified": ("damping x 1000", [31, 119, 180]),
    f"{FLUTTER_DAMPING}/ci_low": ("95 % low", [174, 199, 232]),
    f"{FLUTTER_DAMPING}/ci_high": ("95 % high", [174, 199, 232]),
    f"{FLUTTER_ZW}/point": ("ZW flutter margin F Hz^4", [44, 160, 44]),
}


class VizError(RuntimeError):
    """The Rerun sink cannot be set up; the message says why."""


def modal_entity(i: int) -> str:
    """Entity path of modal coordinate q_i (1-based)."""
    return f"modal/q{i}"


def blueprint(n_modes: int, views: Collection[str] = OPTIONAL_VIEWS, *, whole_run: bool = False,
              shape: bool = True) -> Any:
    """Default layout: tip, modal (none when ``n_modes`` is 0), airspeed+shaker time series, the panel shape in 3-D
    (unless ``shape`` is false: a recording without shapes), and of
    `OPTIONAL_VIEWS` those in ``views``: control command and age, the flutter monitor (margin, damping vs time
    and damping vs airspeed), its predicted U_f (there only once a prediction is made), its ZW flutter margin per
    point (points with both modes identified), the analysis text log.

    ``whole_run``: the readings' and control views show the whole recording (a saved file, looked at afterwards)
    instead of the viewer's window that follows the time cursor (a live stream). The flutter monitor's views always
    show the whole test."""
    import rerun.blueprint as rrb

    unknown = set(views) - set(OPTIONAL_VIEWS)
    if unknown:
        raise VizError(f"unknown views {sorted(unknown)}; optional views are {OPTIONAL_VIEWS}")
    whole = rrb.TimeAxis(view_range=rrb.TimeRange(start=rrb.TimeRangeBoundary.infinite(),
                                                  end=rrb.TimeRangeBoundary.infinite()))
    readings_axis = whole if whole_run else None
    series = [
        rrb.TimeSeriesView(origin="tip", name="Tip deflection w/L", axis_x=readings_axis),
        *([rrb.TimeSeriesView(origin="modal", name=f"Modal coordinates q1..q{n_modes}", axis_x=readings_axis)]
          if n_modes else []),
        # airspeed and shaker apart: on one y axis the taps' 0.05 N/m markers lay flat under the 5-12 m/s airspeed
        rrb.TimeSeriesView(origin="/", contents=["airspeed/**", *AIRSPEED_MARKERS], name="Airspeed (m/s)",
                           axis_x=readings_axis),
        rrb.TimeSeriesView(origin="/", contents=["shaker/**", *SHAKER_MARKERS], name="Shaker force (N/m)",
                           axis_x=readings_axis),
    ]
    if "control" in views:
        series += [rrb.TimeSeriesView(origin="/", contents=[CONTROL_CMD], name="Control command (N/m)",
                                      axis_x=readings_axis),
                   rrb.TimeSeriesView(origin="/", contents=[CONTROL_AGE], name="Control command age (ms)",
                                      axis_x=readings_axis)]
    monitor: list[Any] = []
    if "flutter" in views:
        # one sample per test point (minutes apart): the whole test in view, not the viewer's window at the cursor
        if "flutter_uf" in views:
            monitor.append(rrb.TimeSeriesView(
                origin=FLUTTER_UF, name="Flutter monitor: predicted U_f and 95 % interval; each predictor (m/s)",
                axis_x=whole))
        monitor += [
            rrb.TimeSeriesView(origin=FLUTTER_MARGIN, name="Flutter margin 1 - U/U_f and required (unitless)",
                               axis_x=whole),
            rrb.TimeSeriesView(origin=FLUTTER_DAMPING, name="Flutter mode: damping ratio x 1000 (95 %) per point",
                               axis_x=whole),
        ]
        if "flutter_zw" in views:
            monitor.append(rrb.TimeSeriesView(
                origin=FLUTTER_ZW, name="ZW flutter margin F per point (Hz^4; flutter where it reaches 0)",
                axis_x=whole))
    # Side view of the x-z plane (chord along x, deflection up along z), framing about 1 m.
    eye = rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital, position=[0.35, -2.5, 0.3], look_target=[0.35, 0.0, 0.0],
        eye_up=[0.0, 0.0, 1.0],
    )
    right: list[Any] = []
    if shape:
        right.append(rrb.Spatial3DView(origin="panel", name="Panel shape (x chord, z deflection)", eye_controls=eye))
    if "flutter" in views:
        right.append(rrb.Spatial2DView(origin=FLUTTER_VG,
                                       name="Flutter mode: damping ratio x 1000 (up) vs airspeed (m/s)"))
    if "analysis" in views:
        right.append(rrb.TextLogView(origin=ANALYSIS, name="Analysis: plateau status and flutter onset"))
    # The tip gets twice the height of each other plot: the viewer labels its y axis only at powers of ten far
    # enough apart on screen, and an LCO of tip w/L +-0.65 in a third of a 720-pixel window got the label "0" alone.
    # For the same reason the flutter monitor's plots get a column of their own: below the readings, seven plots
    # shared one column and the tip's random response and the damping per point had no y-axis numbers at all.
    left = rrb.Vertical(*series, row_shares=[TIP_ROW_SHARE] + [1] * (len(series) - 1))
    columns, shares = [left], [3]
    if monitor:
        columns, shares = [*columns, rrb.Vertical(*monitor)], [*shares, 2]
    if right:
        columns, shares = [*columns, rrb.Vertical(*right)], [*shares, 2]
    return rrb.Blueprint(rrb.Horizontal(*columns, column_shares=shares), collapse_panels=True)


def plain_rust_logs() -> None:
    """rerun's own (Rust) log lines without colour codes when stderr is no terminal: a node's log file had them as
    escape sequences. Read when rerun first logs, from the standard ``NO_COLOR``; one already set is kept."""
    if not sys.stderr.isatty():
        os.environ.setdefault("NO_COLOR", "1")


def viewer_problem(url: str, timeout_s: float = VIEWER_PROBE_TIMEOUT_S) -> str | None:
    """Why no Rerun viewer takes connections at gRPC ``url`` (``rerun+http://HOST:PORT/proxy``), or None. Unparsed
    URLs are left to rerun (None)."""
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(url.removeprefix("rerun+"))
        host, port = parts.hostname, parts.port or (443 if parts.scheme == "https" else 80)
    except ValueError:
        return None
    if not host:
        return None
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return None
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        return (f"no Rerun viewer at {url} ({reason.lower()}): start one first (`rerun`), or write a file "
                "(save:PATH.rrd)")


class RerunLogger:
    """Log readings, batches and panel shapes to Rerun. Mode "off" does nothing at all."""

    def __init__(
        self,
        n_modes: int,
        *,
        mode: str,
        target: str | None,
        application_id: str = "panel_rig",
        recording_name: str | None = None,
        batch_period_s: float = 0.1,
        views: Collection[str] = OPTIONAL_VIEWS,
        control_views_on_data: bool = False,
        shape: bool = True,
    ) -> None:
        """``n_modes``: the modal coordinates logged (0: none, no modal view). ``views``: the optional views of the
        layout (:func:`blueprint`). ``control_views_on_data``: the control views join the layout when the first
        control command is logged (a node, where a controller may or may not connect: two empty plots otherwise).
        ``shape``: the layout has the panel-shape view (false for a recording without shapes)."""
        if mode not in MODES:
            raise VizError(f"rerun mode must be one of {MODES}, got {mode!r}")
        if not isinstance(n_modes, int) or isinstance(n_modes, bool) or n_modes < 0:
            raise VizError(f"n_modes must be an int >= 0, got {n_modes!r}")
        self.n_modes = n_modes
        self.mode = mode
        self.target = target
        self.batch_period_s = float(batch_period_s)
        self._pending: list[ReadingBlock] = []
        self._pending_shapes: list[tuple[float, np.ndarray]] = []
        self._pending_control: list[tuple[float, float, float]] = []
        self._pending_since = time.monotonic()
        self._rec: Any = None
        self._views = tuple(views)
        self._shape = shape
        self._control_views_on_data = control_views_on_data and "control" not in self._views
        if mode == "off":
            return
        plain_rust_logs()
        import rerun as rr

        self._rr = rr
        rec = rr.RecordingStream(application_id, send_properties=True)
        bp = self._blueprint()
        if mode == "save":
            rec.save(self._save_path(target), default_blueprint=bp)
        else:
            url = target or DEFAULT_GRPC_URL
            problem = viewer_problem(url)  # rerun connects lazily: an absent viewer held the node's stop forever
            if problem is not None:
                raise VizError(problem)
            try:
                rec.connect_grpc(url, default_blueprint=bp)
            except Exception as exc:  # noqa: BLE001 - rerun raises various types for bad URLs
                raise VizError(f"cannot connect to Rerun viewer at {target}: {exc}") from None
        # a live viewer is fed from a thread of its own: one that stops taking data never stops the caller
        self._rec = QueuedStream(rec) if mode == "connect" else rec
        if recording_name:
            self._rec.send_recording_name(recording_name)
        self.views_with_flutter = "flutter" in views
        self._log_styles()

    def _blueprint(self) -> Any:
        return blueprint(self.n_modes, self._views, whole_run=self.mode == "save", shape=self._shape)

    @one_job
    def _add_control_views(self) -> None:
        """The first control command: the layout gains the control views (sent as the active blueprint)."""
        self._views += ("control",)
        self._control_views_on_data = False
        self._rec.send_blueprint(self._blueprint(), make_active=True, make_default=True)

    # ----------------------------------------------------------------- public API
    @property
    def enabled(self) -> bool:
        return self._rec is not None

    @property
    def dropped_batches(self) -> int:
        """Logging calls a live viewer's queue had no room for (it was not taking data); 0 for a file."""
        return self._rec.dropped if isinstance(self._rec, QueuedStream) else 0

    @one_job
    def log_reading(self, reading: Reading) -> None:
        """Log one rig sample at `reading.time_s`."""
        if self._rec is None:
            return
        rr, rec = self._rr, self._rec
        rec.set_time(TIMELINE, duration=float(reading.time_s))
        rec.log(TIP, rr.Scalars(float(reading.tip_w_over_L)))
        for i, value in enumerate(np.asarray(reading.q, dtype=float)[: self.n_modes], start=1):
            rec.log(modal_entity(i), rr.Scalars(float(value)))
        rec.log(AIRSPEED, rr.Scalars(float(reading.airspeed_mps)))
        rec.log(FORCE, rr.Scalars(float(reading.shaker_force_npm)))

    @one_job
    def log_batch(
        self,
        times_s: np.ndarray,
        tip: np.ndarray,
        q: np.ndarray,
        airspeed: np.ndarray,
        force: np.ndarray,
    ) -> None:
        """Log N samples at once (columnar). `q` has shape (N, n_modes); the rest shape (N,)."""
        if self._rec is None:
            return
        times = np.asarray(times_s, dtype=float).reshape(-1)
        n = times.size
        q_arr = np.asarray(q, dtype=float).reshape(n, -1) if n else np.zeros((0, self.n_modes))
        columns = {TIP: tip, AIRSPEED: airspeed, FORCE: force}
        for name, values in columns.items():
            if np.asarray(values).reshape(-1).size != n:
                raise VizError(f"log_batch: {name} has {np.asarray(values).size} samples, expected {n}")
        if n == 0:
            return
        for i in range(min(self.n_modes, q_arr.shape[1])):
            columns[modal_entity(i + 1)] = q_arr[:, i]
        index = [self._rr.TimeColumn(TIMELINE, duration=times)]
        for entity, values in columns.items():
            data = np.asarray(values, dtype=float).reshape(-1)
            self._rec.send_columns(entity, indexes=index, columns=self._rr.Scalars.columns(scalars=data))

    @one_job
    def log_shape(self, time_s: float, x_m: np.ndarray, z_m: np.ndarray) -> None:
        """Log the deflected airfoil+panel line (x along chord, z deflection, y = 0) as one strip."""
        if self._rec is None:
            return
        points = _strip_points(x_m, z_m, "log_shape")
        self._rec.set_time(TIMELINE, duration=float(time_s))
        self._rec.log(SHAPE, self._rr.LineStrips3D([points]))

    def queue_shape(self, time_s: float, x_m: np.ndarray, z_m: np.ndarray) -> None:
        """As :meth:`log_shape`, but buffered and sent with the next :meth:`flush_blocks` (one call for many)."""
        if self._rec is None:
            return
        self._pending_shapes.append((float(time_s), _strip_points(x_m, z_m, "queue_shape")))

    def log_control(self, time_s: float, command_npm: float, age_ms: float) -> None:
        """A control command (at the simulated time of the reading it answers) and its age on arrival; buffered
        and sent as columns with the next :meth:`flush_blocks`."""
        if self._rec is None:
            return
        self._pending_control.append((float(time_s), float(command_npm), float(age_ms)))

    # Sink protocol (panel_rig.rig.reading.Sink)
    def on_reading(self, reading: Reading) -> None:
        self.log_reading(reading)

    def on_block(self, block: ReadingBlock) -> None:
        """Buffer a block of samples; sent as columns at most every `batch_period_s` of wall time."""
        if self._rec is None:
            return
        self._pending.append(block)
        if time.monotonic() - self._pending_since >= self.batch_period_s:
            self.flush_blocks()

    @one_job
    def flush_blocks(self) -> None:
        """Send the buffered blocks now (one `send_columns` per entity)."""
        pending, self._pending = self._pending, []
        shapes, self._pending_shapes = self._pending_shapes, []
        control, self._pending_control = self._pending_control, []
        self._pending_since = time.monotonic()
        if self._rec is None:
            return
        if control:
            if self._control_views_on_data:
                self._add_control_views()
            rr = self._rr
            arr = np.array(control, dtype=float)
            order = np.argsort(arr[:, 0], kind="stable")
            index = [rr.TimeColumn(TIMELINE, duration=arr[order, 0])]
            for entity, col in ((CONTROL_CMD, 1), (CONTROL_AGE, 2)):
                self._rec.send_columns(entity, indexes=index, columns=rr.Scalars.columns(scalars=arr[order, col]))
        if shapes:
            rr = self._rr
            self._rec.send_columns(
                SHAPE, indexes=[rr.TimeColumn(TIMELINE, duration=np.array([t for t, _ in shapes]))],
                columns=rr.LineStrips3D.columns(strips=[p for _, p in shapes]).partition([1] * len(shapes)),
            )
        if not pending:
            return

        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(b, name) for b in pending])

        self.log_batch(cat("time_s"), cat("tip_w_over_L"), cat("q"), cat("airspeed_mps"), cat("shaker_force_npm"))

    @one_job
    def on_command(self, name: str, value: float, accepted: bool, time_s: float) -> None:
        """Accepted commands become scalars under `commands/<name>`."""
        if self._rec is None or not accepted or name == CONTROL_TOPIC:  # 500 Hz: batched by log_control
            return
        self._rec.set_time(TIMELINE, duration=float(time_s))
        self._rec.log(f"commands/{name}", self._rr.Scalars(float(value)))

    @one_job
    def log_flutter_point(self, time_s: float, points: Any, decision: Any, required_margin: float) -> None:
        """The flutter monitor after a test point, one sample per series at ``time_s``: the predicted U_f with its
        interval (m/s) and each predictor's U_f (damping trend, ZW flutter margin) where it crosses, the margin and
        the required one (unitless, own entity), the last point's identified damping (x 1000) with its 95 %
        interval and its ZW flutter margin F (Hz^4, when both its modes are identified and the first one's damping is
        > 0: the points the ZW predictor fits, the PNG's ZW panel); and
        the 2-D view ``flutter_vg`` of every point so far (see :func:`vg_scene`)."""
        if self._rec is None:
            return
        rr, rec = self._rr, self._rec
        rec.set_time(TIMELINE, duration=float(time_s))
        pred = decision.prediction
        if pred is not None:
            for name, v in zip(("estimate", "ci_low", "ci_high"), (pred.speed_mps, *pred.ci_mps)):
                if np.isfinite(v):
                    rec.log(f"{FLUTTER_UF}/{name}", rr.Scalars(float(v)))
            margin = float(pred.margin(points[-1].airspeed_mps))
            if np.isfinite(margin):
                rec.log(f"{FLUTTER_MARGIN}/current", rr.Scalars(margin))
        for name, each in (("damping_trend", decision.trend), ("zw", decision.zw)):  # both predictors, as the PNG
            if each is not None and np.isfinite(each.speed_mps):
                rec.log(f"{FLUTTER_UF}/{name}", rr.Scalars(float(each.speed_mps)))
        rec.log(f"{FLUTTER_MARGIN}/required", rr.Scalars(float(required_margin)))
        e = points[-1].flutter
        if e is not None:
            for name, v in zip(("identified", "ci_low", "ci_high"), (e.damping_ratio, *e.damping_ci())):
                rec.log(f"{FLUTTER_DAMPING}/{name}", rr.Scalars(1e3 * float(v)))
        from panel_rig.analysis.flutter_test import margin_points, trend_curve

        _, f_rad4 = margin_points(points[-1:])  # the points the ZW predictor fits (a first mode with damping > 0)
        if f_rad4.size and np.isfinite(f_rad4[0]):
            rec.log(f"{FLUTTER_ZW}/point", rr.Scalars(float(f_rad4[0]) / (2 * np.pi) ** 4))

        uf = float(pred.speed_mps) if pred is not None and np.isfinite(pred.speed_mps) else None
        for entity, archetype in vg_scene(points, trend_curve(points, decision), uf).items():
            rec.log(f"{FLUTTER_VG}/{entity}", archetype)

    @one_job
    def log_text(self, time_s: float, entity: str, text: str, warn: bool = False) -> None:
        """A line of text (level INFO, or WARN) on ``entity`` at ``time_s``, e.g. an analysis result."""
        if self._rec is None:
            return
        self._rec.set_time(TIMELINE, duration=float(time_s))
        self._rec.log(entity, self._rr.TextLog(text, level="WARN" if warn else "INFO"))

    def close(self) -> None:
        """Flush everything; the logger is disabled afterwards. Idempotent. VizError when the data did not all
        reach the file or the viewer (within FLUSH_TIMEOUT_S + DISCONNECT_GRACE_S of wall time)."""
        if self._rec is not None:
            self.flush_blocks()
        rec, self._rec = self._rec, None
        if rec is None:
            return
        queued = rec if isinstance(rec, QueuedStream) else None
        native = queued.rec if queued is not None else rec
        wait_s = FLUSH_TIMEOUT_S[self.mode] + DISCONNECT_GRACE_S
        # bounded: a viewer that is gone must not hang the node's shutdown. rerun's own flush timeout is not kept
        # when its gRPC stream cannot deliver (rerun 0.41: a viewer that stopped answering held a node's stop for
        # 10 minutes, until it was killed; upstream rerun-io/rerun#12620), so the flush runs in a thread of its own
        failure: list[str] = []

        def deliver() -> None:
            try:
                if queued is not None and not queued.drain(FLUSH_TIMEOUT_S[self.mode]):
                    failure.append("the queued data was not sent")
                    return
                native.flush(timeout_sec=FLUSH_TIMEOUT_S[self.mode])
            except RuntimeError as exc:  # rerun's timeout and connection errors
                failure.append(str(exc))
            finally:
                native.disconnect()  # gRPC: at most rerun's own 5 s for a last connection attempt

        worker = threading.Thread(target=deliver, name="rerun-flush", daemon=True)
        worker.start()
        worker.join(wait_s)
        lost = ""
        if queued is not None and (queued.dropped or queued.errors):
            lost = (f"; {queued.dropped} of {queued.offered} batches dropped while the viewer took no data (the bag "
                    "has every reading)" if queued.dropped else "") + (
                f"; rerun: {queued.errors[0]}" if queued.errors else "")
        if worker.is_alive():  # stuck in rerun: left behind, and rerun's exit handler (the same flush) is dropped
            self._rr.unregister_shutdown()
            _ABANDONED.append(native)  # never collected: its finaliser would wait on the same stream
            raise VizError(f"Rerun data not delivered ({self.mode}): the viewer at {self.target or DEFAULT_GRPC_URL} "
                           f"took no data for {wait_s:g} s; gave up{lost}")
        if failure:
            raise VizError(f"Rerun data not delivered ({self.mode}): {failure[0]}{lost}")
        if lost:
            raise VizError(f"Rerun data not delivered whole ({self.mode}){lost}")

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _save_path(target: str | None) -> str:
        if not target:
            raise VizError('rerun mode "save" needs a target .rrd path')
        try:  # its directory is made, as the bag's is
            return str(prepare_rrd_path(target, "cannot save Rerun recording"))
        except ValueError as exc:
            raise VizError(str(exc)) from None

    @one_job
    def _log_styles(self) -> None:
        """Static `SeriesLines` per series: name, colour, width and min/max zoom aggregation (`AGGREGATION`)."""
        rr, rec = self._rr, self._rec
        styles = {
            TIP: ("w/L", [31, 119, 180]),
            AIRSPEED: ("airspeed m/s", [44, 160, 44]),
            FORCE: ("shaker N/m", [214, 39, 40]),
            CONTROL_CMD: ("control command N/m", [148, 103, 189]),
            CONTROL_AGE: ("command age ms", [127, 127, 127]),
        }
        if self.views_with_flutter:
            for entity, (name, color) in FLUTTER_STYLES.items():
                rec.log(entity, rr.SeriesLines(names=name, colors=[color], widths=1.5), static=True)
                rec.log(entity, rr.SeriesPoints(names=name, colors=[color], marker_sizes=4.0), static=True)
        for entity, (name, color) in COMMAND_MARKERS.items():
            rec.log(entity, rr.SeriesPoints(names=name, colors=[color], marker_sizes=3.0), static=True)
        palette = [[255, 127, 14], [148, 103, 189], [140, 86, 75], [227, 119, 194], [23, 190, 207]]
        for i in range(1, self.n_modes + 1):
            styles[modal_entity(i)] = (f"q{i}", palette[(i - 1) % len(palette)])
        rec.log("panel", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for entity, (name, color) in styles.items():
            rec.log(
                entity,
                rr.SeriesLines(names=name, colors=[color], widths=1.5, aggregation_policy=AGGREGATION),
                static=True,
            )


def _nice_ticks(lo: float, hi: float, n: int = 5) -> np.ndarray:
    """About ``n`` round tick values (1, 2 or 5 x 10^k apart) within [lo, hi]."""
    raw = max(hi - lo, 1e-9) / n
    mag = 10.0 ** np.floor(np.log10(raw))
    step = mag * min((m for m in (1.0, 2.0, 5.0, 10.0) if m * mag >= raw), default=10.0)
    return np.arange(np.ceil(lo / step) * step, hi + 1e-9 * step, step)


def vg_scene(points: Any, trend: tuple[np.ndarray, np.ndarray] | None, uf_mps: float | None) -> dict[str, Any]:
    """The 2-D damping-vs-airspeed drawing (entity under ``flutter_vg`` -> archetype). A Rerun 2-D view has no
    plot axes and its y axis points down, so the scene is drawn as a plot: x = airspeed (m/s), y = -k x damping x
    1000 (positive damping up, k scales the damping range to 0.6 x the airspeed range), framed around the point
    estimates; 95 % bars, trend and the U_f line are clipped to the frame, and the axes are drawn with
    labelled ticks. Points have a fixed on-screen size."""
    import rerun as rr

    fl = [p for p in points if p.flutter is not None]
    u_all = [p.airspeed_mps for p in points]
    x_lo = 0.9 * min(u_all)
    x_hi = max(1.1 * max(u_all), 1.05 * uf_mps if uf_mps is not None else 0.0)
    z = np.array([1e3 * p.flutter.damping_ratio for p in fl]) if fl else np.zeros(0)
    z_lo = min(0.0, float(z.min()) if z.size else 0.0)
    z_hi = max(1.0, float(z.max()) if z.size else 1.0)
    pad = 0.25 * (z_hi - z_lo)
    z_lo, z_hi = z_lo - pad, z_hi + pad
    k = 0.6 * (x_hi - x_lo) / (z_hi - z_lo)

    def y(v: Any) -> Any:
        return -k * np.clip(v, z_lo, z_hi)

    blue, grey = [31, 119, 180], [90, 90, 90]
    out: dict[str, Any] = {}
    xt, zt = _nice_ticks(x_lo, x_hi), _nice_ticks(z_lo, z_hi)
    tick_x, tick_y = 0.012 * (x_hi - x_lo), 0.012 * (x_hi - x_lo)
    out["axes/lines"] = rr.LineStrips2D(
        [[[x_lo, y(z_lo)], [x_hi, y(z_lo)]], [[x_lo, y(z_lo)], [x_lo, y(z_hi)]]]
        + [[[u, y(z_lo)], [u, y(z_lo) + tick_y]] for u in xt] + [[[x_lo, y(v)], [x_lo - tick_x, y(v)]] for v in zt],
        colors=[grey], radii=rr.Radius.ui_points(1.0))
    # the label points, plus a bare one below them: the view frames the points' positions, not their labels
    out["axes/x_ticks"] = rr.Points2D([[u, y(z_lo) + 2 * tick_y] for u in xt] + [[x_lo, y(z_lo) + 9 * tick_y]],
                                      labels=[f"{u + 0.0:g}" for u in xt] + [""],
                                      radii=rr.Radius.ui_points(0.5), colors=[grey], show_labels=True)
    out["axes/y_ticks"] = rr.Points2D([[x_lo - 4 * tick_x, y(v)] for v in zt], labels=[f"{v + 0.0:g}" for v in zt],
                                      radii=rr.Radius.ui_points(0.5), colors=[grey], show_labels=True)
    out["zero"] = rr.LineStrips2D([[[x_lo, 0.0], [x_hi, 0.0]]], colors=[0, 0, 0], radii=rr.Radius.ui_points(1.0))
    if fl:
        u = [p.airspeed_mps for p in fl]
        out["identified"] = rr.Points2D(np.column_stack([u, y(z)]), radii=rr.Radius.ui_points(5.0), colors=[blue])
        bars = [[[p.airspeed_mps, y(1e3 * lo)], [p.airspeed_mps, y(1e3 * hi)]]
                for p in fl for lo, hi in [p.flutter.damping_ci()]]
        out["interval"] = rr.LineStrips2D(bars, colors=[blue], radii=rr.Radius.ui_points(1.5))
    if trend is not None:
        keep = (trend[0] >= x_lo) & (trend[0] <= x_hi)
        out["trend"] = rr.LineStrips2D([np.column_stack([trend[0][keep], y(1e3 * trend[1][keep])])],
                                       colors=[255, 127, 14], radii=rr.Radius.ui_points(1.5))
    if uf_mps is not None:
        out["predicted_uf"] = rr.LineStrips2D([[[uf_mps, y(z_lo)], [uf_mps, y(z_hi)]]], colors=[214, 39, 40],
                                              radii=rr.Radius.ui_points(1.5),
                                              labels=[f"U_f {uf_mps:.2f} m/s"], show_labels=True)
    return out


def _strip_points(x_m: np.ndarray, z_m: np.ndarray, caller: str) -> np.ndarray:
    """(N, 3) points of the airfoil + panel line: x along the chord, y = 0, z the deflection, m."""
    x = np.asarray(x_m, dtype=float).reshape(-1)
    z = np.asarray(z_m, dtype=float).reshape(-1)
    if x.size != z.size:
        raise VizError(f"{caller}: x has {x.size} points, z has {z.size}")
    return np.column_stack([x, np.zeros_like(x), z])
