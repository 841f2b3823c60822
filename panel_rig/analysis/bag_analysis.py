"""Airspeed plateaus, LCO status and the flutter onset of a recorded run: pure functions on arrays.

Used by `panel-rig analyze BAG` (panel_rig.analyze_cli), which loads the bag with
:func:`panel_rig.recording.series.load_series`. Nothing here reads files or knows about bags.

Criteria (defaults in :class:`Criteria`, all reported in the JSON output):

* **Plateau**: a stretch where the *measured* airspeed stays within ``tol_mps`` of the stretch's
  final value (median of its last half) for at least ``min_duration_s``. Samples are first marked
  steady when some ``window_s`` window containing them spans at most ``tol_mps``; each steady run is
  then trimmed to its longest part within ``tol_mps`` of that final value, which cuts the tunnel's
  first-order-lag approach (and any slow drift) off the front, and ended at the first recorded
  ``airspeed_cmd`` that leaves it (the lag keeps the measured airspeed close for a moment after it).
* **Free response**: the part of a plateau after the last shaker command inside it (a tap: force on,
  force off), or the whole plateau if that leaves less than ``min_free_s``.
* **Metrics window**: the second half of the free response, at most its last ``measure_s`` (5 s, as
  ``panel-rig lco``). The mean tip w/L (a static deflection under a held shaker force), the RMS about it, the peak
  |w/L| (mean included) and the dominant frequency are taken there; the envelope and the status below are those of
  the motion about that mean.
* **Growth rate** (1/s): least-squares slope of log(envelope), the envelope being the RMS of
  consecutive windows of ``max(envelope_window_s, 4 periods)`` (at most an eighth of the free response, when that
  is at least ``envelope_window_s``); windows below ``1e-3`` of the
  largest are left out (numerical floor). ``growth_rate_per_s`` over the free response,
  ``late_growth_rate_per_s`` over the metrics window. After a tap whose envelope falls, ``growth_rate_per_s`` is
  the tapped mode's decay above its random response instead (:mod:`panel_rig.analysis.decay`; its band in
  ``decay_band_hz``), where that fit holds.
* **Status**: ``lco`` if RMS >= ``lco_min_rms`` and ``|late rate| <= max_steady_rate_per_s``, or, for
  the irregular (bursting) LCO of the full nonlinear model, if RMS >= ``irregular_lco_min_rms`` and the
  oscillation is sustained (RMS of the last third of the metrics window within 0.5-2 of the first
  third) or its envelope is not exponential (R^2 of the log-envelope line < 0.7);
  else ``growing`` if both rates > ``max_steady_rate_per_s`` and the log-envelope is a line (R^2 >=
  ``min_growth_r2``): the tunnel's turbulence-driven random response wanders by more than that rate over a few
  seconds and was called growing when either rate was (the demo's 8 m/s plateau, which put the onset bracket
  below it); else ``quiet`` if the envelope never rose above ``quiet_rms`` (`panel-rig analyze`: twice the run's
  tip-sensor noise; a quiet plateau has no frequency; this is checked before every other rule: a plateau of 2 mm
  sensor noise, RMS 0.0073 L, was an ``lco``); else ``decaying`` if the
  free-response rate < ``-max_steady_rate_per_s`` and the decay was measured: a free response after a shaker
  tap, or without a tap an envelope falling along a line (R^2 >= ``min_decay_r2``: the random response's
  envelope reached R^2 0.94 in 200 five-second samples); else ``stationary`` (the turbulence's random
  response below flutter, whose envelope drifts: the demo's 8 m/s plateau, at -0.125 1/s with R^2 0.64, was
  "decaying" and stopped the extrapolation). A plateau with the wind off (U <= ``min_extrapolation_airspeed_mps``) is
  never ``lco`` nor ``growing``: nothing feeds an oscillation there (a large free decay after an abort).
* **Onset**: bracketed by the first unstable plateau in time (``lco`` or ``growing``; also the first
  ``lco`` one is named) and the fastest stable (``decaying``, ``stationary`` or ``quiet``) plateau below it *and before
  it in time*: once an LCO has started, a subcritical system may stay in LCO below the flutter speed
  (hysteresis), so later plateaus say nothing about the onset. Extrapolated where at least
  two decaying plateaus (U > 0.5 m/s, below the bracket) exist: a straight line through the decay
  rates of the (up to ``extrapolation_points``) fastest ones, to zero rate. Where the upper end of
  the bracket is still ``growing`` (its rate is the linear growth rate, not yet saturated), or ``lco`` with the
  growth seen before it saturated (``onset_growth_rate_per_s``: the log-envelope slope over the windows below
  ``onset_ceiling`` of the largest, at least ``onset_min_windows`` of them on a line), and its lower end
  ``decaying`` (U > 0.5 m/s; a ``stationary`` or ``quiet`` plateau has no measured rate), the rate is also interpolated linearly
  between the two bracketing plateaus (``interpolated_mps``).
* **Closed loop**: while a controller commands the panel (``control/force_cmd`` commands no more than the rig's
  watchdog timeout apart) the panel is another system. A plateau is cut where the loop closes or opens (for at
  least ``min_duration_s``: a controller slower than the watchdog opens it at every gap), each part is
  ``open`` or ``closed`` (``loop``), and the onset is estimated over each loop's plateaus alone: ``onset`` of the
  open loop, ``closed_loop_onset`` of the closed one (None without closed-loop plateaus).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panel_rig.analysis.decay import tap_decay
from panel_rig.analysis.signals import dominant_frequency_hz, resolved_frequency_hz, rms, window_std
from panel_rig.topics import CONTROL_TIMEOUT_S, CONTROL_TOPIC

MIN_ENVELOPE_WINDOWS = 8  # envelope windows a free response is cut into at least (when each is >= envelope_window_s)
SHAKER_TOPICS = ("shaker/force_cmd", "shaker/amplitude_cmd", "shaker/frequency_cmd")
Commands = dict[str, list[tuple[float, float]]]  # topic suffix -> [(t_s, value)]


@dataclass(frozen=True)
class Criteria:
    """Thresholds of the plateau split, the LCO decision and the onset estimate (SI units)."""

    tol_mps: float = 0.05
    window_s: float = 1.0
    min_duration_s: float = 3.0
    min_free_s: float = 2.0
    measure_s: float = 5.0
    envelope_window_s: float = 0.5
    lco_min_rms: float = 0.005
    max_steady_rate_per_s: float = 0.03
    irregular_lco_min_rms: float = 0.05
    quiet_rms: float = 1e-7
    min_growth_r2: float = 0.7
    min_extrapolation_airspeed_mps: float = 0.5
    extrapolation_points: int = 3
    min_decay_r2: float = 0.98
    onset_ceiling: float = 0.2
    onset_min_windows: int = 4
    onset_min_r2: float = 0.9


#: a plateau that ends this long (s) after a rig abort or less was ended by it (the abort winds the tunnel off, and
#: the plateau ends within a few samples as the airspeed leaves it)
ABORT_END_S = 0.5

#: the statuses of a plateau below the flutter speed
STABLE = ("decaying", "stationary", "quiet")
GAP_FACTOR = 3.0  # a sample interval this many times the median one is a gap in the recording


def gap_mask(t_s: np.ndarray) -> np.ndarray:
    """Per sample interval (size n - 1): True where the recording has a gap (a chunk a recovered bag lost, or the
    stamps of a real-time node shifted by an overrun): an interval over GAP_FACTOR times both of its neighbours.
    Against the neighbours, not the run's median: a node whose publish_rate_hz was set from 500 to 1 Hz live had
    thousands of "gaps", one per slow interval."""
    d = np.diff(np.asarray(t_s, dtype=float))
    if d.size < 2:
        return np.zeros(d.size, bool)
    neighbours = np.maximum(np.r_[d[1], d[:-1]], np.r_[d[1:], d[-2]])  # the larger of the interval's two neighbours
    return d > GAP_FACTOR * neighbours


def mean_dt(t_s: np.ndarray) -> float:
    """Mean sample interval outside gaps. Not the median: in fast mode readings fall on whole physics steps
    (e.g. 4 or 5 steps of 1/2048 s for 500 Hz), and the median would bias frequencies by 2.4 %. A gap (a lost
    chunk of a recovered bag) counted in the mean changed every window size of the analysis."""
    if t_s.size < 2:
        return 0.0
    d = np.diff(np.asarray(t_s, dtype=float))
    return float(np.mean(d[~gap_mask(t_s)]))


def recording_gaps(t_s: np.ndarray) -> list[dict[str, float]]:
    """The gaps of a recording: [{"from_s", "to_s"}] (times relative as ``t_s``)."""
    return [{"from_s": float(t_s[i]), "to_s": float(t_s[i + 1])} for i in np.flatnonzero(gap_mask(t_s))]


# ---------------------------------------------------------------------------------- plateaus
def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index ranges of consecutive True."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def setpoint_change_times_s(airspeed_cmds: list[tuple[float, float]], crit: Criteria = Criteria()) -> list[float]:
    """The times (s) of the recorded `airspeed_cmd`s (t_s, value) that change the set-point by more than tol_mps."""
    out, last = [], None
    for t, v in sorted(airspeed_cmds):
        if last is None or abs(v - last) > crit.tol_mps:
            out.append(t)
        last = v
    return out


def find_plateaus(t_s: np.ndarray, airspeed_mps: np.ndarray, crit: Criteria = Criteria(),
                  setpoint_changes_s: Sequence[float] = ()) -> list[tuple[int, int]]:
    """[start, end) sample ranges of airspeed plateaus (see the module docstring); none spans one of the
    ``setpoint_changes_s`` (:func:`setpoint_change_times_s`): a step smaller than the tunnel's lag lets the steady
    windows run on across it (the flutter test's capped 0.115 m/s step from 9.222 to 9.337 m/s made one run of two
    plateaus, and only the second was kept)."""
    n = t_s.size
    dt = mean_dt(t_s) or 1.0
    n_w = max(2, int(round(crit.window_s / dt)))
    u = np.nan_to_num(np.asarray(airspeed_mps, dtype=float), nan=np.inf)
    if n < n_w:
        return []
    win = np.lib.stride_tricks.sliding_window_view(u, n_w)
    ok_start = (win.max(axis=1) - win.min(axis=1)) <= crit.tol_mps
    steady = np.convolve(ok_start.astype(float), np.ones(n_w))[:n] > 0
    # a plateau never spans a gap in the recording nor a step of the airspeed between two samples: steady windows
    # on both sides of an instantaneous step (tunnel.time_constant_s = 0) joined two plateaus into one run
    breaks = gap_mask(t_s) | (np.abs(np.diff(u)) > crit.tol_mps)
    at = np.searchsorted(t_s, np.asarray(setpoint_changes_s, float), side="left")  # the first sample of the new one
    breaks[at[(at >= 1) & (at < n)] - 1] = True
    out = []
    for r0, r1 in _runs(steady):
        cuts = [r0, *(r0 + 1 + np.flatnonzero(breaks[r0:r1 - 1])).tolist(), r1]
        for i0, i1 in zip(cuts[:-1], cuts[1:]):
            seg = u[i0:i1]
            ref = float(np.median(seg[seg.size // 2 :]))
            inside = _runs(np.abs(seg - ref) <= crit.tol_mps)
            if not inside:
                continue
            a, b = max(inside, key=lambda r: r[1] - r[0])
            if t_s[i0 + b - 1] - t_s[i0 + a] >= crit.min_duration_s:
                out.append((i0 + a, i0 + b))
    return out


def cut_at_setpoint_changes(t_s: np.ndarray, airspeed_mps: np.ndarray, airspeed_cmds: list[tuple[float, float]],
                            ranges: list[tuple[int, int]], crit: Criteria = Criteria()) -> list[tuple[int, int]]:
    """End each plateau at the first recorded `airspeed_cmd` (t_s, value) inside it that leaves it (by > tol_mps).

    The tunnel lags the set-point, so the measured airspeed stays within tolerance for a moment
    after a new command, while the response may already change.
    """
    out = []
    for i0, i1 in ranges:
        ref = float(np.median(airspeed_mps[i0:i1]))
        t0, t1 = t_s[i0], t_s[i1 - 1]
        t_cut = min((t for t, v in airspeed_cmds if t0 < t <= t1 and abs(v - ref) > crit.tol_mps), default=None)
        if t_cut is not None:
            i1 = int(np.searchsorted(t_s, t_cut, side="left"))
        if i1 > i0 and t_s[i1 - 1] - t_s[i0] >= crit.min_duration_s:
            out.append((i0, i1))
    return out


def control_spans(commands: Commands, timeout_s: float = CONTROL_TIMEOUT_S) -> list[tuple[float, float]]:
    """(start, end) times (s) in which the loop was closed: from a control command until the next one, or until the
    watchdog's ``timeout_s`` after the last of a run of them (then the rig zeroes the control force)."""
    return _bridged([(t, t + timeout_s) for t in sorted(t for t, _ in commands.get(CONTROL_TOPIC, []))], 0.0)


