"""The ``panel-rig`` command: modal and flutter analysis, LCO and forced-response runs, the paper report.

Every subcommand takes ``--params FILE`` (a ROS 2 parameters file, default the paper's) and repeatable
``--set KEY=VALUE`` overrides. Bad input exits with status 2 and one line on stderr.
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any, Callable, Sequence

import numpy as np

from panel_rig.config import ConfigError, PanelConfig, load_config
from panel_rig.model.options import DEFAULT_AERO, DEFAULT_SCHEME, DEFAULT_VARIANT, RIG_AERO_MODELS, SCHEMES, VARIANTS


class UsageError(Exception):
    """Bad command-line input: reported as one line on stderr, exit status 2."""


def _config(args: argparse.Namespace) -> PanelConfig:
    return load_config(args.params, args.set or ())


def _emit(args: argparse.Namespace, payload: dict[str, Any], table: Callable[[], str]) -> None:
    if args.json:
        print(json.dumps(payload, default=_jsonable))
    else:
        print(table())


def _jsonable(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


# ---- subcommands ------------------------------------------------------------------------------
def cmd_modes(args: argparse.Namespace) -> int:
    from panel_rig.model.structure import build_structure

    cfg = _config(args)
    s = build_structure(cfg)
    f = s.natural_frequencies_hz
    payload = {"natural_frequencies_hz": f, "beta_L": s.beta,
               "modal_mass_kg_per_m": s.modal_mass_kg, "bending_stiffness_nm": cfg.bending_stiffness_nm}
    _emit(args, payload, lambda: "mode  beta_L     f (Hz)\n" + "\n".join(
        f"{i + 1:>4}  {b:7.4f}  {fi:9.3f}" for i, (b, fi) in enumerate(zip(s.beta, f))))
    return 0


def cmd_flutter(args: argparse.Namespace) -> int:
    from panel_rig.analysis.flutter import eigenvalues, find_flutter
    from panel_rig.model.aeroelastic import AeroelasticModel

    cfg = _config(args)
    model = AeroelasticModel(cfg)
    rom_modes = args.rom_modes if args.rom_modes is not None else cfg.rom_modes
    if rom_modes < 1:
        raise UsageError("--rom-modes must be >= 1")
    kw = dict(aero=args.aero, rom_modes=rom_modes if args.aero == "rom" else None,
              formulation=args.formulation)
    fp = find_flutter(model, **kw)
    if fp is None:
        payload = {"flutter_speed_mps": None, "flutter_frequency_hz": None, "dominant_mode": None}
    else:
        payload = {"flutter_speed_mps": fp.speed_mps, "flutter_frequency_hz": fp.frequency_hz,
                   "dominant_mode": fp.dominant_mode, "mode_shares": fp.mode_shares}
    payload.update(aero=args.aero, rom_modes=kw["rom_modes"], formulation=args.formulation)
    vg = None
    if args.vg:
        from panel_rig.analysis.vg import model_flutter_speed, plot_vg, vg_diagram

        # the stepper's continuous-time model with the ROM (the aero the rig runs), whatever --aero says
        vg = vg_diagram(model, _range(args.vg, "--vg"), aero="rom", rom_modes=rom_modes)
        payload["vg"] = vg.as_json()
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
            p = fp if akw["aero"] == args.aero else find_flutter(model, formulation=args.formulation, **akw)
            if p is not None:
                marks[label] = (p.speed_mps, p.frequency_hz)
        payload["plot"] = str(plot_flutter_roots(curves, args.plot, marks))

    def table() -> str:
        if fp is None:
            text = "no flutter found up to 60 m/s"
        else:
            text = (f"flutter speed      {fp.speed_mps:8.3f} m/s\n"
                    f"flutter frequency  {fp.frequency_hz:8.3f} Hz\n"
                    f"dominant mode      {fp.dominant_mode} (|q| shares {np.round(fp.mode_shares, 3).tolist()})")
        if vg is not None:
            n = vg.poles.shape[1]
            text += "\n\n U (m/s)" + "".join(f"   f{i + 1} (Hz)  zeta{i + 1}  " for i in range(n)) + "\n" + "\n".join(
                f"{u:8.2f}" + "".join(f"  {f:9.3f} {z:8.5f}" for f, z in zip(fr, zr))
                for u, fr, zr in zip(vg.airspeed_mps, vg.frequency_hz, vg.damping_ratio))
        return text

    _emit(args, payload, table)
    return 0


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
            print(f"\r{self.label} [{bar:<25}] {pct:3d}%", end="" if pct < 100 else "\n", file=sys.stderr, flush=True)


def _airspeed(value: float) -> float:
    if not np.isfinite(value) or value < 0 or value > 200:
        raise UsageError(f"airspeed must be in [0, 200] m/s, got {value}")
    return value


def cmd_lco(args: argparse.Namespace) -> int:
    from panel_rig.analysis.lco import run_lco

    cfg = _config(args)
    if not (0 < args.duration <= 3600):
        raise UsageError(f"--duration must be in (0, 3600] s, got {args.duration}")
    res, tip, _ = run_lco(cfg, _airspeed(args.airspeed), args.duration, args.variant, args.aero, args.scheme,
                          keep=bool(args.plot), progress=Progress("lco"))
    payload = res.as_dict()
    if args.plot:
        from panel_rig.analysis.plots import plot_series

        t = np.arange(tip.size) * cfg.dt_s
        payload["plot"] = str(plot_series(args.plot, t, [(tip, f"{args.variant}, {args.aero}")], "time, s",
                                          "tip w/L", f"U = {args.airspeed} m/s"))
    _emit(args, payload, lambda: "\n".join(f"{k:24s} {v}" for k, v in payload.items()))
    return 0


def _range(text: str, option: str = "--airspeeds") -> np.ndarray:
    try:
        a, b, c = (float(x) for x in text.split(":"))
    except ValueError:
        raise UsageError(f"{option} expects START:STOP:STEP, got {text!r}") from None
    if c <= 0 or b < a:
        raise UsageError(f"{option} needs STOP >= START and STEP > 0, got {text!r}")
    return np.array([_airspeed(u) for u in np.arange(a, b + 0.5 * c, c)])


def cmd_lco_sweep(args: argparse.Namespace) -> int:
    from panel_rig.analysis.lco import lco_sweep

    cfg = _config(args)
    speeds = _range(args.airspeeds)
    res = lco_sweep(cfg, speeds, args.duration, args.variant, args.aero, args.scheme, progress=Progress("sweep"))
    payload = {"airspeed_mps": speeds, "results": [r.as_dict() for r in res]}
    if args.plot:
        from panel_rig.analysis.plots import plot_series

        payload["plot"] = str(plot_series(args.plot, speeds, [
            (np.array([r.rms_tip_w_over_L for r in res]), "RMS tip w/L"),
            (np.array([r.dominant_frequency_hz for r in res]) / 50, "frequency / 50 Hz")],
            "airspeed, m/s", "RMS w/L ; f/50", "LCO vs airspeed (Fig. 8)"))
    _emit(args, payload, lambda: "U (m/s)   RMS w/L    f (Hz)  diverged\n" + "\n".join(
        f"{r.airspeed_mps:7.2f}  {r.rms_tip_w_over_L:8.4f}  {r.dominant_frequency_hz:8.2f}  {r.diverged}" for r in res))
    return 0


def cmd_forced(args: argparse.Namespace) -> int:
    from panel_rig.analysis.forced import forced_sweep

    cfg = _config(args)
    f0, f1 = args.band
    if not (0 < f0 <= f1 <= 500) or not (0 < args.step <= f1 - f0 + 1e-9 or f0 == f1):
        raise UsageError(f"--band needs 0 < F0 <= F1 <= 500 Hz and 0 < --step, got {args.band} {args.step}")
    r = forced_sweep(cfg, f0, f1, args.step, args.variant, args.f0, args.dwell, scheme=args.scheme,
                     progress=Progress("forced"))
    payload = {"frequency_hz": r.frequency_hz, "amplitude_tip_w_over_L": r.amplitude_tip_w_over_L,
               "peak_frequency_hz": r.peak_frequency_hz}
    if args.plot:
        from panel_rig.analysis.plots import plot_series

        payload["plot"] = str(plot_series(args.plot, r.frequency_hz, [(r.amplitude_tip_w_over_L, args.variant)],
                                          "frequency, Hz", "tip w/L amplitude", "forced response (F0)"))
    _emit(args, payload, lambda: f"peak at {r.peak_frequency_hz:.2f} Hz\n" + "\n".join(
        f"{fr:6.2f} Hz  {a:.5f}" for fr, a in zip(r.frequency_hz, r.amplitude_tip_w_over_L)))
    return 0


def cmd_paper(args: argparse.Namespace) -> int:
    from pathlib import Path

    from panel_rig.analysis.report import build_report

    cfg = _config(args)
    out = Path(args.out)
    result = build_report(cfg, out, log=lambda s: print(f"panel-rig paper: {s}", file=sys.stderr),
                          sweep_s=args.sweep_duration)
    print((out / "report.md").read_text() if not args.json else json.dumps(result, default=float))
    return 0


def _node_main(argv: Sequence[str]) -> int:
    from panel_rig.ros.node import main

    return main(argv)


def _operator_main(argv: Sequence[str]) -> int:
    from panel_rig.ros.operator import main

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
    "demo": (_demo_main, "a tunnel session: node (fast) + staircase operator + recording + analysis"),
}


def cmd_bag_recover(args: argparse.Namespace) -> int:
    from panel_rig.recording.recover import main_bag_recover

    return main_bag_recover(args.bag)


def cmd_analyze(args: argparse.Namespace) -> int:
    from panel_rig.recording.analyze import run

    return run(args)


# ---- parser -----------------------------------------------------------------------------------
def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", metavar="FILE", help="ROS 2 parameters YAML (default: the paper's)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE", help="override a parameter (repeatable)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, status 2
        raise UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="panel-rig", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    p = sub.add_parser("modes", help="cantilever natural frequencies")
    _common(p)
    p.set_defaults(func=cmd_modes)

    p = sub.add_parser("flutter", help="linear flutter boundary (Fig. 3)")
    _common(p)
    p.add_argument("--aero", choices=("full", "rom"), default="full")
    p.add_argument("--rom-modes", type=int, metavar="N", help="Ra, aerodynamic eigenmodes (default: aero.rom_modes)")
    p.add_argument("--formulation", choices=("discrete", "continuous"), default="discrete",
                   help="discrete: Eqs. (24)/(25) at dt = dx/U as in the paper; continuous: the stepper's model")
    p.add_argument("--vg", metavar="LO:HI:STEP",
                   help="V-g/V-f: each structural mode's frequency and damping ratio per airspeed (the stepper's "
                        "continuous-time model, ROM aero; modes tracked by continuity); JSON key vg")
    p.add_argument("--plot", metavar="FILE.png",
                   help="write Fig. 3 (damping vs airspeed, root locus); with --vg the V-g and V-f diagram instead")
    p.set_defaults(func=cmd_flutter)

    def model_opts(p: argparse.ArgumentParser, aero: bool = True) -> None:
        p.add_argument("--variant", choices=tuple(VARIANTS), default=DEFAULT_VARIANT)
        p.add_argument("--scheme", choices=SCHEMES, default=DEFAULT_SCHEME,
                       help="implicit: consistent midpoint; paper: Eq. (24) nonlinear mass at t; "
                            "paper_literal: dM multiplying only the new state")
        if aero:
            p.add_argument("--aero", choices=RIG_AERO_MODELS, default=DEFAULT_AERO)
        p.add_argument("--plot", metavar="FILE.png")

    p = sub.add_parser("lco", help="limit-cycle run at one airspeed (Figs. 4, 6, 7)")
    _common(p)
    model_opts(p)
    p.add_argument("--airspeed", type=float, required=True, metavar="U", help="m/s")
    p.add_argument("--duration", type=float, default=30.0, metavar="T", help="simulated seconds")
    p.set_defaults(func=cmd_lco)

    p = sub.add_parser("lco-sweep", help="LCO amplitude and frequency versus airspeed (Fig. 8)")
    _common(p)
    model_opts(p)
    p.add_argument("--airspeeds", required=True, metavar="START:STOP:STEP")
    p.add_argument("--duration", type=float, default=30.0, metavar="T")
    p.set_defaults(func=cmd_lco_sweep)

    p = sub.add_parser("forced", help="forced response without aero, protocol F0 (Fig. 2)")
    _common(p)
    model_opts(p, aero=False)
    p.add_argument("--band", type=float, nargs=2, required=True, metavar=("F0", "F1"), help="Hz")
    p.add_argument("--step", type=float, default=0.1, metavar="DF", help="Hz")
    p.add_argument("--f0", type=float, default=0.05, help="force amplitude at the trailing edge, N/m")
    p.add_argument("--dwell", type=float, default=20.0, help="seconds per frequency")
    p.set_defaults(func=cmd_forced)

    p = sub.add_parser("paper", help="reproduce Figs. 2-8 with report.md and results.json")
    _common(p)
    p.add_argument("--out", required=True, metavar="DIR")
    p.add_argument("--sweep-duration", type=float, default=30.0, help="seconds per Fig. 8 airspeed")
    p.set_defaults(func=cmd_paper)

    for name, (_, text) in PROGRAMS.items():  # listed for --help; main() hands their arguments on untouched
        sub.add_parser(name, help=text, add_help=False)

    p = sub.add_parser("bag", help="recording utilities")
    bag = p.add_subparsers(dest="bag_command", required=True, parser_class=_Parser)
    r = bag.add_parser("recover", help="rebuild a readable bag from a killed recording")
    r.add_argument("bag", metavar="BAG")
    r.set_defaults(func=cmd_bag_recover)

    from panel_rig.recording.analyze import add_arguments as analyze_arguments

    p = sub.add_parser("analyze", help="airspeed plateaus, LCO and flutter onset from a recorded bag")
    analyze_arguments(p)
    p.set_defaults(func=cmd_analyze)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in PROGRAMS:
        return PROGRAMS[argv[0]][0](argv[1:])
    try:
        args = build_parser().parse_args(argv)
        return int(args.func(args) or 0)
    except (UsageError, ConfigError, ValueError) as exc:
        print(f"panel-rig: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("panel-rig: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
