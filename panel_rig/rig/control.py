"""The control actuator at the trailing edge (separate from the test shaker): first-order bandwidth, rate limit,
saturation, a watchdog, and the bookkeeping of how old each command is when it arrives.

Time base: the rig's simulated time. A command answers a reading; it carries that reading's time (``stamp_s``)
and arrives at ``arrival_s`` (the simulated time that corresponds to "now" when it is received: in real time the
ROS clock minus the stamp offset, in fast mode the rig's time). Its *age* is ``arrival_s - stamp_s``. It acts from
the first physics step that starts at or after its arrival (so the loop delay of the emulated rig is the real one),
and is held until the next command.

Watchdog: once commands have started, if none arrives for longer than ``timeout_s`` the target goes to zero (the
force then decays with the actuator's own dynamics) and the event is logged; the next valid command re-arms it.
A controller slower than the watchdog trips it at every gap: at most one trip (and its resume) is logged per
LOG_INTERVAL_S of simulated time, the next line counting those left out (``timeouts`` counts them all).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from panel_rig.topics import CONTROL_TIMEOUT_S

IDLE, ACTIVE, TIMED_OUT = "idle", "active", "timed_out"
LOG_INTERVAL_S = 1.0  # at most one watchdog trip and its resume logged per second of simulated time


@dataclass(frozen=True)
class ControlSettings:
    """The control actuator's parameters (node parameters ``control.*``; one home for their defaults)."""

    bandwidth_hz: float = 100.0  # first-order lag: F' = 2 pi bw (F_target - F)
    max_force_npm: float = 2.0  # saturation +- (commands beyond it are rejected), N/m
    max_rate_npmps: float = 2000.0  # |dF/dt| limit, N/m per s
    timeout_s: float = CONTROL_TIMEOUT_S  # watchdog: no command for longer -> target 0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"control setting {f.name} must be a finite number > 0, got {v!r}")


def check_control_force(force_npm: Any, settings: ControlSettings) -> str | None:
    """A finite number within +-max_force_npm, else the reason."""
    if isinstance(force_npm, bool) or not isinstance(force_npm, (int, float)):
        return f"control force must be a number, got {force_npm!r}"
    if not math.isfinite(force_npm):
        return f"control force must be finite, got {force_npm!r}"
    if abs(force_npm) > settings.max_force_npm:
        return f"control force {force_npm:g} N/m exceeds the saturation +-{settings.max_force_npm:g} N/m"
    return None


FUTURE_TOLERANCE_S = 1e-6  # stamps and arrival times are floats of the same simulated clock


def check_stamp(stamp_s: Any, arrival_s: float, settings: ControlSettings) -> str | None:
    """The answered reading's time must be finite, not after the command's arrival (no reading of the future was
    published: a bogus stamp, or a command to a rig restarted since; it was taken with a latency of 0 ms) and not
    older than the watchdog timeout."""
    if isinstance(stamp_s, bool) or not isinstance(stamp_s, (int, float)) or not math.isfinite(stamp_s):
        return f"command stamp must be finite, got {stamp_s!r}"
    if stamp_s > arrival_s + FUTURE_TOLERANCE_S:
        return (f"command stamp {stamp_s:.6f} s is after its arrival at {arrival_s:.6f} s: it answers no reading "
                "the rig published")
    if arrival_s - stamp_s > settings.timeout_s:
        return (f"command is {1e3 * (arrival_s - stamp_s):.1f} ms old (answers a reading older than "
                f"control.timeout_s = {settings.timeout_s:g} s)")
    return None


