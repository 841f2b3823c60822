"""Scripted operator: plays a YAML profile against a running rig node and prints a summary.

Profile (a list, or ``{steps: [...]}``), times in the rig's simulated time (so fast mode works)::

    - airspeed: 8.0                      # set-point, m/s
    - ramp: {to: 12.0, rate_mps2: 0.5}   # set-point ramp
    - dwell_s: 10.0                      # wait 10 s of rig time
    - shaker: {amplitude: 0.5, frequency_hz: 12.0}
    - force: 0.1                         # held force, N/m
    - abort
    - reset

Run: ``rig_operator --profile config/staircase.yaml [--namespace /rig] [--timeout S] [--startup-timeout S]``.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped, Vector3Stamped
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from panel_rig.analysis.signals import gapped_dominant_frequency_hz, resolved_frequency_hz
from panel_rig.argparsing import OneLineParser
from panel_rig.config import MAX_DURATION_S, ConfigError, load_yaml_file, number_if_text
from panel_rig.model.aerodynamics import MAX_AIRSPEED_MPS
from panel_rig.processes import RIG_STARTUP_TIMEOUT_S, StopRequest
from panel_rig.ros.flutter_monitor import STATUS_NAME as MONITOR_STATUS
from panel_rig.ros.flutter_monitor import TOPIC as MONITOR_TOPIC
from panel_rig.ros.flutter_monitor import monitor_line, parse_monitor
from panel_rig.ros.messages import rig_status
from panel_rig.ros.session import namespace_problem, ros_arguments_problem, ros_session
from panel_rig.topics import REJECTED_SUFFIX

#: the operator's commands and their topics (relative to the rig's namespace)
COMMAND_TOPICS = {"airspeed": "airspeed_cmd", "force": "shaker/force_cmd", "amplitude": "shaker/amplitude_cmd",
                  "frequency": "shaker/frequency_cmd"}
KINDS = ("airspeed", "ramp", "dwell_s", "shaker", "force", "abort", "reset")
COMMAND_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
DIAGNOSTICS_QOS = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)  # /diagnostics: every message


class ProfileError(ValueError):
    """A profile that cannot be played; the message names the step."""


class RigUnavailable(RuntimeError):
    """The rig does not answer (no readings, no service) within the timeout."""


@dataclass(frozen=True)
class Step:
    """One profile step: kind and its argument."""

    kind: str
    arg: Any = None

    def describe(self) -> str:
        """The step as the summary's row names it: the profile's key and value (a shaker or a ramp in words)."""
        if self.kind == "shaker":
            parts = [f"{self.arg['amplitude']:g} N/m" if "amplitude" in self.arg else "",
                     f"{self.arg['frequency_hz']:g} Hz" if "frequency_hz" in self.arg else ""]
            return "shaker " + " at ".join(x for x in parts if x)
        if self.kind == "ramp":
            return f"ramp to {self.arg['to']:g} m/s at {self.arg['rate_mps2']:g} m/s^2"
        return self.kind if self.arg is None else f"{self.kind} {self.arg}"


#: readings stamped this much before the last one come from a restarted rig (its clock started again), not late
RESTART_BACKSTEP_S = 1.0
REFUSED = "rejected by the rig"  # a step's note when the rig echoed one of its commands on <topic>/rejected
#: the note :func:`annotate_aborts` gives a command refused because the rig had aborted
REFUSED_AFTER_ABORT = "rejected (rig aborted; reset to go on)"
ABORTED_NOTE = "rig aborted at t = "  # the note of a step during which the rig aborted by itself (not an abort step)
NOT_AS_WRITTEN = "the profile did not run as written"  # how the exit-1 line of such a run begins


@dataclass
class StepSummary:
    """What happened during one step (rig time, commanded and measured airspeed, tip motion)."""

    index: int
    step: str
    t_start_s: float
    t_end_s: float = math.nan
    commanded_mps: float = math.nan
    measured_mps: float = math.nan
    tip_rms_m: float = math.nan
    tip_freq_hz: float = math.nan
    note: str = ""
    samples: list[tuple[float, float]] = field(default_factory=list, repr=False)


def _number(i: int, key: str, v: Any, lo: float = -math.inf, hi: float = math.inf, unit: str = "") -> float:
    v = number_if_text(v)  # 1e3: text to YAML 1.1, a number to us (as in parameters files)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        rule = ("a finite number" + ("" if lo == -math.inf else f" >= {lo:g}") if hi == math.inf
                else f"a number in [{lo:g}, {hi:g}]{unit}")
        raise ProfileError(f"step {i + 1} ({key}): expected {rule}, got {v!r}")
    return float(v)


def _airspeed(i: int, key: str, v: Any) -> float:
    """A set-point every command takes (the rig refused 150 m/s at run time, after the profile had started)."""
    return _number(i, key, v, 0.0, MAX_AIRSPEED_MPS, " m/s (the incompressible lattice holds to about Mach 0.3)")


def parse_profile(doc: Any) -> list[Step]:
    """Validate a loaded YAML profile into steps."""
    if isinstance(doc, dict) and "steps" in doc:
        doc = doc["steps"]
    if not isinstance(doc, list) or not doc:
        raise ProfileError("a profile is a non-empty list of steps (or {steps: [...]})")
    steps: list[Step] = []
    for i, item in enumerate(doc):
        if isinstance(item, str) and item in ("abort", "reset"):
            steps.append(Step(item))
            continue
        if not isinstance(item, dict) or len(item) != 1:
            raise ProfileError(f"step {i + 1}: expected one of {KINDS} as a one-key mapping, got {item!r}")
        ((kind, arg),) = item.items()
        if kind == "airspeed":
            steps.append(Step(kind, _airspeed(i, kind, arg)))
        elif kind == "force":
            steps.append(Step(kind, _number(i, kind, arg)))
        elif kind == "dwell_s":  # as every command's dwell (1e9 s ran until the operator was killed)
            steps.append(Step(kind, _number(i, kind, arg, 0.0, MAX_DURATION_S, " s")))
        elif kind == "ramp":
            if not isinstance(arg, dict) or set(arg) != {"to", "rate_mps2"}:
                raise ProfileError(f"step {i + 1}: ramp needs {{to: V, rate_mps2: r}}, got {arg!r}")
            rate = _number(i, "ramp.rate_mps2", arg["rate_mps2"], 0.0)
            if rate == 0:
                raise ProfileError(f"step {i + 1}: ramp.rate_mps2 must be > 0")
            steps.append(Step(kind, {"to": _airspeed(i, "ramp.to", arg["to"]), "rate_mps2": rate}))
        elif kind == "shaker":
            if not isinstance(arg, dict) or not set(arg) <= {"amplitude", "frequency_hz"} or not arg:
                raise ProfileError(f"step {i + 1}: shaker takes amplitude: A and/or frequency_hz: f (the other is "
                                   f"kept), got {arg!r}")
            steps.append(Step(kind, {k: _number(i, f"shaker.{k}", v, 0.0) for k, v in arg.items()}))
        elif kind in ("abort", "reset") and arg is None:
            steps.append(Step(kind))
        elif kind in ("abort", "reset"):
            raise ProfileError(f"step {i + 1}: {kind} takes no value (write '- {kind}'), got {kind}: {arg!r}")
        else:
            raise ProfileError(f"step {i + 1}: unknown step {kind!r} (known: {', '.join(KINDS)})")
    return steps


def load_profile(path: str | Path) -> list[Step]:
    """Read and validate a profile file."""
    try:
        doc = load_yaml_file(path, "profile")
    except ConfigError as exc:
        raise ProfileError(str(exc)) from None
    return parse_profile(doc)


#: the operator's reading queue per topic (best effort): in fast mode the node publishes readings faster than the
#: operator takes them, and what it takes at a turn is the newest this many, contiguous (the sensor profile's 5
#: readings, 10 ms at 500 Hz, spanned a fraction of a 17 Hz period)
READINGS_DEPTH = 100


def tip_metrics(samples: Sequence[tuple[float, float]]) -> tuple[float, float]:
    """(RMS about the mean, dominant frequency) of the second half of (t, w) samples. The readings are best
    effort and a busy operator misses many in fast mode (bursts of its queue's newest, then a gap): the frequency is
    the spectrum's peak of the readings on their own time grid, the missing ones left out
    (:func:`~panel_rig.analysis.signals.gapped_dominant_frequency_hz`), as `panel-rig analyze` takes it from the
    bag's every reading. The mean-crossing count it replaces read the demo's 16.3 Hz LCO as 12.2 Hz when a gap hid
    a crossing, and gave none for half the LCO's steps. NaN when the readings span fewer than
    :data:`~panel_rig.analysis.signals.MIN_PERIODS` periods or miss them in a pattern that could alias."""
    if len(samples) < 8:
        return math.nan, math.nan
    arr = np.asarray(samples, dtype=float)
    arr = arr[np.argsort(arr[:, 0], kind="stable")]
    arr = arr[arr[:, 0] >= arr[0, 0] + 0.5 * (arr[-1, 0] - arr[0, 0])]
    t, w = arr[:, 0], arr[:, 1] - arr[:, 1].mean()
    rms = float(np.sqrt(np.mean(w**2)))
    return rms, resolved_frequency_hz(gapped_dominant_frequency_hz(t, w), t[-1] - t[0])


class Operator(Node):
    """The rig's operator console: command publishers, reading subscriptions, service clients."""

    def __init__(self, namespace: str = "/rig", timeout_s: float = 10.0, stop: threading.Event | None = None,
                 startup_timeout_s: float = RIG_STARTUP_TIMEOUT_S) -> None:
        super().__init__("panel_rig_operator", namespace=namespace)
        self.timeout_s = timeout_s  # wall seconds without readings, once the rig is up
        self.startup_timeout_s = startup_timeout_s  # wall seconds for the rig to come up (wait_for_rig)
        self.time_s = math.nan
        self.airspeed_mps = math.nan
        self._last_msg_wall = time.monotonic()
        self._samples: list[tuple[float, float]] | None = None
        self.create_subscription(Vector3Stamped, "airspeed", self._on_airspeed, qos_profile_sensor_data)
        readings = QoSProfile(depth=READINGS_DEPTH, reliability=qos_profile_sensor_data.reliability,
                              durability=qos_profile_sensor_data.durability)
        self.create_subscription(PointStamped, "tip_displacement", self._on_tip, readings)
        self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, DIAGNOSTICS_QOS)
        # a node with flutter_monitor:=true publishes a result per plateau: shown as it comes (stderr)
        self.monitor_lines: list[str] = []
        self.create_subscription(DiagnosticArray, MONITOR_TOPIC, self._on_monitor, DIAGNOSTICS_QOS)
        self.diag_sim_time_s = -math.inf  # the rig's simulated time in its last diagnostics
        self.aborts: dict[float, str] = {}  # abort time (simulated s) -> reason, from the rig's diagnostics
        self.aborted_seen_s: list[float] = []  # simulated times of statuses that said the rig was aborted
        # set by main's SIGINT/SIGTERM handler; the profile stops at the next spin (see _spin)
        self.stop_requested = stop if stop is not None else threading.Event()
        self.pubs = {name: self.create_publisher(Float64, topic, COMMAND_QOS) for name, topic in COMMAND_TOPICS.items()}
        # the rig echoes each command it refuses on <topic>/rejected: the step that sent it is marked
        # (command, value, step, the commanded airspeed before it), oldest first
        self._sent: list[tuple[str, float, StepSummary | None, float]] = []
        self._echoes = [
            self.create_subscription(Float64, topic + REJECTED_SUFFIX,
                                     lambda msg, name=name: self._on_rejected(name, msg.data), COMMAND_QOS)
            for name, topic in COMMAND_TOPICS.items()]
        self._step: StepSummary | None = None  # the step being played
        self.clients_ = {name: self.create_client(Trigger, name) for name in ("reset", "abort")}
        self.commanded_mps = 0.0
        self.setpoint_mps = math.nan  # the rig's airspeed set-point in its last diagnostics
        self.played: list[StepSummary] = []  # the steps done so far
        self.restarted_from_s: float | None = None  # the old rig's last time, once a restarted rig is heard
        self._rig_up = False  # the silence timeout counts once wait_for_rig has seen the rig

    def _on_airspeed(self, msg: Vector3Stamped) -> None:
        t = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if not math.isnan(self.time_s) and t < self.time_s - RESTART_BACKSTEP_S and self.restarted_from_s is None:
            self.restarted_from_s = self.time_s  # a new rig (its clock starts again): see _spin
        if math.isnan(self.time_s) or t > self.time_s:
            self.time_s = t
            self.airspeed_mps = msg.vector.x
        self._last_msg_wall = time.monotonic()

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        values = rig_status(msg, self.get_namespace())  # /diagnostics carries every node's, other rigs' too
        if values is None or "sim_time_s" not in values:
            return
        self.diag_sim_time_s = max(self.diag_sim_time_s, float(values["sim_time_s"]))
        self._last_msg_wall = time.monotonic()  # the rig is alive (a fast node waiting for a command publishes
        # no readings: only its diagnostics)
        self.setpoint_mps = float(values.get("airspeed_setpoint_mps", "nan"))
        if values.get("last_abort_time_s"):
            self.aborts.setdefault(float(values["last_abort_time_s"]), values.get("abort_reason", ""))
        if values.get("state") == "aborted":
            self.aborted_seen_s.append(float(values["sim_time_s"]))

    def _on_monitor(self, msg: DiagnosticArray) -> None:
        if msg.status and msg.status[0].name == MONITOR_STATUS:
            line = monitor_line(parse_monitor(msg))
            self.monitor_lines.append(line)
            print(line, file=sys.stderr, flush=True)

    def _on_tip(self, msg: PointStamped) -> None:
        if self._samples is not None:
            self._samples.append((msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, msg.point.z))

    def _spin(self, timeout_s: float = 0.05) -> None:
        """One executor turn; then KeyboardInterrupt if a stop was requested, RigUnavailable if silent too long.

        The signal handler only sets :attr:`stop_requested`: a KeyboardInterrupt raised by Python's own handler lands
        in whatever runs, e.g. inside rclpy's conversion of a taken sample, which then fails ("Unable to convert
        call argument") and leaves that subscription's callback group marked busy for good: no reading is delivered
        again and the operator ends "no readings from the rig" instead of 130."""
        rclpy.spin_once(self, timeout_sec=timeout_s)
        if self.stop_requested.is_set():
            raise KeyboardInterrupt
        if self.restarted_from_s is not None:  # the set-points given so far went with the old rig
            raise RigUnavailable(f"the rig restarted (its time went back from {self.restarted_from_s:.2f} s): the "
                                 f"profile's set-points were lost with it; stopped at step {len(self.played) + 1}")
        # (not while waiting for the rig to come up: a turn of spin_once that took longer than the timeout under load
        # ended the wait with "no readings from the rig for 0.2 s")
        if self._rig_up and time.monotonic() - self._last_msg_wall > self.timeout_s:
            raise RigUnavailable(f"no readings from the rig for {self.timeout_s:g} s")

    def wait_for_rig(self) -> None:
        """Until the rig publishes (readings, or diagnostics: a fast node with ``fast_wait_for_command`` starts its
        clock with our first command) and every command topic has a subscriber; at most :attr:`startup_timeout_s`
        of wall time (a first start compiles the kernels: the silence timeout counts only once the rig is up)."""
        deadline = time.monotonic() + self.startup_timeout_s
        while ((math.isnan(self.time_s) and not math.isfinite(self.diag_sim_time_s))
               or any(p.get_subscription_count() == 0 for p in self.pubs.values())
               or any(sub.get_publisher_count() == 0 for sub in self._echoes)):
            if time.monotonic() > deadline:
                raise RigUnavailable(f"the rig in {self.get_namespace()} did not come up within "
                                     f"{self.startup_timeout_s:g} s (wall)")
            self._spin(0.1)
        self._last_msg_wall = time.monotonic()
        self._rig_up = True
        if math.isnan(self.time_s):
            self.time_s = self.diag_sim_time_s

    def _on_rejected(self, name: str, value: float) -> None:
        """Mark the step that sent this command (the latest unanswered one of that name and value)."""
        for k in range(len(self._sent) - 1, -1, -1):
            sent, v, step, before_mps = self._sent[k]
            if sent == name and (v == value or (math.isnan(v) and math.isnan(value))):
                del self._sent[k]
                if step is not None and "rejected" not in step.note:
                    step.note = "; ".join(x for x in (step.note, f"{name} {value:g} {REFUSED}") if x)
                if name == "airspeed":  # the rig kept its set-point
                    if self.commanded_mps == value:
                        self.commanded_mps = before_mps
                    keep_commanded(self.played, step, value, before_mps)
                return

    def send(self, name: str, value: float) -> None:
        self._sent.append((name, float(value), self._step, self.commanded_mps))
        del self._sent[:-64]  # the rig answers within moments: only the recent ones can still be refused
        self.pubs[name].publish(Float64(data=float(value)))
        if name == "airspeed":
            self.commanded_mps = float(value)

    def call(self, name: str) -> str:
        client = self.clients_[name]
        if not client.wait_for_service(timeout_sec=self.timeout_s):
            raise RigUnavailable(f"service {name} not available")
        future = client.call_async(Trigger.Request())
        deadline = time.monotonic() + self.timeout_s
        while not future.done():
            if time.monotonic() > deadline:
                raise RigUnavailable(f"service {name} did not answer")
            self._spin(0.05)
        return future.result().message

    def wait_until(self, t_s: float) -> None:
        """Until the rig's simulated time reaches t_s."""
        while self.time_s < t_s:
            self._spin(0.05)

    def wind_off(self, timeout_s: float = 3.0) -> bool:
        """Airspeed 0 and the shaker off, as an operator ends a stopped test; True once the rig's diagnostics show
        the 0 m/s set-point (at most ``timeout_s`` of wall time: the stop flag is set, so no :meth:`_spin`)."""
        for name in ("airspeed", "force", "amplitude"):
            self.send(name, 0.0)
        self.setpoint_mps = math.nan
        deadline = time.monotonic() + timeout_s
        while self.setpoint_mps != 0.0 and time.monotonic() < deadline:
            rclpy.spin_once(self, timeout_sec=0.05)
        return self.setpoint_mps == 0.0

    def play(self, steps: Sequence[Step]) -> list[StepSummary]:
        """Play the steps; returns one summary per step (:attr:`played` holds those done so far)."""
        self.wait_for_rig()
        out = self.played
        for i, step in enumerate(steps):
            s = StepSummary(i + 1, step.describe(), self.time_s)
            self._samples, self._step = s.samples, s
            if step.kind == "airspeed":
                self.send("airspeed", step.arg)
            elif step.kind == "force":
                self.send("force", step.arg)
            elif step.kind == "shaker":
                if "frequency_hz" in step.arg:
                    self.send("frequency", step.arg["frequency_hz"])
                if "amplitude" in step.arg:
                    self.send("amplitude", step.arg["amplitude"])
            elif step.kind == "dwell_s":
                self.wait_until(s.t_start_s + step.arg)
            elif step.kind == "ramp":
                self._ramp(step.arg["to"], step.arg["rate_mps2"])
            else:
                s.note = self.call(step.kind)
                if step.kind in ("abort", "reset"):
                    self.commanded_mps = 0.0
            for _ in range(3):  # let commands go out and the last readings come in
                rclpy.spin_once(self, timeout_sec=0.0)
            s.t_end_s, s.commanded_mps, s.measured_mps = self.time_s, self.commanded_mps, self.airspeed_mps
            s.tip_rms_m, s.tip_freq_hz = tip_metrics(s.samples)
            out.append(s)
            airspeed = f"{s.measured_mps:.2f} m/s" if math.isfinite(s.measured_mps) else "- (no reading yet)"
            self.get_logger().info(f"step {s.index}: {s.step} t = {s.t_end_s:.2f} s U = {airspeed}",
                                   throttle_duration_sec=0.0)
        self._samples = None
        self._await_diagnostics(self.time_s)
        annotate_aborts(out, self.aborts, self.aborted_seen_s)
        return out

    def _await_diagnostics(self, t_s: float, timeout_s: float = 3.0) -> None:
        """Until the rig's diagnostics (published at diagnostics_rate_hz of wall time) cover simulated time t_s, so
        an abort near the end is reported; at most ``timeout_s`` of wall time."""
        deadline = time.monotonic() + timeout_s
        while self.diag_sim_time_s < t_s and time.monotonic() < deadline:
            self._spin(0.05)

    def _ramp(self, to_mps: float, rate_mps2: float) -> None:
        start, t0 = self.commanded_mps, self.time_s
        duration = abs(to_mps - start) / rate_mps2
        last = -math.inf
        while True:
            frac = min(1.0, (self.time_s - t0) / duration) if duration > 0 else 1.0
            if frac >= 1.0 or self.time_s - last >= 0.05:
                self.send("airspeed", start + frac * (to_mps - start))
                last = self.time_s
            if frac >= 1.0:
                return
            self._spin(0.02)


