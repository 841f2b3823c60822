"""The ``panel-rig`` command: modal and flutter analysis, LCO and forced-response runs, the paper report.

Every subcommand takes ``--params FILE`` (a ROS 2 parameters file, default the paper's) and repeatable
``--set KEY=VALUE`` overrides. Bad input exits with status 2 and one line on stderr.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from panel_rig import jsonio
from panel_rig.analysis.flutter_test import FlutterTestSettings
from panel_rig.analysis.run_checks import coarse_step_warning, forced_settling_warning
from panel_rig.analyze_cli import add_analyze_arguments, cmd_analyze
from panel_rig.config import MAX_DURATION_S, ConfigError, PanelConfig, load_config
from panel_rig.model.options import (
    DEFAULT_AERO,
    DEFAULT_SCHEME,
    DEFAULT_VARIANT,
    RIG_AERO_MODELS,
    SCHEMES,
    VARIANTS,
    stepper_problem,
)
from panel_rig.paths import check_output_dir, make_output_dir, prepare_rrd_path, rrd_path_problem
from panel_rig.processes import BROKEN_PIPE_STATUS, INTERRUPTED_STATUS, Aborted, StoppedRun


class UsageError(Exception):
    """Bad command-line input: reported as one line on stderr, exit status 2."""


def _config(args: argparse.Namespace) -> PanelConfig:
    """The run's configuration; also refuses a ``--plot`` that is not a .png file name or whose directory cannot
    be made and written in, before any computation (matplotlib appended .png to other names, and the JSON named a
    file that was never written; a directory it could not write in lost a finished hour-long run). The directory is
    made when the figure is saved, so a command refused for another option leaves none behind."""
    plot = getattr(args, "plot", None)
    if plot is not None:
        if Path(plot).suffix.lower() != ".png":
            raise UsageError(f"--plot must name a .png file, got {plot!r}")
        if Path(plot).is_dir() or str(plot).endswith(("/", os.sep)):  # `x.png/` wrote the file x.png
            raise UsageError(f"--plot: {plot} is a directory: name the .png file in it")
        check_output_dir(Path(plot).parent, "--plot")
    return load_config(args.params, args.set or ())


def _march_checks(args: argparse.Namespace, cfg: PanelConfig) -> None:
    """For a command that marches the equations in time, once its own refusals are through (a warning, then an
    error, read as two results): its options as the stepper will take them, then the step's warning."""
    problem = stepper_problem(getattr(args, "variant", DEFAULT_VARIANT), getattr(args, "aero", DEFAULT_AERO),
                              getattr(args, "scheme", DEFAULT_SCHEME))
    if problem:
        raise UsageError(problem)
    coarse = coarse_step_warning(cfg)
    if coarse:
        _note(coarse)


MAX_RANGE_POINTS = 10_000


def _some(values: Sequence[Any], shown: int = 5) -> str:
    """A list in an error line: its first ``shown`` values and how many more."""
    more = f" and {len(values) - shown} more" if len(values) > shown else ""
    return ", ".join(f"{v:g}" if isinstance(v, float) else str(v) for v in values[:shown]) + more


def _duration(value: float, option: str, cfg: PanelConfig, least_s: float = 0.0) -> float:
    """Simulated seconds: at least one physics step (and ``least_s``), at most MAX_DURATION_S."""
    low = max(cfg.dt_s, least_s)
    if not (np.isfinite(value) and low <= value <= MAX_DURATION_S):
        raise UsageError(f"{option} must be in [{low:g}, {MAX_DURATION_S:g}] s (simulated), got {value}")
    return value


def _points(a: float, b: float, step: float, option: str) -> np.ndarray:
    """a, a + step, ... up to b (inclusive to half a step), at most MAX_RANGE_POINTS of them."""
    if not (np.isfinite(a) and np.isfinite(b) and np.isfinite(step)) or step <= 0 or b < a:
        raise UsageError(f"{option} needs finite bounds, STOP >= START and STEP > 0, got {a:g}:{b:g}:{step:g}")
    n = int(np.ceil((b + 0.5 * step - a) / step))  # what np.arange(a, b + step / 2, step) makes, before making it
    if n > MAX_RANGE_POINTS:
        raise UsageError(f"{option} gives {n} points, more than {MAX_RANGE_POINTS}: use a larger step")
    # a + k step, rounded to 10 decimals: the points the user typed (np.arange's 12.549999999999999 for 10:27:0.85
    # reached the JSON); the rounding moves none by more than 5e-11
    return np.round(a + step * np.arange(n), 10)


def _emit(args: argparse.Namespace, payload: dict[str, Any], table: Callable[[], str]) -> None:
    if args.json:
        print(jsonio.dumps(payload))
    else:
        print(table())


# ---- subcommands ------------------------------------------------------------------------------
LINEAR_NOTE = ("linear analysis: every variant linearises at rest to the same model (the cubic terms vanish; exact: "
               "its own M(0) by quadrature, = m_p L^3 I to 1.5e-9)")


def cmd_modes(args: argparse.Namespace) -> int:
    from panel_rig.model.linearisation import natural_frequencies_hz
    from panel_rig.model.structure import build_structure

    cfg = _config(args)
    s = build_structure(cfg)
    f = natural_frequencies_hz(s, args.variant)
    payload = {"natural_frequencies_hz": f, "beta_L": s.beta, "variant": args.variant,
               "modal_mass_kg_per_m": s.modal_mass_kg, "bending_stiffness_nm": cfg.bending_stiffness_nm}
    _emit(args, payload, lambda: f"variant {args.variant} ({LINEAR_NOTE})\nmode  beta_L     f (Hz)\n" + "\n".join(
        f"{i + 1:>4}  {b:7.4f}  {fi:9.3f}" for i, (b, fi) in enumerate(zip(s.beta, f))))
    return 0


