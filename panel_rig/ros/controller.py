"""``panel-rig control``: the reference flutter-suppression controller, a separate ROS 2 node.

It uses only what a real controller has: the measured tip (``tip_displacement``) and airspeed (``airspeed``). For
every tip reading it runs the reference law (``panel_rig.analysis.control``: filtered tip-rate feedback, in
discrete time at the reading rate) and publishes ``control/force_cmd`` (geometry_msgs/WrenchStamped,
``wrench.force.z`` in N per metre span, ``header.stamp`` = the answered reading's stamp, so the rig measures the
loop's latency). Run::

    panel-rig control --ros-args -r __ns:=/rig [-p gain_nspm2:=0.4] [-p derivative_hz:=150.0]

Parameters: ``gain_nspm2`` (N/m of force per m/s of tip velocity; 0 = design it at start from the physics
parameters, ``--params FILE``, for ``design_delay_ms``), ``derivative_hz`` (derivative filter corner),
``design_delay_ms`` (loop delay the design assumes), ``actuator_bandwidth_hz`` and ``max_force_npm`` (the rig's
``control.*`` values: the command is clipped to the saturation, so the rig never rejects it), ``enabled``.
``gain_nspm2`` (> 0), ``derivative_hz``, ``max_force_npm`` and ``enabled`` may be changed live (``ros2 param set``);
the design inputs (``design_delay_ms``, ``actuator_bandwidth_hz``) act only at start, and a live change is refused.
The law is not gain-scheduled: one gain is stable from rest to its closed-loop flutter speed (checked at design);
the airspeed is only reported.
"""

from __future__ import annotations

import math
import sys
import threading
from collections.abc import Sequence

import rclpy
from geometry_msgs.msg import PointStamped, Vector3Stamped, WrenchStamped
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import InvalidParameterTypeException
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from panel_rig.analysis.control import DESIGN_DELAY_S, ControlLaw, DiscreteLaw
from panel_rig.argparsing import OneLineParser
from panel_rig.rig.control import ControlSettings
from panel_rig.ros.params import as_declared, undeclared_problem
from panel_rig.ros.session import ros_arguments_problem, ros_session
from panel_rig.topics import CONTROL_TOPIC

NODE_NAME = "panel_rig_controller"
COMMAND_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
MAX_GAP_S = 0.05  # a longer gap between readings restarts the filter (no kick from a stale state)
# a reading stamped this much before the last one is not late (best-effort readings are milliseconds late) but from
# a rig whose clock started again (a restarted fast node: its time starts at 0): the controller follows it
RESTART_BACKSTEP_S = 1.0
#: the parameters a running controller takes; the design inputs are read at start only
LIVE = ("gain_nspm2", "derivative_hz", "max_force_npm", "enabled")
DESIGN_INPUTS = ("design_delay_ms", "actuator_bandwidth_hz")
REPORT_S = 5.0  # wall seconds between the log lines of the counts


def _positive(name: str, v: object) -> str | None:
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0
    return None if ok else f"{name} must be a finite number > 0, got {v!r}"


def parameter_problem(name: str, value: object, at_start: bool) -> str | None:
    """Why a controller parameter value is refused (None: accepted). ``gain_nspm2`` 0 means "design it", at start
    only; ``design_delay_ms`` is in [0, 100] ms."""
    if name == "enabled":
        return None if isinstance(value, bool) else f"enabled must be true or false, got {value!r}"
    if name not in LIVE and not at_start:
        what = "a design input" if name in DESIGN_INPUTS else "read at start"  # (use_sim_time: rclpy's own)
        return f"{name} is {what}, used at start only: restart the controller to change it"
    if name == "gain_nspm2" and at_start and value == 0.0:
        return None
    if name == "design_delay_ms":
        ok = isinstance(value, (int, float)) and math.isfinite(value) and 0 <= value <= 100
        return None if ok else f"design_delay_ms must be in [0, 100] ms, got {value!r}"
    return _positive(name, value)


