"""The flutter-test client: drives a running rig node over its topics, as a tunnel's test engineer would.

It publishes airspeed set-points on ``airspeed_cmd`` and reads one result per test point from the node's
``flutter_monitor`` (DiagnosticArray, see :mod:`panel_rig.ros.flutter_monitor`): the node's monitor identifies
each plateau on the full-rate measured tip in-process (settle and dwell in simulated time), so the 500 Hz tip
stream never goes through this client. The client rebuilds each test point from the message (the estimates bit
for bit), predicts and decides with its own settings (:func:`panel_rig.analysis.flutter_test.run_points`), and
reads liveness and simulated time from ``/diagnostics`` (2 Hz wall). It subscribes to nothing at the sample rate.
"""

from __future__ import annotations

import math
import time
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64

from panel_rig.analysis.flutter_test import TestPoint
from panel_rig.processes import RIG_STARTUP_TIMEOUT_S, StopRequest, stop_exception
from panel_rig.ros.flutter_monitor import STATUS_NAME, TOPIC, parse_monitor, point_from_values
from panel_rig.ros.messages import rig_status

COMMAND_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
MONITOR_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


class RigGone(RuntimeError):
    """The node stopped answering (no diagnostics, or its process ended) before the test finished."""


#: wall seconds from the client's start before its first command: a node already running on the domain is seen only
#: once it announces itself again, every 3 s by Fast DDS's default (measured here: its endpoints were discovered
#: after 0.1 s or after 2.4-3.0 s, 15 trials), while the test's own, new node announces itself at once. Without the
#: wait a rig left running on the domain could take the first commands unseen.
DISCOVERY_SETTLE_S = 3.5


class PointWatchdog:
    """Bounds the wait for one test point in the node's simulated time: its result is due when the plateau's run-in
    and dwell (``point_s``) have passed, and the node's monitor publishes it in the block that completes the dwell.
    Past ``point_s`` + the slack, the point is overdue: :meth:`check` raises RigGone (the test winds the tunnel off
    and stops its node) instead of waiting while the node runs free, recording, in fast mode (a window the monitor
    never identified once ran 269,000 simulated s and filled the disk with a 76 GB bag). Times come from the node's
    /diagnostics (2 Hz wall); the first report after the command is the reference, so a report from before the
    command cannot make a point look overdue."""

    #: the slack past run-in + dwell: a diagnostics report's age (0.5 s wall) at real time, plus room
    SLACK_S, SLACK_FRACTION = 10.0, 0.1

    def __init__(self, airspeed_mps: float, point_s: float) -> None:
        self.airspeed_mps, self.point_s = float(airspeed_mps), float(point_s)
        self.limit_s = self.point_s + max(self.SLACK_S, self.SLACK_FRACTION * self.point_s)
        self._since_s: float | None = None

    def check(self, sim_time_s: float) -> None:
        """``sim_time_s``: the node's simulated time in a diagnostics report received after the command (s)."""
        if not math.isfinite(sim_time_s):
            return
        if self._since_s is None or sim_time_s < self._since_s:  # the first report (or a restarted node's clock)
            self._since_s = sim_time_s
        waited = sim_time_s - self._since_s
        if waited > self.limit_s:
            raise RigGone(f"the node's flutter monitor gave no result for {self.airspeed_mps:g} m/s in {waited:.0f} s "
                          f"(simulated) after the command, where run-in + dwell take {self.point_s:g} s: the test "
                          "stopped there (a fault of the monitor: please report it with the node log)")


