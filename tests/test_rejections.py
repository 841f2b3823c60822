"""The node's throttled warnings of rejected commands (panel_rig.ros.rejections), on a clock of the test's."""

from __future__ import annotations

from panel_rig.ros.rejections import RejectionLog


def test_a_flood_of_rejections_logs_at_most_one_line_per_topic_and_period() -> None:
    """A controller commanding an aborted rig at 500 Hz: each 0.2 s gave the warning due and a line of its own for
    the ones held back before it, and the diagnostics period a third: ~10 lines a second per topic, where the README
    promises at most one per topic every 0.2 s. The held ones now ride on the next line."""
    log, lines = RejectionLog(0.2), []
    for k in range(2000):  # 4 s at 500 Hz on one topic, and the diagnostics period every 0.5 s
        now = k / 500.0
        line = log.rejected("control/force_cmd", f"force {k} rejected", now)
        lines += [(now, line)] if line is not None else []
        if k % 250 == 0:
            lines += [(now, x) for x in log.due(now)]
    times = [t for t, _ in lines]
    assert len(lines) == 20 and all(b - a >= 0.2 - 1e-12 for a, b in zip(times, times[1:])), times
    assert lines[0][1] == "force 0 rejected"
    # every later line carries the 99 held back since the previous one, with the last one's reason
    assert lines[1][1] == ("force 100 rejected (99 more command(s) on control/force_cmd rejected (warnings at most "
                           "every 0.2 s per topic); the last: force 99 rejected)")


def test_held_back_warnings_are_said_at_a_diagnostics_period_and_topics_have_their_own_throttle() -> None:
    """Three bad airspeeds back to back: the first is logged, the other two are said at the next diagnostics
    period once 0.2 s have passed (not before), with the last one's reason; a rejected force right after the first
    airspeed has its own line."""
    log = RejectionLog(0.2)
    assert log.rejected("airspeed_cmd", "airspeed 77 rejected", 10.0) == "airspeed 77 rejected"
    assert log.rejected("shaker/force_cmd", "force 100 rejected", 10.001) == "force 100 rejected"
    assert log.rejected("airspeed_cmd", "airspeed 88 rejected", 10.002) is None
    assert log.rejected("airspeed_cmd", "airspeed -1.5 rejected", 10.003) is None
    assert log.due(10.1) == []  # within the topic's period: still held
    assert log.due(10.5) == ["2 more command(s) on airspeed_cmd rejected (warnings at most every 0.2 s per topic); "
                             "the last: airspeed -1.5 rejected"]
    assert log.due(11.0) == []  # said once
    assert log.rejected("airspeed_cmd", "airspeed 99 rejected", 10.6) is None  # within 0.2 s of that summary line


def test_the_stop_line_counts_every_tick_not_only_the_jitter_sample() -> None:
    """A real-time node's stop line capped `ticks` at 500 000 (the length of the deque its jitter is taken from):
    a 20-minute run reported 500000. run_stats takes the count apart from the sample."""
    from collections import deque
    from types import SimpleNamespace

    from panel_rig.ros.diagnostics import run_stats

    sample: deque[float] = deque(maxlen=3)
    for _ in range(5):
        sample.append(0.002)
    rig = SimpleNamespace(time_s=1.0, overrun_count=0)
    assert run_stats(rig, 1.0, sample, 0.002, ticks=5)["ticks"] == 5
    assert run_stats(rig, 1.0, sample, 0.002)["ticks"] == 3