def cut_at_loop_switches(t_s: np.ndarray, ranges: list[tuple[int, int]], spans: list[tuple[float, float]],
                         crit: Criteria = Criteria()) -> list[tuple[int, int, bool]]:
    """Split each plateau [i0, i1) where the loop closes or opens (``spans``: :func:`control_spans`); the parts of
    at least ``min_duration_s`` as (i0, i1, closed). The loop opening for less than ``min_duration_s`` does not cut
    (a controller slower than the watchdog trips it at every gap: an 8 Hz one opened the loop for 25 ms in each
    0.125 s, and the cuts left no part long enough to be a plateau)."""
    spans = _bridged(spans, crit.min_duration_s)
    out = []
    edges = np.array(sorted(x for span in spans for x in span))
    for i0, i1 in ranges:
        cuts = [i0, *np.searchsorted(t_s, edges[(edges > t_s[i0]) & (edges < t_s[i1 - 1])]).tolist(), i1]
        for a, b in zip(cuts[:-1], cuts[1:]):
            if b > a and t_s[b - 1] - t_s[a] >= crit.min_duration_s:
                mid = 0.5 * (t_s[a] + t_s[b - 1])
                out.append((a, b, any(lo <= mid <= hi for lo, hi in spans)))
    return out


def _bridged(spans: list[tuple[float, float]], gap_s: float) -> list[tuple[float, float]]:
    """``spans`` (ascending starts) joined where they overlap or the gap between them is at most ``gap_s``."""
    out: list[tuple[float, float]] = []
    for lo, hi in spans:
        if out and lo - out[-1][1] <= gap_s:
            out[-1] = (out[-1][0], max(out[-1][1], hi))
        else:
            out.append((lo, hi))
    return out


