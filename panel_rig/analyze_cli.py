"""``panel-rig analyze``: glue between the bag loader (:mod:`panel_rig.recording.series`) and the analysis
(:mod:`panel_rig.analysis.bag_analysis`): the plateau table and onset, the flutter-test replay, PNG plots and a
Rerun replay of a recording. Bad or damaged bags exit with status 2 and one line on stderr.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import time
from pathlib import Path
from typing import Any, Callable, NamedTuple, Sequence

import numpy as np

from panel_rig import jsonio
from panel_rig.config import ConfigError, PanelConfig
from panel_rig.model.options import VARIANTS
from panel_rig.paths import make_output_dir, prepare_rrd_path

ANALYZE_PROG = "panel-rig analyze"
FLUTTER_TEST_PLOT = "flutter_test_vg.png"  # with --plots, when the replay identified a test point


def _bag_size_mb(bag_dir: Path) -> float:
    return sum(f.stat().st_size for f in bag_dir.glob("*.mcap") if f.is_file()) / 1e6 if bag_dir.is_dir() else 0.0


def analyze_bag(bag_dir: Any, plots_dir: Any = None, rerun_path: Any = None, criteria: Any = None,
                progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Analyse a rig bag: per-plateau metrics and onset; optional PNG plots and `.rrd`. ``progress``: called with
    a line at each stage (a long recording takes ~0.03 s a MB to check and read).

    Raises RecordingError (CorruptBagError for a damaged bag, naming `panel-rig bag recover`)."""

    from panel_rig.analysis.bag_analysis import Criteria, analyze_series, write_plots
    from panel_rig.recording.series import load_series

    say = progress if progress is not None else (lambda line: None)
    crit = criteria if criteria is not None else Criteria()
    t0 = time.monotonic()
    say(f"checking and reading {bag_dir} ({_bag_size_mb(Path(bag_dir)):.0f} MB)")
    rec = load_series(Path(bag_dir), shapes=rerun_path is not None)
    span = f"{rec.t_s[-1] - rec.t_s[0]:.1f} s" if rec.t_s.size else "no time"
    say(f"read {rec.t_s.size} readings ({span}) in {time.monotonic() - t0:.1f} s; finding the plateaus and the "
        "flutter-test points")
    if criteria is None:  # "quiet" above the run's sensor noise: a panel at rest read 5 um of noise, "stationary"
        crit = dataclasses.replace(crit, quiet_rms=quiet_rms_of(rec.parameters, rec.panel_length_m, crit.quiet_rms))
    core = analyze_series(rec.t_s, rec.tip_w_over_L, rec.airspeed_mps, rec.commands, crit,
                          abort_times_s=[t for t, _ in rec.aborts],
                          control_timeout_s=control_timeout_s(rec.parameters))
    result: dict[str, Any] = {
        "bag": str(rec.bag_dir), "panel_length_m": rec.panel_length_m, "panel_length_source": rec.length_source,
        "missing_parameters": missing_parameters(rec.parameters),
        "variant": rec.parameters.get("model.variant", rec.parameters.get("variant")),
        "refused_commands": rec.refused_commands, **core,
        "aborts": [{"time_s": t, "reason": reason} for t, reason in rec.aborts],
        "monitor_flutter": [{"time_s": t, "airspeed_mps": u} for t, u in rec.monitor_flutter],
    }
    replay = _replay(rec)
    result["flutter_test"], ft_points = (replay.payload, replay.points) if replay else (None, [])
    ft_times = replay.ends_s if replay else []
    if plots_dir is not None:
        say(f"writing the plots to {plots_dir}")
    result["plots"] = (write_plots(Path(plots_dir), rec.t_s, rec.tip_w_over_L, rec.airspeed_mps, result,
                                   rec.commands) if plots_dir is not None else [])
    if plots_dir is not None and replay is not None and replay.points:
        result["plots"].append(_plot_replay(replay, Path(plots_dir) / FLUTTER_TEST_PLOT))
    if rerun_path is not None:
        say(f"writing the Rerun recording {rerun_path}")
    result["rerun"] = (_write_rerun(rec, Path(rerun_path), result, ft_points, ft_times) if rerun_path is not None
                       else None)
    return result


