"""``rig_node``, the program: its command line, the node's start overrides and the loop that runs the node.

Run: ``rig_node --ros-args -r __ns:=/rig --params-file config/tang_dowell_2002.yaml`` (also ``panel-rig run``,
``ros2 run panel_rig rig_node``, ``python -m panel_rig.ros.rig_node``). Its own options (``--fast``, ``--params FILE``)
stand anywhere outside ``--ros-args ... [--]``; the ``--params`` files become the node's parameter overrides. The
node itself (topics, services, parameters) is :class:`panel_rig.ros.node.RigNode`; :func:`spin` runs it: timers
in real-time mode, a stepping loop that serves the executor in fast mode, paced by an optional real-time-factor cap.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from panel_rig.argparsing import OneLineParser
from panel_rig.config import ConfigError, number_if_text, read_params_file
from panel_rig.ros.node import RigNode, StartupError, StepperFactory
from panel_rig.ros.params import parameter_table
from panel_rig.ros.session import ros_arguments_problem, ros_rules, ros_session

FAST_SPIN_PERIOD_S = 0.005  # fast mode: wall time between executor passes (commands, services, diagnostics) ...
FAST_SPIN_SHARE = 0.05  # ... at least; at most this share of the wall time in passes (one costs ~0.3-0.6 ms here)
FAST_SPIN_MAX_PERIOD_S = 0.02  # ... and never less often than this


def spin(node: RigNode, executor: SingleThreadedExecutor, should_stop: Callable[[], bool]) -> None:
    """Run the node until ``should_stop()``: timers in real-time mode; in fast mode a stepping loop that
    serves the executor (commands, services, diagnostics) every ``FAST_SPIN_PERIOD_S`` of wall time, or less
    often when a pass costs more than ``FAST_SPIN_SHARE`` of that (at least every ``FAST_SPIN_MAX_PERIOD_S``).
    With ``fast_max_realtime_factor`` > 0 it marches the next block only once the wall clock has caught up with
    the simulated time at that factor, serving callbacks while it waits."""
    next_spin = 0.0
    pace = _Pace(node.rig.time_s)
    while not should_stop() and rclpy.ok(context=node.context):
        node.apply_pending()
        if not node.fast:
            executor.spin_once(timeout_sec=0.05)
            continue
        if node.holds.waiting_for_command() or node.holds.flutter_holding():  # a client to come, or deciding: callbacks only
            executor.spin_once(timeout_sec=FAST_SPIN_PERIOD_S)
            pace.anchor(node.rig.time_s)
            continue
        ahead_s = pace.ahead_s(node.rig.time_s, node.fast_max_rtf)
        if ahead_s > 0:  # ahead of the capped clock: wait, serving callbacks, before marching on
            executor.spin_once(timeout_sec=min(ahead_s, FAST_SPIN_PERIOD_S))
            next_spin = time.monotonic() + FAST_SPIN_PERIOD_S
            continue
        node.fast_iteration()
        node.lockstep_wait(executor)
        now = time.monotonic()
        if now >= next_spin:
            executor.spin_once(timeout_sec=0.0)
            cost = time.monotonic() - now  # rclpy rebuilds the wait set each pass: keep its share of the wall bounded
            next_spin = now + min(max(FAST_SPIN_PERIOD_S, cost / FAST_SPIN_SHARE), FAST_SPIN_MAX_PERIOD_S)


class _Pace:
    """The fast mode's optional real-time-factor cap: a wall-clock anchor and the simulated time at it."""

    def __init__(self, sim_s: float):
        self.anchor(sim_s)
        self._factor = 0.0

    def anchor(self, sim_s: float) -> None:
        self._wall_s, self._sim_s = time.monotonic(), sim_s

    def ahead_s(self, sim_s: float, factor: float) -> float:
        """Wall seconds the simulation at ``sim_s`` is ahead of the anchor's clock at ``factor`` (0: no cap).
        Re-anchors when uncapped, when the factor changed, and when it fell more than 0.1 s behind (a slow
        stretch is not made up in a burst)."""
        if factor <= 0 or factor != self._factor:
            self._factor = factor
            self.anchor(sim_s)
            return 0.0
        ahead_s = self._wall_s + (sim_s - self._sim_s) / factor - time.monotonic()
        if ahead_s < -0.1:
            self.anchor(sim_s)
            return 0.0
        return ahead_s


