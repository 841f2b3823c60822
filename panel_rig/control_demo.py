"""``panel-rig control-demo``: active flutter suppression over topics, end to end, with a printed verdict.

Starts the rig node (fast mode: the controller runs in lock-step with it, the transport latency emulated as
``control.fast_delay_s``, so the result does not depend on the machine's load; recording a bag and a Rerun
``.rrd``) and the reference controller (``panel-rig control``) as separate processes, then, from a client node:

1. at 1.2 x the open-loop flutter speed U_f, taps the panel with the shaker and shows it quiet: tip RMS over the
   last 2 s of a 6 s window below QUIET_FACTOR x the assumed sensor noise;
2. steps the airspeed up over 0.95 ... 1.05 x the predicted closed-loop flutter speed (linear ROM model with the
   controller, actuator and loop delay), taps at each step and fits the growth rate of the tip envelope: the
   emulated onset is where it crosses zero (stepping stops once it is bracketed); compares it with the prediction.

``panel-rig control-demo [--delay-ms 2] [--out out/control_demo] [--bag-dir bags] [--json]``
"""

from __future__ import annotations

import contextlib
import math
import os
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from panel_rig import jsonio
from panel_rig.argparsing import OneLineParser
from panel_rig.config import number_if_text
from panel_rig.domains import private_domain_id
from panel_rig.paths import check_output_dir
from panel_rig.processes import (
    RIG_STARTUP_TIMEOUT_S,
    Interrupted,
    StopRequest,
    interruption,
    module_command,
    signals_set,
    sigterm_exits,
    spawn,
    stop,
    stop_exception,
)

ROOT = Path(__file__).resolve().parents[1]
QUIET_AT = 1.2  # x open-loop U_f
ONSET_FACTORS = (0.95, 0.975, 1.0, 1.025, 1.05)  # x predicted closed-loop U_f
SETTLE_S, WINDOW_S = 1.0, 3.0  # per onset step: tunnel settling, then the growth-rate window after a tap
#: onset taps, N/m for 20 ms: ten times the quiet check's, so the free response stands ~10x above the response
#: to the tunnel's turbulence (at the 0.05 N/m of the quiet check the two are alike and the envelope's growth rate
#: measures the turbulence, not the closed loop)
ONSET_TAP_NPM = 0.5
RATE_HZ = 500.0
STOP_TIMEOUT_S = 20.0  # wall: SIGINT, then this long for the node to close its bag


class DemoError(RuntimeError):
    pass


