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


def test_a_period_a_gap_could_hide_a_crossing_in_is_left_out() -> None:
    """Under load the operator's 8 Hz shaker row read 5.26 Hz: gaps of half a period or more hid mean crossings
    and doubled the periods across them. Those periods are left out (a gap over a quarter of the period); the
    others give 8 Hz. Readings with such a gap in every period give no frequency."""
    t = np.arange(0.0, 10.0, 0.002)
    w = 0.01 * np.sin(2 * np.pi * 8.0 * t)
    assert tip_metrics(list(zip(t, w)))[1] == pytest.approx(8.0, rel=0.01)
    keep = np.ones(t.size, bool)
    for start in np.arange(5.2, 10.0, 0.6):  # a 70 ms gap every 0.6 s: 88 % of the readings kept
        keep[(t > start) & (t < start + 0.07)] = False
    rms, f = tip_metrics(list(zip(t[keep], w[keep])))
    assert f == pytest.approx(8.0, rel=0.01) and rms == pytest.approx(0.01 / math.sqrt(2), rel=0.05)
    # readings only around every other up-crossing (40 ms windows): half of the crossings are hidden, and the
    # periods between those seen are 0.25 s (4 Hz), each with a 210 ms gap in it
    every_other = ((t + 0.02) % 0.25) < 0.04
    ups = np.nonzero((w[every_other][:-1] < 0) & (w[every_other][1:] >= 0))[0]
    assert ups.size > 10 and np.allclose(np.diff(t[every_other][ups]), 0.25, atol=0.003)
    rms, f = tip_metrics(list(zip(t[every_other], w[every_other])))
    assert math.isnan(f)


def test_the_fast_operator_s_bursts_of_readings_give_the_lco_frequency() -> None:
    """In fast mode the operator takes the newest readings at each turn (its queue, READINGS_DEPTH of them: 0.2 s at
    500 Hz) and misses what came between turns: bursts with random gaps. A 17 Hz LCO with the sensor's noise reads
    17 Hz."""
    rng = np.random.default_rng(3)
    t = np.arange(0.0, 20.0, 0.002)
    w = 0.094 * np.sin(2 * np.pi * 17.0 * t + 0.3) + 5e-6 * rng.standard_normal(t.size)
    keep = np.zeros(t.size, bool)
    i = 0
    while i < t.size:  # a burst of 20-100 readings, then 0.05-1 s missed
        n = int(rng.integers(20, 101))
        keep[i : i + n] = True
        i += n + int(rng.integers(25, 500))
    rms, f = tip_metrics(list(zip(t[keep], w[keep])))
    assert f == pytest.approx(17.0, rel=0.005) and rms == pytest.approx(0.094 / math.sqrt(2), rel=0.05)


def test_operator_frequency_counts_only_the_periods_its_readings_cover() -> None:
    """Best-effort readings a busy operator missed halved the mean-crossing count: the demo's 17 Hz LCO read 5.4 Hz.
    With all readings (at the node's alternating 4/5-step intervals): 17 Hz; with 70 % lost at random, the periods
    without a long gap still give 17 Hz; with 90 % lost, none is left: no frequency, never a wrong one."""
    steps = np.cumsum(np.tile([4, 5], 2250)) / 2048.0  # 500 Hz readings on 2048 Hz physics steps, ~10 s
    w = 0.01 * np.sin(2 * np.pi * 17.0 * steps)
    rms, f = tip_metrics(list(zip(steps, w)))
    assert f == pytest.approx(17.0, rel=0.01) and rms == pytest.approx(0.01 / np.sqrt(2), rel=0.01)
    rng = np.random.default_rng(0)
    kept = rng.random(steps.size) < 0.3  # 70 % lost
    rms_lost, f_lost = tip_metrics(list(zip(steps[kept], w[kept])))
    assert f_lost == pytest.approx(17.0, rel=0.01) and rms_lost == pytest.approx(rms, rel=0.05)
    sparse = rng.random(steps.size) < 0.1  # 90 % lost: a gap of a quarter period (7 readings) in every period
    assert math.isnan(tip_metrics(list(zip(steps[sparse], w[sparse])))[1])