def missing_parameters(parameters: dict[str, Any]) -> list[str]:
    """The physics parameters (config.SCHEMA) a recording's parameter record lacks: their defaults are used for
    the analysis. A bag of an older version, or a damaged record: the MCAP's metadata record carries no checksum,
    and one flipped bit turned `panel.length_m` into `panel*length_m`, read as "L = 0.27 m (default)" without a
    word. Empty when the bag has no parameter record at all (the length line says "default" then)."""
    from panel_rig.config import SCHEMA

    return sorted(set(SCHEMA) - set(parameters)) if parameters else []


#: a plateau whose envelope stays below this many times the tip sensor's noise (w/L) is "quiet": it did not move
QUIET_NOISE_FACTOR = 2.0


def quiet_rms_of(parameters: dict[str, Any], panel_length_m: float, floor: float) -> float:
    """The "quiet" threshold (w/L) of a run: QUIET_NOISE_FACTOR x its tip sensor's noise (white noise and the
    quantisation step's q / sqrt(12), from the bag's parameters), at least ``floor``."""
    def number(key: str) -> float:
        value = parameters.get(key)
        return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else 0.0

    noise_m = math.hypot(number("sensor.tip_noise_m"), number("sensor.resolution_m") / math.sqrt(12.0))
    return max(floor, QUIET_NOISE_FACTOR * noise_m / panel_length_m)


class FlutterTestReplay(NamedTuple):
    """The flutter-test replay of a recording: its JSON part, the identified points (TestPoint), the final
    decision on them, the model of the run's parameters with its linear U_f (m/s) and flutter mode, and when each
    point was identified (its window's end, s)."""

    payload: dict[str, Any]
    points: list[Any]
    decision: Any
    model: Any
    uf_mps: float
    mode: int
    ends_s: list[float]


def control_timeout_s(parameters: dict[str, Any]) -> float:
    """The run's control watchdog (s): its recorded ``control.timeout_s``, or the rig's default for a run that did
    not record one."""
    from panel_rig.topics import CONTROL_TIMEOUT_S

    timeout = parameters.get("control.timeout_s")
    return float(timeout) if isinstance(timeout, (int, float)) and timeout > 0 else CONTROL_TIMEOUT_S


def _replay(rec: Any) -> FlutterTestReplay | None:
    """The flutter-test identification and predictors on a recording (the same core as `panel-rig flutter-test`):
    per airspeed plateau of the subcritical ascent the identified flutter-mode frequency and damping (95 %), and
    the predicted U_f. Bands from the model of the run's parameters (defaults for keys it lacks). None when the
    bag has no airspeed commands or the model does not flutter."""
    from panel_rig.analysis.bag_analysis import control_spans
    from panel_rig.analysis.flutter_test import (
        DEFAULT_SETTLE_S,
        FlutterTestSettings,
        bands_from_model,
        decide,
        no_point_reason,
        replay_points,
    )
    from panel_rig.analysis.vg import model_flutter_speed
    from panel_rig.config import SCHEMA, config_from_flat
    from panel_rig.model.stepper import Stepper

    cmds = rec.commands.get("airspeed_cmd", [])
    if not cmds:
        return None
    try:
        cfg = config_from_flat({k: v for k, v in rec.parameters.items() if k in SCHEMA})
    except ConfigError:
        cfg = PanelConfig()
    variant = rec.parameters.get("model.variant", "full")
    model = Stepper(cfg, variant=variant if variant in VARIANTS else "full").model
    found = model_flutter_speed(model)
    if found is None:
        return None
    uf, mode = found
    force = rec.force_npm if np.any(rec.force_npm) else None
    # a node run with the flutter monitor recorded its test-point window: replay exactly that window
    # (a run without the monitor records the flutter_test.* defaults too: its plateaus are replayed whole)
    monitored = rec.parameters.get("flutter_monitor") is True
    window = {k: float(rec.parameters[f"flutter_test.{k}"]) for k in ("settle_s", "dwell_s")
              if monitored and isinstance(rec.parameters.get(f"flutter_test.{k}"), (int, float))}
    # (a flutter test's, whose node holds after each point: only the windows it completed; a test stopped during a
    # dwell took no point there, though the node identifies a cut plateau of the minimum dwell)
    flutter_test = monitored and rec.parameters.get("flutter_test.hold") is True
    skipped: list[str] = []
    ends: list[float] = []
    points = replay_points(rec.t_s, rec.tip_w_over_L * rec.panel_length_m, cmds, bands_from_model(model, mode),
                           rec.panel_length_m, force, airspeed_mps=rec.airspeed_mps,
                           complete_only=flutter_test and "dwell_s" in window, skipped=skipped,
                           closed_loop_s=control_spans(rec.commands, control_timeout_s(rec.parameters)),
                           ends_s=ends, **window)
    margin = float(rec.parameters.get("flutter_test.margin", 0.1))
    out: dict[str, Any] = {"test_points": [p.as_dict() for p in points], "model_flutter_speed_mps": uf,
                           "predicted_flutter_speed_mps": None, "predicted_flutter_speed_ci_mps": None,
                           "prediction_method": None, "margin": None, "required_margin": margin}
    if not points:
        out["no_test_point_reason"] = no_point_reason(skipped, window.get("settle_s", DEFAULT_SETTLE_S))
    d = None
    if points:
        d = decide(points, FlutterTestSettings(start_mps=points[0].airspeed_mps, step_mps=0.0, margin=margin))
        if d.prediction is not None:
            pd = d.prediction.as_dict()  # open (infinite) bounds as null
            out.update(predicted_flutter_speed_mps=pd["predicted_flutter_speed_mps"],
                       predicted_flutter_speed_ci_mps=pd["predicted_flutter_speed_ci_mps"],
                       prediction_method=d.prediction.method,
                       margin=d.prediction.margin(points[-1].airspeed_mps))
    return FlutterTestReplay(out, points, d, model, uf, mode, ends)