def _stamp(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


class _Client:
    """Readings in, commands out (airspeed, shaker), diagnostics."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PointStamped, Vector3Stamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
        from std_msgs.msg import Float64

        from panel_rig.ros.discovery import use_quick_announcements
        from panel_rig.ros.messages import rig_status

        self._rclpy, self._Float64, self._rig_status = rclpy, Float64, rig_status
        use_quick_announcements()
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node("control_demo", namespace="/rig", context=self.ctx)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        rel = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.tip: list[tuple[float, float]] = []
        self.airspeed = math.nan
        self.diag: dict[str, str] = {}
        self.node.create_subscription(PointStamped, "tip_displacement",
                                      lambda m: self.tip.append((_stamp(m), m.point.z)), qos_profile_sensor_data)
        self.node.create_subscription(Vector3Stamped, "airspeed", self._on_air, qos_profile_sensor_data)
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, rel)
        self.pubs = {t: self.node.create_publisher(Float64, t, rel) for t in ("airspeed_cmd", "shaker/force_cmd")}
        self.stop: StopRequest | None = None  # set by a signal: the waits end between rclpy calls

    def _on_air(self, m: Any) -> None:
        self.airspeed = m.vector.x

    def _on_diag(self, m: Any) -> None:
        values = self._rig_status(m, self.node.get_namespace())
        if values is not None:
            self.diag = values

    def wait(self, cond: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not cond():
            if self.stop is not None and self.stop.is_set():
                raise stop_exception(self.stop)
            if time.monotonic() > deadline:
                raise DemoError(f"timed out after {timeout_s:g} s waiting for {what}")
            self.ex.spin_once(timeout_sec=0.02)

    def now(self) -> float:
        return self.tip[-1][0] if self.tip else -math.inf

    def wait_sim(self, dt_s: float, timeout_s: float = 120.0) -> None:
        end = self.now() + dt_s
        self.wait(lambda: self.now() >= end, timeout_s, f"{dt_s:g} s of rig time")

    def send(self, topic: str, value: float) -> None:
        self.wait(lambda: self.pubs[topic].get_subscription_count() > 0, 20.0, f"a subscriber on {topic}")
        self.pubs[topic].publish(self._Float64(data=float(value)))

    def tap(self, force_npm: float = 0.05, duration_s: float = 0.02) -> float:
        self.send("shaker/force_cmd", force_npm)
        self.wait_sim(duration_s)
        self.send("shaker/force_cmd", 0.0)
        return self.now()

    def window(self, t0: float, t1: float) -> tuple[np.ndarray, np.ndarray]:
        a = np.array([x for x in self.tip if t0 <= x[0] <= t1])
        return (a[:, 0], a[:, 1]) if a.size else (np.zeros(0), np.zeros(0))

    def close(self) -> None:
        self.ex.shutdown()
        self.node.destroy_node()
        self._rclpy.shutdown(context=self.ctx)


def diag_number(value: Any) -> Any:
    """A value of the node's diagnostics (KeyValues carry text) as a number: ``'12'`` -> 12, ``'0.213'`` -> 0.213;
    None when absent or ``'nan'`` (no samples yet; JSON has no NaN); other text unchanged."""
    if value is None or (isinstance(value, str) and value.strip().lower() == "nan"):
        return None
    if isinstance(value, str) and value.strip().isdigit():
        return int(value)
    return number_if_text(value)


def diagnostics_summary(diag: dict[str, str]) -> dict[str, Any]:
    """The summary's part from the node's last tunnel diagnostics: command ages (ms) and counts as numbers."""
    return {"latency_mean_total_ms": diag_number(diag.get("control_latency_mean_total_ms")),
            "latency_p99_total_ms": diag_number(diag.get("control_latency_p99_total_ms")),
            "rig_state": diag.get("state"), "control_commands": diag_number(diag.get("control_commands")),
            "rejected_commands": diag_number(diag.get("rejected_commands"))}


def run(delay_ms: float, out: Path, bag_dir: Path, log: Callable[[str], None]) -> dict[str, Any]:
    """The whole demonstration; returns the summary (written to ``out/<run>_summary.json`` and ``out/summary.json``)."""
    from panel_rig.analysis.control import (
        QUIET_FACTOR,
        SENSOR_NOISE_M,
        LoopModel,
        closed_loop_flutter,
        design_law,
        effective_delay,
    )
    from panel_rig.config import load_config
    from panel_rig.model.aeroelastic import AeroelasticModel
    from panel_rig.rig.control import ControlSettings

    cfg = load_config()
    model = AeroelasticModel(cfg)
    design = design_law(model)
    u_f = design.open_loop_flutter_mps
    delay_s = effective_delay(delay_ms * 1e-3, RATE_HZ, cfg.dt_s)
    pred = closed_loop_flutter(model, design.law, LoopModel(ControlSettings().bandwidth_hz, delay_s))
    if pred.speed_mps is None or pred.speed_mps <= u_f:  # nothing suppressed: the demo has nothing to show
        at = ("no closed-loop flutter below 2.5 U_f" if pred.speed_mps is None and not pred.unstable_at_low_speed
              else "the loop unstable from low speed" if pred.speed_mps is None or pred.speed_mps < 0.5 * u_f
              else f"closed-loop flutter at {pred.speed_mps:.3f} m/s, below the open loop's {u_f:.3f} m/s")
        raise DemoError(f"with a {delay_s * 1e3:.2f} ms loop delay (command age {delay_ms:g} ms) the linear model "
                        f"predicts {at}: the delay is too long for the law (robust to "
                        f"{design.notes['robust_delay_s'] * 1e3:.1f} ms); see panel-rig flutter --control "
                        f"--command-age-ms {delay_ms:g}")
    log(f"design: gain {design.law.gain_nspm2:g} N s/m^2; open-loop U_f {u_f:.3f} m/s; predicted closed-loop U_f "
        f"{pred.speed_mps:.3f} m/s with loop delay {delay_s * 1e3:.2f} ms (command age {delay_ms:g} ms)")

    run_name = time.strftime("control_demo_%Y%m%d_%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    bag_dir.mkdir(parents=True, exist_ok=True)
    rrd = out / f"{run_name}.rrd"
    env = dict(os.environ, ROS_DOMAIN_ID=str(private_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_LOG_DIR=str(out / "ros_log"))
    before = {p.name for p in bag_dir.glob("rig_*")}
    node_log, ctl_log = out / f"{run_name}_node.log", out / f"{run_name}_controller.log"
    with open(node_log, "w") as fh:  # own sessions: a Ctrl-C reaches this process, which stops them in order
        node = spawn(
            [*module_command("panel_rig.ros.rig_node"), "--fast", "--ros-args", "-r", "__ns:=/rig",
             "--params-file", str(ROOT / "config" / "rig.yaml"), "-p", "tunnel.time_constant_s:=0.3",
             "-p", f"control.fast_delay_s:={delay_ms * 1e-3}", "-p", "fast_max_realtime_factor:=5.0",
             "-p", "diagnostics_rate_hz:=5.0", "-p", "record:=true", "-p", f"bag_dir:={bag_dir}",
             "-p", f"rerun:=save:{rrd}"], env=env, stdout=fh, stderr=subprocess.STDOUT)
    with open(ctl_log, "w") as fh:
        ctl = spawn(
            [*module_command("panel_rig.ros.controller"), "--ros-args", "-r", "__ns:=/rig",
             "-p", f"gain_nspm2:={design.law.gain_nspm2}", "-p", f"derivative_hz:={design.law.derivative_hz}"],
            env=env, stdout=fh, stderr=subprocess.STDOUT)
    os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    client = _Client(int(env["ROS_DOMAIN_ID"]))
    # from here a signal only sets a flag, which the client's waits turn into KeyboardInterrupt / SystemExit between
    # rclpy calls: raised inside rclpy's conversion of a taken sample it became a RuntimeError, and the demo died
    # without its summary (seen on a loaded machine)
    client.stop = stop_request = StopRequest()
    # filled as it is measured: an interrupted demo writes what it has
    summary: dict[str, Any] = {
        "interrupted": False, "open_loop_flutter_speed_mps": u_f, "closed_loop_flutter_speed_mps": pred.speed_mps,
        "command_age_ms": delay_ms, "loop_delay_ms": delay_s * 1e3, "law": design.law.as_dict(),
        "quiet_airspeed_mps": None, "quiet_tip_rms_m": None, "quiet_threshold_m": None, "quiet": None}
    rates: list[float] = []
    stopped, failure = None, None
    with signals_set(stop_request):
        try:
            client.wait(lambda: client.diag.get("control_lockstep") == "True", RIG_STARTUP_TIMEOUT_S,
                        "the controller in lock-step")
            summary.update(_quiet_check(client, u_f))
            log(f"1.2 U_f = {summary['quiet_airspeed_mps']:.2f} m/s: tip RMS {summary['quiet_tip_rms_m'] * 1e6:.2f} um "
                f"over t_tap + 4..6 s (quiet below {summary['quiet_threshold_m'] * 1e6:.0f} um = {QUIET_FACTOR:g} x "
                f"sensor noise {SENSOR_NOISE_M * 1e6:g} um)")  # after the update: a stop now keeps what it says
            _onset_steps(client, pred.speed_mps, rates, log)
            client.send("airspeed_cmd", 0.0)
        except DemoError as exc:  # e.g. the tunnel did not reach a set-point: what was measured is still written
            failure = exc
        except (KeyboardInterrupt, SystemExit) as exc:
            stopped = interruption(exc)
            if stopped is None:
                raise
        finally:
            client.stop = None  # the wind-off and the stops run to their end: a second signal only sets the flag
            if stopped is not None or failure is not None:  # the wind off first, as the flutter test does (and in
                with contextlib.suppress(DemoError):  # the bag: the rig's diagnostics show the set-point taken)
                    client.send("airspeed_cmd", 0.0)
                    client.wait(lambda: client.diag.get("airspeed_setpoint_mps") == f"{0.0:.4f}", 5.0, "the wind off")
            summary.update(**onset_summary(rates, pred.speed_mps), **diagnostics_summary(dict(client.diag)))
            client.close()
            # the node first: the loop stays closed until the rig stops (stopped the other way round, the rig ran on
            # uncontrolled above the open-loop U_f for a moment, and its bag could end in a flutter onset)
            node_code = stop(node, STOP_TIMEOUT_S)
            ctl_code = stop(ctl, STOP_TIMEOUT_S)
    new = sorted(p for p in bag_dir.glob("rig_*") if p.name not in before and p.is_dir())
    summary.update(interrupted=stopped is not None, error=None if failure is None else str(failure),
                   bag=str(new[-1]) if new else None,
                   rerun=str(rrd) if rrd.exists() else None, node_exit=node_code, controller_exit=ctl_code,
                   node_log=str(node_log), controller_log=str(ctl_log))
    # the run's own summary beside its .rrd and logs, and summary.json the latest run's (it was the only one: each
    # run overwrote the last)
    path = out / f"{run_name}_summary.json"
    path.write_text(jsonio.dumps(summary, indent=1))
    (out / "summary.json").write_text(jsonio.dumps(summary, indent=1))
    if stopped is not None:
        raise Interrupted(stopped, summary, f"stopped by {stopped.name}: what was measured so far is in {path} "
                                            f"(bag {summary['bag']}, node log {node_log})")
    if failure is not None:
        raise DemoError(f"{failure}; what was measured so far is in {path} (node log {node_log})")
    return summary


def _quiet_check(client: _Client, u_f: float) -> dict[str, Any]:
    """Step 1: a tap at QUIET_AT x U_f, the tip RMS 4..6 s after it against the quiet threshold."""
    from panel_rig.analysis.control import QUIET_FACTOR, SENSOR_NOISE_M

    u_quiet = QUIET_AT * u_f
    client.send("airspeed_cmd", u_quiet)
    client.wait(lambda: client.airspeed > 0.999 * u_quiet, 60.0, "the tunnel at 1.2 U_f")
    t_tap = client.tap()
    client.wait_sim(6.0)
    _, w = client.window(t_tap + 4.0, t_tap + 6.0)
    rms = float(np.sqrt(np.mean(w**2))) if w.size else math.nan
    threshold = QUIET_FACTOR * SENSOR_NOISE_M
    return {"quiet_airspeed_mps": u_quiet, "quiet_tip_rms_m": rms, "quiet_threshold_m": threshold,
            "quiet": bool(rms < threshold)}


def _onset_steps(client: _Client, pred_mps: float, rates: list[float], log: Callable[[str], None]) -> None:
    """Step 2: up through ONSET_FACTORS x the predicted closed-loop U_f, a tap at each, the envelope's growth rate
    (1/s) appended to ``rates`` as it is measured; stops once the zero crossing is bracketed or the rig aborts."""
    from panel_rig.rig.control import envelope_growth_rate

    for fac in ONSET_FACTORS:
        if client.diag.get("state") != "running":
            break  # the flutter reached the tip limit and the rig aborted: the onset lies below this step
        u = fac * pred_mps
        client.send("airspeed_cmd", u)
        client.wait(lambda u=u: abs(client.airspeed - u) < 1e-3 * u, 60.0, f"the tunnel at {u:.2f} m/s")
        client.wait_sim(SETTLE_S)
        t0 = client.tap(ONSET_TAP_NPM)
        client.wait_sim(WINDOW_S)
        t, w = client.window(t0 + 0.5, t0 + WINDOW_S)
        aborted = client.diag.get("state") != "running"  # the window ends in an abort: no rate to measure
        g = envelope_growth_rate(t, w) if t.size > 50 and not aborted else math.nan
        rates.append(g)
        log(f"  U = {u:.3f} m/s ({fac:.3f} x predicted): tip envelope growth rate {g:+.3f} 1/s"
            + (" (the rig aborted in this window: the flutter reached the tip limit)" if aborted else ""))
        if client.diag.get("state") != "running" or (g > 0 and any(x < 0 for x in rates[:-1])):
            break  # the onset is bracketed: no need to let the flutter grow further


def onset_summary(rates: Sequence[float], pred_mps: float) -> dict[str, Any]:
    """The onset steps measured so far (growth rates, 1/s, at ONSET_FACTORS x ``pred_mps``) and the emulated
    onset: the first zero crossing of the rate, interpolated (None until one is bracketed)."""
    speeds = np.array(ONSET_FACTORS[: len(rates)]) * pred_mps
    r = np.array(rates, dtype=float)
    cross = [i for i in range(len(r) - 1) if r[i] < 0 <= r[i + 1]]
    onset = (float(speeds[cross[0]] - r[cross[0]] * (speeds[cross[0] + 1] - speeds[cross[0]])
                   / (r[cross[0] + 1] - r[cross[0]])) if cross else None)
    return {"emulated_closed_loop_onset_mps": onset,
            "onset_error": None if onset is None else onset / pred_mps - 1.0,
            "onset_airspeeds_mps": speeds.tolist(), "onset_growth_rates_per_s": list(rates)}


def main(argv: Sequence[str] | None = None) -> int:
    ap = OneLineParser(prog="panel-rig control-demo", description=__doc__.splitlines()[0])
    ap.add_argument("--delay-ms", type=float, default=2.0,
                    help="command age the rig emulates (lock-step), ms; e.g. the p99 of benchmarks/control_latency.py; its "
                         "prediction is panel-rig flutter --control --command-age-ms (default: %(default)s)")
    ap.add_argument("--out", default="out/control_demo",
                    help="directory for the Rerun file and summary.json (default: %(default)s)")
    ap.add_argument("--bag-dir", default="bags", help="directory for the node's bag (default: %(default)s)")
    ap.add_argument("--json", action="store_true", help="print the summary as one JSON object on stdout")
    args = ap.parse_args(argv)
    if not (math.isfinite(args.delay_ms) and 0 <= args.delay_ms <= 50):
        print(f"panel-rig control-demo: --delay-ms must be in [0, 50], got {args.delay_ms:g}", file=sys.stderr)
        return 2
    try:  # before anything runs: a directory that cannot be made was a traceback after the design; checked without
        # a trace (`run` makes them once the design is accepted: a refused command age left two empty directories)
        check_output_dir(args.out, "--out")
        check_output_dir(args.bag_dir, "--bag-dir")
    except ValueError as exc:
        print(f"panel-rig control-demo: {exc}", file=sys.stderr)
        return 2
    t0 = time.monotonic()
    try:
        with sigterm_exits():  # a kill leaves through run's clean-up: the node does not go on recording
            # absolute paths in the summary (bag, .rrd, logs), whichever directory it is read from
            s = run(args.delay_ms, Path(args.out).resolve(), Path(args.bag_dir).resolve(),
                    log=(lambda m: print(m, file=sys.stderr)) if args.json else print)
    except DemoError as exc:
        print(f"panel-rig control-demo: {exc}", file=sys.stderr)
        return 1
    except Interrupted as stopped:  # Ctrl-C, SIGTERM: node and controller stopped, summary.json written
        print(f"panel-rig control-demo: {stopped.message}", file=sys.stderr, flush=True)
        if args.json:
            print(jsonio.dumps(stopped.payload))
        return stopped.exit_status
    ok = s.get("quiet") and s.get("onset_error") is not None and abs(s["onset_error"]) <= 0.05 and s["bag"]
    if args.json:
        print(jsonio.dumps(s))
    else:
        onset = s.get("emulated_closed_loop_onset_mps")
        print(f"\nopen-loop U_f {s['open_loop_flutter_speed_mps']:.3f} m/s; closed loop: predicted "
              f"{s['closed_loop_flutter_speed_mps']:.3f} m/s, emulated onset "
              + ("not bracketed" if onset is None else f"{onset:.3f} m/s ({100 * s['onset_error']:+.1f} %)"))
        print(f"quiet at 1.2 U_f: {'yes' if s.get('quiet') else 'NO'} (tip RMS {s['quiet_tip_rms_m'] * 1e6:.2f} um)")
        print(f"bag: {s['bag']}\nrerun: {s['rerun']}\nsummary: {Path(args.out) / 'summary.json'}  "
              f"({time.monotonic() - t0:.0f} s wall)")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
