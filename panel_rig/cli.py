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
    if args.plot:
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
            return "no flutter found up to 60 m/s"
        return (f"flutter speed      {fp.speed_mps:8.3f} m/s\n"
                f"flutter frequency  {fp.frequency_hz:8.3f} Hz\n"
                f"dominant mode      {fp.dominant_mode} (|q| shares {np.round(fp.mode_shares, 3).tolist()})")

    _emit(args, payload, table)
    return 0


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
    p.add_argument("--plot", metavar="FILE.png", help="write Fig. 3 (damping vs airspeed, root locus)")
    p.set_defaults(func=cmd_flutter)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        return int(args.func(args) or 0)
    except (UsageError, ConfigError) as exc:
        print(f"panel-rig: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("panel-rig: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