#: steps that send an airspeed set-point (or, for abort and reset, make the rig's 0)
AIRSPEED_STEPS = ("airspeed", "ramp", "abort", "reset")


def keep_commanded(summary: Sequence[StepSummary], step: StepSummary | None, refused_mps: float,
                   kept_mps: float) -> None:
    """The rig refused the airspeed set-point ``refused_mps`` sent during ``step``: that row and the rows after it
    that still show it as commanded (until the next step that sets the airspeed) show the set-point the rig kept,
    ``kept_mps`` (the table showed a refused 4 m/s after an abort as U_cmd, the rig at 0)."""
    if step is None or not any(s is step for s in summary):
        return
    start = next(k for k, s in enumerate(summary) if s is step)
    for s in summary[start:]:
        if s is not step and s.step.split()[0] in AIRSPEED_STEPS:
            break
        if s.commanded_mps == refused_mps:
            s.commanded_mps = kept_mps


def annotate_aborts(summary: Sequence[StepSummary], aborts: dict[float, str],
                    aborted_seen_s: Sequence[float] = ()) -> None:
    """Note each abort (simulated time -> reason) on the step during which it happened, and say why the commands
    the rig refused after it (echoed: "... rejected by the rig") were refused, until a reset step. Commands of 0
    (wind or shaker off) an aborted rig takes: they stay unmarked."""
    for t_abort, reason in sorted(aborts.items()):
        own = [s for s in summary if f"aborted at t = {t_abort:.3f} s" in s.note]  # the rig's answer says when
        started = own or [s for s in summary if s.t_start_s <= t_abort]
        if not started:  # aborted before the profile: the commands it refused say why (they said only "rejected"),
            # when a status during the profile, before its first reset, still said aborted (it may have been reset)
            resets = [s.t_start_s for s in summary if s.step.startswith("reset")]
            t_first, t_reset = (summary[0].t_start_s if summary else math.inf), min(resets, default=math.inf)
            if not any(t_first <= t <= t_reset for t in aborted_seen_s):
                continue
            before = f" (it aborted at t = {t_abort:.2f} s, before the profile: {reason})"
            for s in summary:
                if s.step.startswith("reset"):
                    break
                if REFUSED in s.note:
                    s.note, before = REFUSED_AFTER_ABORT + before, ""
            continue
        hit = started[-1]
        if not own:
            hit.note = "; ".join(x for x in (hit.note, f"{ABORTED_NOTE}{t_abort:.2f} s: {reason}") if x)
        for s in summary[summary.index(hit) + 1:]:
            if s.step.startswith("reset"):
                break
            if REFUSED in s.note:
                s.note = REFUSED_AFTER_ABORT