def cmd_flutter(args: argparse.Namespace) -> int:
    from panel_rig.analysis.flutter import (
        UnstableAtScanStart,
        eigenvalues,
        find_flutter,
        flutter_point,
        instability_ranges,
    )
    from panel_rig.model.aeroelastic import AeroelasticModel
    from panel_rig.model.linearisation import linear_mass_matrix_kg
    from panel_rig.model.structure import build_structure

    cfg = _config(args)
    model = AeroelasticModel(cfg, linear_mass_kg=linear_mass_matrix_kg(build_structure(cfg), args.variant))
    rom_modes = args.rom_modes if args.rom_modes is not None else cfg.rom_modes
    if rom_modes < 1:
        raise UsageError("--rom-modes must be >= 1")
    _flutter_options_apply(args)
    if args.control:
        return _flutter_control(args, cfg, model, rom_modes)
    kw = dict(aero=args.aero, rom_modes=rom_modes if args.aero == "rom" else None,
              formulation=args.formulation)
    from panel_rig.model.aerodynamics import MAX_AIRSPEED_MPS

    # over the whole airspeed range every command takes (find_flutter's default; it stopped at 60 m/s: a 1.2 mm panel
    # that flutters near 60-70 m/s was "no flutter"); the same 1 m/s scan, so a flutter speed below 60 m/s is the
    # same number
    search_max_mps = MAX_AIRSPEED_MPS
    unstable = None  # a result, not a bad input (a study reports such a case as "unstable at 1 m/s")
    try:  # every range, not only the first crossing: a window that closes again is not a flutter boundary
        ranges = instability_ranges(model, **kw, u_max=search_max_mps)
    except UnstableAtScanStart as exc:
        ranges, unstable = [], str(exc)
    fp = flutter_point(model, ranges[0][0], **kw) if ranges else None
    if fp is None:
        payload = {"flutter_speed_mps": None, "flutter_frequency_hz": None, "dominant_mode": None,
                   "mode_shares": None, "unstable_at_scan_start": unstable}
    else:
        payload = {"flutter_speed_mps": fp.speed_mps, "flutter_frequency_hz": fp.frequency_hz,
                   "dominant_mode": fp.dominant_mode, "mode_shares": fp.mode_shares}
    payload.update(searched_up_to_mps=search_max_mps, unstable_ranges_mps=[list(r) for r in ranges])
    payload.update(aero=args.aero, rom_modes=kw["rom_modes"], formulation=args.formulation, variant=args.variant)
    vg = None
    if args.vg:
        from panel_rig.analysis.vg import model_flutter_speed, plot_vg, vg_diagram

        # the stepper's continuous-time model with the ROM (the aero the rig runs), whatever --aero says
        vg = vg_diagram(model, _range(args.vg, "--vg"), aero="rom", rom_modes=rom_modes)
        payload["vg"] = vg.as_json()
        # the poles' model, which "aero" / "formulation" above (the flutter search's) need not be
        payload["vg_model"] = {"aero": "rom", "rom_modes": rom_modes, "formulation": "continuous"}
        if args.plot:
            uf = model_flutter_speed(model, aero="rom", rom_modes=rom_modes)
            payload["plot"] = str(plot_vg(vg, args.plot, uf[0] if uf else None, f"(ROM Ra={rom_modes})"))
    if args.plot and vg is None:
        from panel_rig.analysis.plots import plot_flutter_roots

        speeds = np.linspace(1.0, 20.0, 39)
        curves, marks = {}, {}
        for label, akw in (("full (all vortices)", dict(aero="full", rom_modes=None)),
                           (f"ROM Ra={rom_modes}", dict(aero="rom", rom_modes=rom_modes))):
            curves[label] = (speeds, [eigenvalues(model, u, formulation=args.formulation, **akw).s
                                      for u in speeds])
            try:
                p = fp if akw["aero"] == args.aero else find_flutter(model, formulation=args.formulation, **akw)
            except UnstableAtScanStart:
                p = None
            if p is not None:
                marks[label] = (p.speed_mps, p.frequency_hz)
        payload["plot"] = str(plot_flutter_roots(curves, args.plot, marks))

    def table() -> str:
        if unstable is not None:
            text = (f"no flutter speed: {unstable}, the scan's lowest airspeed (the model turns unstable at or "
                    "below it)")
        elif fp is None:
            text = f"no flutter found up to {search_max_mps:g} m/s (the incompressible lattice's limit)"
        else:
            text = (f"variant            {args.variant} ({LINEAR_NOTE})\n"
                    f"flutter speed      {fp.speed_mps:8.3f} m/s ({_model_label(args.aero, kw['rom_modes'])}, "
                    f"{args.formulation})\n"
                    f"flutter frequency  {fp.frequency_hz:8.3f} Hz\n"
                    f"dominant mode      {fp.dominant_mode} (|q| shares {np.round(fp.mode_shares, 3).tolist()})")
            if ranges[0][1] is not None:  # a window that closes again: the flutter speed is not a boundary
                low_rom = ("; the aero ROM is least accurate at low airspeed (high reduced frequency): compare "
                           "--aero full") if args.aero == "rom" and fp.speed_mps < 0.5 * search_max_mps else ""
                text += (f"\nunstable           {_ranges_text(ranges, False)} (the first range closes again: a "
                         f"window of instability{low_rom})")
        if vg is not None:
            n = vg.poles.shape[1]
            text += f"\n\nV-g of the model the stepper marches ({_model_label('rom', rom_modes)}, continuous time):"
            text += "\n U (m/s)" + "".join(f"   f{i + 1} (Hz)  zeta{i + 1}  " for i in range(n)) + "\n" + "\n".join(
                f"{u:8.2f}" + "".join(f"  {f:9.3f} {z:8.5f}" for f, z in zip(fr, zr))
                for u, fr, zr in zip(vg.airspeed_mps, vg.frequency_hz, vg.damping_ratio))
        if payload.get("plot"):
            text += f"\nplot               {payload['plot']}"
        return text

    _emit(args, payload, table)
    return 0


def _model_label(aero: str, rom_modes: int | None) -> str:
    return "full lattice" if aero == "full" else f"ROM Ra={rom_modes}"


def _flutter_options_apply(args: argparse.Namespace) -> None:
    """Refuse options the chosen analysis would silently ignore; fill in the defaults of the others."""
    if args.control:
        ignored = [opt for opt, given in (("--aero full", args.aero == "full"), ("--vg", args.vg),
                                          ("--formulation discrete", args.formulation == "discrete")) if given]
        if ignored:
            raise UsageError(f"--control analyses the ROM in continuous time: {', '.join(ignored)} does not apply")
        args.rate_hz = 500.0 if args.rate_hz is None else args.rate_hz
    else:
        ignored = [opt for opt, given in (("--delay-ms", args.delay_ms), ("--command-age-ms", args.command_age_ms),
                                          ("--rate-hz", args.rate_hz), ("--actuator-bandwidth-hz",
                                                                        args.actuator_bandwidth_hz))
                   if given is not None]
        if ignored:
            raise UsageError(f"{', '.join(ignored)} {'applies' if len(ignored) == 1 else 'apply'} only with --control")
        if args.aero != "rom" and args.rom_modes is not None and not (args.vg or args.plot):
            raise UsageError("--rom-modes sets the ROM: give it with --aero rom, --vg, --plot or --control")
    args.aero = args.aero or "full"
    args.formulation = args.formulation or "discrete"