def overrides_from_files(paths: Sequence[str]) -> list[Parameter]:
    """The parameters of ``panel_rig:`` parameter files (e.g. the physics file), as node overrides.

    Given to the node as ``parameter_overrides``, they apply in any namespace (rcl matches a plain
    ``panel_rig:`` key only to ``/panel_rig``) and win over ``--ros-args --params-file`` values, not over
    ``--ros-args -p`` ones (:func:`command_line_parameter_names`). Later files win.
    """
    values: dict[str, Any] = {}
    for path in paths:
        try:
            values.update(read_params_file(path))
        except ConfigError as exc:
            raise StartupError(str(exc)) from None
    table = parameter_table()
    for name, value in values.items():  # `publish_rate_hz: 1e3` is text to YAML 1.1, a number to rcl's --params-file
        if name in table and isinstance(table[name][0], float):
            values[name] = number_if_text(value)
    return [Parameter(name, value=value) for name, value in values.items()]


def command_line_parameter_names(argv: Sequence[str]) -> set[str]:
    """Names set by ``-p NAME:=VALUE`` / ``--param`` inside ``--ros-args ... [--]`` blocks (``NODE:NAME:=VALUE``
    too). The files of ``--params`` yield to them: a value typed on the command line is the one meant."""
    return {rule.split(":=", 1)[0].rsplit(":", 1)[-1] for rule in ros_rules(argv, ("-p", "--param"))}


def start_overrides(param_files: Sequence[str], rcl_args: Sequence[str], fast: bool) -> list[Parameter]:
    """The node's overrides: the ``--params`` files' values but those typed with ``-p`` (which rcl applies), and
    ``fast`` for ``--fast``."""
    typed = command_line_parameter_names(rcl_args)
    overrides = [p for p in overrides_from_files(param_files) if p.name not in typed]
    return overrides + [Parameter("fast", value=True)] if fast else overrides


def parse_args(argv: Sequence[str], prog: str = "rig_node") -> tuple[Any, list[str]]:
    """(own options, full argument list for rclpy). Own options are whatever is not a ROS argument
    (rclpy's ``remove_ros_args``): ``--fast``, ``--params FILE`` (repeatable). ``prog`` names the program in
    ``--help`` and usage errors."""

    from rclpy.utilities import remove_ros_args

    parser = OneLineParser(prog=prog, description="panel_rig emulated wind tunnel node")
    parser.add_argument("--fast", action="store_true", help="run as fast as possible, publish /clock")
    parser.add_argument("--params", action="append", default=[], metavar="FILE",
                        help="a 'panel_rig:' parameters file applied in any namespace (repeatable)")
    own = remove_ros_args(["rig_node", *argv])[1:]
    return parser.parse_args(own), ["rig_node", *argv]


def main(argv: Sequence[str] | None = None, stepper_factory: StepperFactory | None = None, *,
         prog: str = "rig_node") -> int:
    """Entry point (``rig_node``; ``panel-rig run``). argv excludes the program name; ``prog`` is the name its
    messages and ``--help`` give (the command the user typed). Returns an exit code.

    Own options anywhere outside ``--ros-args ... [--]``: ``--fast``, ``--params FILE`` (see
    :func:`overrides_from_files`).
    """
    args = sys.argv[1:] if argv is None else list(argv)
    problem = ros_arguments_problem(args)
    if problem:
        print(f"{prog}: {problem}", file=sys.stderr)
        return 2
    opts, rcl_args = parse_args(args, prog)
    try:
        overrides = start_overrides(opts.params, rcl_args, opts.fast)
    except StartupError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2

    stop = threading.Event()
    node: RigNode | None = None
    code = 0
    with ros_session(rcl_args, stop):
        try:
            node = RigNode(stepper_factory=stepper_factory, parameter_overrides=overrides)
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            spin(node, executor, stop.is_set)
            node.get_logger().info(f"stopping: {node.stats()}")
        except StartupError as exc:  # one line (the node's logger printed it a second time on the console)
            print(f"{prog}: {exc}", file=sys.stderr)
            code = 2
        finally:
            if node is not None:
                node.close()
                node.destroy_node()
    return code


if __name__ == "__main__":
    sys.exit(main())