#: under the table when a step with a tip RMS has no frequency
NO_FREQUENCY_NOTE = ("f_Hz -: the readings that arrived span too few periods, or miss them in a pattern that could "
                     "alias (readings are best effort; in fast mode a subscriber misses many); the bag's analysis has "
                     "every reading")


def profile_problem(summary: Sequence[StepSummary]) -> str | None:
    """One line when the profile did not run as written (the rig aborted by itself, or refused a command), else
    None: the operator then exits 1 (it exited 0, and a script could not tell a refused 150 m/s from a clean run).
    An ``abort`` step of the profile is a command, not a problem."""
    aborted = [s.index for s in summary if ABORTED_NOTE in s.note]
    refused = [s.index for s in summary if REFUSED in s.note or REFUSED_AFTER_ABORT in s.note]
    parts = []
    if aborted:
        parts.append(f"the rig aborted during step{'s' if len(aborted) > 1 else ''} {_indices(aborted)}")
    if refused:
        parts.append(f"it refused the command{'s' if len(refused) > 1 else ''} of step"
                     f"{'s' if len(refused) > 1 else ''} {_indices(refused)}")
    if not parts:
        return None
    return f"{NOT_AS_WRITTEN}: " + "; ".join(parts) + " (see the table)"


def _indices(indices: Sequence[int]) -> str:
    return ", ".join(str(i) for i in indices)


