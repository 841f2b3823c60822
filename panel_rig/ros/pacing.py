"""How far the rig node steps at a time, and when simulated time waits for a client.

:func:`step_counts` turns the sample times of a block into whole physics steps before each sample (what
``Rig.advance_samples`` marches); :class:`PublishGrid` gives the samples of a real-time tick on the publish
grid (one publish period apart; a late tick's are the samples it owes). :class:`ClientHolds` is the fast mode's waits for a client:
simulated time does not start before the first command (``fast_wait_for_command``) and stops at each published
flutter-test point until the next airspeed command (``flutter_test.hold``); each is released after
``HOLD_TIMEOUT_S`` of wall time, logged. The node asks; the loop that runs it (:func:`panel_rig.ros.rig_node.spin`)
serves callbacks only while a hold lasts.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

HOLD_TIMEOUT_S = 60.0  # fast mode, flutter_test.hold: wall time to wait for the client's next airspeed command


def step_counts(time_s: float, targets_s: Iterable[float], dt_s: float) -> list[int]:
    """Whole physics steps (``dt_s``) from ``time_s`` before each sample at ``targets_s`` (ascending), each
    counted from where the steps before it ended (a sample at a target already passed: 0 steps)."""
    counts, t = [], time_s
    for target in targets_s:
        n = max(math.floor((target - t) / dt_s + 1e-6), 0)
        counts.append(n)
        t += n * dt_s
    return counts


@dataclass
class PublishGrid:
    """The real-time node's sample times on the publish grid: ``anchor_s + k period_s`` for an integer index k from
    ``next_index`` on (an index from an anchor does not drift as a running sum of periods does: ~1e-9 s a day)."""

    anchor_s: float
    period_s: float
    next_index: int = 1

    def point_s(self, k: int) -> float:
        """Grid point k (simulated s)."""
        return self.anchor_s + k * self.period_s

    def tick(self, time_s: float, target_s: float) -> list[float]:
        """The samples of a real-time tick: every grid point from the next one up to the clock ``target_s`` (several
        when the tick is late: the samples it owes; none when timer jitter brought it before the next one). A grid
        point the rig (at ``time_s``) has already passed, in a catch-up march without samples, is skipped. Samples at
        the tick's own clock time were 1-6 physics steps apart and 501.5 a second at 500 Hz: a late tick's owed
        samples came on top of the next tick's."""
        k = self.next_index
        if self.point_s(k) < time_s - 1e-12:
            k += math.ceil((time_s - self.point_s(k)) / self.period_s - 1e-9)
        n = max(math.floor((target_s - self.point_s(k)) / self.period_s + 1e-9) + 1, 0)
        self.next_index = k + n
        return [self.point_s(k + i) for i in range(n)]


class ClientHolds:
    """The fast mode's holds of simulated time for a client (``rig``: its time in the log lines)."""

    def __init__(self, rig: Any, logger: Any, *, wait_for_command: bool, flutter_hold: bool,
                 flutter_monitor: Any | None, recording_uncapped: bool = False) -> None:
        self._rig, self._log, self._monitor = rig, logger, flutter_monitor
        self._recording_uncapped = recording_uncapped  # record on, fast_max_realtime_factor 0: the bag races
        self._flutter_hold = bool(flutter_hold and flutter_monitor is not None)
        # fast_wait_for_command: released by the first command, or after HOLD_TIMEOUT_S of wall time (logged)
        self._start_hold_until: float | None = time.monotonic() + HOLD_TIMEOUT_S if wait_for_command else None
        self._hold_since: float | None = None

    def waiting_for_command(self) -> bool:
        """Fast mode with ``fast_wait_for_command``: true until the first command arrives, so a session's clock
        starts with its operator (the fast node ran ~40 simulated s at 0 m/s while one was discovered)."""
        if self._start_hold_until is None:
            return False
        if time.monotonic() > self._start_hold_until:
            self._start_hold_until = None
            self._log.warning(f"no command for {HOLD_TIMEOUT_S:g} s (wall): simulated time starts anyway" + (
                "; the fast node records as fast as it runs (2.4 GB of bag a minute at the default rates here: a "
                "review's unattended node wrote 24 GB in 10 min): stop it, or cap it with fast_max_realtime_factor"
                if self._recording_uncapped else ""))
            return False
        return True

    def command_arrived(self) -> None:
        """A command came: the start hold (if any) ends."""
        if self._start_hold_until is not None:
            self._start_hold_until = None
            self._log.info(f"first command: simulated time starts at t = {self._rig.time_s:.3f} s")

    def flutter_holding(self) -> bool:
        """Fast mode with ``flutter_test.hold``: true until the first airspeed command and from each published test
        point until the next one (the flutter-test client connects, then decides; simulated time waits, so results
        do not depend on how fast the client is, and a run is reproducible from its seed). A client silent for
        HOLD_TIMEOUT_S of wall time releases the hold (logged)."""
        if not (self._flutter_hold and self._monitor.waiting):
            self._hold_since = None
            return False
        now = time.monotonic()
        if self._hold_since is None:
            self._hold_since = now
        if now - self._hold_since > HOLD_TIMEOUT_S:
            self._flutter_hold = False
            self._log.warning(f"no airspeed command for {HOLD_TIMEOUT_S:g} s (wall) after a test point: "
                              f"flutter-test hold released at t = {self._rig.time_s:.3f} s")
            return False
        return True