def _flutter_control(args: argparse.Namespace, cfg: PanelConfig, model: Any, rom_modes: int) -> int:
    """``flutter --control``: open- and closed-loop flutter speed of the linear ROM model (continuous time) with
    the reference law, the control actuator's bandwidth and the loop delay (given, or from a measured command
    age); optional damping plot."""
    from panel_rig.analysis.control import (
        DESIGN_DELAY_S,
        LoopModel,
        closed_loop_flutter,
        damping_curves,
        design_law,
        effective_delay,
        noise_force_rms,
    )
    from panel_rig.rig.control import ControlSettings

    if args.delay_ms is not None and args.command_age_ms is not None:
        raise UsageError("give --delay-ms or --command-age-ms, not both")
    if not (np.isfinite(args.rate_hz) and 1.0 <= args.rate_hz <= 1e5):
        raise UsageError(f"--rate-hz must be in [1, 1e5] Hz, got {args.rate_hz}")
    for name in ("delay_ms", "command_age_ms"):
        v = getattr(args, name)
        if v is not None and not (np.isfinite(v) and 0 <= v <= 100):
            raise UsageError(f"--{name.replace('_', '-')} must be in [0, 100] ms, got {v}")
    bw = args.actuator_bandwidth_hz if args.actuator_bandwidth_hz is not None else ControlSettings().bandwidth_hz
    if not (np.isfinite(bw) and 0 < bw <= 1e4):
        raise UsageError(f"--actuator-bandwidth-hz must be in (0, 1e4], got {bw}")
    if args.command_age_ms is not None:
        delay_s, source = effective_delay(args.command_age_ms * 1e-3, args.rate_hz, cfg.dt_s), "command age"
    elif args.delay_ms is not None:
        delay_s, source = args.delay_ms * 1e-3, "given"
    else:
        delay_s, source = DESIGN_DELAY_S, "design"
    design = design_law(model, bw, rom_modes=rom_modes)
    loop = LoopModel(bw, delay_s)
    u_max = 2.5 * design.open_loop_flutter_mps
    cl = closed_loop_flutter(model, design.law, loop, rom_modes, u_max=u_max, n_scan=40, all_ranges=True)
    payload: dict[str, Any] = {
        "flutter_speed_mps": design.open_loop_flutter_mps,
        "flutter_frequency_hz": design.notes["open_loop_flutter_frequency_hz"],
        "closed_loop_flutter_speed_mps": cl.speed_mps,
        "closed_loop_flutter_frequency_hz": cl.frequency_hz,
        "closed_loop_unstable_at_low_speed": cl.unstable_at_low_speed,
        "closed_loop_unstable_ranges_mps": [list(r) for r in cl.unstable_ranges_mps],
        "ratio": None if cl.speed_mps is None else cl.speed_mps / design.open_loop_flutter_mps,
        "loop_delay_s": delay_s, "loop_delay_source": source, "actuator_bandwidth_hz": bw,
        "law": design.law.as_dict(), "design_delay_s": design.loop.delay_s,
        "robust_delay_s": design.notes["robust_delay_s"], "sensor_noise_m": design.sensor_noise_m,
        "noise_force_rms_npm": noise_force_rms(design.law, args.rate_hz), "controller_rate_hz": args.rate_hz,
        "aero": "rom", "rom_modes": rom_modes, "formulation": "continuous", "variant": args.variant,
    }
    if args.plot:
        from panel_rig.analysis.plots import plot_control_damping

        # from the scan's lowest speed to past the instability that lasts (an early closed band, 0.55-2.4 m/s at
        # 50 ms, gave an axis of 0.5-1 m/s that ended before it did)
        last = cl.unstable_ranges_mps[-1] if cl.unstable_ranges_mps else None
        top = u_max if last is None or last[1] is not None else min(u_max, max(1.6 * last[0], 1.0))
        speeds = np.linspace(0.5, top, 60)
        payload["plot"] = str(plot_control_damping(
            speeds, damping_curves(model, speeds, None, loop, rom_modes),
            damping_curves(model, speeds, design.law, loop, rom_modes), args.plot, design.open_loop_flutter_mps,
            cl.speed_mps, f"rate feedback g = {design.law.gain_nspm2:g} N s/m^2, derivative filter "
                          f"{design.law.derivative_hz:g} Hz, actuator {bw:g} Hz, loop delay {delay_s * 1e3:.2f} ms"))

    def table() -> str:
        if cl.unstable_at_low_speed:  # the loop itself is unstable (too much delay): no flutter speed to quote
            speed = "unstable already at low speed (the loop delay is too long for this law)"
        elif cl.speed_mps is None:
            speed = "stable up to {:.1f} m/s".format(u_max)
        else:
            speed = f"{cl.speed_mps:8.3f} m/s"
        return (f"open-loop flutter speed    {design.open_loop_flutter_mps:8.3f} m/s (ROM, continuous)\n"
                f"closed-loop flutter speed  {speed}"
                + ("" if cl.speed_mps is None else f" (x{cl.speed_mps / design.open_loop_flutter_mps:.3f}, "
                                                   f"{cl.frequency_hz:.2f} Hz)") + "\n"
                + (f"closed loop unstable       {_ranges_text(cl.unstable_ranges_mps, cl.unstable_at_low_speed)}\n"
                   if len(cl.unstable_ranges_mps) > 1 or cl.unstable_at_low_speed else "")
                + f"law                        F = -{design.law.gain_nspm2:g} s/(1 + s/(2 pi "
                f"{design.law.derivative_hz:g})) w   [N/m per m/s]\n"
                f"loop                       actuator {bw:g} Hz, delay {delay_s * 1e3:.3f} ms ({source})"
                + (f"\nplot                       {payload['plot']}" if payload.get("plot") else ""))

    _emit(args, payload, table)
    return 0


def _ranges_text(ranges: Sequence[tuple[float, float | None]], from_lowest: bool) -> str:
    """Unstable airspeed intervals as the table shows them: "0.552-2.437 m/s, from 13.125 m/s"; ``from_lowest``:
    the first is unstable already at the scan's lowest speed ("up to 3.859 m/s", "at every speed scanned")."""
    def text(k: int, lo: float, hi: float | None) -> str:
        if k == 0 and from_lowest:
            return f"up to {hi:.3f} m/s" if hi is not None else f"at every speed scanned ({lo:g} m/s and up)"
        return f"{lo:.3f}-{hi:.3f} m/s" if hi is not None else f"from {lo:.3f} m/s"

    return ", ".join(text(k, lo, hi) for k, (lo, hi) in enumerate(ranges))