class Controller(Node):
    """Tip reading in, force command out, one for one."""

    def __init__(self, physics_files: Sequence[str] = (), **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        defaults = ControlSettings()
        self._defaults = {"gain_nspm2": (0.0, None), "derivative_hz": (150.0, None),
                          "design_delay_ms": (DESIGN_DELAY_S * 1e3, None),
                          "actuator_bandwidth_hz": (float(defaults.bandwidth_hz), None),
                          "max_force_npm": (float(defaults.max_force_npm), None), "enabled": (True, None)}
        # an integer given for a float parameter (-p gain_nspm2:=1, ros2 param set ... 1) is that float, as the
        # rig node takes it; rclpy refused it at start ("expecting type 'DOUBLE'")
        overrides = getattr(self, "_parameter_overrides", {})
        for name in self._defaults:
            if name in overrides:
                overrides[name] = as_declared(self._defaults, overrides[name])
        for name, (default, _) in self._defaults.items():
            try:
                self.declare_parameter(name, default)
            except InvalidParameterTypeException as exc:  # `-p design_delay_ms:=abc`: the parameter and why, not
                raise ValueError(f"{name}: {str(exc).removesuffix(f': {name}')}") from None  # rclpy's class name
        problem = undeclared_problem(sorted(overrides), self.list_parameters([], 0).names)
        if problem:  # a misspelt -p (gian_nspm2:=1) was ignored without a word and the gain designed
            raise ValueError(f"invalid parameters: {problem}")
        self.add_pre_set_parameters_callback(lambda params: [as_declared(self._defaults, p) for p in params])
        for name in (*LIVE, *DESIGN_INPUTS):
            problem = parameter_problem(name, self.get_parameter(name).value, at_start=True)
            if problem:
                raise ValueError(problem)
        gain = float(self.get_parameter("gain_nspm2").value)
        derivative_hz = float(self.get_parameter("derivative_hz").value)
        if gain <= 0:
            gain = self._design(physics_files, derivative_hz)
        self.law = ControlLaw(gain, derivative_hz)
        self.discrete = DiscreteLaw(self.law)
        self.max_force = float(self.get_parameter("max_force_npm").value)
        self.enabled = bool(self.get_parameter("enabled").value)
        self.pub = self.create_publisher(WrenchStamped, CONTROL_TOPIC, COMMAND_QOS)
        self.create_subscription(PointStamped, "tip_displacement", self._on_tip, qos_profile_sensor_data)
        self.create_subscription(Vector3Stamped, "airspeed", self._on_airspeed, qos_profile_sensor_data)
        self._msg = WrenchStamped()
        self._msg.header.frame_id = "panel_rig"
        self._last_stamp_ns: int | None = None
        self.airspeed_mps = math.nan
        self.sent = 0
        self.clipped = 0
        self.readings = 0  # tip readings since the last report
        self.create_timer(REPORT_S, self._report)
        self.add_on_set_parameters_callback(self._on_set)
        self.get_logger().info(
            f"controller up: F = -{gain:g} s/(1 + s/(2 pi {derivative_hz:g})) w [N/m per m/s], clip "
            f"+-{self.max_force:g} N/m, {'enabled' if self.enabled else 'disabled'}")

    def _design(self, physics_files: Sequence[str], derivative_hz: float) -> float:
        from panel_rig.analysis.control import design_law
        from panel_rig.config import load_config
        from panel_rig.model.aeroelastic import AeroelasticModel

        cfg = load_config(physics_files[-1] if physics_files else None)
        design = design_law(AeroelasticModel(cfg), float(self.get_parameter("actuator_bandwidth_hz").value),
                            float(self.get_parameter("design_delay_ms").value) * 1e-3, derivative_hz)
        self.get_logger().info(
            f"designed on the ROM: gain {design.law.gain_nspm2:g} N s/m^2; predicted flutter speed "
            f"{design.open_loop_flutter_mps:.2f} -> {design.closed_loop_flutter_mps or math.inf:.2f} m/s")
        return design.law.gain_nspm2

    def set_parameters_atomically(self, parameter_list: list[Parameter]) -> SetParametersResult:
        """As rclpy's, except that a name the node does not declare is refused with a reason that names it."""
        problem = undeclared_problem([prm.name for prm in parameter_list], self.list_parameters([], 0).names)
        if problem:
            return SetParametersResult(successful=False, reason=problem)
        return super().set_parameters_atomically(parameter_list)

    def _on_set(self, params: list[Parameter]) -> SetParametersResult:
        """Live changes: all checked first, then applied together (the law keeps its filter state)."""
        for p in params:
            problem = parameter_problem(p.name, p.value, at_start=False)
            if problem:
                return SetParametersResult(successful=False, reason=problem)
        new = {p.name: p.value for p in params}
        if "gain_nspm2" in new or "derivative_hz" in new:
            self.law = ControlLaw(float(new.get("gain_nspm2", self.law.gain_nspm2)),
                                  float(new.get("derivative_hz", self.law.derivative_hz)))
            self.discrete = DiscreteLaw(self.law)
            self._last_stamp_ns = None  # the new filter starts from the next reading
        self.max_force = float(new.get("max_force_npm", self.max_force))
        self.enabled = bool(new.get("enabled", self.enabled))
        self.get_logger().info(f"parameters changed: {new}")
        return SetParametersResult(successful=True)

    def _on_airspeed(self, msg: Vector3Stamped) -> None:
        self.airspeed_mps = msg.vector.x

    def _on_tip(self, msg: PointStamped) -> None:
        self.readings += 1
        st = msg.header.stamp
        ns = st.sec * 1_000_000_000 + st.nanosec
        last = self._last_stamp_ns
        if last is not None and ns <= last:
            if last - ns < RESTART_BACKSTEP_S * 1e9:
                return  # late or repeated reading (best effort): the answer to a newer one is out already
            self.get_logger().info("the rig's time went back: a restarted rig; the filter starts again")
            last = None
        if last is None or ns - last > MAX_GAP_S * 1e9:
            self.discrete.reset()
        dt = 0.0 if last is None else (ns - last) * 1e-9
        self._last_stamp_ns = ns
        force = self.discrete.step(msg.point.z, dt)
        if not math.isfinite(force):
            self.discrete.reset()
            return
        if abs(force) > self.max_force:
            force = math.copysign(self.max_force, force)
            self.clipped += 1
        if not self.enabled:
            return
        m = self._msg
        m.header.stamp = st  # the answered reading's stamp: the rig measures the command's age from it
        m.wrench.force.z = float(force)
        self.pub.publish(m)
        self.sent += 1

    def _report(self) -> None:
        self.get_logger().info(report_line(self.readings, self.sent, self.clipped, self.airspeed_mps,
                                           self.get_namespace()))
        self.readings = 0


def report_line(readings: int, sent: int, clipped: int, airspeed_mps: float, namespace: str) -> str:
    """The periodic log line: the counts, or that no rig is heard (it read "airspeed nan m/s" then)."""
    if readings == 0:
        return (f"no tip readings in the last {REPORT_S:g} s: is a rig node running in {namespace} on this "
                f"ROS_DOMAIN_ID? (commands sent {sent}, clipped {clipped})")
    return f"commands sent {sent}, clipped {clipped}, airspeed {airspeed_mps:.2f} m/s"


def main(argv: Sequence[str] | None = None, *, prog: str = "rig_controller") -> int:
    """Entry point (``rig_controller``; ``panel-rig control``). argv excludes the program name; ``prog`` is the
    name its messages and ``--help`` give."""
    from rclpy.utilities import remove_ros_args

    args = list(sys.argv[1:] if argv is None else argv)
    parser = OneLineParser(prog=prog, description=__doc__.splitlines()[0])
    parser.add_argument("--params", action="append", default=[], metavar="FILE",
                        help="physics parameters for the design (default: the paper's)")
    problem = ros_arguments_problem(args)
    if problem:
        print(f"{prog}: {problem}", file=sys.stderr)
        return 2
    opts = parser.parse_args(remove_ros_args(["controller", *args])[1:])
    stop = threading.Event()
    node = None
    code = 0
    with ros_session(["controller", *args], stop):
        try:
            node = Controller(opts.params)
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            while not stop.is_set() and rclpy.ok():
                executor.spin_once(timeout_sec=0.05)
            node.get_logger().info(f"stopping: {node.sent} commands sent, {node.clipped} clipped")
        except ValueError as exc:  # a bad parameter: its own message says which and why
            print(f"{prog}: {exc}", file=sys.stderr)
            code = 2
        except Exception as exc:  # noqa: BLE001 (one line and exit 2, never a traceback wall)
            print(f"{prog}: {type(exc).__name__}: {exc}", file=sys.stderr)
            code = 2
        finally:
            if node is not None:
                node.destroy_node()
    return code


if __name__ == "__main__":
    sys.exit(main())
