"""Signal metrics of a sampled response: RMS, peak, dominant frequency, steady-state detection."""

from __future__ import annotations

import numpy as np


def rms(x: np.ndarray) -> float:
    """Root mean square, scaled by the largest |x| first: a response decayed to ~1e-160 and below squared to 0
    (`lco --duration 3600` reported RMS 0.0 beside a peak of 5.5e-322)."""
    x = np.asarray(x, float)
    peak = float(np.max(np.abs(x))) if x.size else 0.0
    if peak == 0.0 or not np.isfinite(peak):
        return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")
    return peak * float(np.sqrt(np.mean(np.square(x / peak))))


def dominant_frequency_hz(x: np.ndarray, dt_s: float) -> float:
    """Frequency of the largest FFT peak (Hann window, mean removed), refined by parabolic interpolation; NaN
    (no frequency: null in JSON) for fewer than 8 samples or a signal that does not move (it was 0.0 Hz)."""
    x = np.asarray(x, float) - np.mean(x)
    if x.size < 8 or not np.any(x):
        return float("nan")
    x = x / np.max(np.abs(x))  # a response decayed to denormals keeps its spectrum's shape
    spec = np.abs(np.fft.rfft(x * np.hanning(x.size)))
    k = int(np.argmax(spec[1:]) + 1)
    if 1 <= k < spec.size - 1:
        a, b, c = np.log(spec[k - 1 : k + 2] + 1e-300)
        k = k + 0.5 * (a - c) / (a - 2 * b + c) if (a - 2 * b + c) != 0 else k
    return float(k / (x.size * dt_s))


#: periods a window must span for its spectrum's peak to count as a frequency: the resolution is one period over
#: the span (an operator's 0.5 s tap step, under 6 periods at 23 Hz, read 13-26 Hz; `analyze`'s 5 s window of a
#: plateau cut short read 0.24 Hz, its own length)
MIN_PERIODS = 8


def resolved_frequency_hz(freq_hz: float, span_s: float) -> float:
    """``freq_hz`` when a window of ``span_s`` seconds holds at least MIN_PERIODS of its periods, else NaN."""
    return float(freq_hz) if freq_hz * span_s >= MIN_PERIODS else float("nan")


#: the largest sidelobe of a gapped record's spectral window (the Hann-windowed spectrum of its pattern of kept
#: readings, against its main lobe) that still leaves the largest peak to the signal: a pattern repeating near a
#: period of the signal (readings only around every other crossing: 0.96) could pass an alias for it. The fast
#: operator's bursts of readings reach 0.51
MAX_ALIAS_SIDELOBE = 0.75


def gapped_dominant_frequency_hz(t_s: np.ndarray, x: np.ndarray) -> float:
    """:func:`dominant_frequency_hz` of readings with gaps (stamps ``t_s``, s, increasing): the readings on their
    own time grid (the mean interval of the contiguous ones), the missing ones at zero after the mean is removed
    (the periodogram Lomb-Scargle would compute for such a grid, at an FFT's cost). NaN for fewer than 8
    readings, or when the pattern of missing readings could pass an alias for the peak (its spectral window has a
    sidelobe above MAX_ALIAS_SIDELOBE of the main lobe)."""
    t, x = np.asarray(t_s, float), np.asarray(x, float)
    if t.size < 8:
        return float("nan")
    steps = np.diff(t)
    steps = steps[steps > 0]
    if steps.size == 0:
        return float("nan")
    dt = float(np.mean(steps[steps < 1.5 * np.median(steps)]))  # the reading interval, without the gaps
    idx = np.round((t - t[0]) / dt).astype(np.int64)
    kept = np.zeros(int(idx[-1]) + 1)
    kept[idx] = 1.0
    filled = np.zeros(kept.size)
    filled[idx] = x - np.mean(x)
    window = np.abs(np.fft.rfft(kept * np.hanning(kept.size)))
    if window.size > 3 and window[3:].max() > MAX_ALIAS_SIDELOBE * window[0]:  # beyond the Hann main lobe
        return float("nan")
    return dominant_frequency_hz(filled, dt)


def window_rms(x: np.ndarray, n_window: int) -> np.ndarray:
    """RMS of consecutive non-overlapping windows of n_window samples."""
    m = x.size // n_window
    return np.sqrt(np.mean(np.square(x[: m * n_window].reshape(m, n_window)), axis=1))


def window_std(x: np.ndarray, n_window: int) -> np.ndarray:
    """RMS about each window's own mean, of consecutive non-overlapping windows of n_window samples: the envelope
    of an oscillation about a mean that is not zero (a static deflection, or the cycle's own offset)."""
    m = x.size // n_window
    return np.std(x[: m * n_window].reshape(m, n_window), axis=1)


#: a steady state shows as STEADY_WINDOWS consecutive windows of STEADY_WINDOW_S seconds (:func:`steady_onset_s`)
STEADY_WINDOW_S, STEADY_WINDOWS = 1.0, 3


def steady_onset_s(x: np.ndarray, dt_s: float, window_s: float = STEADY_WINDOW_S, rel_tol: float = 0.03,
                   n_stable: int = STEADY_WINDOWS) -> float | None:
    """Start time of the steady part: the first window from which n_stable consecutive 1 s windows have
    RMS within rel_tol of the final window's RMS. None if the end is not steady."""
    w = window_rms(x, max(1, int(round(window_s / dt_s))))
    if w.size < n_stable or w[-1] == 0:
        return None
    ok = np.abs(w / w[-1] - 1) <= rel_tol
    if not ok[-n_stable:].all():
        return None
    first = w.size - 1
    while first > 0 and ok[first - 1]:
        first -= 1
    return first * window_s


def growth_rate_per_s(x: np.ndarray, dt_s: float, window_s: float = 0.5) -> float:
    """Exponential growth (+) or decay (-) rate of the windowed RMS envelope, 1/s (least squares on log)."""
    w = window_rms(x, max(1, int(round(window_s / dt_s))))
    w = w[w > 0]
    if w.size < 3:
        return 0.0
    t = np.arange(w.size) * window_s
    return float(np.polyfit(t, np.log(w), 1)[0])