def format_summary(summary: Sequence[StepSummary]) -> str:
    """A plain table: per step rig time, commanded/measured airspeed, tip RMS (mm) and frequency."""
    lines = [f"{'#':>3} {'step':<34} {'t_end_s':>8} {'U_cmd':>6} {'U_meas':>6} {'tip_rms_mm':>10} {'f_Hz':>6}"]

    def num(x: float, width: int, digits: int) -> str:
        return f"{x:>{width}.{digits}f}" if math.isfinite(x) else f"{'-':>{width}}"

    for s in summary:
        lines.append(
            f"{s.index:>3} {s.step[:34]:<34} {num(s.t_end_s, 8, 2)} {num(s.commanded_mps, 6, 2)} "
            f"{num(s.measured_mps, 6, 2)} {num(s.tip_rms_m * 1e3, 10, 3)} {num(s.tip_freq_hz, 6, 2)}"
            + (f"  {s.note}" if s.note else "")
        )
    if any(math.isfinite(s.tip_rms_m) and not math.isfinite(s.tip_freq_hz) for s in summary):
        lines.append(NO_FREQUENCY_NOTE)
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None, *, prog: str = "rig_operator") -> int:
    """Entry point (``rig_operator``; ``panel-rig operate``). argv excludes the program name; ``prog`` is the name
    its messages and ``--help`` give."""
    from rclpy.executors import ExternalShutdownException
    from rclpy.utilities import remove_ros_args

    args = list(sys.argv[1:] if argv is None else argv)
    parser = OneLineParser(prog=prog, description="play a profile against the panel_rig node")
    parser.add_argument("--profile", required=True, metavar="FILE.yaml", help="YAML profile (see config/staircase.yaml)")
    parser.add_argument("--namespace", default="/rig", help="the rig's namespace (default /rig)")
    parser.add_argument("--timeout", type=float, default=10.0,
                        help="wall seconds without readings, once the rig is up = failure (default 10)")
    parser.add_argument("--startup-timeout", type=float, default=RIG_STARTUP_TIMEOUT_S,
                        help=f"wall seconds to wait for the rig to come up (default {RIG_STARTUP_TIMEOUT_S:g}: a first "
                             "start compiles the kernels)")
    problem = ros_arguments_problem(args)
    if problem:
        print(f"{prog}: {problem}", file=sys.stderr)
        return 2
    opts = parser.parse_args(remove_ros_args(["rig_operator", *args])[1:])
    problem = namespace_problem(opts.namespace)
    if not (math.isfinite(opts.timeout) and opts.timeout > 0):
        problem = f"--timeout must be a positive number of seconds, got {opts.timeout}"
    elif not (math.isfinite(opts.startup_timeout) and opts.startup_timeout > 0):
        problem = f"--startup-timeout must be a positive number of seconds, got {opts.startup_timeout}"
    elif problem:
        problem = f"--namespace {opts.namespace!r}: {problem}"
    if problem:
        print(f"{prog}: {problem}", file=sys.stderr)
        return 2
    try:
        steps = load_profile(opts.profile)
    except ProfileError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    # SIGINT/SIGTERM set a flag that the spin loop turns into a clean stop (130 / 143): rclpy's handler shut the
    # context down under whatever call was running, Python's raised KeyboardInterrupt inside rclpy (Operator._spin)
    stop = StopRequest()
    code = 0
    with ros_session(["rig_operator", *args], stop):
        node = Operator(opts.namespace, opts.timeout, stop=stop, startup_timeout_s=opts.startup_timeout)
        try:
            summary = node.play(steps)
            print(format_summary(summary))
            problem = profile_problem(summary)
            if problem:
                print(f"{prog}: {problem}", file=sys.stderr)
                code = 1
        except RigUnavailable as exc:
            print(f"{prog}: {exc}", file=sys.stderr)
            if node.played:
                print(format_summary(node.played))
            code = 1
        except (KeyboardInterrupt, ExternalShutdownException):  # a stop requested by a signal
            code = stop.exit_status
            print(f"{prog}: {stopped_note(node, len(steps))}", file=sys.stderr)
            if node.played:
                print(format_summary(node.played))
        finally:
            node.destroy_node()
    return code


def stopped_note(node: Operator, n_steps: int) -> str:
    """Wind off after a stopped profile, and the line saying so, without the program's name (the tunnel was left
    at the last set-point)."""
    at = len(node.played) + 1
    if node.wind_off():
        return f"stopped at step {at} of {n_steps}: tunnel commanded to 0 m/s, shaker off"
    return (f"stopped at step {at} of {n_steps}: the rig did not confirm the wind-off commands "
            "(0 m/s, shaker off); check it")


if __name__ == "__main__":
    sys.exit(main())