class ControlActuator:
    """Per physics step: apply due commands, watchdog, then F += (1 - a)(target - F) (exact first order,
    a = exp(-2 pi bw dt)), limited to max_rate * dt per step and to +-max_force."""

    def __init__(self, dt_s: float, settings: ControlSettings | None = None, logger: Any = None,
                 age_window: int = 100_000) -> None:
        if not dt_s > 0:
            raise ValueError(f"dt_s must be > 0, got {dt_s!r}")
        self.dt_s = float(dt_s)
        self.log = logger
        self.ages_s: deque[float] = deque(maxlen=age_window)  # the last age_window commands
        self.window_ages_s: list[float] = []  # since the last :meth:`take_window`
        self.commands = 0
        self.timeouts = 0
        self.configure(settings or ControlSettings())
        self.reset()

    def configure(self, settings: ControlSettings) -> None:
        self.settings = settings
        self._decay = math.exp(-2 * math.pi * settings.bandwidth_hz * self.dt_s)

    def reset(self) -> None:
        """Force 0, no pending command, watchdog disarmed."""
        self.force_npm = 0.0
        self.target_npm = 0.0
        self.state = IDLE
        self._pending: deque[tuple[float, float]] = deque()  # (arrival_s, value)
        self._last_arrival_s = -math.inf
        self._trip_logged = False  # the current trip was logged (so is its resume)
        self._last_trip_log_s = -math.inf
        self._unlogged_trips = 0

    # ---- commands -------------------------------------------------------------------------------------
    def command(self, force_npm: float, stamp_s: float, arrival_s: float) -> None:
        """Queue a checked command (see :func:`check_control_force`, :func:`check_stamp`)."""
        age = max(arrival_s - stamp_s, 0.0)
        self.ages_s.append(age)
        self.window_ages_s.append(age)
        self.commands += 1
        self._pending.append((float(arrival_s), float(force_npm)))

    def take_window(self) -> np.ndarray:
        """Ages (s) of the commands since the last call (for a diagnostics period)."""
        w, self.window_ages_s = self.window_ages_s, []
        return np.asarray(w, dtype=float)

    # ---- stepping --------------------------------------------------------------------------------------
    def snapshot(self) -> tuple:
        return (self.force_npm, self.target_npm, self.state, tuple(self._pending), self._last_arrival_s,
                self.timeouts)

    def restore(self, snap: tuple) -> None:
        self.force_npm, self.target_npm, self.state, pending, self._last_arrival_s, self.timeouts = snap
        self._pending = deque(pending)

    def _log_trip(self, t_s: float) -> None:
        """The watchdog's warning, at most once per LOG_INTERVAL_S (then naming the trips left out since)."""
        if self.log is None:
            return
        if t_s - self._last_trip_log_s < LOG_INTERVAL_S:
            self._unlogged_trips += 1
            return
        more = (f" ({self._unlogged_trips} more trip(s) since the last of these lines, not logged; "
                "/diagnostics control_timeouts counts every one)" if self._unlogged_trips else "")
        self.log.warning(f"control watchdog: last command at t = {self._last_arrival_s:.4f} s, none for "
                         f"control.timeout_s = {self.settings.timeout_s:g} s: control actuator to zero at "
                         f"t = {t_s:.4f} s{more}")
        self._trip_logged = True
        self._last_trip_log_s = t_s
        self._unlogged_trips = 0

    @property
    def quiet(self) -> bool:
        """No force, none commanded and none pending, watchdog not armed: :meth:`step` returns 0 and changes
        nothing, for as many steps as it is called."""
        return not self._pending and self.state != ACTIVE and self.force_npm == 0.0 and self.target_npm == 0.0

    def step(self, t_start_s: float) -> float:
        """The force for the physics step that starts at ``t_start_s`` (then advanced by one dt)."""
        while self._pending and self._pending[0][0] <= t_start_s + 1e-12:
            arrival, value = self._pending.popleft()
            self.target_npm = value
            self._last_arrival_s = arrival
            if self.state == TIMED_OUT and self._trip_logged and self.log is not None:
                self.log.info(f"control commands resumed at t = {t_start_s:.3f} s")
            self.state = ACTIVE
            self._trip_logged = False
        if self.state == ACTIVE and t_start_s - self._last_arrival_s > self.settings.timeout_s:
            self.state = TIMED_OUT
            self.target_npm = 0.0
            self.timeouts += 1
            self._log_trip(t_start_s)
        if self.force_npm == 0.0 and self.target_npm == 0.0:
            return 0.0
        s = self.settings
        new = self.target_npm + (self.force_npm - self.target_npm) * self._decay
        dmax = s.max_rate_npmps * self.dt_s
        new = min(max(new, self.force_npm - dmax), self.force_npm + dmax)
        new = min(max(new, -s.max_force_npm), s.max_force_npm)
        if abs(new) < 1e-300:
            new = 0.0
        applied = self.force_npm  # the force over this step: its value at the start (as the shaker's)
        self.force_npm = new
        return applied

    def latency_stats_ms(self, ages_s: np.ndarray | None = None) -> dict[str, float]:
        """Mean, p99 and max command age (ms) of the given ages (default: all kept)."""
        a = np.asarray(self.ages_s if ages_s is None else ages_s, dtype=float)
        if not a.size:
            return {"mean": math.nan, "p99": math.nan, "max": math.nan, "n": 0}
        return {"mean": float(a.mean() * 1e3), "p99": float(np.percentile(a, 99) * 1e3),
                "max": float(a.max() * 1e3), "n": int(a.size)}