def _plot_replay(replay: FlutterTestReplay, path: Path) -> str:
    """The replay's V-g figure (the one `panel-rig flutter-test --plot` draws)."""
    from panel_rig.analysis.flutter_test import FlutterTestResult
    from panel_rig.analysis.plots import plot_flutter_test

    res = FlutterTestResult(points=list(replay.points), decisions=[replay.decision])
    title = f"flutter-test replay of the recording (panel-rig analyze): {len(res.points)} point(s)"
    return str(plot_flutter_test(res, replay.model, replay.mode, replay.uf_mps, path, title))


def _write_rerun(rec: Any, path: Any, result: dict[str, Any] | None = None, ft_points: list[Any] = (),
                 ft_times: list[float] = ()) -> str:
    """The recording as a Rerun `.rrd` through the rig's own logger (same entities as live), with the analysis of
    ``result``: the plateaus' status and the onset (text log), and the flutter-test replay's identified points
    (flutter monitor views, each at ``ft_times``: when it was identified). The blueprint holds only views with
    data: control views when the bag has control commands, the flutter views when the replay identified a point,
    the analysis log when there are plateaus, the modal and panel-shape views when the bag has modal states and
    shapes."""
    from panel_rig.analysis.flutter_test import margin_points
    from panel_rig.topics import CONTROL_TOPIC
    from panel_rig.viz import RerunLogger

    n_modes = rec.q.shape[1]  # 0: the bag has no modal states (a flutter test's), no modal view
    result = result or {}
    control = rec.commands.get(CONTROL_TOPIC, [])
    decisions = _replay_decisions(ft_points, rec.parameters)
    views = (("control",) if control else ()) + (("flutter",) if ft_points else ()) + (
        ("flutter_uf",) if any(d.prediction is not None for d in decisions) else ()) + (
        ("flutter_zw",) if margin_points(ft_points)[0].size else ()) + (
        ("analysis",) if result.get("plateaus") else ())
    logger = RerunLogger(n_modes, mode="save", target=str(path), recording_name=rec.bag_dir.name, views=views,
                         shape=bool(rec.shapes))
    try:
        logger.log_batch(rec.t_s, rec.tip_w_over_L, rec.q, np.nan_to_num(rec.airspeed_mps), rec.force_npm)
        for name, events in rec.commands.items():
            for t, value in events:
                logger.on_command(name, value, True, t)
        for t, value in control:  # the command's age is not in the bag: 0
            logger.log_control(t, value, 0.0)
        for t, x, z in rec.shapes:
            logger.log_shape(t, x, z)
        margin = float(rec.parameters.get("flutter_test.margin", 0.1))
        for k, (t, d) in enumerate(zip(ft_times, decisions), start=1):
            logger.log_flutter_point(t, ft_points[:k], d, margin)
        _log_analysis(logger, result)
    finally:
        logger.close()
    return str(path)


