"""``panel-rig demo`` (``make run``): one tunnel session end to end, with a printed summary.

Starts the rig node in fast mode as a subprocess (own ROS domain, localhost discovery, logs under
``out/``) recording a bag and a Rerun ``.rrd``, plays ``config/staircase.yaml`` with the scripted
operator, stops the node with SIGINT, then analyses the new bag (if ``panel_rig.analyze_cli.analyze_bag``
exists) into PNGs and prints what happened.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from panel_rig import jsonio
from panel_rig.argparsing import OneLineParser
from panel_rig.domains import private_domain_id
from panel_rig.paths import make_output_dir
from panel_rig.processes import (
    INTERRUPTED_STATUS,
    RIG_STARTUP_TIMEOUT_S,
    module_command,
    sigterm_exits,
    spawn,
    stop,
)

ROOT = Path(__file__).resolve().parents[1]
#: the structure the demo tunnel runs: the exact (elastica) panel, the one that behaves like a real panel at LCO
#: amplitudes (its tip cannot pass its own length, and it does not diverge past ~1.2 U_f as the cubic ones do)
DEMO_VARIANT = "exact"
NODE_STOP_TIMEOUT_S = 20.0
NODE_WATCH_S = 0.5  # wall: how soon the demo notices a node that ended while the operator waits for it
OPERATOR_TIMEOUT_S = RIG_STARTUP_TIMEOUT_S + 110.0  # wall: the rig's start-up, then the staircase (~10-30 s here)


def _env(log_dir: Path) -> dict[str, str]:
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(private_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               ROS_LOG_DIR=str(log_dir))
    return env


def _new_bag(bag_dir: Path, before: set[str]) -> Path | None:
    new = sorted(p for p in bag_dir.glob("rig_*") if p.name not in before and p.is_dir())
    return new[-1] if new else None


def _analyze(bag: Path, out: Path) -> str:
    """Analyse the new bag: PNGs and analysis.json into out; returns the human-readable table."""
    from panel_rig.analyze_cli import analyze_bag, format_table

    result = analyze_bag(bag, plots_dir=out)
    (out / "analysis.json").write_text(jsonio.dumps(result, indent=1, default=str))
    return format_table(result)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo session; 0 on success (an abort of the rig is reported, not a failure), 130 when stopped by
    Ctrl-C (143 by SIGTERM)."""
    ap = OneLineParser(prog="panel-rig demo", description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default=str(ROOT / "config" / "staircase.yaml"),
                    help="the operator's profile, YAML (default: config/staircase.yaml)")
    ap.add_argument("--out", default="out/demo", help="directory for the .rrd, plots and logs")
    ap.add_argument("--bag-dir", default="bags", help="where the node records its bag (default: bags)")
    ap.add_argument("--max-rtf", type=float, default=20.0, help="fast-mode real-time factor cap (0: none)")
    args = ap.parse_args(argv)
    problem = _arguments_problem(args)
    if problem:  # before anything runs: the node and the operator refused them, and the demo waited for neither
        print(f"panel-rig demo: {problem}", file=sys.stderr)
        return 2
    try:  # before anything runs (a file or /proc as --out was a traceback; '' wrote into the working directory)
        out = make_output_dir(args.out, "--out")
        bag_dir = make_output_dir(args.bag_dir, "--bag-dir")
        make_output_dir(out / "ros_log", "--out")
    except ValueError as exc:
        print(f"panel-rig demo: {exc}", file=sys.stderr)
        return 2
    with sigterm_exits():
        return _session(args, out, bag_dir)


def _arguments_problem(args: argparse.Namespace) -> str | None:
    """One line for a --max-rtf the node would refuse or a --profile the operator would refuse, else None. (With
    either the node or the operator exited at once while the demo waited out the rig's start-up, then printed a
    session summary.)"""
    from panel_rig.ros.operator import ProfileError, load_profile
    from panel_rig.ros.params import check_node_params

    problems = check_node_params({"fast_max_realtime_factor": args.max_rtf})
    if problems:
        return "--max-rtf: " + problems[0].split(": ", 1)[1]
    try:
        load_profile(args.profile)
    except ProfileError as exc:
        return f"--profile {args.profile}: {exc}"
    return None