@dataclass(frozen=True)
class ClosedLoopRun:
    """Result of :func:`run_closed_loop`: tip w (m) at each controller sample, and the rig's final state."""

    time_s: np.ndarray
    tip_w_m: np.ndarray
    command_npm: np.ndarray
    state: str


def run_closed_loop(rig: Any, law: Any, airspeed_mps: float, duration_s: float, command_age_s: float,
                    rate_hz: float = 500.0, kick_npm: float = 0.05, kick_s: float = 0.02,
                    noise_m: float = 0.0, seed: int = 0) -> ClosedLoopRun:
    """The emulated tunnel with a controller in the loop, in one process and deterministic: at ``rate_hz`` the
    controller reads the tip (plus white noise ``noise_m``), runs ``law`` (a :class:`DiscreteLaw`-like object with
    ``step(w, dt)``) and sends its command stamped with the reading's time, arriving ``command_age_s`` later.
    The tunnel starts at ``airspeed_mps`` (no lag) and a shaker tap of ``kick_npm`` for ``kick_s`` perturbs it."""
    rng = np.random.default_rng(seed)
    rig.actuator.airspeed_mps = rig.actuator.setpoint_mps = float(airspeed_mps)
    period = 1.0 / rate_hz
    n = int(round(duration_s * rate_hz))
    t, w, f = np.empty(n), np.empty(n), np.empty(n)
    rig.command_force(kick_npm)
    t0 = rig.time_s
    kicked = True
    for k in range(n):
        rig.advance_to(t0 + (k + 1) * period)
        if kicked and rig.time_s - t0 >= kick_s:
            rig.command_force(0.0)
            kicked = False
        now = rig.time_s
        tip = rig.stepper.tip_w_over_L * rig.panel_length_m + (noise_m * rng.standard_normal() if noise_m else 0.0)
        cmd = law.step(tip, period)
        cmd = min(max(cmd, -rig.control.settings.max_force_npm), rig.control.settings.max_force_npm)
        rig.command_control(cmd, now, now + command_age_s)
        t[k], w[k], f[k] = now, tip, cmd
        if rig.state != "running":
            return ClosedLoopRun(t[: k + 1], w[: k + 1], f[: k + 1], rig.state)
    return ClosedLoopRun(t, w, f, rig.state)


def envelope_growth_rate(time_s: np.ndarray, w: np.ndarray, window_s: float = 0.25) -> float:
    """Slope (1/s) of log RMS over consecutive windows: > 0 growing, < 0 decaying."""
    t = np.asarray(time_s) - time_s[0]
    edges = np.arange(0.0, t[-1] + 1e-9, window_s)
    centres, logs = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        sel = (t >= a) & (t < b)
        if sel.sum() > 3:
            centres.append(0.5 * (a + b))
            logs.append(math.log(max(float(np.sqrt(np.mean(np.square(w[sel])))), 1e-300)))
    if len(centres) < 3:
        return math.nan
    return float(np.polyfit(centres, logs, 1)[0])