def _replay_decisions(points: list[Any], parameters: dict[str, Any]) -> list[Any]:
    """The decision the flutter test would take after each replayed point (as :func:`_replay`)."""
    from panel_rig.analysis.flutter_test import FlutterTestSettings, decide

    if not points:
        return []
    margin = float(parameters.get("flutter_test.margin", 0.1))
    settings = FlutterTestSettings(start_mps=points[0].airspeed_mps, step_mps=0.0, margin=margin)
    return [decide(points[:k], settings) for k in range(1, len(points) + 1)]


def _log_analysis(logger: Any, result: dict[str, Any]) -> None:
    """Each plateau's status at its end and the onset line at the end of the last plateau (text log)."""
    plateaus = result.get("plateaus") or []
    for p in plateaus:
        logger.log_text(p["t_end_s"], "analysis/plateaus",
                        f"plateau {p['index']}: {p['airspeed_mps']:.2f} m/s {p['status']} (rms w/L "
                        f"{p['rms_tip_w_over_L']:.3g}, peak {p['peak_tip_w_over_L']:.3g}, "
                        f"{p['dominant_frequency_hz']:.2f} Hz, rate {p['growth_rate_per_s']:.3f} 1/s"
                        + (", closed loop)" if p.get("loop") == "closed" else ")"),
                        warn=p["status"] in ("lco", "growing"))
    for line, onset in onset_lines(result):
        logger.log_text(plateaus[-1]["t_end_s"], "analysis/onset", line, warn=onset["bracket_high_mps"] is not None)


def _hz(f_hz: float | None) -> str:
    """A frequency for the table: "-" for none (the operator's table has it so; "nan" read as a fault)."""
    return "-" if f_hz is None or not math.isfinite(f_hz) else f"{f_hz:.2f}"


MAX_GAPS_SHOWN = 10  # gaps listed in the table (a line of thousands was 80 kB)
HELD_DEFLECTION_W_OVER_L = 1e-4  # a plateau's mean tip w/L named under the table above this (and above its RMS)


def _rate(plateau: dict[str, Any]) -> str:
    """A plateau's growth rate for the table: "-" for a stationary or quiet one, which has no measured rate (its
    envelope's drift; the JSON keeps it), and no '-0.000'."""
    if plateau["status"] in ("stationary", "quiet") or plateau.get("growth_rate_per_s") is None:
        return "-"
    return f"{round(plateau['growth_rate_per_s'], 3) + 0.0:.3f}"  # + 0.0: no '-0.000'


def num(x: float | None) -> str:
    """A number for the table, two decimals; "-" for none."""
    return "-" if x is None else f"{x:.2f}"


def onset_line(o: dict[str, Any], crit: dict[str, Any]) -> str:
    """The table's flutter-onset line of an `analyze_bag` result's ``onset`` (``crit``: its ``criteria``)."""
    # an estimate that could not be made says why ("- m/s" read as a figure lost)
    extrapolated = (f"{num(o['extrapolated_mps'])} m/s" if o["extrapolated_mps"] is not None
                    else "none (the rates do not rise towards 0)" if len(o["extrapolation_points"]) >= 2
                    else "none (needs two plateaus with a measured decay)")
    interpolated = (f"{num(o['interpolated_mps'])} m/s" if o["interpolated_mps"] is not None
                    else "none (needs a measured growth at the bracket's top and a decay at its bottom)")
    if o["bracket_high_mps"] is None:  # "bracket 0.00 .. -" read as an onset found
        # (a wind-off plateau is no evidence: "stable up to 0.00 m/s" after a first point that fluttered)
        low, wind_on_mps = o["bracket_low_mps"], crit.get("min_extrapolation_airspeed_mps", 0.5)
        return ("flutter onset: no plateau was unstable"
                + (f" (stable up to {num(low)} m/s)" if low is not None and low > wind_on_mps else "")
                + f"; extrapolated from decay rates: {extrapolated}")
    if o["bracket_low_mps"] is None:  # "bracket 0.00 .. 12.00" (the tunnel at rest) read as a lower bound
        return (f"flutter onset: at or below {num(o['bracket_high_mps'])} m/s (no stable plateau with the wind "
                f"on before it); extrapolated from decay rates: {extrapolated}")
    low, high = num(o["bracket_low_mps"]), num(o["bracket_high_mps"])
    if low == high:  # two plateaus at one nominal airspeed ("9.00 .. 9.00"): the digits that tell them apart
        low, high = f"{o['bracket_low_mps']:.3f}", f"{o['bracket_high_mps']:.3f}"
    return (f"flutter onset bracket: {low} .. {high} m/s; "
            f"extrapolated from decay rates: {extrapolated}; interpolated across the bracket: {interpolated}")


