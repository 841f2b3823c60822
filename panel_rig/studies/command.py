"""``panel-rig study``: read the spec, run the missing cases, write summary and figures, print the outcome."""

from __future__ import annotations

import signal
import sys
from pathlib import Path
from typing import Any

from panel_rig import jsonio
from panel_rig.config import ConfigError
from panel_rig.processes import INTERRUPTED_STATUS, TERMINATED_STATUS, interruption, sigterm_exits


def _stored(out: Path) -> int:
    """Cases done in the store under ``out`` (0 if there is none yet)."""
    import numpy as np
    import zarr

    from panel_rig.studies.store import STORE_NAME

    try:
        return int(np.sum(zarr.open_group(str(out / STORE_NAME), mode="r")["done"][:]))
    except Exception:  # noqa: BLE001 (no store yet, or one being created)
        return 0


def _shown(value: Any) -> str:
    """A summary value for the table: numbers to 3 decimals (4 significant digits below 1), a mapping as "key: value" pairs (the
    percentiles printed as a Python dict of 16-digit floats); the JSON keeps every digit."""
    if value is None:  # a figure that does not exist (null in the JSON)
        return "-"
    if isinstance(value, dict):
        return ", ".join(f"P{k} {_shown(v)}" if str(k).isdigit() else f"{k}: {_shown(v)}" for k, v in value.items())
    if isinstance(value, float):
        return f"{value:.3f}" if abs(value) >= 1 else f"{value:.4g}"
    return str(value)


def run(args: Any) -> int:
    from panel_rig.studies.spec import load_spec

    if args.workers is not None and not (1 <= args.workers <= 512):
        raise ConfigError(f"--workers must be in [1, 512], got {args.workers}")
    if args.out is not None and not args.out.strip():  # it silently meant the default directory
        raise ConfigError("--out must name a directory, got an empty path")
    if args.out and Path(args.out).exists() and not Path(args.out).is_dir():  # it said "File exists"
        raise ConfigError(f"--out {args.out} is a file, not a directory")
    study = load_spec(args.spec, args.params)  # bad specs fail here, before dask is imported

    from panel_rig.studies.report import plot, summarize
    from panel_rig.studies.runner import case_records, run_study
    out = Path(args.out) if args.out else Path("out") / "study" / Path(args.spec).stem
    show = not args.json and sys.stderr.isatty()
    try:
        # SIGTERM (a `kill`, a job scheduler's time limit) stops it as Ctrl-C does: it ended at once with status -15,
        # no word of what was kept, and the cluster's semaphores leaked
        with sigterm_exits():
            info = run_study(study, out, workers=args.workers or (None if args.scheduler else 2),
                             scheduler=args.scheduler, progress=show)
    except (KeyboardInterrupt, SystemExit) as exc:  # what arrived is stored (run_study flushes on the way out): say
        stopped = interruption(exc)  # so, and how to go on
        if stopped is None:
            raise
        from panel_rig.studies.store import STORE_NAME

        how = "interrupted" if stopped == signal.SIGINT else f"stopped by {stopped.name}"
        print(f"panel-rig study: {how}; {_stored(out)} of {len(study.cases)} cases are stored in "
              f"{out / STORE_NAME}: the same command resumes", file=sys.stderr)
        return INTERRUPTED_STATUS if stopped == signal.SIGINT else TERMINATED_STATUS
    ds = info["store"].load()
    summary = summarize(study, ds)
    (out / "summary.json").write_text(jsonio.dumps(summary, indent=1) + "\n")
    files = plot(study, ds, summary, out)
    if args.json:
        print(jsonio.dumps({"cases": case_records(study, ds), "wall_s": info["wall_s"], "workers": info["workers"],
                          "computed": info["computed"], "out": str(out), "summary": summary,
                          "plots": [str(f) for f in files]}))
        return 0
    if info["workers"]:
        workers = f"{info['workers']} worker" + ("s" if info["workers"] != 1 else "")
        print(f"{study.kind}: {len(study.cases)} cases ({info['computed']} computed now, on {workers}) in "
              f"{info['wall_s']:.1f} s")
    else:
        print(f"{study.kind}: {len(study.cases)} cases, all already in {info['store'].path} (nothing to compute)")
    for k, v in summary.items():
        if k not in ("kind", "branches", "sensitivity"):
            print(f"  {k:24s} {_shown(v)}")
    for line in sensitivity_lines(summary.get("sensitivity", [])):
        print(line)
    for line in branch_lines(summary.get("branches", [])):
        print(line)
    print(f"results: {info['store'].path}  (xarray.open_zarr(PATH, consolidated=False))")
    for f in files:
        print(f"plot:    {f}")
    return 0


def sensitivity_lines(rank: list[dict[str, Any]]) -> list[str]:
    """The table's sensitivity lines: key, measure and its value (none when the measure has no value)."""
    return [f"  sensitivity  {r['key']:28s} {r['measure']}" + ("" if r["value"] is None else f" {r['value']:+.3f}")
            for r in rank]


def branch_lines(rows: list[dict[str, Any]]) -> list[str]:
    """The table's bifurcation lines, one per variant and grid point: ``key value`` pairs (it printed Python dicts),
    and a warning line under a chain with cases that never settled."""
    out = []
    for r in rows:
        out.append("  branch  " + ", ".join(f"{k} {_shown(v)}" for k, v in r.items()))
        if r.get("unsettled_cases"):
            out.append(f"  warning: {r['unsettled_cases']} case(s) of this chain never settled (steady_after_s null: "
                       "raise duration_s); its LCO onset, lowest LCO and hysteresis are read from transients")
    return out
