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


def test_gaps_in_the_readings_neither_hide_nor_invent_a_frequency() -> None:
    """Under load the operator's 8 Hz shaker row read 5.26 Hz: gaps of half a period or more hid mean crossings.
    The frequency is now the spectrum's peak of the readings on their own time grid: gaps (a 70 ms one every
    0.6 s) leave 8 Hz. Readings only around every other up-crossing (40 ms windows, every 0.25 s) fit 4 Hz as
    well as 8 Hz: their pattern's spectral window has a sidelobe of 0.96, and they give no frequency."""
    from panel_rig.analysis.signals import MAX_ALIAS_SIDELOBE

    t = np.arange(0.0, 10.0, 0.002)
    w = 0.01 * np.sin(2 * np.pi * 8.0 * t)
    assert tip_metrics(list(zip(t, w)))[1] == pytest.approx(8.0, rel=0.01)
    keep = np.ones(t.size, bool)
    for start in np.arange(5.2, 10.0, 0.6):  # a 70 ms gap every 0.6 s: 88 % of the readings kept
        keep[(t > start) & (t < start + 0.07)] = False
    rms, f = tip_metrics(list(zip(t[keep], w[keep])))
    assert f == pytest.approx(8.0, rel=0.01) and rms == pytest.approx(0.01 / math.sqrt(2), rel=0.05)
    every_other = ((t + 0.02) % 0.25) < 0.04
    ups = np.nonzero((w[every_other][:-1] < 0) & (w[every_other][1:] >= 0))[0]
    assert ups.size > 10 and np.allclose(np.diff(t[every_other][ups]), 0.25, atol=0.003)
    rms, f = tip_metrics(list(zip(t[every_other], w[every_other])))
    assert math.isnan(f)
    assert 0.5 < MAX_ALIAS_SIDELOBE < 0.96


def test_the_demo_s_lco_reads_its_frequency_where_a_gap_hid_a_crossing() -> None:
    """The demo's 9 m/s LCO step (16.3 Hz, from the bag) read 12.15 Hz: of its 78 periods between up-crossings
    three had no gap over a quarter period, and one of them was two periods whose negative lobe a 28 ms gap had
    hidden. The fast operator took its readings in bursts of 4-9 (the node's 500 Hz on 2048 Hz steps) with gaps of
    33-58 steps (16-28 ms). In 20 such patterns the frequency is 16.3 Hz within 0.5 % (the mean crossings gave a
    wrong one or none in all of 40)."""
    for seed in range(20):
        rng = np.random.default_rng(seed)
        steps, k = [], 0
        while len(steps) < 2500:
            for _ in range(int(rng.integers(4, 10))):
                steps.append(k)
                k += 4 if rng.random() < 0.9 else 5
            k += int(rng.integers(33, 59))
        t = np.array(steps) / 2048.0
        w = 0.08 * np.sin(2 * np.pi * 16.3 * t + 0.4) + 0.004 * np.sin(2 * np.pi * 32.6 * t)
        assert tip_metrics(list(zip(t, w)))[1] == pytest.approx(16.3, rel=0.005), seed


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
    With all readings (at the node's 4/5-step intervals): 17 Hz; with 70 % or 90 % lost at random, 17 Hz; a step
    whose readings span under eight periods gives none."""
    steps = np.cumsum(np.tile([4, 5], 2250)) / 2048.0  # 500 Hz readings on 2048 Hz physics steps, ~10 s
    w = 0.01 * np.sin(2 * np.pi * 17.0 * steps)
    rms, f = tip_metrics(list(zip(steps, w)))
    assert f == pytest.approx(17.0, rel=0.01) and rms == pytest.approx(0.01 / np.sqrt(2), rel=0.01)
    rng = np.random.default_rng(0)
    kept = rng.random(steps.size) < 0.3  # 70 % lost
    rms_lost, f_lost = tip_metrics(list(zip(steps[kept], w[kept])))
    assert f_lost == pytest.approx(17.0, rel=0.01) and rms_lost == pytest.approx(rms, rel=0.05)
    sparse = rng.random(steps.size) < 0.1  # 90 % lost at random: still 17 Hz (the mean crossings gave none)
    assert tip_metrics(list(zip(steps[sparse], w[sparse])))[1] == pytest.approx(17.0, rel=0.01)
    short = steps < 0.9  # 0.45 s of readings in the second half: under eight periods, no frequency
    assert math.isnan(tip_metrics(list(zip(steps[short], w[short])))[1])