# ---------------------------------------------------------------------------------- metrics
def envelope_rate_per_s(x: np.ndarray, dt_s: float, window_s: float, floor_ratio: float = 1e-3) -> float:
    """Slope of log(windowed RMS about each window's mean) vs time, 1/s; windows below floor_ratio of the largest
    dropped."""
    n_w = max(2, int(round(window_s / dt_s)))
    env = window_std(np.asarray(x, dtype=float), n_w)
    if env.size < 3 or not np.any(env > 0):
        return 0.0
    t = (np.arange(env.size) + 0.5) * n_w * dt_s
    keep = env > floor_ratio * env.max()
    if keep.sum() < 3:
        return 0.0
    return float(np.polyfit(t[keep], np.log(env[keep]), 1)[0])


def _free_start(commands: Commands, t0: float, t1: float, crit: Criteria) -> float:
    times = [t for name in SHAKER_TOPICS for t, _ in commands.get(name, []) if t0 <= t <= t1]
    start = max(times, default=t0)
    return start if t1 - start >= crit.min_free_s else t0


def _log_fit_r2(env: np.ndarray) -> float:
    """R^2 of a straight line through log(envelope): near 1 for exponential growth or decay."""
    keep = env > 0
    if keep.sum() < 3:
        return 1.0
    t, y = np.flatnonzero(keep).astype(float), np.log(env[keep])
    resid = y - np.polyval(np.polyfit(t, y, 1), t)
    ss = float(np.sum((y - y.mean()) ** 2))
    return 1.0 - float(np.sum(resid**2)) / ss if ss > 0 else 1.0


