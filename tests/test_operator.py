"""The operator's summary table (no ROS needed): what its rows say and what a missing frequency means."""

from __future__ import annotations

import math

import numpy as np
import pytest

from panel_rig.ros.operator import NO_FREQUENCY_NOTE, StepSummary, format_summary, parse_profile, tip_metrics


def test_shaker_and_ramp_rows_name_their_values_in_words() -> None:
    """`make run`'s table printed "shaker {'amplitude': 0.3, 'frequen" (a dict cut at the column's 34 characters)."""
    steps = parse_profile([{"shaker": {"amplitude": 0.3, "frequency_hz": 22.5}}, {"shaker": {"amplitude": 0.0}},
                           {"ramp": {"to": 12.0, "rate_mps2": 0.25}}, {"airspeed": 8.0}, {"dwell_s": 10.0}, "reset"])
    labels = [s.describe() for s in steps]
    assert labels == ["shaker 0.3 N/m at 22.5 Hz", "shaker 0 N/m", "ramp to 12 m/s at 0.25 m/s^2", "airspeed 8.0",
                      "dwell_s 10.0", "reset"]
    assert all(len(x) <= 34 for x in labels)


def test_a_missing_frequency_is_explained_under_the_table() -> None:
    """Every f_Hz of the demo's fast-mode table was "-" with no word why; a row with a tip RMS but no frequency
    now puts one note under the table, and a table whose frequencies are all there has none."""
    rows = [StepSummary(1, "airspeed 11.2", 0.0, 0.1), StepSummary(2, "dwell_s 30.0", 0.1, 30.1, 11.2, 11.2,
                                                                   tip_rms_m=0.09)]
    table = format_summary(rows).splitlines()
    assert table[-1] == NO_FREQUENCY_NOTE and table[2].split()[-1] == "-"
    rows[1].tip_freq_hz = 17.2
    assert NO_FREQUENCY_NOTE not in format_summary(rows)
    assert math.isnan(rows[0].tip_rms_m)  # a command row has neither: no note for it


def test_a_gap_that_can_hide_a_crossing_gives_no_frequency() -> None:
    """Under load the operator's 8 Hz shaker row read 5.26 Hz: the readings covered the window (coverage above
    0.65) but gaps of half a period or more hid mean crossings. A gap over a quarter of the period found: no
    frequency; the same readings without those gaps: 8 Hz."""
    t = np.arange(0.0, 10.0, 0.002)
    w = 0.01 * np.sin(2 * np.pi * 8.0 * t)
    assert tip_metrics(list(zip(t, w)))[1] == pytest.approx(8.0, rel=0.01)
    keep = np.ones(t.size, bool)
    for start in np.arange(5.2, 10.0, 0.6):  # a 70 ms gap every 0.6 s: 88 % of the readings kept
        keep[(t > start) & (t < start + 0.07)] = False
    rms, f = tip_metrics(list(zip(t[keep], w[keep])))
    assert math.isnan(f) and rms == pytest.approx(0.01 / math.sqrt(2), rel=0.05)
