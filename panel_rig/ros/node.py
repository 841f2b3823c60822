"""The rig node, :class:`RigNode`: the rclpy adapter around :class:`panel_rig.rig.rig.Rig` (logic lives in
``panel_rig.rig``); the program that runs it, ``rig_node``, is :mod:`panel_rig.ros.rig_node`.

Real-time mode (default): a timer at ``publish_rate_hz`` advances the rig in whole physics steps to
the steady clock. Fast mode (``fast: true``): steps as fast as possible, publishes ``/clock``. The node declares
its topics, services, parameters and timers here and hands the work on: readings and shapes go out through a
:class:`~panel_rig.ros.publishing.ReadingPublisher` (and a :class:`~panel_rig.ros.publishing.Recording`), step
counts and the fast mode's holds come from :mod:`panel_rig.ros.pacing`, the parameter checks from
:mod:`panel_rig.ros.params` and the /diagnostics values from :mod:`panel_rig.ros.diagnostics`.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped, Vector3Stamped, WrenchStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker

from panel_rig.config import SCHEMA, ConfigError, PanelConfig, config_from_flat
from panel_rig.rig.control import ControlSettings
from panel_rig.rig.rig import ABORTED, Rig, StepperLike, TunnelSettings, tunnel_extras
from panel_rig.rig.safety import SafetyLimits
from panel_rig.ros import messages
from panel_rig.ros.diagnostics import diagnostic_level, diagnostic_values, jitter_p99_ms, run_stats
from panel_rig.ros.pacing import ClientHolds, PublishGrid, step_counts
from panel_rig.ros.params import (
    CONTROL_FIELDS,
    LIMIT_FIELDS,
    NODE_PARAMS,
    as_declared,
    check_node_params,
    live_change_problem,
    parameter_table,
    publish_rate_problem,
    undeclared_problem,
)
from panel_rig.ros.publishing import SHAPE_POINTS, ReadingPublisher, ReadingTopics, Recording
from panel_rig.ros.rejections import RejectionLog
from panel_rig.topics import CONTROL_TOPIC, REJECTED_SUFFIX

NODE_NAME = "panel_rig"
COMMAND_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
#: the tunnel commands in: a depth-10 queue lost part of a burst sent back to back (each command counts)
COMMAND_IN_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
#: the echoes of refused commands: a burst (20 NaNs 5 ms apart) overran a depth of 10 and a monitor saw 5 of them
REJECTED_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATEST_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE)
FAST_MAX_BLOCK_PERIODS = 64  # fast mode: publish periods marched in one compiled call (at most)
LOCKSTEP_TIMEOUT_S = 0.5  # fast mode with a controller: wall time to wait for its answer before running free
StepperFactory = Callable[[PanelConfig, str, str], StepperLike]
#: a live viewer's dropped batches are warned about at most this often (wall s)
VIEWER_WARNING_PERIOD_S = 10.0


class StartupError(RuntimeError):
    """The node cannot start (bad parameters, model unavailable); main() exits with code 2."""


def default_stepper_factory(cfg: PanelConfig, variant: str, aero: str) -> StepperLike:
    """The real model: ``panel_rig.model.stepper.Stepper``."""
    try:
        from panel_rig.model.stepper import Stepper
    except ImportError as exc:
        raise StartupError(f"model stepper unavailable: {exc}") from exc
    return Stepper(cfg, variant=variant, aero=aero)


class RigNode(Node):
    """Topics, services, parameters and timers around one :class:`Rig`."""

    def __init__(self, *, stepper_factory: StepperFactory | None = None, **node_kwargs: Any) -> None:
        super().__init__(NODE_NAME, **node_kwargs)
        self._table = parameter_table()
        self._startup_warnings: list[str] = []  # found while reading the parameters, logged once the node can start
        self.cfg, p = self._read_parameters()
        self.fast: bool = p["fast"]
        limits = SafetyLimits(**{f: p[k] for k, f in LIMIT_FIELDS.items()})
        tunnel = TunnelSettings(p["tunnel.time_constant_s"], p["tunnel.max_rate_mps2"])
        factory = stepper_factory or default_stepper_factory
        try:
            stepper = factory(self.cfg, p["model.variant"], p["model.aero"])
        except StartupError:
            raise
        except Exception as exc:
            raise StartupError(f"cannot build the model ({type(exc).__name__}: {exc})") from exc
        try:  # warm-up (JIT compile, caches) before the clock starts; then back to rest
            stepper.step(0.0, 0.0)
            if callable(getattr(stepper, "advance_sampled", None)):
                stepper.advance_sampled(np.zeros(2), np.zeros(2), np.array([1, 2]))
            stepper.shape_w_over_L(np.linspace(0.0, 1.0, SHAPE_POINTS))  # builds its cached basis / sampler
            stepper.reset()
        except Exception as exc:
            raise StartupError(f"the model fails its first step ({type(exc).__name__}: {exc})") from exc
        control = ControlSettings(**{f: p[k] for k, f in CONTROL_FIELDS.items()})
        # the tunnel's turbulence and the tip sensor (physics config tunnel.turbulence.*, sensor.*)
        extras = tunnel_extras(self.cfg, stepper) if hasattr(stepper, "x_colloc_m") else {}
        self.rig = Rig(stepper, self.cfg.panel_length_m, limits=limits, tunnel=tunnel, logger=self.get_logger(),
                       control=control, **extras)
        self.dt_s = self.rig.dt_s
        self._publish_period_s = 1.0 / p["publish_rate_hz"]
        self._max_lag_s = p["max_lag_s"]
        self.fast_max_rtf: float = p["fast_max_realtime_factor"]
        self._names = [f"q{i + 1}" for i in range(len(np.atleast_1d(stepper.q)))]
        self.recording = Recording(self.get_logger(), min_free_bytes=p["record_min_free_mb"] * 1e6)
        self._topic_prefix = self.get_namespace().rstrip("/")
        self._open_sinks(p)  # before the clock starts: opening a recording or a viewer takes time
        # said once the model and the sinks are up: before a start-up error they read as if the node were starting,
        # and a start that fails prints its one error line alone
        for warning in self._startup_warnings:
            self.get_logger().warning(warning)
        self.get_logger().info(
            f"physics parameters given: {self._physics_given} of {len(SCHEMA)} (others: paper defaults)"
        )

        # readings out (sensor-data QoS), commands in (reliable)
        sensor = qos_profile_sensor_data
        self.pub_tip = self.create_publisher(PointStamped, "tip_displacement", sensor)  # through the sensor model
        self.pub_truth = self.create_publisher(PointStamped, "tip_displacement/truth", sensor)  # the model's tip
        self.pub_modal = self.create_publisher(JointState, "modal_states", sensor)
        self.pub_airspeed = self.create_publisher(Vector3Stamped, "airspeed", sensor)
        self.pub_shape = self.create_publisher(Marker, "panel_shape", LATEST_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", COMMAND_QOS)
        self.pub_clock = self.create_publisher(Clock, "/clock", LATEST_QOS) if self.fast else None
        topics = ReadingTopics(self.pub_tip, self.pub_truth, self.pub_modal, self.pub_airspeed, self.pub_shape,
                               self.pub_clock)
        self.publication = ReadingPublisher(self.rig, self.cfg, self._names, topics, self.recording, rerun=self._rerun,
                                            logger=self.get_logger(), shape_period_s=1.0 / p["shape_rate_hz"])
        recorded = [self.pub_tip, self.pub_modal, self.pub_airspeed, self.pub_shape, self.pub_diag, self.pub_truth]
        if self._flutter_monitor is not None:  # created with the sinks: recorded under its full name too
            recorded.append(self.pub_flutter)
        self.recording.topics.update({pub: self._topic_name(pub.topic_name) for pub in recorded})
        commands = {
            "airspeed_cmd": self.rig.command_airspeed,
            "shaker/force_cmd": self.rig.command_force,
            "shaker/amplitude_cmd": self.rig.command_amplitude,
            "shaker/frequency_cmd": self.rig.command_frequency,
        }
        self._subs = [
            self.create_subscription(Float64, topic, self._command_callback(topic, fn), COMMAND_IN_QOS)
            for topic, fn in commands.items()
        ]
        self._init_control()
        self.create_service(Trigger, "reset", self._on_reset)
        self.create_service(Trigger, "abort", self._on_abort)

        # clocks: the physics follows the steady clock; stats for diagnostics and the benchmark
        self._diag_rejected = 0
        self._diag_record_errors = 0
        self._diag_viewer_dropped = 0
        self._viewer_warned_wall = -math.inf
        self._diag_aborts = 0  # the rig's abort count at the last /diagnostics
        self._rejections = RejectionLog()  # the warnings of rejected commands, throttled per topic
        # real time: readings carry the ROS clock (sim time + offset, shifted by every overrun); fast: sim time
        if not self.fast:
            self.publication.stamp_offset_ns = self.get_clock().now().nanoseconds - messages.stamp_ns(self.rig.time_s)
        self._wall0 = time.monotonic()
        self._wall_anchor = self._wall0
        self._sim_anchor = self.rig.time_s
        self._last_tick: float | None = None
        self._grid = PublishGrid(self.rig.time_s, self._publish_period_s)  # real time: the readings' sample times
        self.tick_intervals_s: deque[float] = deque(maxlen=500_000)  # the last ones: the jitter's sample
        self.tick_count = 0  # every real-time tick interval (the deque keeps the last 500 000: 17 min at 500 Hz)
        self._window_intervals: list[float] = []
        self._diag_wall = self._wall0
        self._diag_sim = self.rig.time_s
        self._fast_next_s = self.rig.time_s
        self._pending: dict[str, Any] = {}
        self._tick_timer = None if self.fast else self.create_timer(self._publish_period_s, self._tick)
        self._diag_timer = self.create_timer(1.0 / p["diagnostics_rate_hz"], self.publish_diagnostics)
        self.add_pre_set_parameters_callback(self._before_set_parameters)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        mode = "fast" if self.fast else "real-time"
        self.get_logger().info(
            f"panel_rig up ({mode}): dt = {self.dt_s:.6g} s, publish {1 / self._publish_period_s:g} Hz, "
            f"variant {p['model.variant']}, aero {p['model.aero']}, {len(self._names)} modes; readings stamped "
            + ("with simulated time (/clock published)" if self.fast else "with the ROS clock")
        )

    # ---- parameters ------------------------------------------------------------------------------
    def _read_parameters(self) -> tuple[PanelConfig, dict[str, Any]]:
        """Declare every parameter statically typed (with range and read-only flag) and read them."""
        overrides = getattr(self, "_parameter_overrides", {})
        for name, given in list(overrides.items()):  # e.g. an integer given for a float parameter is that float
            overrides[name] = as_declared(self._table, given)
        problems = []
        for name, (default, descriptor) in self._table.items():
            try:
                self.declare_parameter(name, default, descriptor)
            except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
                problems.append(f"{name}: {str(exc).removesuffix(f': {name}')}")  # rclpy ends it with the name
        if problems:
            raise StartupError("invalid parameters: " + "; ".join(problems))
        # a misspelt -p (model.variantt:=exact) ran the default variant behind a warning: refused, named, the
        # nearest name offered (rclpy's own parameters, declared at its start, count as the node's)
        problem = undeclared_problem(sorted(overrides), self.list_parameters([], 0).names)
        if problem:
            raise StartupError(f"invalid parameters: {problem}")
        node_values = {n: self.get_parameter(n).value for n in NODE_PARAMS}
        problems = check_node_params(node_values)
        if problems:
            raise StartupError("invalid node parameters: " + "; ".join(problems))
        physics = {k: self.get_parameter(k).value for k in SCHEMA}
        if node_values["physics_dt"] > 0:
            physics["sim.dt_s"] = node_values["physics_dt"]
        try:
            cfg = config_from_flat(physics)
        except ConfigError as exc:
            raise StartupError(f"invalid physics parameter: {exc}") from exc
        problem = publish_rate_problem(node_values["publish_rate_hz"], cfg.dt_s)
        if problem:
            raise StartupError(f"invalid node parameters: {problem}")
        self._physics_given = len(set(overrides) & set(SCHEMA))  # logged once the node can start (see __init__)
        if node_values["safety.max_tip_w_over_L"] >= cfg.max_tip_w_over_L:
            self._startup_warnings.append(
                f"safety.max_tip_w_over_L = {node_values['safety.max_tip_w_over_L']:g} is not below the "
                f"model's divergence bound sim.max_tip_w_over_L = {cfg.max_tip_w_over_L:g}"
            )
        return cfg, node_values

    def _before_set_parameters(self, params: list[Parameter]) -> list[Parameter]:
        return [as_declared(self._table, prm) for prm in params]

    def set_parameters_atomically(self, parameter_list: list[Parameter]) -> SetParametersResult:
        """As rclpy's, except that setting a read-only parameter to the value it has is accepted as a no-op,
        so ``ros2 param load`` of the file the node started with (or of a ``ros2 param dump``) succeeds, and that
        a name the node does not declare is refused with a reason that names it."""
        problem = undeclared_problem([prm.name for prm in parameter_list], self.list_parameters([], 0).names)
        if problem:
            return SetParametersResult(successful=False, reason=problem)
        changing = [prm for prm in parameter_list if not self._unchanged_read_only(prm)]
        if not changing:
            return SetParametersResult(successful=True, reason="unchanged (read-only)")
        return super().set_parameters_atomically(changing)

    def _unchanged_read_only(self, prm: Parameter) -> bool:
        """A read-only parameter (ours or rclpy's own) given the value and type it has."""
        if not self.has_parameter(prm.name) or not self.describe_parameter(prm.name).read_only:
            return False
        prm, current = as_declared(self._table, prm), self.get_parameter(prm.name)
        return prm.type_ == current.type_ and prm.value == current.value

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Validate a live change: physics and structural parameters are refused with a reason."""
        reason = live_change_problem(params, lambda name: self.get_parameter(name).value, self.rig.dt_s)
        if reason is not None:
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, params: list[Parameter]) -> None:
        """Apply accepted live changes (rates are applied between callbacks, see :meth:`apply_pending`)."""
        limits: dict[str, float] = {}
        control: dict[str, float] = {}
        for prm in params:
            if prm.name not in NODE_PARAMS:
                continue
            value = prm.value
            if prm.name in LIMIT_FIELDS:
                limits[LIMIT_FIELDS[prm.name]] = value
            elif prm.name in CONTROL_FIELDS:
                control[CONTROL_FIELDS[prm.name]] = value
            elif prm.name == "tunnel.time_constant_s":
                self.rig.actuator.set_time_constant(value)
            elif prm.name == "tunnel.max_rate_mps2":
                self.rig.actuator.set_max_rate(value)
            elif prm.name == "max_lag_s":
                self._max_lag_s = value
            elif prm.name == "control.fast_delay_s":
                self._fast_delay_s = value
            elif prm.name == "fast_max_realtime_factor":
                self.fast_max_rtf = value
            else:
                self._pending[prm.name] = value
        if control:
            self.rig.set_control(**control)
        if limits:
            self.rig.set_limits(**limits)  # acts on the present: ramps the tunnel down or aborts, logged
        self.get_logger().info("parameters set: " + ", ".join(f"{p.name}={p.value}" for p in params))

    def apply_pending(self) -> None:
        """Re-create timers for changed rates (outside any callback)."""
        pending, self._pending = self._pending, {}
        if "publish_rate_hz" in pending:
            self._publish_period_s = 1.0 / pending["publish_rate_hz"]
            if self._tick_timer is not None:
                self.destroy_timer(self._tick_timer)
                self._tick_timer = self.create_timer(self._publish_period_s, self._tick)
                self._last_tick = None
            self._grid = PublishGrid(self.rig.time_s, self._publish_period_s)  # the grid of the new rate
        if "shape_rate_hz" in pending:
            self.publication.shape_period_s = 1.0 / pending["shape_rate_hz"]
        if "diagnostics_rate_hz" in pending:
            self.destroy_timer(self._diag_timer)
            self._diag_timer = self.create_timer(1.0 / pending["diagnostics_rate_hz"], self.publish_diagnostics)

    # ---- sinks -----------------------------------------------------------------------------------
    def _open_sinks(self, p: dict[str, Any]) -> None:
        """The flutter monitor (``flutter_monitor``), Rerun (``rerun``) and the recording (``record``/``bag_dir``).
        A sink asked for that cannot be opened (a bad path, a missing package) is a StartupError."""
        self._flutter_monitor: Any = None
        if p["flutter_monitor"] and hasattr(self.rig.stepper, "model"):
            from panel_rig.rig.flutter_run import FlutterMonitorSink
            from panel_rig.ros.flutter_monitor import TOPIC

            self.pub_flutter = self.create_publisher(DiagnosticArray, TOPIC, COMMAND_QOS)
            self._flutter_monitor = FlutterMonitorSink(self.cfg, self.rig.stepper.model, self._publish_flutter,
                                                       margin=p["flutter_test.margin"],
                                                       settle_s=p["flutter_test.settle_s"],
                                                       dwell_s=p["flutter_test.dwell_s"],
                                                       repeats=p["flutter_test.repeats"])
            self.rig.sinks.append(self._flutter_monitor)
        self.holds = ClientHolds(self.rig, self.get_logger(), wait_for_command=p["fast_wait_for_command"] and p["fast"],
                                 flutter_hold=p["flutter_test.hold"] and p["fast"], flutter_monitor=self._flutter_monitor,
                                 recording_uncapped=p["record"] and not p["fast_max_realtime_factor"])
        # asked for and not possible: the node does not start (a run believed recorded must not go unrecorded)
        self._rerun: Any = None
        if p["rerun"] != "none":
            mode, _, target = p["rerun"].partition(":")
            try:
                from panel_rig.viz import RerunLogger

                # the control views once a controller commands (control can be switched on at run time); the
                # monitor's when it runs
                views = ("flutter", "flutter_uf", "flutter_zw") if self._flutter_monitor is not None else ()
                self._rerun = RerunLogger(len(self._names), mode=mode, target=target or None, views=views,
                                          control_views_on_data=True)
            except Exception as exc:  # noqa: BLE001 (VizError, rerun's own errors, no rerun-sdk)
                raise StartupError(f"cannot open the Rerun sink {p['rerun']!r}: {type(exc).__name__}: {exc}") from None
            self.rig.sinks.append(self._rerun)
            self.get_logger().info(f"rerun sink: {p['rerun']}")
        if p["record"]:
            try:
                from panel_rig.recording import BagWriter, fresh_bag_dir

                writer = BagWriter(fresh_bag_dir(Path(p["bag_dir"]), "rig"))
                self.recording.recorders.append(writer)
                writer.write_parameters({prm.name: prm.value for prm in self._parameters.values()})
            except Exception as exc:  # noqa: BLE001 (RecordingError, OSError, no mcap)
                self.close()
                raise StartupError(f"cannot record in {p['bag_dir']!r}: {type(exc).__name__}: {exc}") from None
            self.get_logger().info(f"recording to {writer.bag_dir}")

    def _publish_flutter(self, time_s: float, point: Any, decision: Any, fluttered: bool = False) -> None:
        """One flutter-monitor message per identified plateau (to the topic, the bag and the viewer)."""
        from panel_rig.ros.flutter_monitor import monitor_msg

        mon = self._flutter_monitor
        band = mon.bands(point.airspeed_mps)[1]
        plateau = {"point_index": mon.published, "plateau_start_s": mon.plateau_start_s, "settle_s": mon.settle_s,
                   "dwell_s": mon.dwell_s, "sim_time_s": time_s, "flutter_band_low_hz": band[0],
                   "flutter_band_high_hz": band[1], "identify_wall_s": mon.last_wall_s}
        stamp = self.publication.stamp_ns(time_s)
        msg = monitor_msg(stamp, point, decision, mon.settings.margin, fluttered=fluttered, plateau=plateau)
        self.publication.publish(self.pub_flutter, msg, stamp, qos="reliable")
        if self._rerun is not None and not fluttered:
            self._rerun.log_flutter_point(time_s, self._flutter_monitor.points, decision,
                                          self._flutter_monitor.settings.margin)

    def _topic_name(self, name: str) -> str:
        return name if name.startswith("/") else f"{self._topic_prefix}/{name}"

    # ---- closed-loop control (issue 13): control/force_cmd; the logic is in panel_rig.rig.control ------------
    def _init_control(self) -> None:
        """``control/force_cmd`` (geometry_msgs/WrenchStamped: ``wrench.force.z`` N/m, ``header.stamp`` = the stamp
        of the tip reading it answers)."""
        self._control_topic = self._topic_name(CONTROL_TOPIC)
        self._fast_delay_s = float(self.get_parameter("control.fast_delay_s").value)
        self._lockstep = False  # fast mode: engaged by each control command, released when the controller is silent
        self._answered_ns = -1
        self._control_sub = self.create_subscription(WrenchStamped, CONTROL_TOPIC, self._on_control,
                                                     COMMAND_QOS)

    def _on_control(self, msg: WrenchStamped) -> None:
        """Age = now - stamp in the rig's time base (real time: the ROS clock; fast: simulated time); the command
        acts from the simulated instant of its arrival."""
        self.holds.command_arrived()
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        stamp_s = (stamp_ns - self.publication.stamp_offset_ns) * 1e-9
        if self.fast:  # lock-step: the rig waited for this answer; the transport latency is emulated
            arrival_s = self.rig.time_s + self._fast_delay_s
        else:
            arrival_s = (self.get_clock().now().nanoseconds - self.publication.stamp_offset_ns) * 1e-9
        force = msg.wrench.force.z
        result = self.rig.command_control(force, stamp_s, arrival_s)
        if self.fast and stamp_ns <= self.publication.stamp_ns(self.rig.time_s):
            # a controller answered a reading: march in lock-step with it, even when this answer was refused as too
            # old (uncapped, the rig ran free hundreds of times faster than real time and refused every answer, so
            # a lock-step engaged only by an accepted one never came); a stamp from the future answers nothing
            self._lockstep = True
            self._answered_ns = max(self._answered_ns, stamp_ns)
        self._record_command(self._control_topic, msg, result.accepted)
        if result.accepted and self._rerun is not None:
            try:
                self._rerun.log_control(stamp_s, force, (arrival_s - stamp_s) * 1e3)
            except Exception as exc:  # noqa: BLE001
                self.get_logger().error(f"rerun control failed: {exc}", throttle_duration_sec=5.0)
        if not result.accepted:
            # the reason's times are the rig's (simulated s); the stamp as the controller sent it, when it differs
            sent = (f" (times in the rig's seconds; header.stamp was {msg.header.stamp.sec}."
                    f"{msg.header.stamp.nanosec:09d} s)" if self.publication.stamp_offset_ns else "")
            self._warn_rejected(CONTROL_TOPIC, f"{CONTROL_TOPIC} {force!r} rejected: {result.reason}{sent}")

    def lockstep_wait(self, executor: SingleThreadedExecutor) -> None:
        """Fast mode with a controller attached: serve callbacks until the reading just published is answered (a
        hardware-in-the-loop lock-step, deterministic whatever the machine's load). A controller silent for
        LOCKSTEP_TIMEOUT_S of wall time releases the lock-step (the watchdog then acts in simulated time)."""
        if not (self.fast and self._lockstep):
            return
        published = messages.stamp_ns(self.rig.time_s)
        deadline = time.monotonic() + LOCKSTEP_TIMEOUT_S
        while self._answered_ns < published and self._lockstep:
            if time.monotonic() > deadline:
                self._lockstep = False
                self.get_logger().warning(f"controller silent for {LOCKSTEP_TIMEOUT_S:g} s (wall): lock-step released "
                                          f"at t = {self.rig.time_s:.3f} s")
                return
            executor.spin_once(timeout_sec=0.002)

    # ---- commands and services -----------------------------------------------------------------------
    def _command_callback(self, topic: str, command: Callable[[float], Any]) -> Callable[[Float64], None]:
        """The subscription callback of one command topic: apply, record, and on a refusal warn and echo the
        command on ``<topic>/rejected`` (live, so a client knows which of its commands did not act)."""
        full = self._topic_name(topic)
        echo = self.create_publisher(Float64, topic + REJECTED_SUFFIX, REJECTED_QOS)

        def callback(msg: Float64) -> None:
            self.holds.command_arrived()
            result = command(msg.data)
            self._record_command(full, msg, result.accepted)
            if not result.accepted:
                self._warn_rejected(topic, f"{topic} {msg.data!r} rejected: {result.reason}")
                echo.publish(msg)

        return callback

    def _warn_rejected(self, topic: str, text: str) -> None:
        """A warning per rejected command, throttled per topic (:class:`~panel_rig.ros.rejections.RejectionLog`)."""
        line = self._rejections.rejected(topic, text, time.monotonic())
        if line is not None:
            self.get_logger().warning(line)

    def _log_held_rejections(self) -> None:
        """At each diagnostics period: the warnings the throttle held back, one line per topic, once its period
        has passed."""
        for line in self._rejections.due(time.monotonic()):
            self.get_logger().warning(line)

    def _record_command(self, topic: str, msg: Any, accepted: bool) -> None:
        """Every command received goes into the recording: on its own topic if the rig took it, else on
        ``<topic>/rejected`` (a replay or an analysis of the bag then sees the commands that acted)."""
        if not self.recording.active:
            return
        name = topic if accepted else topic + REJECTED_SUFFIX
        stamp = self.publication.stamp_ns(self.rig.time_s)
        self.recording.record(lambda rec: rec.write(name, msg, stamp, qos="reliable"))

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        was = self.rig.state
        self.rig.reset()
        response.success = True
        response.message = f"reset at t = {self.rig.time_s:.3f} s (was {was})"
        self.get_logger().info(response.message)
        return response

    def _on_abort(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        rig = self.rig
        was = rig.state == ABORTED
        rig.abort("abort service")
        response.success = True
        response.message = (f"already aborted at t = {rig.abort_time_s:.3f} s ({rig.abort_reason})" if was
                            else f"aborted at t = {rig.time_s:.3f} s") + "; airspeed ramping to 0"
        return response

    # ---- time ------------------------------------------------------------------------------------------
    def _tick(self) -> None:
        """Real-time tick: step to the last point of the publish grid the steady clock has passed (bounded by one
        tick of wall time) and publish. A late tick also publishes the samples it owes, one publish period apart (as
        a data-acquisition buffer would), so a loaded machine delays readings instead of dropping them; only those
        within max_lag_s are owed."""
        now = time.monotonic()
        if self._last_tick is not None:
            interval = now - self._last_tick
            self.tick_intervals_s.append(interval)
            self.tick_count += 1
            self._window_intervals.append(interval)
        self._last_tick = now
        target = self._sim_anchor + (now - self._wall_anchor)
        deadline = now + self._publish_period_s
        owed_from_s = target - self._max_lag_s
        chunk = max(2, math.ceil(self._publish_period_s / self.dt_s))
        while self.rig.time_s < owed_from_s and self.rig.advance_to(owed_from_s, max_steps=chunk) \
                and time.monotonic() < deadline:
            pass
        if time.monotonic() < deadline:  # on time (as nearly always): one compiled call to the grid's last point
            times = self._grid.tick(self.rig.time_s, target)
            if times:
                self.publication.publish_block(self.rig.advance_samples(step_counts(self.rig.time_s, times,
                                                                                   self.dt_s)))
        else:
            self.publication.publish_readings()
        self._diagnose_new_abort()
        # behind the clock by more than the grid allows (the next point is up to a period and a step ahead)
        lag = target - self.rig.time_s - self._publish_period_s - self.dt_s
        if lag > self._max_lag_s:
            # cannot catch up within the bound: count it and let simulated time slip
            self.rig.note_overrun()
            self._wall_anchor += lag
            self.publication.stamp_offset_ns += round(lag * 1e9)  # stamps stay on the ROS clock
            self.get_logger().warning(f"overrun: {lag * 1e3:.1f} ms behind the clock", throttle_duration_sec=1.0)

    def fast_iteration(self) -> None:
        """Fast mode: march up to FAST_MAX_BLOCK_PERIODS publish periods in one block (up to the next shape sample
        if the stepper cannot draw a sample's shape or the readings have subscribers), then publish them all."""
        start = max(self._fast_next_s, self.rig.time_s)
        periods = 1 if self._lockstep else FAST_MAX_BLOCK_PERIODS  # a controller in lock-step: one period
        # blocks end at the next shape sample if the shape needs the stepper's own state, and while anyone subscribes
        # to the readings: a best-effort subscriber (depth 5) keeps up with bursts of ~17 periods, not of 64
        out = self.publication
        if not out.shape_of_q or out.readings_subscribed():
            periods = min(max(math.ceil((out.next_shape_s - start) / self._publish_period_s - 1e-9), 1), periods)
        targets = [start + k * self._publish_period_s for k in range(1, periods + 1)]
        counts = step_counts(self.rig.time_s, targets, self.dt_s)
        self._fast_next_s = start + periods * self._publish_period_s
        self.publication.publish_block(self.rig.advance_samples(counts))
        self._diagnose_new_abort()

    def _diagnose_new_abort(self) -> None:
        """/diagnostics at once when the rig has aborted since the last status: at the diagnostics period (wall
        time) a fast run that aborted and stopped within it recorded no status of the abort at all."""
        if self.rig.abort_count != self._diag_aborts:
            self.publish_diagnostics()

    def stats(self) -> dict[str, float]:
        """Real-time factor since start, overruns, tick jitter (p99 of |interval - period|, ms)."""
        return run_stats(self.rig, time.monotonic() - self._wall0, self.tick_intervals_s, self._publish_period_s,
                         self.tick_count)

    def publish_diagnostics(self) -> None:
        """State, real-time factor (last window), overruns, rejected commands, last rejection."""
        self._log_held_rejections()
        now = time.monotonic()
        rig, recording = self.rig, self.recording
        self._diag_aborts = rig.abort_count
        rtf = (rig.time_s - self._diag_sim) / (now - self._diag_wall) if now > self._diag_wall else 0.0
        self._diag_wall, self._diag_sim = now, rig.time_s
        jitter_ms = jitter_p99_ms(self._window_intervals, self._publish_period_s)
        self._window_intervals = []
        values = diagnostic_values(rig, recording, fast=self.fast, rtf=rtf, jitter_ms=jitter_ms, lockstep=self._lockstep)
        rejected_now = rig.rejected_count - self._diag_rejected
        self._diag_rejected = rig.rejected_count
        record_errors_now = recording.errors - self._diag_record_errors
        self._diag_record_errors = recording.errors
        level, message = diagnostic_level(rig, rejected_now, record_errors_now, recording.last_error,
                                          recording.stopped)
        dropped = self._rerun.dropped_batches if self._rerun is not None else 0
        values["viewer_dropped_batches"] = dropped
        if dropped > self._diag_viewer_dropped:  # a live viewer that stopped taking data: said while it happens,
            # at most every VIEWER_WARNING_PERIOD_S (each status said it: 39 lines in 20 s at 2 Hz)
            if now - self._viewer_warned_wall >= VIEWER_WARNING_PERIOD_S:
                self.get_logger().warning(f"the Rerun viewer is not taking data: {dropped} batches dropped so far "
                                          "(the bag has every reading)")
                self._viewer_warned_wall = now
            self._diag_viewer_dropped = dropped
        stamp = self.publication.stamp_ns(rig.time_s)
        msg = messages.diagnostics_msg(stamp, level, message, values, hardware_id=self.get_namespace())
        self.publication.publish(self.pub_diag, msg, stamp, "reliable")

    def close(self) -> None:
        """Close recorders, then the rig's sinks (idempotent): the bag is closed first, whatever a viewer sink
        does on closing."""
        self.recording.close()
        self.rig.close()


if __name__ == "__main__":  # `python -m panel_rig.ros.node`, the earlier releases' documented form: the same program
    import sys

    from panel_rig.ros.rig_node import main

    sys.exit(main())