class Progress:
    """A one-line progress bar on a terminal (stderr); silent otherwise."""

    def __init__(self, label: str):
        self.label = label
        self.on = sys.stderr.isatty()
        self._last = -1

    def __call__(self, fraction: float) -> None:
        pct = int(100 * fraction)
        if self.on and pct != self._last:
            self._last = pct
            bar = "#" * (pct // 4)
            _note(f"\r{self.label} [{bar:<25}] {pct:3d}%", end="" if pct < 100 else "\n")


def _airspeed(value: float) -> float:
    from panel_rig.model.aerodynamics import MAX_AIRSPEED_MPS

    if not np.isfinite(value) or value < 0 or value > MAX_AIRSPEED_MPS:
        raise UsageError(f"airspeed must be in [0, {MAX_AIRSPEED_MPS:g}] m/s (the incompressible lattice holds to "
                         f"about Mach 0.3), got {value:.10g}")  # 100.0001 read "got 100"
    return value


def cmd_lco(args: argparse.Namespace) -> int:
    from panel_rig.analysis.lco import run_lco

    cfg = _config(args)
    _duration(args.duration, "--duration", cfg)
    _airspeed(args.airspeed)
    _march_checks(args, cfg)
    if args.turbulence_intensity is not None or args.seed is not None:
        # the tunnel: the panel starts at rest and only the turbulence disturbs it (the same Rig as the node)
        from panel_rig.analysis.lco import diverged_result, lco_metrics
        from panel_rig.rig.runs import run_tunnel

        changes: dict[str, Any] = {}
        if args.turbulence_intensity is not None:
            changes["turbulence_intensity"] = args.turbulence_intensity
        if args.seed is not None:
            changes["turbulence_seed"] = args.seed
        cfg = cfg.replace(**changes)
        run = run_tunnel(cfg, _airspeed(args.airspeed), args.duration, args.variant, args.aero, args.scheme,
                         progress=Progress("lco"))
        tip = run.tip_w_over_L
        res = (diverged_result(args.airspeed, run.aborted_at_s) if run.aborted_at_s is not None
               else lco_metrics(tip, run.dt_s, args.airspeed))
        payload = res.as_dict()
        # the rig's stop (the tip at |w/L| = 1 or the wall) is `diverged` too, and says which limit it was
        payload.update(turbulence_intensity=cfg.turbulence_intensity, turbulence_spectrum=cfg.turbulence_spectrum,
                       seed=cfg.turbulence_seed, abort_reason=run.abort_reason)
    else:  # the paper's computation: a quiet tunnel, a small initial 2nd-mode deflection starts the flutter
        res, tip, _ = run_lco(cfg, _airspeed(args.airspeed), args.duration, args.variant, args.aero, args.scheme,
                              keep=bool(args.plot), progress=Progress("lco"))
        payload = res.as_dict()
    for line in lco_warnings(payload, args.duration):
        _note(line)
    if args.plot:
        from panel_rig.analysis.plots import plot_series

        t = np.arange(tip.size) * cfg.dt_s
        gone = payload.get("diverged_at_s") if payload.get("diverged") else None
        tunnel = ("" if "turbulence_intensity" not in payload else
                  f", turbulence {100 * payload['turbulence_intensity']:g} % (seed {payload['seed']})")
        title = (f"U = {args.airspeed} m/s: {args.variant}, {args.aero} aero{tunnel}"
                 + ("" if gone is None else f": diverged at {gone:.2f} s (|w/L| over the bound)"))
        payload["plot"] = str(plot_series(args.plot, t, [(tip, f"{args.variant}, {args.aero}")], "time, s",
                                          "tip w/L", title,
                                          marks=None if gone is None else (np.array([gone]), "diverged")))
    _emit(args, payload, lambda: _key_value_table(payload))
    return 0


#: what a tip past |w/L| = 1 means for the run (lco's and lco-sweep's warnings)
OUTSIDE_RANGE = ("the cubic-truncated model is outside its range (docs/validation.md section 4; --variant exact "
                 "holds it)")


def lco_warnings(payload: dict[str, Any], duration_s: float | None = None) -> list[str]:
    """What the numbers of an lco run do not say themselves: a tip past the panel's length (the cubic-truncated
    variants above ~1.05 U_f: `full` at 10.84 m/s read RMS 0.32-0.54 with a peak of 1.28 L, from 0.1 % changes of
    the airspeed or the duration), and a response that never settled (its RMS and frequency are a transient's; in
    the tunnel below flutter, the turbulence's random response). A panel that stayed at rest (a quiet tunnel below
    flutter) gets none: its RMS 0 says it."""
    if payload.get("diverged"):  # no metrics at all: the JSON's null and a table of "-" said nothing of why
        at = payload.get("diverged_at_s")
        when = "" if at is None else f" at t = {at:.3f} s"
        if payload.get("abort_reason"):  # the tunnel's rig stopped the run (its tip limit, the wall): its log said so
            return []
        return [f"warning: the run diverged{when} (|w/L| over sim.max_tip_w_over_L, or a non-finite state): no "
                f"LCO metrics; {OUTSIDE_RANGE}"]
    out = []
    peak = payload.get("peak_tip_w_over_L")
    if peak is not None and peak > 1.0:
        out.append(f"warning: the tip reached |w/L| = {peak:.3g}, past the panel's own length, where no inextensible "
                   f"panel goes: {OUTSIDE_RANGE}")
    if payload.get("steady_after_s") is None and payload.get("rms_tip_w_over_L"):
        what = ("a random response to the turbulence (below flutter), a growing or an irregular one"
                if payload.get("turbulence_intensity") else "a transient or an irregular response")
        from panel_rig.analysis.signals import STEADY_WINDOW_S, STEADY_WINDOWS

        span_s = STEADY_WINDOW_S * STEADY_WINDOWS  # the shortest run in which a steady state can show
        why = ("the RMS of the last 1 s windows still changes" if duration_s is None or duration_s >= span_s
               else f"a run of {duration_s:g} s is too short to show one: it takes {span_s:g} s")
        out.append(f"warning: no steady state within the run ({why}): the RMS and frequency are of {what}, not of a "
                   "limit cycle")
    return out


def lco_sweep_warning(results: Sequence[Any]) -> str | None:
    """One line naming the airspeeds of a sweep whose tip passed |w/L| = 1 without diverging (a single `lco` run
    warns of each; the sweep's table gave their RMS of 0.69-0.80 without a word)."""
    past = [r for r in results if not r.diverged and r.peak_tip_w_over_L > 1.0]
    if not past:
        return None
    speeds = ", ".join(f"{r.airspeed_mps:g}" for r in past)
    return (f"warning: at {speeds} m/s the tip passed |w/L| = 1 (up to {max(r.peak_tip_w_over_L for r in past):.3g}), "
            f"past the panel's own length: {OUTSIDE_RANGE.replace('its range', 'its range there')}")


def _key_value_table(payload: dict[str, Any]) -> str:
    """One ``key value`` line per entry; a value that does not exist (None, NaN: null in the JSON) reads "-"."""
    def shown(v: Any) -> Any:
        return "-" if v is None or (isinstance(v, float) and np.isnan(v)) else v

    return "\n".join(f"{k:24s} {shown(v)}" for k, v in payload.items())


def _range(text: str, option: str = "--airspeeds") -> np.ndarray:
    try:
        a, b, c = (float(x) for x in text.split(":"))
    except ValueError:
        raise UsageError(f"{option} expects START:STOP:STEP, got {text!r}") from None
    for end, value in (("START", a), ("STOP", b)):  # the bound typed, not the first point past the limit
        try:
            _airspeed(value)
        except UsageError as exc:
            raise UsageError(f"{option} {end}: {exc}") from None
    return np.array([_airspeed(u) for u in _points(a, b, c, option)])


def cmd_lco_sweep(args: argparse.Namespace) -> int:
    from panel_rig.analysis.lco import lco_sweep

    cfg = _config(args)
    speeds = _range(args.airspeeds)
    _duration(args.duration, "--duration", cfg)
    _march_checks(args, cfg)
    res = lco_sweep(cfg, speeds, args.duration, args.variant, args.aero, args.scheme, progress=Progress("sweep"))
    payload = {"airspeed_mps": speeds, "results": [r.as_dict() for r in res]}
    if args.plot:
        from panel_rig.analysis.plots import plot_lco_sweep

        payload["plot"] = str(plot_lco_sweep(args.plot, speeds, res, "LCO vs airspeed (Fig. 8)"))
    past = lco_sweep_warning(res)
    if past:
        _note(past)
    _emit(args, payload, lambda: _lco_sweep_table(res))
    return 0


def _lco_sweep_table(results: Sequence[Any]) -> str:
    """The sweep's text table; a diverged run has no metrics ("-", and when it diverged), not nan."""
    def cell(v: float | None, fmt: str, width: int) -> str:
        return f"{'-':>{width}}" if v is None or not np.isfinite(v) else format(v, fmt)

    lines = ["U (m/s)   RMS w/L  peak w/L    f (Hz)  diverged"]
    for r in results:
        gone = f"at {r.diverged_at_s:.2f} s" if r.diverged and r.diverged_at_s is not None else str(r.diverged)
        lines.append(f"{r.airspeed_mps:7.2f}  {cell(r.rms_tip_w_over_L, '8.4f', 8)}  "
                     f"{cell(r.peak_tip_w_over_L, '8.4f', 8)}  {cell(r.dominant_frequency_hz, '8.2f', 8)}  {gone}")
    return "\n".join(lines)


def cmd_forced(args: argparse.Namespace) -> int:
    from panel_rig.analysis.forced import forced_sweep
    from panel_rig.model.stepper import DivergenceError

    cfg = _config(args)
    f0, f1 = args.band
    if not (0 < f0 <= f1 <= 500) or not (0 < args.step <= f1 - f0 + 1e-9 or f0 == f1):
        raise UsageError(f"--band needs 0 < F0 <= F1 <= 500 Hz and 0 < --step <= F1 - F0 (F0 = F1: one frequency), "
                         f"got {args.band} {args.step}")
    _points(f0, f1, args.step, "--band/--step")
    _duration(args.dwell, "--dwell", cfg, least_s=1.0)  # the amplitude is read over the last second of each dwell
    if not (np.isfinite(args.f0) and args.f0 > 0):  # 0 gave all-zero amplitudes and a "peak" at the band's start
        raise UsageError(f"--f0 must be a finite force amplitude > 0 N/m, got {args.f0}")
    _march_checks(args, cfg)
    unsettled = forced_settling_warning(cfg, f0, f1, args.dwell)
    if unsettled:
        _note(unsettled)
    try:
        r = forced_sweep(cfg, f0, f1, args.step, args.variant, args.f0, args.dwell, scheme=args.scheme,
                         progress=Progress("forced"))
    except DivergenceError as exc:  # a response beyond the model's range: the force is too large for this band
        raise UsageError(f"{exc}: lower --f0 (a forced response needs a bounded panel)") from None
    payload = {"frequency_hz": r.frequency_hz, "amplitude_tip_w_over_L": r.amplitude_tip_w_over_L,
               "peak_frequency_hz": r.peak_frequency_hz}
    past = r.amplitude_tip_w_over_L > 1.0  # as lco and lco-sweep say it (forced gave 1.15 L without a word)
    if past.any():
        _note(f"warning: at {', '.join(f'{f:g}' for f in r.frequency_hz[past])} Hz the tip passed |w/L| = 1 (up to "
              f"{r.amplitude_tip_w_over_L.max():.3g}), past the panel's own length: "
              f"{OUTSIDE_RANGE.replace('its range', 'its range there')}")
    if args.plot:
        from panel_rig.analysis.plots import plot_series

        payload["plot"] = str(plot_series(args.plot, r.frequency_hz, [(r.amplitude_tip_w_over_L, args.variant)],
                                          "frequency, Hz", "tip w/L amplitude",
                                          f"forced response (F0): {args.variant}, f0 = {args.f0:g} N/m, dwell "
                                          f"{args.dwell:g} s"))
    _emit(args, payload, lambda: f"peak at {r.peak_frequency_hz:.2f} Hz\n" + "\n".join(
        f"{fr:6.2f} Hz  {a:.5f}" for fr, a in zip(r.frequency_hz, r.amplitude_tip_w_over_L)))
    return 0


def cmd_gust(args: argparse.Namespace) -> int:
    from panel_rig.analysis.gust import GUST_WAKE_CHORDS, sears_comparison

    cfg = _config(args)
    ks = args.k or []
    bad = [k for k in ks if not (np.isfinite(k) and 0 < k <= 10)]
    if not ks or bad:  # the values refused, not the whole list (1000 values made a 7 kB line)
        raise UsageError(f"--k needs reduced frequencies in (0, 10], got {_some(bad) if bad else 'none'}")
    if len(ks) > MAX_RANGE_POINTS:
        raise UsageError(f"--k takes at most {MAX_RANGE_POINTS} values, got {len(ks)}")
    wake = GUST_WAKE_CHORDS if args.wake_chords is None else args.wake_chords
    if not (np.isfinite(wake) and 1 <= wake <= 500):
        raise UsageError(f"--wake-chords must be in [1, 500], got {wake}")
    points = sears_comparison(cfg, ks, wake)
    payload = {"points": points, "elements": cfg.n_elements, "wake_chords": wake, "running_sum": cfg.running_sum}
    _emit(args, payload, lambda: _gust_table(points, cfg.n_elements, wake, cfg.running_sum))
    return 0


def _gust_table(points: list[dict], elements: int, wake_chords: float, running_sum: str) -> str:
    """The Sears comparison as text, with the errors of |L| (per cent of Sears) and of the phase (deg)."""
    from panel_rig.model.aerodynamics import RUNNING_SUM_OWN

    own = RUNNING_SUM_OWN[running_sum]
    order = "as printed: first order in dx" if own == 1.0 else "not the paper's"
    head = (f"rigid lattice: {elements} elements, {wake_chords:g}-chord wake; Eq. 4's running sum '{running_sum}' "
            f"(element j's own vortex x {own:g}, {order}; aero.running_sum, docs/validation.md section 6)\n"
            "     k   |L|/(2 pi rho U b w0)   phase (deg)   Sears |S|   Sears phase (deg)   |L| error   phase error (deg)")
    rows = [f"{p['k']:6.3f}  {p['lift_magnitude']:21.4f}  {p['lift_phase_deg']:12.2f}  {p['sears_magnitude']:10.4f}"
            f"  {p['sears_phase_deg']:18.2f}  {100 * (p['lift_magnitude'] / p['sears_magnitude'] - 1):+9.2f} %"
            f"  {(p['lift_phase_deg'] - p['sears_phase_deg'] + 180) % 360 - 180:+17.2f}" for p in points]
    return "\n".join([head, *rows])


def cmd_static(args: argparse.Namespace) -> int:
    from panel_rig.model.elastica import static_tip_load

    cfg = _config(args)
    D, L = cfg.bending_stiffness_nm, cfg.panel_length_m
    alpha = args.tip_load_parameter if args.tip_load_parameter is not None else args.tip_force * L**2 / D
    if not np.isfinite(alpha):
        raise UsageError(f"the tip load must be finite, got {alpha}")
    try:
        r = static_tip_load(float(alpha), args.variant, n_modes=cfg.n_modes)
    except RuntimeError as exc:
        raise UsageError(str(exc)) from None
    payload = r.as_dict()
    # a dead load across the clamped direction turns the tip towards it, never past it (pi/2 as the load grows
    # without bound): a tip angle beyond is the modal series' truncation (3 modes pass it between P L^2/D = 30 and 35)
    if not (abs(r.tip_w_over_L) <= 1.0 and abs(r.tip_u_over_L) <= 1.0 and np.isfinite(r.tip_angle_rad)):
        model = ("the linear variant's small-deflection theory" if r.variant == "linear"
                 else f"the {r.variant} variant's cubic expansion")
        note = (f"{model} does not hold at this load (tip w/L {r.tip_w_over_L:.3g}, u/L {r.tip_u_over_L:.3g}: a slope "
                "beyond 1 or a tip beyond the panel's length); use --variant exact")
    elif abs(r.tip_angle_rad) >= np.pi / 2:
        modes = "1 mode does" if cfg.n_modes == 1 else f"{cfg.n_modes} modes do"
        note = (f"the tip angle passes pi/2, which a dead transverse load cannot do: {modes} not resolve this load; "
                "raise structure.modes (e.g. --set structure.modes=6)")
    else:
        note = None
    payload.update(tip_force_npm=alpha * D / L**2, n_modes=cfg.n_modes, note=note)
    _emit(args, payload, lambda: (
        f"dead transverse tip load, variant {r.variant}, {cfg.n_modes} modes\n"
        f"P L^2/D          {r.alpha:10.5f}   (P = {alpha * D / L**2:.5g} N/m)\n"
        f"tip w/L          {r.tip_w_over_L:10.5f}\n"
        f"tip u/L          {r.tip_u_over_L:10.5f}   (axial shortening)\n"
        + (f"tip angle, rad   {r.tip_angle_rad:10.5f}" if np.isfinite(r.tip_angle_rad)
           else "tip angle, rad            -   (none: the cubic slope exceeds 1, asin has no angle)")
        + ("" if note is None else f"\nnote: {note}")))
    return 0


def cmd_paper(args: argparse.Namespace) -> int:

    from panel_rig.analysis.report import build_report

    cfg = _config(args)
    _duration(args.sweep_duration, "--sweep-duration", cfg)
    out = make_output_dir(args.out, "--out")
    result = build_report(cfg, out, log=lambda s: _note(f"panel-rig paper: {s}"),
                          sweep_s=args.sweep_duration)
    print((out / "report.md").read_text() if not args.json else jsonio.dumps(result, default=float))
    return 0


def cmd_study(args: argparse.Namespace) -> int:
    try:
        import panel_rig.studies.runner  # noqa: F401 (dask, xarray, zarr: the 'study' extra)
        from panel_rig.studies.command import run
    except ImportError as exc:
        raise UsageError(f"panel-rig study needs the 'study' extra (pip install -e '.[study]'): {exc}") from None
    return run(args)


def _node_main(argv: Sequence[str]) -> int:
    from panel_rig.ros.rig_node import main

    return main(argv, prog="panel-rig run")


def _operator_main(argv: Sequence[str]) -> int:
    from panel_rig.ros.operator import main

    return main(argv, prog="panel-rig operate")


def _control_main(argv: Sequence[str]) -> int:
    from panel_rig.ros.controller import main

    return main(argv, prog="panel-rig control")


def _control_demo_main(argv: Sequence[str]) -> int:
    from panel_rig.control_demo import main

    return main(argv)


def _demo_main(argv: Sequence[str]) -> int:
    from panel_rig.demo import main

    return main(argv)


#: subcommands that are programs of their own (ROS arguments included): their argv is passed on untouched
PROGRAMS: dict[str, tuple[Callable[[Sequence[str]], int], str]] = {
    "run": (_node_main, "the live rig node (same as `ros2 run panel_rig rig_node`): [--fast] [--params FILE] "
                        "[--ros-args ...]"),
    "operate": (_operator_main, "play a test procedure over the rig's command topics: --profile FILE "
                                "[--namespace NS] [--ros-args ...]"),
    "control": (_control_main, "the reference flutter-suppression controller node: [--params FILE] "
                               "[--ros-args -r __ns:=/rig -p gain_nspm2:=G ...]"),
    "control-demo": (_control_demo_main, "flutter suppression over topics: node + controller, quiet at 1.2 U_f, "
                                         "predicted vs emulated closed-loop onset, bag + Rerun"),
    "demo": (_demo_main, "a tunnel session: node (fast) + staircase operator + recording + analysis"),
}


def cmd_flutter_test(args: argparse.Namespace) -> int:
    from panel_rig.flutter_cli import format_flutter_test, run_flutter_test

    if not 0 < args.margin < 1:
        raise UsageError(f"--margin must be in (0, 1), got {args.margin}")
    cfg = _config(args)
    from panel_rig.rig.flutter_run import MAX_DWELL_S, MAX_REPEATS, MAX_SETTLE_S, MIN_DWELL_S

    if args.dwell is not None and not MIN_DWELL_S <= args.dwell <= MAX_DWELL_S:
        raise UsageError(f"--dwell must be in [{MIN_DWELL_S:g}, {MAX_DWELL_S:g}] s (simulated), got {args.dwell}")
    if args.start_mps is not None:
        from panel_rig.model.aerodynamics import MAX_AIRSPEED_MPS

        if not 0.0 < args.start_mps <= MAX_AIRSPEED_MPS:  # one form for every bad value (nan included)
            raise UsageError(f"--start-mps must be in (0, {MAX_AIRSPEED_MPS:g}] m/s, got {args.start_mps:.10g}")
    if args.max_points is not None and args.max_points < 1:
        raise UsageError(f"--max-points must be >= 1, got {args.max_points}")
    if args.repeats is not None and not 0 <= args.repeats <= MAX_REPEATS:
        raise UsageError(f"--repeats must be in [0, {MAX_REPEATS}], got {args.repeats}")
    if args.settle is not None and not 0.0 <= args.settle <= MAX_SETTLE_S:
        raise UsageError(f"--settle must be in [0, {MAX_SETTLE_S:g}] s (simulated), got {args.settle}")
    if args.domain_id is not None and args.in_process:  # accepted and silently meaningless before
        raise UsageError("--domain-id applies to the live node, not with --in-process")
    if args.domain_id is not None and not 0 <= args.domain_id <= MAX_DOMAIN_ID:
        raise UsageError(f"--domain-id must be in [0, {MAX_DOMAIN_ID}] (ROS 2 on Linux), got {args.domain_id}")
    # where the results go is checked before the test runs, not after (a failed plot lost the whole run; the
    # --plot directory is checked by _config)
    problem = rrd_path_problem(args.rerun) if args.rerun else None
    if problem:  # before any directory is made (a refused --rerun left the --bag-dir made)
        raise UsageError(f"--rerun: {problem}")
    _march_checks(args, cfg)
    make_output_dir(Path(args.bag_dir), "--bag-dir")
    if args.rerun:
        prepare_rrd_path(args.rerun, "--rerun")
    try:
        out = run_flutter_test(cfg, args.variant, args.margin, args.start_mps, args.bag_dir, args.plot, args.rerun,
                               params={"set": " ".join(args.set or ()), "params": args.params or ""},
                               dwell_s=args.dwell, settle_s=args.settle, in_process=args.in_process,
                               domain_id=args.domain_id, max_points=args.max_points,
                               progress=_note, repeats=args.repeats)
    except StoppedRun as stopped:  # Ctrl-C, SIGTERM, a failed recording or a lost node after points:
        # the points identified so far, reported as a finished test's (a signal's line names the test itself)
        print(f"panel-rig flutter-test: {stopped.message}" if isinstance(stopped, Aborted) else stopped.message,
              file=sys.stderr, flush=True)
        partial = {**stopped.payload, "rerun": args.rerun}
        _emit(args, partial, lambda: format_flutter_test(partial))
        return stopped.exit_status
    except RuntimeError as exc:  # the live node failed to start or stopped answering (its log is named)
        print(f"panel-rig flutter-test: {exc}", file=sys.stderr)
        return 1
    out["rerun"] = args.rerun  # the Rerun file written (None without --rerun)
    _emit(args, out, lambda: format_flutter_test(out))
    from panel_rig.analysis.flutter_test import NOT_IDENTIFIED

    if (out.get("stop_reason") or "").startswith(NOT_IDENTIFIED):  # it ended without clearing its last point
        print(f"panel-rig flutter-test: stopped without clearance: {out['stop_reason']}", file=sys.stderr)
        return 1
    return 1 if out["fluttered"] else 0


def cmd_bag_recover(args: argparse.Namespace) -> int:
    from panel_rig.recording.recover import main_bag_recover

    return main_bag_recover(args.bag)


# ---- parser -----------------------------------------------------------------------------------
def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", metavar="FILE", help="ROS 2 parameters YAML (default: the paper's)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a parameter (repeatable)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        # a negative number in exponent form is a value, not an option: `--tip-force -5e0` was "expected one
        # argument" (argparse's own pattern knows -5 and -.5 only; no option of ours looks like a number). A range
        # that starts below zero (`--vg -5:20:1`) is a value too: it gets the range's own message, not argparse's
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?(:[^:\s]*)*$")

    def parse_known_args(self, args: Any = None, namespace: Any = None) -> Any:
        self._given = list(sys.argv[1:] if args is None else args)  # for error(): the options it did not know
        return super().parse_known_args(args, namespace)

    def error(self, message: str) -> None:  # one line, status 2
        unknown = self._unknown_options() if message.startswith("the following arguments are required") else []
        if unknown:  # a mistyped required option: argparse names only the missing one (`paper --outt x`)
            message = f"{'; '.join(unknown)}; {message}"
        raise UsageError(message)

    def _unknown_options(self) -> list[str]:
        """'unrecognized argument X (did you mean Y?)' for each given option this parser does not know."""
        import difflib

        known = list(self._option_string_actions)
        out = []
        for token in getattr(self, "_given", []):
            name = token.split("=", 1)[0]
            if (not name.startswith("-") or self._negative_number_matcher.match(name)
                    or any(opt.startswith(name) for opt in known)):
                continue
            close = difflib.get_close_matches(name, known, n=1)
            out.append(f"unrecognized argument {name}" + (f" (did you mean {close[0]}?)" if close else ""))
        return out


def package_version() -> str:
    """The installed distribution's version (setup.py, package.xml), or "unknown" when not installed."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("panel_rig")
    except PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="panel-rig", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"panel-rig {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    linear_variant_help = ("structural variant, linearised at rest (default %(default)s); " + LINEAR_NOTE
                           + ", so every variant gives the same numbers")
    p = sub.add_parser("modes", help="cantilever natural frequencies")
    _common(p)
    p.add_argument("--variant", choices=tuple(VARIANTS), default=DEFAULT_VARIANT, help=linear_variant_help)
    p.set_defaults(func=cmd_modes)

    p = sub.add_parser("flutter", help="linear flutter boundary (Fig. 3)")
    _common(p)
    p.add_argument("--variant", choices=tuple(VARIANTS), default=DEFAULT_VARIANT, help=linear_variant_help)
    p.add_argument("--aero", choices=("full", "rom"), help="default full (--control: the ROM, always)")
    p.add_argument("--rom-modes", type=int, metavar="N", help="Ra, aerodynamic eigenmodes (default: aero.rom_modes)")
    p.add_argument("--formulation", choices=("discrete", "continuous"),
                   help="discrete (default): Eqs. (24)/(25) at dt = dx/U as in the paper; continuous: the stepper's "
                        "model (--control: always)")
    p.add_argument("--plot", metavar="FILE.png", help="write Fig. 3 (damping vs airspeed, root locus); with "
                   "--control: open- vs closed-loop damping; with --vg the V-g and V-f diagram instead")
    p.add_argument("--vg", metavar="LO:HI:STEP",
                   help="V-g/V-f: each structural mode's frequency and damping ratio per airspeed (the stepper's "
                        "continuous-time model, ROM aero; modes tracked by continuity); JSON key vg")
    p.add_argument("--control", action="store_true",
                   help="closed loop with the reference controller, the control actuator and the loop delay")
    p.add_argument("--delay-ms", type=float, help="--control: total loop delay, ms (default: the design delay)")
    p.add_argument("--command-age-ms", type=float,
                   help="--control: a measured mean command age, ms (the loop delay adds half a controller period and "
                        "half a physics step)")
    p.add_argument("--rate-hz", type=float, help="--control: controller rate, Hz (default 500)")
    p.add_argument("--actuator-bandwidth-hz", type=float, help="--control: default control.bandwidth_hz")
    p.set_defaults(func=cmd_flutter)

    def model_opts(p: argparse.ArgumentParser, aero: bool = True) -> None:
        p.add_argument("--variant", choices=tuple(VARIANTS), default=DEFAULT_VARIANT,
                       help="structure (default: %(default)s)")
        p.add_argument("--scheme", choices=SCHEMES, default=DEFAULT_SCHEME,
                       help="implicit: consistent midpoint; paper: Eq. (24) nonlinear mass at t; "
                            "paper_literal: dM multiplying only the new state (default: %(default)s)")
        if aero:
            p.add_argument("--aero", choices=RIG_AERO_MODELS, default=DEFAULT_AERO,
                           help="aerodynamics: the reduced-order model or the full lattice (default: %(default)s)")
        p.add_argument("--plot", metavar="FILE.png", help="also draw the result in a PNG (lco: the tip w/L history; "
                       "lco-sweep: RMS and frequency against airspeed; forced: the response curve)")

    p = sub.add_parser("lco", help="limit-cycle run at one airspeed (Figs. 4, 6, 7)")
    _common(p)
    model_opts(p)
    p.add_argument("--airspeed", type=float, required=True, metavar="U", help="m/s")
    p.add_argument("--duration", type=float, default=30.0, metavar="T", help="simulated seconds (default: %(default)s)")
    p.add_argument("--turbulence-intensity", type=float, metavar="X",
                   help="run in the tunnel from rest with this turbulence intensity sigma/U (sets "
                        "tunnel.turbulence.intensity; 0 = quiet tunnel from rest); without it and --seed: the paper's "
                        "quiet run from a small initial deflection")
    p.add_argument("--seed", type=int, metavar="N", help="turbulence seed (sets tunnel.turbulence.seed)")
    p.set_defaults(func=cmd_lco)

    p = sub.add_parser("lco-sweep", help="LCO amplitude and frequency versus airspeed (Fig. 8)")
    _common(p)
    model_opts(p)
    p.add_argument("--airspeeds", required=True, metavar="START:STOP:STEP",
                   help="m/s, STOP included (e.g. 10:14:0.5); independent runs from the same small disturbance")
    p.add_argument("--duration", type=float, default=30.0, metavar="T",
                   help="simulated seconds per airspeed (default: %(default)s)")
    p.set_defaults(func=cmd_lco_sweep)

    p = sub.add_parser("forced", help="forced response without aero, protocol F0 (Fig. 2)")
    _common(p)
    model_opts(p, aero=False)
    p.add_argument("--band", type=float, nargs=2, required=True, metavar=("F0", "F1"), help="Hz")
    p.add_argument("--step", type=float, default=0.1, metavar="DF", help="Hz (default: %(default)s)")
    p.add_argument("--f0", type=float, default=0.05, help="force amplitude at the trailing edge, N/m (default: %(default)s)")
    p.add_argument("--dwell", type=float, default=20.0, help="seconds per frequency (default: %(default)s)")
    p.set_defaults(func=cmd_forced)

    p = sub.add_parser("gust", help="lift of the rigid lattice in a convected sinusoidal gust vs the Sears function")
    _common(p)
    p.add_argument("--k", type=float, nargs="+", required=True, metavar="K",
                   help="reduced frequencies omega b / U, b = half of airfoil + panel chord")
    p.add_argument("--wake-chords", type=float, metavar="W",
                   help="wake length in chords for this check (default 60, as the Theodorsen check)")
    p.set_defaults(func=cmd_gust)

    from panel_rig.model.elastica import STATIC_VARIANTS

    p = sub.add_parser("static", help="static deflection under a dead transverse tip load (the elastica)")
    _common(p)
    load = p.add_mutually_exclusive_group(required=True)
    load.add_argument("--tip-load-parameter", type=float, metavar="ALPHA", help="P L^2 / D (D: the model's "
                      "bending stiffness per unit span)")
    load.add_argument("--tip-force", type=float, metavar="N_PER_M", help="P, N per metre span")
    p.add_argument("--variant", choices=STATIC_VARIANTS, default="exact",
                   help="structure (statics have no inertia: full and stiffness agree)")
    p.set_defaults(func=cmd_static)

    p = sub.add_parser("paper", help="reproduce Figs. 2-8 with report.md and results.json")
    _common(p)
    p.add_argument("--out", required=True, metavar="DIR", help="where report.md, results.json and the figures go "
                   "(made if missing)")
    p.add_argument("--sweep-duration", type=float, default=30.0, metavar="T",
                   help="simulated seconds per Fig. 8 airspeed (default: %(default)s)")
    p.set_defaults(func=cmd_paper)

    p = sub.add_parser("study", help="parameter study on Dask: flutter map, uncertainty, bifurcation (docs/studies.md)")
    p.add_argument("--spec", required=True, metavar="FILE.yaml", help="the study (kind, vary, set, ...)")
    p.add_argument("--params", metavar="FILE", help="base ROS 2 parameters YAML (default: the paper's)")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, metavar="N", help="LocalCluster worker processes (default 2)")
    where.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="an existing Dask scheduler")
    p.add_argument("--out", metavar="DIR", help="results.zarr, summary.json, plots (default out/study/<spec name>)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout (no progress bar)")
    p.set_defaults(func=cmd_study)

    for name, (_, text) in PROGRAMS.items():  # listed for --help; main() hands their arguments on untouched
        sub.add_parser(name, help=text, add_help=False)

    p = sub.add_parser("bag", help="recording utilities")
    bag = p.add_subparsers(dest="bag_command", metavar="command", required=True, parser_class=_Parser)
    r = bag.add_parser("recover", help="rebuild a readable bag from a killed or corrupt recording")
    r.add_argument("bag", metavar="BAG")
    r.set_defaults(func=cmd_bag_recover)

    p = sub.add_parser("flutter-test", help="automatic flutter clearance: step up, identify, predict, stop short")
    _common(p)
    p.add_argument("--variant", choices=tuple(VARIANTS), default="full",
                   help="the rig's structure (default: %(default)s, the paper's cubic panel)")
    p.add_argument("--start-mps", type=float, metavar="U0", help="first test point (default: half the model's U_f)")
    p.add_argument("--margin", type=float, default=0.1, metavar="M", help="required speed margin (default 0.1)")
    p.add_argument("--dwell", type=float, metavar="S",
                   help="simulated seconds of response identified per test point (default 200)")
    p.add_argument("--settle", type=float, metavar="S",
                   help="simulated seconds of run-in dropped after each airspeed step (default 5)")
    p.add_argument("--max-points", type=int, metavar="N", help="stop after N test points (default 12)")
    plan = FlutterTestSettings(start_mps=0.0, step_mps=0.0)  # the plan's defaults, named in the help
    p.add_argument("--repeats", type=int, metavar="N",
                   help=f"before a margin stop on an uncertain prediction (its 95 %% interval open or wider than "
                        f"{100 * plan.wide_ci:g} %%), take the same airspeed again up to N times (default "
                        f"{plan.repeats}; 0: stop at once)")
    p.add_argument("--in-process", action="store_true",
                   help="drive an in-process Rig instead of the live node (no ROS; the unit tests' path)")
    p.add_argument("--domain-id", type=int, metavar="ID",
                   help="ROS_DOMAIN_ID of the private node + client pair (default: a free-looking random one)")
    p.add_argument("--bag-dir", default="bags", help="directory for the recording (default bags)")
    p.add_argument("--plot", default="out/flutter_test/vg.png", metavar="FILE.png",
                   help="V-g plot with the extrapolation (default out/flutter_test/vg.png)")
    p.add_argument("--rerun", metavar="OUT.rrd", help="also write a Rerun recording (readings and the monitor)")
    p.set_defaults(func=cmd_flutter_test)

    p = sub.add_parser("analyze", help="airspeed plateaus, LCO and flutter onset from a recorded bag")
    add_analyze_arguments(p)
    p.set_defaults(func=cmd_analyze)
    return parser


MAX_DOMAIN_ID = 232  # ROS 2 domain ids on Linux (higher ids give ports beyond 65535)


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] in PROGRAMS:
            return PROGRAMS[argv[0]][0](argv[1:])
        return _run_subcommand(argv)
    except BrokenPipeError:  # `panel-rig ... | head -1`: the reader closed the pipe; end quietly, not a traceback
        _silence_stdout()
        return BROKEN_PIPE_STATUS
    except KeyboardInterrupt:  # Ctrl-C outside a program's own stop handling (e.g. just after it finished)
        print("panel-rig: interrupted", file=sys.stderr)
        return INTERRUPTED_STATUS


def _run_subcommand(argv: Sequence[str]) -> int:
    try:
        args = build_parser().parse_args(argv)
        return int(args.func(args) or 0)
    except (UsageError, ConfigError, ValueError) as exc:
        print(f"panel-rig: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        raise
    except OSError as exc:  # a file that cannot be written or read (a plot in a missing directory, ...): one line
        print(f"panel-rig: error: {exc}", file=sys.stderr)
        return 2
    except MemoryError as exc:  # a size the checks let through but this machine cannot hold: one line, not a traceback
        print(f"panel-rig: error: out of memory ({exc or 'the allocation failed'}): use a smaller model", file=sys.stderr)
        return 1


def _note(text: str, end: str = "\n") -> None:
    """A progress line on stderr. A reader that left (`2>&1 >/dev/null | head -1`) does not stop the work: the paper
    report died there with status 141 after its first figure."""
    try:
        print(text, end=end, file=sys.stderr, flush=True)
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)  # the later lines and the exit's flush go nowhere, quietly
        os.dup2(devnull, sys.stderr.fileno())


def _silence_stdout() -> None:
    """Point stdout at the null device, so the interpreter's flush at exit does not raise a second broken pipe."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


if __name__ == "__main__":
    sys.exit(main())
