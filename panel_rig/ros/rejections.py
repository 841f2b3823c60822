"""The node's warnings of rejected commands, throttled per topic (pure: no ROS, a clock handed in)."""

from __future__ import annotations

import math

REJECTION_LOG_S = 0.2  # wall seconds between two warnings of rejected commands on one topic


class RejectionLog:
    """At most one warning line per topic every ``period_s`` (wall), whatever the rate of rejections: rclpy's own
    throttle is per call site, so a rejected airspeed hid a rejected force sent just after it. What the throttle
    holds back is counted and said with the topic's next line (its count and the last one's reason); :meth:`due`,
    at each diagnostics period, says what is still held once the topic's period has passed. (Held-back warnings
    had a line of their own before each next warning, and a flood of 500 bad commands a second logged ten lines a
    second per topic.)"""

    def __init__(self, period_s: float = REJECTION_LOG_S) -> None:
        self.period_s = period_s
        self._logged: dict[str, float] = {}  # topic -> wall time of its last line
        self._held: dict[str, tuple[int, str]] = {}  # topic -> (warnings held back, the last one)

    def rejected(self, topic: str, text: str, now_s: float) -> str | None:
        """The line to log for a rejection on ``topic`` now (with what was held back before it), or None: held."""
        if now_s - self._logged.get(topic, -math.inf) < self.period_s:
            n, _ = self._held.get(topic, (0, ""))
            self._held[topic] = (n + 1, text)
            return None
        self._logged[topic] = now_s
        held = self._held.pop(topic, None)
        return text if held is None else f"{text} ({self._summary(topic, *held)})"

    def due(self, now_s: float) -> list[str]:
        """One line per topic whose held-back warnings can be said now (its period since its last line passed)."""
        lines = []
        for topic in [t for t in self._held if now_s - self._logged.get(t, -math.inf) >= self.period_s]:
            n, last = self._held.pop(topic)
            self._logged[topic] = now_s
            lines.append(self._summary(topic, n, last))
        return lines

    def _summary(self, topic: str, n: int, last: str) -> str:
        return (f"{n} more command(s) on {topic} rejected (warnings at most every {self.period_s:g} s per topic); "
                f"the last: {last}")