class FlutterTestClient(Node):
    """Airspeed commands out; flutter-monitor results and tunnel diagnostics in."""

    def __init__(self, namespace: str = "/rig", timeout_s: float = 60.0, alive: Callable[[], bool] | None = None,
                 **kwargs: Any) -> None:
        super().__init__("panel_rig_flutter_test", namespace=namespace, **kwargs)
        self.timeout_s = timeout_s
        self.point_s = math.inf  # a test point's run-in + dwell, simulated s (the test's settings): PointWatchdog
        self.alive = alive or (lambda: True)
        self.stop: StopRequest | None = None  # set by a signal: the test's waits end between rclpy calls
        self.pub_airspeed = self.create_publisher(Float64, "airspeed_cmd", COMMAND_QOS)
        self.results: list[dict[str, Any]] = []
        self.diagnostics: dict[str, str] = {}
        self.diagnostics_received = 0  # tunnel diagnostics messages so far
        self._last_heard = self._created = time.monotonic()
        self.sub_monitor = self.create_subscription(DiagnosticArray, TOPIC, self._on_monitor, MONITOR_QOS)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, COMMAND_QOS)

    def _on_monitor(self, msg: DiagnosticArray) -> None:
        if msg.status and msg.status[0].name == STATUS_NAME:
            self.results.append(parse_monitor(msg))
            self._last_heard = time.monotonic()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        values = rig_status(msg, self.get_namespace())
        if values is not None:
            self.diagnostics = values
            self.diagnostics_received += 1
            self._last_heard = time.monotonic()

    @property
    def sim_time_s(self) -> float:
        """The node's simulated time as of its last diagnostics (nan before any)."""
        return float(self.diagnostics.get("sim_time_s", "nan"))

    def _spin(self, executor: Any, timeout_s: float = 0.05) -> None:
        executor.spin_once(timeout_sec=timeout_s)
        if self.stop is not None and self.stop.is_set():
            raise stop_exception(self.stop)
        if not self.alive():
            raise RigGone("the rig node exited")
        failure = recording_failure(self.diagnostics)
        if failure is not None:
            raise RigGone(failure)
        self._check_alone()
        if time.monotonic() - self._last_heard > self.timeout_s:
            raise RigGone(f"nothing from the rig node for {self.timeout_s:g} s (wall)")

    def wait_for_rig(self, executor: Any, startup_s: float = RIG_STARTUP_TIMEOUT_S) -> None:
        """Until the node publishes diagnostics and its flutter monitor and subscribes to ``airspeed_cmd`` (model
        build and JIT load can take a minute on a cold cache: ``startup_s`` of wall time). A second rig node in the
        namespace (somebody's own, on the same ROS domain) would take the test's commands: refused (:meth:`_check_alone`,
        at every spin of the test), and the first command waits until such a node has had time to be discovered
        (DISCOVERY_SETTLE_S after the client's start)."""
        deadline = time.monotonic() + startup_s
        while (not self.diagnostics or self.pub_airspeed.get_subscription_count() == 0
               or self.sub_monitor.get_publisher_count() == 0
               or time.monotonic() - self._created < DISCOVERY_SETTLE_S):
            self._last_heard = time.monotonic()  # start-up is bounded by the deadline, not the silence timeout
            self._spin(executor, 0.1)
            if time.monotonic() > deadline:
                raise RigGone(f"the rig node did not come up within {startup_s:g} s (wall)")

    def _check_alone(self) -> None:
        """A second rig node in the namespace (somebody's own, on the same ROS domain) takes the test's commands
        too: refused, whenever discovery shows it (at start, or as soon as its endpoint is seen)."""
        n = self.pub_airspeed.get_subscription_count()
        if n > 1:
            raise RigGone(f"{n} nodes take {self.pub_airspeed.topic_name} on this ROS domain (another rig?): the test "
                          "would drive them all; choose another --domain-id")

    def command(self, airspeed_mps: float) -> None:
        self.pub_airspeed.publish(Float64(data=float(airspeed_mps)))

    def test_point(self, executor: Any, airspeed_mps: float) -> tuple[TestPoint | None, bool, dict[str, Any]]:
        """Command ``airspeed_mps`` and wait for the monitor's result for it: (point, fluttered, raw values). The
        dwell is the node's, in simulated time; this waits in wall time for however long that takes, up to the
        :class:`PointWatchdog`'s bound in simulated time."""
        seen = len(self.results)
        rejected = self._rejected()
        self.command(airspeed_mps)
        self._last_heard = time.monotonic()
        watchdog, reports = PointWatchdog(airspeed_mps, self.point_s), self.diagnostics_received
        while True:
            for values in self.results[seen:]:
                if values.get("airspeed_mps") == float(airspeed_mps):
                    fluttered = values.get("fluttered") == "true"
                    return (None if fluttered else point_from_values(values)), fluttered, values
            seen = len(self.results)
            if self._rejected() > rejected:  # the node refused the set-point: no test point will come
                raise RigGone(f"airspeed {airspeed_mps:g} m/s rejected by the rig: "
                              f"{self.diagnostics.get('last_rejection', '?')}")
            if self.diagnostics_received > reports:
                watchdog.check(self.sim_time_s)
            self._spin(executor, 0.05)

    def _rejected(self) -> int:
        try:
            return int(self.diagnostics.get("rejected_commands", "0"))
        except ValueError:
            return 0

    def confirm_setpoint(self, executor: Any, airspeed_mps: float, wall_s: float = 5.0) -> bool:
        """Serve callbacks until the node's diagnostics show this set-point (at most ``wall_s``): a stopping test
        knows its last command arrived before the node is stopped, whatever the machine's load."""
        end, seen = time.monotonic() + wall_s, self.diagnostics_received  # a report from after the command
        while time.monotonic() < end:
            try:
                shown = float(self.diagnostics.get("airspeed_setpoint_mps", "nan"))
            except ValueError:
                shown = math.nan
            if self.diagnostics_received > seen and abs(shown - airspeed_mps) < 1e-3:
                return True
            executor.spin_once(timeout_sec=0.05)
        return False

    def settle_commands(self, executor: Any, wall_s: float = 0.3) -> None:
        """Serve callbacks for a moment so a last command goes out before the client stops."""
        end = time.monotonic() + wall_s
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)


def recording_failure(diagnostics: dict[str, str]) -> str | None:
    """Why the test stops when the node's /diagnostics say its recording failed (a full disk: the node runs on and
    says so, and a test going on would record nothing); None while it records."""
    state = diagnostics.get("recording")
    why = diagnostics.get("last_recording_error") or "?"
    if state == "stopped":  # at the node's free-space reserve: the bag is whole up to there
        return f"the rig node's recording stopped ({why}); the test stopped there"
    if state != "failed":
        return None
    return (f"the rig node's recording failed ({why}); the test stopped there. Free some space, then "
            "`panel-rig bag recover` on the run's rig_* bag rebuilds what was written")


def finite_or_none(x: float) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)