def onset_growth_rate_per_s(env: np.ndarray, window_s: float, crit: Criteria) -> float | None:
    """Linear growth rate (1/s) of an oscillation that grew into an LCO within the plateau: the slope of log(envelope)
    over the windows before the first one above ``onset_ceiling`` of the largest (the small-amplitude, linear
    part of the growth). None unless there are ``onset_min_windows`` of them, their log is a line (R^2 >=
    ``onset_min_r2``) and it rises faster than ``max_steady_rate_per_s``: an LCO carried over from an earlier
    plateau, or one that grew during the tunnel's ramp, has no such part."""
    big = np.flatnonzero(env > crit.onset_ceiling * env.max()) if env.size else np.zeros(0, int)
    rising = env[: big[0]] if big.size else env[:0]
    if rising.size < crit.onset_min_windows or np.any(rising <= 0) or _log_fit_r2(rising) < crit.onset_min_r2:
        return None
    slope = float(np.polyfit(np.arange(rising.size) * window_s, np.log(rising), 1)[0])
    return slope if slope > crit.max_steady_rate_per_s else None


def _status(rms_late: float, peak_env: float, rate: float, rate_late: float, sustain: float, r2: float,
            crit: Criteria, tapped: bool = True, wind_off: bool = False) -> str:
    """lco: a sustained oscillation, either steady (|late rate| small) or irregular but large: RMS above
    irregular_lco_min_rms and either the RMS of the last third of the window within [0.5, 2] of the first
    third, or an envelope that is not exponential (R^2 of the log-envelope fit < 0.7; a free decay or growth
    fits with R^2 > 0.9). decaying: a measured decay, the free response after a shaker tap (``tapped``), or
    without one an envelope falling along a line (R^2 >= ``min_decay_r2``); a panel that moves but neither
    decays so nor grows is stationary (the turbulence's random response: its envelope drifts), one that does not
    move quiet. With the ``wind_off`` (at most ``min_extrapolation_airspeed_mps``) nothing feeds an oscillation: never
    lco nor growing (the free decay of a panel the wind had left at 0.3-0.8 L after an abort, -0.1 1/s, was "lco" by
    the irregular rule, whose 5 s window cannot tell so slow a decay from a sustained cycle)."""
    lim = crit.max_steady_rate_per_s
    if peak_env <= crit.quiet_rms:  # first: a plateau within the sensor's noise is no cycle (2 mm of noise, RMS
        return "quiet"  # 0.0073 L, was an "lco" by the RMS rule, and its airspeed the flutter onset)
    if wind_off:
        pass
    elif rms_late >= crit.lco_min_rms and abs(rate_late) <= lim:
        return "lco"
    elif rms_late >= crit.irregular_lco_min_rms and (0.5 <= sustain <= 2.0 or r2 < 0.7):
        return "lco"
    elif rate > lim and rate_late > lim and peak_env > crit.quiet_rms and r2 >= crit.min_growth_r2:
        return "growing"
    if rate < -lim and (tapped or r2 >= crit.min_decay_r2):
        return "decaying"
    return "stationary"