def onset_lines(result: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """(line, onset) of each loop that has plateaus: the open loop's onset, then the closed loop's (its line says
    so: the controller's flutter speed, not the panel's)."""
    plateaus = result.get("plateaus") or []
    crit = result.get("criteria") or {}
    out = []
    if any(p.get("loop", "open") == "open" for p in plateaus):
        out.append((onset_line(result["onset"], crit), result["onset"]))
    if result.get("closed_loop_onset"):
        out.append(("closed loop: " + onset_line(result["closed_loop_onset"], crit), result["closed_loop_onset"]))
    return out


def format_table(result: dict[str, Any]) -> str:
    """Human-readable plateau table and onset lines of an `analyze_bag` result."""
    from panel_rig.analysis.flutter_test import prediction_text

    loops = any(p.get("loop") == "closed" for p in result["plateaus"])  # the column only when a loop was closed
    head = (f"{'#':>2} {'t_s':>13} {'U_mps':>7} {'rms_w/L':>9} {'peak_w/L':>9} {'f_Hz':>6} "
            f"{'rate_1/s':>8} " + ("loop   " if loops else "") + "status")
    lines = [f"{result['bag']}: {result['duration_s']:.1f} s, {result['samples']} samples, "
             f"L = {result['panel_length_m']:g} m ({result['panel_length_source']})"]
    missing = result.get("missing_parameters") or []
    if missing:
        lines.append(f"warning: the recorded parameters lack {', '.join(missing)} (a damaged record, or an older "
                     "bag): their defaults are used")
    refused = result.get("refused_commands") or {}
    if refused:
        lines.append("commands the rig refused (left out): "
                     + ", ".join(f"{topic} {count}" for topic, count in sorted(refused.items())))
    for a in result.get("aborts") or []:  # a run that ended in an abort showed only its plateaus
        lines.append(f"rig aborted at t = {a['time_s']:.3f} s (rig time): {a['reason']}")
    for f in result.get("monitor_flutter") or []:  # a plateau cut short by its flutter is often no plateau here
        lines.append(f"flutter monitor: the panel fluttered at {f['airspeed_mps']:.3f} m/s "
                     f"(reported at t = {f['time_s']:.3f} s, rig time)")
    gaps = result.get("gaps") or []
    if gaps:  # (a real-time node's overrun shifts its stamps too: a jump, not a reading lost)
        shown = ", ".join(f"{g['from_s']:.2f}-{g['to_s']:.2f} s" for g in gaps[:MAX_GAPS_SHOWN])
        more = f" and {len(gaps) - MAX_GAPS_SHOWN} more (JSON: gaps)" if len(gaps) > MAX_GAPS_SHOWN else ""
        lines.append("gaps in the time stamps (a chunk a recovery dropped, or a real-time node's overrun that shifted "
                     f"its clock; no plateau spans one): {shown}{more}")
    crit = result.get("criteria") or {}
    if result["plateaus"]:
        lines.append(head)
    else:  # an empty table and "flutter onset: no plateau was unstable" read as a run that stayed stable
        lines.append(f"no plateau: the airspeed stays within {crit.get('tol_mps', 0.05):g} m/s for "
                     f"{crit.get('min_duration_s', 3.0):g} s nowhere in this {result['duration_s']:.1f} s; no flutter "
                     "onset to bracket")
    for p in result["plateaus"]:
        lines.append(
            f"{p['index']:>2} {p['t_start_s']:>6.1f}-{p['t_end_s']:<6.1f} {p['airspeed_mps']:>7.2f} "
            f"{p['rms_tip_w_over_L']:>9.4g} {p['peak_tip_w_over_L']:>9.4g} {_hz(p['dominant_frequency_hz']):>6} "
            f"{_rate(p):>8} " + (f"{p.get('loop', 'open'):<6} " if loops else "") + p["status"]
        )
    for p in result["plateaus"]:  # a force held on the shaker: the table's RMS is the motion about the deflection
        mean = p.get("mean_tip_w_over_L") or 0.0
        if abs(mean) > max(p["rms_tip_w_over_L"], HELD_DEFLECTION_W_OVER_L):
            lines.append(f"plateau {p['index']}: the tip is held at w/L = {mean:.4g} on average (a static deflection, "
                         "a force held on the shaker); rms_w/L is the motion about it")
    lines.extend(line for line, _ in onset_lines(result))
    ft = result.get("flutter_test")
    if ft and not ft["test_points"] and ft.get("no_test_point_reason"):
        lines.append(f"flutter-test replay: no test point ({ft['no_test_point_reason']})")
    if ft and ft["test_points"]:
        lines.append("flutter-test replay (subcritical ascent; flutter mode, 95 % intervals):")
        for p in ft["test_points"]:
            ci = p["damping_ci"]
            lines.append(f"   U {p['airspeed_mps']:7.3f} m/s  f {num(p['frequency_hz'])} Hz  zeta "
                         + ("-" if p["damping_ratio"] is None else
                            f"{p['damping_ratio']:.4f} [{ci[0]:.4f}, {ci[1]:.4f}]") + f"  {p['method']}")
        pred = prediction_text(ft["predicted_flutter_speed_mps"], ft["predicted_flutter_speed_ci_mps"],
                               ft["prediction_method"], digits=2)
        lines.append(f"   {pred}; model linear U_f {ft['model_flutter_speed_mps']:.2f} m/s")
    for path in result.get("plots") or []:
        lines.append(f"plot: {path}")
    if result.get("rerun"):
        lines.append(f"rerun: {result['rerun']}")
    return "\n".join(lines)


def add_analyze_arguments(p: argparse.ArgumentParser) -> None:
    """The `analyze` options."""
    p.add_argument("bag", metavar="BAG", help="rosbag2 directory (metadata.yaml + .mcap)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--plots", metavar="DIR",
                   help="write time_history/spectrogram/lco_vs_airspeed PNGs here (and flutter_test_vg.png when the "
                        "flutter-test replay identified a point)")
    p.add_argument("--rerun", metavar="OUT.rrd", help="write the replay as a Rerun recording")


def cmd_analyze(args: argparse.Namespace) -> int:
    """0 ok; 2 bad or damaged bag (one stderr line; a damaged one names `panel-rig bag recover`);
    1 cannot write outputs."""
    from panel_rig.recording.errors import RecordingError

    try:  # before the analysis: a --rerun or --plots that cannot be written threw the whole result away
        if args.rerun is not None:
            prepare_rrd_path(args.rerun, "--rerun")
        if args.plots is not None:
            make_output_dir(args.plots, "--plots")
    except ValueError as exc:
        print(f"{ANALYZE_PROG}: {exc}", file=sys.stderr)
        return 2
    try:
        # stage lines on a terminal (a long bag was minutes of silence); a log or a pipe keeps one line per error
        result = analyze_bag(args.bag, args.plots, args.rerun, progress=(
            (lambda line: print(f"{ANALYZE_PROG}: {line}", file=sys.stderr, flush=True)) if sys.stderr.isatty()
            else None))
    except RecordingError as exc:
        print(f"{ANALYZE_PROG}: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"{ANALYZE_PROG}: {exc.filename or args.bag}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    except Exception as exc:  # noqa: BLE001 - e.g. VizError: never a traceback
        print(f"{ANALYZE_PROG}: {args.bag}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 2
    print(jsonio.dumps(result, indent=2) if args.json else format_table(result))
    return 0


def analyze_main(argv: Sequence[str] | None = None) -> int:
    """`panel-rig analyze BAG [--json] [--plots DIR] [--rerun OUT.rrd]` on its own (usage error: exit 2)."""

    class _AnalyzeParser(argparse.ArgumentParser):
        def error(self, message: str) -> None:  # one line, status 2
            print(f"{ANALYZE_PROG}: {message}", file=sys.stderr)
            raise SystemExit(2)

    parser = _AnalyzeParser(prog=ANALYZE_PROG, description="airspeed plateaus, LCO and flutter onset from a bag")
    add_analyze_arguments(parser)
    return cmd_analyze(parser.parse_args(argv))
