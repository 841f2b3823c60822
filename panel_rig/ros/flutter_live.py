"""``panel-rig flutter-test`` on the live node: start the rig node (fast, turbulence and sensor of the run's
physics, recording, flutter monitor with hold) in a private ROS domain, drive it with the flutter-test client, stop
it, and hand back the JSON payload. See :mod:`panel_rig.flutter_cli` for why a subprocess."""

from __future__ import annotations

import contextlib
import math
import os
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import yaml

from panel_rig.analysis.flutter_margin import finite_or_none
from panel_rig.domains import private_domain_id
from panel_rig.processes import (
    RIG_STARTUP_TIMEOUT_S,
    Aborted,
    Interrupted,
    StopRequest,
    interruption,
    module_command,
    signals_set,
    spawn,
    stop,
)
from panel_rig.rig.flutter_run import (
    max_test_airspeed_mps,
    noise_problem,
    pretest_plan,
    start_problem,
    start_warnings,
)

if TYPE_CHECKING:
    from panel_rig.analysis.flutter_test import FlutterTestResult

NAMESPACE = "/rig"
STOP_WAIT_S = 60.0  # wall: the node closes its bag on SIGINT


@dataclass
class Drive:
    """What the client's side gathered, also when it was stopped part-way: the procedure's result so far, the
    monitor's messages, and the wall times of the node's start-up and of the test (s; nan: not reached)."""

    res: FlutterTestResult
    results: list[dict[str, Any]] = field(default_factory=list)
    startup_s: float = math.nan
    test_s: float = math.nan
    sim_time_s: float = math.nan  # the node's simulated time in its last diagnostics report (s)


def node_parameters(cfg: Any, variant: str, margin: float, settle_s: float, dwell_s: float, uf_mps: float,
                    bag_dir: Path | None, rerun: str | None, repeats: int) -> dict[str, Any]:
    """Every parameter the node needs for the test: the run's physics (so the node's model is the one the test
    plan was made for), fast mode, the monitor's window and hold, recording and the viewer."""
    from panel_rig.config import SCHEMA
    from panel_rig.ros.params import NODE_PARAMS

    flat = {k: getattr(cfg, spec.field) for k, spec in SCHEMA.items()}
    flat = {k: (list(v) if isinstance(v, tuple) else v) for k, v in flat.items()}
    # readings every whole number of physics steps nearest the default 500 Hz (4 steps of 1/2048 s: 512 Hz), so
    # the monitor identifies on a regular record as the in-process driver does; at 500 Hz the intervals alternate
    # between 4 and 5 steps and each window must be interpolated onto a grid
    steps = max(1, round(1.0 / (NODE_PARAMS["publish_rate_hz"].default * cfg.dt_s)))
    return {**flat, "fast": True, "model.variant": variant, "flutter_monitor": True,
            "publish_rate_hz": 1.0 / (steps * cfg.dt_s),
            "flutter_test.settle_s": float(settle_s), "flutter_test.dwell_s": float(dwell_s),
            "flutter_test.margin": float(margin), "flutter_test.repeats": int(repeats), "flutter_test.hold": True,
            "safety.max_airspeed_mps": max_test_airspeed_mps(uf_mps),
            "record": bag_dir is not None, "bag_dir": str(bag_dir) if bag_dir is not None else "bags",
            "rerun": f"save:{rerun}" if rerun else "none"}


#: what stopped a live test whose node failed (its recording, or the node itself), in its stop reason
LOST_NODE = "the rig node's failure"