def _wait_for_operator(operator: subprocess.Popen, node: subprocess.Popen, timeout_s: float
                       ) -> tuple[str, str, bool]:
    """The operator's (stdout, stderr) once it has played the profile, and False; or, when the node ends first
    (it refused its parameters, or crashed), at once (within NODE_WATCH_S) what the operator wrote so far and True.
    An operator that does not finish within ``timeout_s`` (wall) gives a line saying so as its stderr."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            out, err = operator.communicate(timeout=min(NODE_WATCH_S, max(deadline - time.monotonic(), 0.0)))
            return out, err, False
        except subprocess.TimeoutExpired:  # retrying communicate() loses no output (subprocess docs)
            if node.poll() is not None:
                return "", "", True
            if time.monotonic() >= deadline:
                return "", f"the operator did not finish within {timeout_s:g} s (wall)", False


def _node_failure(node_code: int | None, node_log: Path) -> str:
    """Why the session ended early: the node's exit status and the last line of its log that names a problem."""
    lines = [line.strip() for line in node_log.read_text(errors="replace").splitlines() if line.strip()]
    said = [line for line in lines if any(w in line.lower() for w in ("error", "invalid", "refused", "failed"))]
    last = (said or lines or ["(the node log is empty)"])[-1]
    return f"the rig node exited (status {node_code}) before the operator had played the profile: {last}"


