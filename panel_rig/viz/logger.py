"""`RerunLogger`: the rig's time series and panel shape in Rerun (live viewer or `.rrd` file).

Uses its own `rr.RecordingStream` (never the global one), so several loggers can coexist.
All data is on the duration timeline `sim_time` (simulated seconds).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

import numpy as np

from panel_rig.paths import rrd_path_problem

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
# the flutter monitor: predicted U_f (and its interval) and the margin vs time; damping (x 1000) vs airspeed
FLUTTER_UF = "flutter/predicted_uf_mps"
FLUTTER_MARGIN = "flutter/margin"
FLUTTER_VG = "flutter_vg"
DEFAULT_GRPC_URL = "rerun+http://127.0.0.1:9876/proxy"
#: how long close() waits for the last data to reach the viewer or the .rrd file (s)
FLUSH_TIMEOUT_S = {"connect": 5.0, "save": 60.0}
# How a time-series view draws the samples that share a pixel when zoomed out. Rerun's default is the
# average, which flattens an oscillation (an LCO of tip w/L +-1.2 shows as about +-0.2); min/max keeps
# its envelope at any zoom.
AGGREGATION = "MinMax"


class VizError(RuntimeError):
    """The Rerun sink cannot be set up; the message says why."""


def modal_entity(i: int) -> str:
    """Entity path of modal coordinate q_i (1-based)."""
    return f"modal/q{i}"


def blueprint(n_modes: int) -> Any:
    """Default layout: tip, modal, airspeed+shaker time series and the panel shape in 3-D."""
    import rerun.blueprint as rrb

    series = rrb.Vertical(
        rrb.TimeSeriesView(origin="tip", name="Tip deflection w/L"),
        rrb.TimeSeriesView(origin="modal", name=f"Modal coordinates q1..q{n_modes}"),
        rrb.TimeSeriesView(
            origin="/", contents=["airspeed/**", "shaker/**"], name="Airspeed (m/s) & shaker (N/m)"
        ),
        rrb.TimeSeriesView(origin="/", contents=[CONTROL_CMD], name="Control command (N/m)"),
        rrb.TimeSeriesView(origin="/", contents=[CONTROL_AGE], name="Control command age (ms)"),
        rrb.TimeSeriesView(origin="/", contents=[f"{FLUTTER_UF}/**", FLUTTER_MARGIN],
                           name="Flutter monitor: predicted U_f (m/s) and margin"),
    )
    # Side view of the x-z plane (chord along x, deflection up along z), framing about 1 m.
    eye = rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital, position=[0.35, -2.5, 0.3], look_target=[0.35, 0.0, 0.0],
        eye_up=[0.0, 0.0, 1.0],
    )
    shape = rrb.Spatial3DView(origin="panel", name="Panel shape (x chord, z deflection)", eye_controls=eye)
    vg = rrb.Spatial2DView(origin=FLUTTER_VG, name="Flutter mode: damping ratio x 1000 vs airspeed (m/s)")
    return rrb.Blueprint(rrb.Horizontal(series, rrb.Vertical(shape, vg), column_shares=[3, 2]),
                         collapse_panels=True)


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
    ) -> None:
        if mode not in MODES:
            raise VizError(f"rerun mode must be one of {MODES}, got {mode!r}")
        if not isinstance(n_modes, int) or n_modes < 1:
            raise VizError(f"n_modes must be a positive int, got {n_modes!r}")
        self.n_modes = n_modes
        self.mode = mode
        self.target = target
        self.batch_period_s = float(batch_period_s)
        self._pending: list[ReadingBlock] = []
        self._pending_shapes: list[tuple[float, np.ndarray]] = []
        self._pending_control: list[tuple[float, float, float]] = []
        self._pending_since = time.monotonic()
        self._rec: Any = None
        if mode == "off":
            return
        import rerun as rr

        self._rr = rr
        rec = rr.RecordingStream(application_id, send_properties=True)
        bp = blueprint(n_modes)
        if mode == "save":
            rec.save(self._save_path(target), default_blueprint=bp)
        else:
            try:
                rec.connect_grpc(target or DEFAULT_GRPC_URL, default_blueprint=bp)
            except Exception as exc:  # noqa: BLE001 - rerun raises various types for bad URLs
                raise VizError(f"cannot connect to Rerun viewer at {target}: {exc}") from None
        if recording_name:
            rec.send_recording_name(recording_name)
        self._rec = rec
        self._log_styles()

    # ----------------------------------------------------------------- public API
    @property
    def enabled(self) -> bool:
        return self._rec is not None

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

    def flush_blocks(self) -> None:
        """Send the buffered blocks now (one `send_columns` per entity)."""
        pending, self._pending = self._pending, []
        shapes, self._pending_shapes = self._pending_shapes, []
        control, self._pending_control = self._pending_control, []
        self._pending_since = time.monotonic()
        if self._rec is None:
            return
        if control:
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

    def on_command(self, name: str, value: float, accepted: bool, time_s: float) -> None:
        """Accepted commands become scalars under `commands/<name>`."""
        if self._rec is None or not accepted or name == "control/force_cmd":  # 500 Hz: batched by log_control
            return
        self._rec.set_time(TIMELINE, duration=float(time_s))
        self._rec.log(f"commands/{name}", self._rr.Scalars(float(value)))

    def log_flutter_point(self, time_s: float, points: Any, decision: Any, required_margin: float) -> None:
        """The flutter monitor after a test point: predicted U_f with its interval and the margin on the time
        line; the identified damping (x 1000, 95 % bars) of every point so far vs airspeed with the damping-trend
        extrapolation and the predicted U_f as a vertical line (2-D view ``flutter_vg``)."""
        if self._rec is None:
            return
        from panel_rig.analysis.flutter_test import trend_curve

        rr, rec = self._rr, self._rec
        rec.set_time(TIMELINE, duration=float(time_s))
        pred = decision.prediction
        if pred is not None and np.isfinite(pred.speed_mps):
            rec.log(f"{FLUTTER_UF}/estimate", rr.Scalars(float(pred.speed_mps)))
            for name, v in zip(("ci_low", "ci_high"), pred.ci_mps):
                if np.isfinite(v):
                    rec.log(f"{FLUTTER_UF}/{name}", rr.Scalars(float(v)))
            rec.log(FLUTTER_MARGIN, rr.Scalars(float(pred.margin(points[-1].airspeed_mps))))
        rec.log(f"{FLUTTER_UF}/required_margin", rr.Scalars(float(required_margin)))
        fl = [p for p in points if p.flutter is not None]
        if fl:
            xy = [[p.airspeed_mps, 1e3 * p.flutter.damping_ratio] for p in fl]
            rec.log(f"{FLUTTER_VG}/identified", rr.Points2D(xy, radii=0.05, colors=[31, 119, 180]))
            bars = [[[p.airspeed_mps, 1e3 * lo], [p.airspeed_mps, 1e3 * hi]]
                    for p in fl for lo, hi in [p.flutter.damping_ci()]]
            rec.log(f"{FLUTTER_VG}/interval", rr.LineStrips2D(bars, colors=[31, 119, 180]))
        curve = trend_curve(points, decision)
        if curve is not None:
            rec.log(f"{FLUTTER_VG}/trend", rr.LineStrips2D([np.column_stack([curve[0], 1e3 * curve[1]])],
                                                           colors=[255, 127, 14]))
        if pred is not None and np.isfinite(pred.speed_mps):
            rec.log(f"{FLUTTER_VG}/predicted_uf", rr.LineStrips2D([[[pred.speed_mps, -2.0], [pred.speed_mps, 10.0]]],
                                                                  colors=[214, 39, 40]))
        rec.log(f"{FLUTTER_VG}/zero", rr.LineStrips2D([[[0.0, 0.0], [1.5 * points[-1].airspeed_mps, 0.0]]],
                                                       colors=[0, 0, 0]))

    def close(self) -> None:
        """Flush everything; the logger is disabled afterwards. Idempotent."""
        if self._rec is not None:
            self.flush_blocks()
        rec, self._rec = self._rec, None
        if rec is None:
            return
        try:  # bounded: a viewer that is gone must not hang the node's shutdown (rerun's default waits forever)
            rec.flush(timeout_sec=FLUSH_TIMEOUT_S[self.mode])
        except RuntimeError as exc:  # rerun's timeout and connection errors
            raise VizError(f"Rerun data not delivered ({self.mode}): {exc}") from None
        finally:
            rec.disconnect()  # gRPC: at most rerun's own 5 s for a last connection attempt

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _save_path(target: str | None) -> str:
        if not target:
            raise VizError('rerun mode "save" needs a target .rrd path')
        problem = rrd_path_problem(target)
        if problem:
            raise VizError(f"cannot save Rerun recording: {problem}")
        return str(target)

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


def _strip_points(x_m: np.ndarray, z_m: np.ndarray, caller: str) -> np.ndarray:
    """(N, 3) points of the airfoil + panel line: x along the chord, y = 0, z the deflection, m."""
    x = np.asarray(x_m, dtype=float).reshape(-1)
    z = np.asarray(z_m, dtype=float).reshape(-1)
    if x.size != z.size:
        raise VizError(f"{caller}: x has {x.size} points, z has {z.size}")
    return np.column_stack([x, np.zeros_like(x), z])