def analyze_plateau(t_s: np.ndarray, tip_w_over_L: np.ndarray, airspeed_mps: np.ndarray, commands: Commands,
                    i0: int, i1: int, crit: Criteria = Criteria(), aborted: bool = False) -> dict[str, Any]:
    """Metrics of one plateau [i0, i1) (see the module docstring); ``aborted``: the rig aborted at its end."""
    t, w, dt = t_s, tip_w_over_L, mean_dt(t_s)
    t0, t1 = float(t[i0]), float(t[i1 - 1])
    f0 = _free_start(commands, t0, t1, crit)
    j0 = int(np.searchsorted(t, f0, side="right"))
    free = w[j0:i1]
    half = free[free.size // 2 :]
    late = half[-max(16, int(round(crit.measure_s / dt))) :]
    # the motion about its mean: a force held on the shaker bends the panel to a static deflection, and an RMS with
    # that mean in it made a panel at rest under the force an "lco" (the envelope's windows each about their own
    # mean: an LCO's own offset, the exact panel's, is no envelope either)
    mean = float(np.mean(late))
    dt_late = mean_dt(t[i1 - late.size : i1])
    freq = dominant_frequency_hz(late, dt_late)
    win_s = max(crit.envelope_window_s, 4.0 / freq) if freq > 0 else crit.envelope_window_s
    # at least MIN_ENVELOPE_WINDOWS over the free response: the turbulence's response in a long dwell after a tap
    # put a 0.43 Hz peak in the last 5 s, a 9.4 s window left under 3 of them, and the tap's decay rate was 0
    win_s = min(win_s, max(crit.envelope_window_s, (t1 - float(t[j0])) / MIN_ENVELOPE_WINDOWS))
    win_n = max(2, int(round(win_s / dt)))  # samples per envelope window
    env = window_std(free, win_n)
    rate = envelope_rate_per_s(free, dt, win_s)
    tap = tap_decay(free, dt, win_s) if f0 > t0 and rate < 0 else None
    if tap is not None:  # the tapped mode alone, above its random response (panel_rig.analysis.decay)
        rate = tap[0].rate_per_s
    rate_late = envelope_rate_per_s(late, dt, min(win_s, late.size * dt / 3))
    rms_late = rms(late - mean)
    third = max(1, late.size // 3)
    sustain = rms(late[-third:] - np.mean(late[-third:])) / max(rms(late[:third] - np.mean(late[:third])), 1e-300)
    u = airspeed_mps[i0:i1]
    status = _status(rms_late, float(env.max()) if env.size else 0.0, rate, rate_late, sustain, _log_fit_r2(env), crit,
                     tapped=f0 > t0, wind_off=float(np.mean(u)) <= crit.min_extrapolation_airspeed_mps)
    if aborted and status == "lco" and rate_late > crit.max_steady_rate_per_s:
        # still growing when the rig stopped it at its tip limit: no cycle was reached (a panel that grew from a
        # closed loop's quiet into the wall, +1.8 1/s over its last 5 s, was "lco" by the irregular rule)
        status = "growing"
    if status == "quiet" or rms_late <= crit.quiet_rms:  # the peak of a sensor's noise is no frequency of the
        freq = float("nan")  # panel (it read 100-240 Hz; 161 Hz in a wind-off plateau's noise after a decay)
    else:  # a window shorter than MIN_PERIODS periods has no resolved peak (a 5 s window read 0.24 Hz)
        freq = resolved_frequency_hz(freq, late.size * dt_late)
    return {
        "t_start_s": round(t0, 4), "t_end_s": round(t1, 4), "free_from_s": round(float(t[j0]), 4),
        "measure_from_s": round(float(t[i1 - late.size]), 4),
        "airspeed_mps": float(np.mean(u)), "airspeed_std_mps": float(np.std(u)),
        "rms_tip_w_over_L": rms_late, "mean_tip_w_over_L": mean, "peak_tip_w_over_L": float(np.max(np.abs(late))),
        "dominant_frequency_hz": freq, "growth_rate_per_s": rate, "late_growth_rate_per_s": rate_late,
        "decay_band_hz": [round(e, 3) if e is not None else None for e in tap[1]] if tap else None,
        "onset_growth_rate_per_s": (onset_growth_rate_per_s(env, win_n * dt, crit)
                                    if status == "lco" else None),
        "status": status,
    }


# ---------------------------------------------------------------------------------- onset
def estimate_onset(plateaus: list[dict[str, Any]], crit: Criteria = Criteria()) -> dict[str, Any]:
    """Bracket (the fastest stable plateau with the wind on before the first unstable one, and that unstable one;
    ``bracket_low_mps`` None when there is none) and the linear extrapolation of decay rate to zero."""
    unstable = [p for p in plateaus if p["status"] in ("lco", "growing")]
    first_lco = next((p for p in plateaus if p["status"] == "lco"), None)
    upper = unstable[0] if unstable else None
    u_hi = upper["airspeed_mps"] if upper else math.inf
    # stable plateaus (decaying, or at rest) below the first unstable one, taken before it in time: after an
    # LCO has started, a subcritical system can stay in LCO below the flutter speed (hysteresis); with the wind on
    # (a tunnel at rest bounds nothing: "bracket 0.00 .. 12.00 m/s" after a first point that fluttered)
    stable = [p for p in plateaus if p["status"] in STABLE
              and crit.min_extrapolation_airspeed_mps < p["airspeed_mps"] < u_hi]
    before = [p for p in stable if upper is None or p["t_end_s"] <= upper["t_start_s"]]
    lower = max(before, key=lambda p: p["airspeed_mps"], default=None)
    below = [p for p in before if p["status"] == "decaying"]
    out: dict[str, Any] = {
        "bracket_low_mps": lower["airspeed_mps"] if lower else None,
        "bracket_high_mps": u_hi if upper else None,
        "first_lco_mps": first_lco["airspeed_mps"] if first_lco else None,
        "extrapolated_mps": None, "extrapolation_points": [], "interpolated_mps": None,
    }
    # a quiet or stationary plateau's rate is noise (a response that never rose, or the turbulence's random
    # response drifting): only a measured decay is interpolated;
    # the top's rate is a growing plateau's, or the growth an LCO plateau saw before it saturated
    top_rate = (None if upper is None else upper["growth_rate_per_s"] if upper["status"] == "growing"
                else upper.get("onset_growth_rate_per_s"))
    if (lower and top_rate is not None and lower["status"] == "decaying"
            and lower["airspeed_mps"] > crit.min_extrapolation_airspeed_mps
            and top_rate > 0 > lower["growth_rate_per_s"]):
        (u0, r0), (u1, r1) = (lower["airspeed_mps"], lower["growth_rate_per_s"]), (upper["airspeed_mps"], top_rate)
        out["interpolated_mps"] = float(u0 - r0 * (u1 - u0) / (r1 - r0))
    pts = sorted(
        ((p["airspeed_mps"], p["growth_rate_per_s"]) for p in below
         if p["airspeed_mps"] > crit.min_extrapolation_airspeed_mps),
        key=lambda x: x[0],
    )[-crit.extrapolation_points :]
    if len({round(u, 3) for u, _ in pts}) >= 2:
        slope, icpt = np.polyfit([u for u, _ in pts], [r for _, r in pts], 1)
        out["extrapolation_points"] = [[u, r] for u, r in pts]
        if slope > 0:
            out["extrapolated_mps"] = float(-icpt / slope)
    return out


# ---------------------------------------------------------------------------------- a whole run
def analyze_series(t_s: np.ndarray, tip_w_over_L: np.ndarray, airspeed_mps: np.ndarray, commands: Commands,
                   crit: Criteria = Criteria(), abort_times_s: Sequence[float] = (),
                   control_timeout_s: float = CONTROL_TIMEOUT_S) -> dict[str, Any]:
    """Plateaus (numbered from 1), their metrics and the onset estimates of one run's series (open and closed loop);
    ``abort_times_s``: when the rig aborted (a plateau that ends within ABORT_END_S of one ended by it);
    ``control_timeout_s``: the rig's control watchdog (:func:`control_spans`)."""
    cmds = commands.get("airspeed_cmd", [])
    ranges = cut_at_setpoint_changes(t_s, airspeed_mps, cmds,
                                     find_plateaus(t_s, airspeed_mps, crit, setpoint_change_times_s(cmds, crit)), crit)
    parts = cut_at_loop_switches(t_s, ranges, control_spans(commands, control_timeout_s), crit)
    plateaus = [analyze_plateau(t_s, tip_w_over_L, airspeed_mps, commands, i0, i1, crit,
                                aborted=any(t_s[i0] <= a <= t_s[i1 - 1] + ABORT_END_S for a in abort_times_s))
                for i0, i1, _ in parts]
    for k, (p, (_, _, closed)) in enumerate(zip(plateaus, parts, strict=True), start=1):
        p["index"] = k
        p["lco"] = p["status"] == "lco"
        p["loop"] = "closed" if closed else "open"
    closed = [p for p in plateaus if p["loop"] == "closed"]
    dt = mean_dt(t_s)
    return {
        "duration_s": float(t_s[-1] - t_s[0]),
        "samples": int(t_s.size),
        "sample_rate_hz": 1.0 / dt if dt > 0 else None,
        "gaps": recording_gaps(t_s),
        "criteria": asdict(crit),
        "plateaus": plateaus,
        "onset": estimate_onset([p for p in plateaus if p["loop"] == "open"], crit),
        "closed_loop_onset": estimate_onset(closed, crit) if closed else None,
    }


def shown_loop(result: dict[str, Any]) -> str:
    """The loop whose onset a single figure shows: "open", or "closed" when every plateau was closed-loop."""
    plateaus = result.get("plateaus") or []
    return "closed" if plateaus and all(p.get("loop") == "closed" for p in plateaus) else "open"


def shaker_on_times(commands: Commands) -> list[float]:
    """Times (s) of the accepted shaker commands that drive the panel: a sine amplitude or a held force not 0."""
    return sorted(t for name in ("shaker/amplitude_cmd", "shaker/force_cmd")
                  for t, value in commands.get(name, []) if value != 0.0)


def write_plots(plots_dir: Path, t_s: np.ndarray, tip_w_over_L: np.ndarray, airspeed_mps: np.ndarray,
                result: dict[str, Any], commands: Commands | None = None) -> list[str]:
    """Time history (with the shaker commands of ``commands`` marked), spectrogram and amplitude/frequency vs
    airspeed (Fig. 8) as PNG."""
    from panel_rig.analysis import plots

    plots_dir = Path(plots_dir)
    spans = [(p["t_start_s"], p["t_end_s"], p["status"]) for p in result["plateaus"]]
    paths = [
        plots.plot_time_history(plots_dir / "time_history.png", t_s, tip_w_over_L, airspeed_mps, spans,
                                shaker_on_times(commands or {})),
        plots.plot_spectrogram(plots_dir / "spectrogram.png", t_s, tip_w_over_L, airspeed_mps),
        plots.plot_lco_vs_airspeed(plots_dir / "lco_vs_airspeed.png", result["plateaus"],
                                   result["closed_loop_onset" if shown_loop(result) == "closed" else "onset"],
                                   shown_loop(result)),
    ]
    return [str(p) for p in paths]