def _session(args: argparse.Namespace, out: Path, bag_dir: Path) -> int:
    """Node and operator, stopped in order (operator, then node) however the session ends; then the analysis,
    written before anything is printed (a closed pipe lost it)."""
    run = time.strftime("demo_%Y%m%d_%H%M%S")
    rrd = out / f"{run}.rrd"
    env = _env(out / "ros_log")
    before = {p.name for p in bag_dir.glob("rig_*")}
    t0 = time.monotonic()
    node_log = out / f"{run}_node.log"
    node_cmd = [*module_command("panel_rig.ros.rig_node"), "--fast", "--params",
                str(ROOT / "config" / "tang_dowell_2002.yaml"), "--ros-args", "-r", "__ns:=/rig",
                "--params-file", str(ROOT / "config" / "rig.yaml"),
                "-p", "record:=true", "-p", f"bag_dir:={bag_dir}", "-p", f"rerun:=save:{rrd}",
                "-p", "fast:=true", "-p", f"fast_max_realtime_factor:={args.max_rtf}",
                "-p", f"model.variant:={DEMO_VARIANT}", "-p", "fast_wait_for_command:=true"]
    op_cmd = [*module_command("panel_rig.ros.operator"), "--profile", args.profile, "--namespace", "/rig",
              "--timeout", "30", "--startup-timeout", f"{RIG_STARTUP_TIMEOUT_S:g}"]
    node = operator = None
    op_out = op_err = ""
    node_ended = False
    stopped: BaseException | None = None
    print("panel-rig demo: starting the rig node and the operator (a first run compiles the physics kernels: "
          "about half a minute)", file=sys.stderr, flush=True)
    try:
        # the operator first: it waits for the rig, so the fast node does not run ahead at 0 m/s while the
        # operator starts up (a third of the runs began with ~40 simulated seconds of nothing)
        operator = spawn(op_cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        with open(node_log, "w") as log:
            node = spawn(node_cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
        op_out, op_err, node_ended = _wait_for_operator(operator, node, OPERATOR_TIMEOUT_S)
    except (KeyboardInterrupt, SystemExit) as exc:  # Ctrl-C, SIGTERM: the session's children do not outlive it
        stopped = exc
    finally:
        op_code = stop(operator, NODE_STOP_TIMEOUT_S) if operator is not None else None
        node_code = stop(node, NODE_STOP_TIMEOUT_S) if node is not None else None
    if stopped is not None:
        return _stopped(stopped, operator, _new_bag(bag_dir, before) or bag_dir, rrd, node_log)
    if node_ended:
        bag = _new_bag(bag_dir, before)
        print(f"panel-rig demo: {_node_failure(node_code, node_log)} (node log {node_log}"
              + (f"; its recording: {bag}, `panel-rig bag recover` rebuilds it if it was not closed)" if bag else ")"),
              file=sys.stderr)
        return 1
    wall_s = time.monotonic() - t0
    from panel_rig.ros.operator import NOT_AS_WRITTEN

    log_text = node_log.read_text(errors="replace")
    aborts = [line.split("]: ", 1)[-1] for line in log_text.splitlines() if "rig aborted" in line]
    bag = _new_bag(bag_dir, before)
    table, failure = None, None
    if bag is not None:
        try:
            table = _analyze(bag, out)
        except Exception as exc:  # noqa: BLE001 - reported, and the demo then fails
            failure = f"analysis failed: {type(exc).__name__}: {exc}"
    print(f"panel-rig demo: profile {args.profile}, node exit {node_code}, operator exit {op_code}, "
          f"{wall_s:.1f} s wall")
    print("\nWhat the operator did (rig time; tip RMS over the second half of each step):")
    print(op_out.strip() or "(no output)")
    if op_code != 0:
        print(op_err.strip()[-2000:], file=sys.stderr)
    not_as_written = [line.split(": ", 1)[-1] for line in op_err.splitlines() if NOT_AS_WRITTEN in line]
    print("\nAborts: " + ("; ".join(aborts) if aborts else "none" + (
        "" if not_as_written else " (the rig ran the whole procedure)")))
    if not_as_written:  # a command the rig refused: the procedure did not run as written (said, not a failure)
        print(f"Operator: {not_as_written[-1]}")
    print(f"Bag: {bag or '(none found)'}\nRerun: {rrd if rrd.exists() else '(not written)'}\nNode log: {node_log}")
    if failure:
        print(failure, file=sys.stderr)
    elif table is not None:
        print(f"\nAnalysis of {bag.name} (PNGs and analysis.json in {out}):\n{table}")
    # an abort of the rig (or a command it refused) is reported above, not a failure of the demo
    played = op_code == 0 or (op_code == 1 and NOT_AS_WRITTEN in op_err)
    ok = played and node_code == 0 and bag is not None and table is not None
    return 0 if ok else 1


def _stopped(exc: BaseException, operator: subprocess.Popen | None, bag: Path, rrd: Path, node_log: Path) -> int:
    """A stopped session (its children stopped already): the steps the operator played, one line, the status.
    It printed two lines and lost the operator's table, which its Ctrl-C had printed into the pipe."""
    if operator is not None:
        try:  # the rest of what the stopped operator wrote (its table and its stop line)
            op_out, op_err = operator.communicate(timeout=NODE_STOP_TIMEOUT_S)
        except (subprocess.TimeoutExpired, ValueError, OSError):
            op_out = op_err = ""
        if op_out.strip():
            print("What the operator played before the stop (rig time):\n" + op_out.strip())
        said = [line.removeprefix("rig_operator: ") for line in op_err.splitlines() if "stopped at step" in line]
        if said:
            print(f"panel-rig demo: operator {said[-1]}", file=sys.stderr)
    print(f"panel-rig demo: stopped; the recording so far is in {bag}" + (f", the Rerun file {rrd}" if rrd.exists()
          else "") + f", the node log {node_log}", file=sys.stderr)
    if isinstance(exc, SystemExit):
        raise exc
    return INTERRUPTED_STATUS


if __name__ == "__main__":
    sys.exit(main())