def run_live(cfg: Any, variant: str = "full", margin: float = 0.1, start_mps: float | None = None,
             bag_dir: str | Path | None = "bags", plot: str | Path | None = None, rerun: str | None = None,
             dwell_s: float | None = None, settle_s: float | None = None, domain_id: int | None = None,
             max_points: int | None = None, startup_s: float = RIG_STARTUP_TIMEOUT_S,
             progress: Callable[[str], None] | None = None, repeats: int | None = None) -> dict[str, Any]:
    """The procedure on a freshly started live node; returns the JSON payload (the issue's keys, plus
    ``simulated_s``, ``wall_s``, ``node_rtf`` and the node's own last prediction for comparison). ``progress``:
    called with a line after each test point (:func:`panel_rig.flutter_cli.point_line`)."""
    t0 = time.monotonic()
    # the pre-test analysis (this process) gives the plan: U_f, the start and the step; a start the node would refuse
    # ends here, before a run directory is made
    st, uf, mode, settings = pretest_plan(cfg, variant, margin, start_mps, dwell_s, settle_s, max_points, repeats)
    problem = start_problem(settings, max_test_airspeed_mps(uf)) or noise_problem(cfg.sensor_tip_noise_m,
                                                                                   cfg.panel_length_m)
    if problem is not None:
        raise ValueError(problem)
    did = private_domain_id() if domain_id is None else int(domain_id)
    from panel_rig.recording.writer import fresh_bag_dir

    # named as the in-process test's, made with the user's umask (mkdtemp made it 0700: others could not read a
    # shared bags directory's run)
    run_dir = fresh_bag_dir(Path(bag_dir) if bag_dir is not None else Path(tempfile.gettempdir()), "flutter_test")

    for warning in start_warnings(cfg, start_mps, uf, margin) if progress is not None else ():
        progress(warning)
    model = st.model
    prm = node_parameters(cfg, variant, margin, settings.settle_s, settings.dwell_s, uf,
                          run_dir if bag_dir is not None else None, rerun, settings.repeats)
    if bag_dir is not None:
        from panel_rig.flutter_cli import LIVE_BAG_BYTES_PER_SAMPLE, disk_warning
        from panel_rig.ros.params import NODE_PARAMS

        short = disk_warning(run_dir, settings, 1.0 / prm["publish_rate_hz"], LIVE_BAG_BYTES_PER_SAMPLE,
                             NODE_PARAMS["record_min_free_mb"].default * 1e6)
        if short is not None and progress is not None:
            progress(short)
    params_file = run_dir / "node_params.yaml"
    params_file.write_text(yaml.safe_dump({"panel_rig": {"ros__parameters": prm}}))
    env = dict(os.environ, ROS_DOMAIN_ID=str(did), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    # the monitor's SVDs are <= ~160 x 160: BLAS threads only contend (measured 3-7x slower per point with the
    # default threads on the 2 shared cores, docs/validation.md section 10); the user's own setting wins
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    cmd = [*module_command("panel_rig.ros.rig_node"), "--fast", "--params", str(params_file),
           "--ros-args", "-r", f"__ns:={NAMESPACE}"]
    log_path = run_dir / "node.log"
    with open(log_path, "w") as log:  # its own session: a Ctrl-C in the terminal reaches this process only, which
        node = spawn(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)  # winds off before stopping the node
    from panel_rig.analysis.flutter_test import FlutterTestResult, interrupted_result
    from panel_rig.flutter_cli import flutter_line, point_line, stopped_message
    from panel_rig.ros.flutter_client import RigGone

    drive = Drive(FlutterTestResult())

    def on_point(point: Any, decision: Any) -> None:
        if progress is not None:
            progress(point_line(len(drive.res.points), point, decision))

    def on_flutter(airspeed_mps: float) -> None:
        if progress is not None:
            progress(flutter_line(len(drive.res.points) + 1, airspeed_mps))

    stopped = gone = None
    # a signal only sets a flag, which the client's waits turn into KeyboardInterrupt / SystemExit between rclpy
    # calls (raised inside rclpy's conversion of a taken sample it became a RuntimeError): the wind off, the node
    # stopped, the points so far reported. The flag stays the only effect until the report is made: a second Ctrl-C
    # (or a SIGTERM after it) during the wind-off, the node's stop or the plot lost the whole report
    stop_request = StopRequest()
    with signals_set(stop_request):
        try:
            _drive(node, did, settings, startup_s, drive, on_point, stop_request, on_flutter)
        except RigGone as exc:
            gone = RigGone(f"{exc} (node log: {log_path})")
            if not drive.res.points:  # nothing measured: the line alone
                raise gone from None
        except (KeyboardInterrupt, SystemExit) as exc:
            stopped = interruption(exc)
            if stopped is None:
                raise
        finally:
            code = stop(node, STOP_WAIT_S)
        res = drive.res
        if stopped is not None:  # after the wind-off and the node's stop: this may take a decision (a bootstrap) still
            late = take_late_result(res, drive.results)
            interrupted_result(res, settings, stopped.name)
            if late == "point":  # its line, as every point's (a stop during its identification left it out)
                on_point(res.points[-1], res.decisions[-1])
            elif late == "flutter":
                on_flutter(res.max_airspeed_mps)
        elif gone is not None:  # a failed recording or a lost node, after test points: they are reported
            interrupted_result(res, settings, LOST_NODE)
        bags = sorted(p for p in run_dir.glob("rig_*") if p.is_dir())
        res.bag = str(bags[-1]) if bags and bag_dir is not None else None
        out = res.as_dict()
        results = drive.results
        last = results[-1] if results else {}
        # the last result's time; a test stopped before any (or overdue) has the node's last reported time
        sim = finite_or_none(float(last.get("sim_time_s", drive.sim_time_s)))
        out.update(model_flutter_speed_mps=uf, flutter_mode=mode, variant=variant, required_margin=margin, live=True,
                   dwell_s=settings.dwell_s, settle_s=settings.settle_s, simulated_s=sim,
                   wall_s=time.monotonic() - t0, node_startup_wall_s=finite_or_none(drive.startup_s),
                   test_wall_s=finite_or_none(drive.test_s),
                   node_rtf=sim / drive.test_s if sim is not None and drive.test_s > 0 else None,
                   node_exit_code=code, node_log=str(log_path), ros_domain_id=did,
                   node_prediction_mps=finite_or_none(last.get("predicted_flutter_speed_mps")),
                   monitor_times_s=[float(r["sim_time_s"]) for r in results],
                   identify_wall_s=[float(r.get("identify_wall_s", float("nan"))) for r in results])
        if plot is not None and (res.interrupted is None or res.points):
            from panel_rig.analysis.flutter_test import figure_title
            from panel_rig.analysis.plots import plot_flutter_test

            title = figure_title(res, cfg, variant, settings.dwell_s, "live node")
            out["plot"] = str(plot_flutter_test(res, model, mode, uf, plot, title))
        if gone is not None:
            raise Aborted(out, str(gone))
        if stopped is not None:
            where = f"recording and node log in {run_dir}"
            raise Interrupted(stopped, out, stopped_message(stopped, len(res.points), where, res.bag))
        return out


def take_late_result(res: FlutterTestResult, results: list[dict[str, Any]]) -> str | None:
    """The node's result for the point under way that a stopped client did not take (it came while the client
    turned the wind off): ``res`` counts its flutter, or the point if its window was the whole dwell (the wind-off
    cuts the plateau, and the node identifies a cut one too when it kept the minimum dwell: not a point of the
    test's plan). Returns what was taken: "point", "flutter" or None."""
    from panel_rig.ros.flutter_monitor import point_from_values

    u = res.max_airspeed_mps  # the point under way: its airspeed is commanded before it is measured
    if not results or u <= 0 or res.fluttered:
        return None
    v = results[-1]
    # the node numbers its results from 1 and each before the one under way was a point (a flutter ends the test):
    # taken when there are as many points (a repeated airspeed is a result of its own)
    if v.get("airspeed_mps") != u or int(v.get("point_index", -1)) <= len(res.points):
        return None
    if v.get("fluttered") == "true":
        res.fluttered = True
        return "flutter"
    if v["sim_time_s"] >= v["plateau_start_s"] + v["settle_s"] + v["dwell_s"] - 1e-6:
        res.points.append(point_from_values(v))
        return "point"
    return None


def _drive(node: subprocess.Popen, domain_id: int, settings: Any, startup_s: float, drive: Drive,
           on_point: Callable[[Any, Any], None] | None = None, stop_request: StopRequest | None = None,
           on_flutter: Callable[[float], None] | None = None) -> None:
    """The client's side, in its own rclpy context (the calling process may have another); fills ``drive``, also
    when stopped part-way."""
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from panel_rig.analysis.flutter_test import run_points
    from panel_rig.ros.discovery import use_quick_announcements
    from panel_rig.ros.flutter_client import FlutterTestClient

    saved = os.environ.get("ROS_AUTOMATIC_DISCOVERY_RANGE")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # read by the middleware at init
    use_quick_announcements()
    ctx = Context()
    try:
        rclpy.init(context=ctx, domain_id=domain_id)
    finally:
        if saved is None:
            os.environ.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
        else:
            os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = saved
    executor = SingleThreadedExecutor(context=ctx)
    client = FlutterTestClient(NAMESPACE, alive=lambda: node.poll() is None, context=ctx)
    client.stop = stop_request
    client.point_s = settings.settle_s + settings.dwell_s
    executor.add_node(client)
    t0 = time.monotonic()
    try:
        client.wait_for_rig(executor, startup_s)
        drive.startup_s = time.monotonic() - t0
        t1 = time.monotonic()

        def next_point(u: float) -> tuple[Any, bool]:
            pt, fluttered, _ = client.test_point(executor, u)
            return pt, fluttered

        try:
            run_points(next_point, settings, on_point, drive.res, on_flutter)
        except BaseException:  # Ctrl-C, SIGTERM, a lost node: the wind off first, as an operator stops a test
            drive.test_s = time.monotonic() - t1
            with contextlib.suppress(Exception):
                client.command(0.0)
                client.confirm_setpoint(executor, 0.0)  # seen by the node (and recorded) before it is stopped
            raise
        drive.test_s = time.monotonic() - t1
        client.command(0.0)  # the tunnel down, as an operator ends a test
        client.settle_commands(executor)
    finally:
        drive.results = list(client.results)
        drive.sim_time_s = client.sim_time_s
        executor.remove_node(client)
        client.destroy_node()
        executor.shutdown()
        rclpy.shutdown(context=ctx)
