"""``panel-rig flutter-test``: the automatic flutter-clearance procedure on the live rig node, turbulence on.

Default (live): the command starts the rig node (``python -m panel_rig.ros.rig_node --fast``, the program a user
runs) as a subprocess in a private ROS domain (a random ``ROS_DOMAIN_ID``, discovery limited to this host) with
the run's physics, recording a bag, the flutter monitor on and its hold engaged, and drives it over topics with
:class:`panel_rig.ros.flutter_client.FlutterTestClient`: airspeed set-points on ``/rig/airspeed_cmd``, one
result per test point from ``/rig/flutter_monitor``. The node's monitor identifies each dwell on the full-rate
measured tip in-process (simulated time, so the result does not depend on the machine's speed); the client
rebuilds the points, predicts and decides. A subprocess rather than a node in this process: it is the node
exactly as deployed (its own ``main``, signals, recording), and the model's stepping and the client's decisions
run on two cores instead of sharing one interpreter lock.

``--in-process``: the node-equivalent Rig (the same Stepper, turbulence, sensor and safety the rig node builds,
marched in blocks as fast mode does) in this process, recorded to a bag with the node's topic names
(``/rig/tip_displacement``, ``/rig/tip_displacement/truth``, ``/rig/airspeed``, ``/rig/airspeed_cmd``,
``/rig/flutter_monitor``); the unit tests' path.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from panel_rig.processes import (
    Aborted,
    Interrupted,
    StopRequest,
    interruption,
    signals_deferred,
    signals_set,
    sigterm_exits,
)
from panel_rig.rig.reading import SinkStop

NAMESPACE = "/rig"


#: what stopped a test whose recording failed, in its stop reason ("interrupted by a failed recording after ...")
RECORDING_FAILED = "a failed recording"


class RecordingStopped(SinkStop):
    """The bag writer failed (a full disk): the in-process test stops there, the bag written so far kept. A
    :class:`~panel_rig.rig.reading.SinkStop`, which the rig lets through (its other sink errors are logged and
    the rig goes on: a test whose recording failed went on for its whole course, printing the sink's traceback)."""


class BagSink:
    """Rig sink writing the node's reading topics and the airspeed commands to a BagWriter. A failed write
    (``failure``) raises :class:`RecordingStopped` once; later writes are skipped."""

    def __init__(self, writer: Any, n_modes: int, cfg: Any) -> None:
        from panel_rig.ros import messages

        self.writer = writer
        self.msgs = messages.ReadingMessages([f"q{i + 1}" for i in range(n_modes)],
                                             cfg.airfoil_length_m + cfg.panel_length_m, cfg.panel_length_m)
        self.last_ns = 0
        self.failure: Exception | None = None

    def write(self, topic: str, msg: Any, stamp_ns: int, **kwargs: Any) -> None:
        """``writer.write``, or nothing after a failure; the first failure raises RecordingStopped."""
        from panel_rig.recording.errors import RecordingError

        if self.failure is not None:
            return
        try:
            self.writer.write(topic, msg, stamp_ns, **kwargs)
        except (OSError, RecordingError) as exc:
            self.failure = exc
            raise RecordingStopped(str(exc)) from exc

    def on_reading(self, reading: Any) -> None:
        from panel_rig.rig.reading import ReadingBlock

        self.on_block(ReadingBlock.of([reading]))

    def on_block(self, block: Any) -> None:
        m = self.msgs
        # modal_states left out: the test needs only the measured tip (and the truth to score it); it would
        # double the bag (~0.25 MB per simulated second with it)
        names = ("tip_displacement", None, "airspeed", "tip_displacement/truth")
        objs = (m.tip, m.modal, m.airspeed, m.truth)
        for stamp_ns, *encoded in m.encode(block):
            for name, msg, data in zip(names, objs, encoded):
                if name is not None:
                    self.write(f"{NAMESPACE}/{name}", msg, stamp_ns, data=data)
            self.last_ns = stamp_ns

    def on_command(self, name: str, value: float, accepted: bool, time_s: float) -> None:
        if name != "airspeed_cmd" or not accepted:
            return
        from std_msgs.msg import Float64

        from panel_rig.ros import messages

        self.write(f"{NAMESPACE}/airspeed_cmd", Float64(data=float(value)), messages.stamp_ns(time_s),
                   qos="reliable")

    def close(self) -> None:
        pass


class ShapeSink:
    """Rig sink queueing the panel shape on a Rerun logger every ``period_s`` of simulated time (the node draws it
    from its shape timer; without this the in-process test's panel-shape view stayed empty). The strip is the
    node's: the rigid airfoil at z = 0, then the panel (``SHAPE_POINTS`` points, its modal shape at the sample)."""

    SHAPE_POINTS = 31  # as panel_rig.ros.publishing.SHAPE_POINTS (not imported: that module needs rclpy)
    N_AIRFOIL = 5

    def __init__(self, viz: Any, rig: Any, cfg: Any, period_s: float = 0.1) -> None:
        self.viz, self.rig, self.period_s = viz, rig, float(period_s)
        self.L = float(cfg.panel_length_m)
        self.x_over_L = np.linspace(0.0, 1.0, self.SHAPE_POINTS)
        self.x_m = np.concatenate([np.linspace(0.0, cfg.airfoil_length_m, self.N_AIRFOIL, endpoint=False),
                                   cfg.airfoil_length_m + self.L * self.x_over_L])
        self.next_s = 0.0

    def on_reading(self, reading: Any) -> None:
        if reading.time_s >= self.next_s - 1e-9:
            self._queue(float(reading.time_s), np.asarray(reading.q, dtype=float))

    def on_block(self, block: Any) -> None:
        times = np.asarray(block.time_s, dtype=float)
        k = int(np.searchsorted(times, self.next_s - 1e-9, side="left"))
        while k < times.size:
            self._queue(float(times[k]), np.asarray(block.q[k], dtype=float))
            k = int(np.searchsorted(times, self.next_s - 1e-9, side="left"))

    def on_command(self, name: str, value: float, accepted: bool, time_s: float) -> None:
        pass

    def _queue(self, t: float, q: np.ndarray) -> None:
        w = np.nan_to_num(self.rig.shape_w_over_L(self.x_over_L, q))
        self.viz.queue_shape(t, self.x_m, np.concatenate([np.zeros(self.N_AIRFOIL), self.L * w]))
        self.next_s = t + self.period_s

    def close(self) -> None:
        pass


def run_flutter_test(cfg: Any, variant: str = "full", margin: float = 0.1, start_mps: float | None = None,
                     bag_dir: str | Path | None = "bags", plot: str | Path | None = None, rerun: str | None = None,
                     params: dict[str, Any] | None = None, dwell_s: float | None = None,
                     settle_s: float | None = None, in_process: bool = False,
                     domain_id: int | None = None, max_points: int | None = None,
                     progress: Callable[[str], None] | None = None, repeats: int | None = None) -> dict[str, Any]:
    """Run the procedure (live node by default, see the module docstring); returns the JSON payload.
    ``progress``: called with :func:`point_line` after each test point. Stopped by Ctrl-C or SIGTERM, it raises
    :class:`panel_rig.processes.Interrupted` with the payload of the points identified so far."""
    if in_process:
        return run_in_process(cfg, variant, margin, start_mps, bag_dir, plot, rerun, params, dwell_s, settle_s,
                              max_points, progress, repeats)
    from panel_rig.ros.flutter_live import run_live

    return run_live(cfg, variant, margin, start_mps, bag_dir, plot, rerun, dwell_s, settle_s, domain_id,
                    max_points=max_points, progress=progress, repeats=repeats)


def flutter_line(index: int, airspeed_mps: float) -> str:
    """The line of a test point that fluttered (the tip past its flutter fraction of L, or the rig's abort)."""
    from panel_rig.analysis.flutter_test import fluttered_reason

    return f"point {index}: {airspeed_mps:.3f} m/s: {fluttered_reason(airspeed_mps)}; stop (the tunnel to 0 m/s)"


def point_line(index: int, point: Any, decision: Any) -> str:
    """One line per test point while a test runs: the identified flutter mode (95 % interval) and what comes
    next, so a test stopped half-way has shown what it found."""
    from panel_rig.analysis.flutter_test import flutter_mode_text

    found = flutter_mode_text(point.flutter)
    nxt = "stop" if decision.stop else f"next {decision.next_airspeed_mps:.3f} m/s"
    reason = decision.reason.split(": ", 1)[-1] if decision.unidentified else decision.reason  # found says it
    return f"point {index}: {point.airspeed_mps:.3f} m/s: {found}; {nxt} ({reason})"


def stopped_message(signum: Any, n_points: int, where: str, bag: str | None) -> str:
    """The line an interrupted test prints: how many points, where its files are, how to replay it."""
    replay = "" if bag is None else f"; `panel-rig analyze {bag}` replays the flutter test from the recording"
    return (f"flutter-test stopped by {signum.name} after {n_points} identified test point(s) (a test under way "
            f"commands the tunnel to 0 m/s first); {where}{replay}")


def run_in_process(cfg: Any, variant: str = "full", margin: float = 0.1, start_mps: float | None = None,
                   bag_dir: str | Path | None = "bags", plot: str | Path | None = None, rerun: str | None = None,
                   params: dict[str, Any] | None = None, dwell_s: float | None = None,
                   settle_s: float | None = None, max_points: int | None = None,
                   progress: Callable[[str], None] | None = None, repeats: int | None = None) -> dict[str, Any]:
    """The procedure on an in-process Rig; returns the JSON payload (see the CLI)."""
    from panel_rig.analysis.flutter_test import (
        FlutterTestResult,
        bands_from_model,
        flutter_report,
        interrupted_result,
        run_procedure,
    )
    from panel_rig.rig.flutter_run import (
        RigMeasure,
        max_test_airspeed_mps,
        node_equivalent_rig,
        noise_problem,
        pretest_plan,
        start_problem,
        start_warnings,
        take_late_point,
    )
    from panel_rig.ros import messages
    from panel_rig.ros.flutter_monitor import TOPIC, monitor_msg

    t0 = time.monotonic()
    st, uf, mode, settings = pretest_plan(cfg, variant, margin, start_mps, dwell_s, settle_s, max_points, repeats)
    problem = start_problem(settings, max_test_airspeed_mps(uf)) or noise_problem(cfg.sensor_tip_noise_m,
                                                                                   cfg.panel_length_m)
    if problem is not None:  # before the bag is made: nothing half-recorded is left behind
        raise ValueError(problem)
    for warning in start_warnings(cfg, start_mps, uf, margin) if progress is not None else ():
        progress(warning)
    sinks: list[Any] = []
    writer = bag_sink = None
    if bag_dir is not None:
        from panel_rig.recording import BagWriter, fresh_bag_dir

        writer = BagWriter(fresh_bag_dir(Path(bag_dir), "flutter_test"))
        from panel_rig.config import SCHEMA

        # the run's configuration under its parameter keys, so a replay rebuilds the same model
        flat = {k: getattr(cfg, spec.field) for k, spec in SCHEMA.items()}
        # and the monitor's window and hold as a flutter test's node records them (flutter_monitor, flutter_test.*):
        # the replay takes the same windows, so it reproduces this test's identification
        writer.write_parameters({**flat, **(params or {}), "model.variant": variant, "flutter_monitor": True,
                                 "flutter_test.margin": margin, "flutter_test.settle_s": settings.settle_s,
                                 "flutter_test.dwell_s": settings.dwell_s, "flutter_test.hold": True})
        bag_sink = BagSink(writer, len(np.atleast_1d(st.q)), cfg)
        sinks.append(bag_sink)
    viz = None
    if rerun:
        from panel_rig.viz import RerunLogger

        viz = RerunLogger(len(np.atleast_1d(st.q)), mode="save", target=rerun, recording_name="flutter_test",
                          views=("flutter", "flutter_uf", "flutter_zw"))
        sinks.append(viz)
    rig = node_equivalent_rig(cfg, st, uf, sinks)
    if viz is not None:
        rig.sinks.append(ShapeSink(viz, rig, cfg))
    history: list[tuple[float, Any, Any]] = []
    res = FlutterTestResult()
    measure, bands = RigMeasure(rig, settings, atomic=signals_deferred), bands_from_model(st.model, mode)
    short = None if writer is None else disk_warning(writer.bag_dir, settings, measure.dt_s)
    if short is not None and progress is not None:
        progress(short)

    def record_monitor(point: Any, decision: Any, fluttered: bool = False) -> None:
        """The monitor's message of a point, as the node records it (with the plateau's sim_time_s)."""
        if bag_sink is not None:
            stamp = messages.stamp_ns(rig.time_s)
            band = bands(point.airspeed_mps)[1]
            plateau = {"point_index": len(history) + 1, "plateau_start_s": measure.plateau_start_s,
                       "settle_s": settings.settle_s, "dwell_s": settings.dwell_s, "sim_time_s": rig.time_s,
                       "flutter_band_low_hz": band[0], "flutter_band_high_hz": band[1]}
            msg = monitor_msg(stamp, point, decision, margin, fluttered=fluttered, plateau=plateau)
            bag_sink.write(f"{NAMESPACE}/{TOPIC}", msg, stamp, qos="reliable")

    def on_point(point: Any, decision: Any) -> None:
        with signals_deferred():  # a stop waits until the point is recorded whole
            record_monitor(point, decision)
            history.append((rig.time_s, point, decision))
            if progress is not None:
                progress(point_line(len(history), point, decision))
            if viz is not None:
                viz.log_flutter_point(rig.time_s, [h[1] for h in history], decision, margin)

    def on_flutter(airspeed_mps: float) -> None:
        with signals_deferred():  # the node's monitor message of a plateau that fluttered, recorded whole
            record_monitor(*flutter_report(airspeed_mps, res.points, settings), fluttered=True)
            if progress is not None:
                progress(flutter_line(len(res.points) + 1, airspeed_mps))

    with contextlib.ExitStack() as after_stop:
        stopped = None
        try:
            # SIGTERM leaves through the clean-up below as Ctrl-C does; either waits for the end of the block of readings
            # being marched and recorded (a Ctrl-C inside the bag writer left a bag its summary did not match)
            with sigterm_exits():
                run_procedure(measure, bands, settings, on_point, res, on_flutter=on_flutter)
        except RecordingStopped:
            pass  # bag_sink.failure says why; reported once the wind is off and the bag closed as far as it can be
        except (KeyboardInterrupt, SystemExit) as exc:
            stopped = interruption(exc)
            if stopped is None:
                raise
            # from here a second Ctrl-C (or a SIGTERM after it) only sets a flag nobody reads: it lost the whole report
            after_stop.enter_context(signals_set(StopRequest()))
            # a dwell recorded whole is a point of the test, though the stop cut its analysis or its recording
            with signals_deferred():
                if take_late_point(res, measure.last, bands, settings) or len(history) < len(res.points):
                    interrupted_result(res, settings, stopped.name)
                    on_point(res.points[-1], res.decisions[-1])
        finally:
            with signals_deferred():  # a second Ctrl-C waits until the recording is closed
                # the wind-off is applied before its record is written, and that write may be the one that fails
                # (bag_sink.failure then says why)
                with contextlib.suppress(RecordingStopped):
                    rig.command_airspeed(0.0)
                for s in sinks:
                    if hasattr(s, "flush_blocks"):
                        s.flush_blocks()
                close_recording(writer, bag_sink)
                if viz is not None:
                    viz.close()
        failed = None if bag_sink is None or bag_sink.failure is None else bag_sink.failure
        if stopped is not None or failed is not None:  # after the wind-off: this may take a decision (a bootstrap)
            interrupted_result(res, settings, RECORDING_FAILED if stopped is None else stopped.name)
        res.bag = str(writer.bag_dir) if writer is not None else None
        out = res.as_dict()
        out.update(model_flutter_speed_mps=uf, flutter_mode=mode, variant=variant, required_margin=margin, live=False,
                   dwell_s=settings.dwell_s, settle_s=settings.settle_s, simulated_s=rig.time_s,
                   wall_s=time.monotonic() - t0, monitor_times_s=[h[0] for h in history])
        if plot is not None and (res.interrupted is None or res.points):
            from panel_rig.analysis.flutter_test import figure_title
            from panel_rig.analysis.plots import plot_flutter_test

            title = figure_title(res, cfg, variant, settings.dwell_s, "in-process")
            out["plot"] = str(plot_flutter_test(res, st.model, mode, uf, plot, title))
        if failed is not None:  # the points so far are reported as an interrupted test's, then the line why
            raise Aborted(out, recording_failed_message(failed, len(res.points), rig.time_s, writer.bag_dir))
        if stopped is not None:
            where = "no recording" if res.bag is None else f"recording in {res.bag}"
            raise Interrupted(stopped, out, stopped_message(stopped, len(res.points), where, res.bag))
        return out


#: bytes the in-process test's bag takes per tip sample (the measured and true tip, the airspeed; 7.66 MB for 50 s
#: at 512 samples/s, 2026-12-05; the default paper test's 156.3 MB for 524 800 samples, 298 B, 2026-12-06)
BAG_BYTES_PER_SAMPLE = 300
#: the same for the live node's bag, which records every topic of the node (the modal states and the panel shape
#: too; 4.18 MB for 7044 samples, 2026-12-05; the default paper test's 323.6 MB for 524 800 samples, 617 B,
#: 2026-12-06)
LIVE_BAG_BYTES_PER_SAMPLE = 600


def disk_warning(bag_dir: Path, settings: Any, sample_dt_s: float,
                 bytes_per_sample: float = BAG_BYTES_PER_SAMPLE, reserve_bytes: float = 0.0) -> str | None:
    """A warning when the test's longest course (every point's settle and dwell) could record more than the disk
    under ``bag_dir`` has free (less ``reserve_bytes``: the live node stops recording at its ``record_min_free_mb``);
    None when it fits."""
    import shutil

    longest_s = settings.max_points * (settings.settle_s + settings.dwell_s)
    need = bytes_per_sample * longest_s / sample_dt_s
    free = shutil.disk_usage(bag_dir).free
    if need <= free - reserve_bytes:
        return None
    stops = (f"the node stops recording, and the test, with {reserve_bytes / 1e6:.0f} MB left" if reserve_bytes > 0
             else "a full disk stops the test")
    return (f"warning: {settings.max_points} test points of {settings.settle_s + settings.dwell_s:g} s could "
            f"record about {need / 1e6:.0f} MB; {bag_dir} has {free / 1e6:.0f} MB free ({stops}, the bag written so "
            "far kept)")


def close_recording(writer: Any, bag_sink: BagSink | None) -> None:
    """Close the bag; after a failed write its summary may not fit either (the disk is still full): the bag is
    left for ``bag recover``, its lock released."""
    from panel_rig.recording.errors import RecordingError

    if writer is None:
        return
    try:
        writer.close()
    except (OSError, RecordingError):
        if bag_sink is None or bag_sink.failure is None:
            raise


def recording_failed_message(failure: Exception, n_points: int, time_s: float, bag_dir: Path) -> str:
    """The line a test whose recording failed ends with: where, why, and how to get the bag back."""
    why = failure.strerror if isinstance(failure, OSError) and failure.strerror else failure
    return (f"the recording failed after {n_points} test point(s), at t = {time_s:.1f} s simulated: {why}; "
            f"the test stopped there. Free some space, then `panel-rig bag recover {bag_dir}` rebuilds what was "
            "written")


def _method_cell(point: dict[str, Any]) -> str:
    """A test point's method column: its name, or for a point whose flutter mode it did not identify, saying so."""
    return point["method"] if point["damping_ratio"] is not None else f"- ({point['method']}: not identified)"


def format_flutter_test(out: dict[str, Any]) -> str:
    from panel_rig.analysis.flutter_test import prediction_text

    def num(x: Any, fmt: str) -> str:  # "-" in the column's width ("7.3f": 7), so a row without a mode stays aligned
        return format("-", ">" + fmt.partition(".")[0]) if x is None else format(x, fmt)

    lines = [f"{'#':>2} {'U_mps':>7} {'f_Hz':>7} {'zeta':>8} {'zeta 95% CI':>19} method" if out["test_points"]
             else "no test point identified (see stop)"]  # a header over no rows read as a lost table
    for k, p in enumerate(out["test_points"], 1):
        ci = p["damping_ci"]
        ci_s = "-" if ci is None else f"[{ci[0]:.4f}, {ci[1]:.4f}]"
        lines.append(f"{k:>2} {p['airspeed_mps']:>7.3f} {num(p['frequency_hz'], '7.3f')} "
                     f"{num(p['damping_ratio'], '8.4f')} {ci_s:>19} {_method_cell(p)}")
    pred = prediction_text(out["predicted_flutter_speed_mps"], out["predicted_flutter_speed_ci_mps"],
                           out["prediction_method"])
    lines.append(f"{pred}; model linear U_f {out['model_flutter_speed_mps']:.3f} m/s")
    margin = "" if out.get("margin") is None else (
        f"predicted margin {out['margin']:.3f} at the last point (required {out.get('required_margin', 0.1):g}); ")
    lines.append(f"max airspeed {out['max_airspeed_mps']:.3f} m/s; {margin}fluttered: {'yes' if out['fluttered'] else 'no'}; "
                 f"stop: {out['stop_reason']}")
    # (the wall time includes the node's start: "7 s simulated in 4.9 s wall ... RTF 79.7" read as a contradiction)
    where = (f"live node (ROS_DOMAIN_ID {out['ros_domain_id']}; its start took {num(out['node_startup_wall_s'], '.1f')} s, "
             f"the test {num(out['test_wall_s'], '.1f')} s: RTF {num(out['node_rtf'], '.1f')})"
             if out.get("live") else "in-process rig")
    rerun = f"rerun: {out['rerun']}; " if out.get("rerun") else ""
    lines.append(f"bag: {out['bag'] or '-'}; plot: {out.get('plot') or '-'}; {rerun}{num(out['simulated_s'], '.0f')} s "
                 f"simulated in {out['wall_s']:.1f} s wall on the {where}")
    return "\n".join(lines)
