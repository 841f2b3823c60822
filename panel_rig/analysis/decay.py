"""The decay rate of a shaker tap's free response in a turbulent tunnel: the tapped mode alone, above the floor of
its own random response.

A tap excites every mode: the panel's tip then holds the least damped mode (the one that flutters) and faster
decaying ones (at 0.6 U_f, default model: 23.6 Hz at -1.04 1/s, 69.6 Hz at -3.5 1/s, 4.4 Hz at -10 1/s), while the
turbulence keeps the tapped mode moving at a stationary level. A straight line through the log of the whole
envelope mixes the three: the early windows decay faster (the other modes), the late ones not at all (the floor).
Here the response is band-limited around the tap's dominant frequency first, and its windowed mean square is fitted
with the sum of a decaying free response and a constant floor (the two are uncorrelated):

    env(t)^2 = A^2 exp(2 sigma t) + F^2

in the log domain (every window weighs the same). Pure functions on arrays; validated against the model's
eigenvalues in tests/test_rig_turbulence.py and docs/validation.md.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.optimize import least_squares
from scipy.signal import butter, sosfiltfilt

from panel_rig.analysis.signals import dominant_frequency_hz, window_std

BAND_RATIO = 1.5  # the band is [f / BAND_RATIO, f * BAND_RATIO] around the tap's dominant frequency f
BAND_ORDER = 4  # Butterworth order of each edge (applied forward and backward: zero phase, twice the roll-off)
MAX_BAND_NYQUIST = 0.9  # the band's upper edge at most this fraction of the Nyquist frequency
MIN_WINDOWS = 4  # envelope windows the fit needs
MIN_DECAY_WINDOWS = 3  # windows in which the free decay must stand above the floor for its rate to count
FREQUENCY_PART = 4  # the tap's frequency is the dominant one of the first 1/FREQUENCY_PART of the free response
FILTER_PAD_SAMPLES = 3 * (2 * BAND_ORDER + 1)  # sosfiltfilt's default padding of the band-pass (BAND_ORDER sections)


class FloorDecay(NamedTuple):
    """The fit env(t)^2 = A^2 exp(2 sigma t) + F^2 (A, F in the signal's units, t from the first window's centre)."""

    rate_per_s: float  # sigma
    amplitude: float  # A: the free response's envelope at the first window's centre
    floor: float  # F: the stationary envelope it decays into
    decay_windows: int  # windows in which A exp(sigma t) > F


def mode_band_hz(x: np.ndarray, dt_s: float) -> tuple[float, float | None] | None:
    """The band [f / BAND_RATIO, f * BAND_RATIO] (Hz) around the dominant frequency f of the first part of a free
    response x (samples every dt_s); its upper edge None (a high-pass) where it would pass MAX_BAND_NYQUIST of the
    Nyquist frequency (a 64 Hz recording of a 23 Hz mode: the faster modes alias below the band); None when there
    is no frequency or the lower edge passes that limit too."""
    head = np.asarray(x, float)[: max(16, x.size // FREQUENCY_PART)]
    f = dominant_frequency_hz(head, dt_s)
    top = MAX_BAND_NYQUIST * 0.5 / dt_s
    if not np.isfinite(f) or f <= 0 or f / BAND_RATIO >= top:
        return None
    return f / BAND_RATIO, (f * BAND_RATIO if f * BAND_RATIO <= top else None)


def band_limited(x: np.ndarray, dt_s: float, band_hz: tuple[float, float | None]) -> np.ndarray:
    """x about its mean through a zero-phase Butterworth band-pass, or high-pass with no upper edge (BAND_ORDER,
    forward and backward)."""
    low, high = band_hz
    if high is None:
        sos = butter(BAND_ORDER, low, btype="highpass", fs=1.0 / dt_s, output="sos")
    else:
        sos = butter(BAND_ORDER, (low, high), btype="bandpass", fs=1.0 / dt_s, output="sos")
    x = np.asarray(x, float)
    return sosfiltfilt(sos, x - np.mean(x))


def fit_floor_decay(env: np.ndarray, t_s: np.ndarray) -> FloorDecay | None:
    """Least squares of log env against log sqrt(A^2 exp(2 sigma t) + F^2) (t_s: the windows' centres, s); None
    with fewer than MIN_WINDOWS positive windows or when the fit does not converge to finite numbers."""
    keep = np.isfinite(env) & (env > 0)
    if keep.sum() < MIN_WINDOWS:
        return None
    y, t = np.log(env[keep]), np.asarray(t_s, float)[keep] - t_s[0]
    head = max(3, y.size // 3)
    sigma0 = min(float(np.polyfit(t[:head], y[:head], 1)[0]), -1e-3)
    p0 = [2.0 * y[0], sigma0, 2.0 * float(y.min())]

    def residual(p: np.ndarray) -> np.ndarray:
        return y - 0.5 * np.logaddexp(p[0] + 2.0 * p[1] * t, p[2])

    sol = least_squares(residual, p0, method="lm")
    if not (sol.success and np.isfinite(sol.x).all()):
        return None
    log_a2, sigma, log_f2 = (float(v) for v in sol.x)
    above = int(np.sum(log_a2 + 2.0 * sigma * t > log_f2))
    return FloorDecay(sigma, float(np.exp(0.5 * log_a2)), float(np.exp(0.5 * log_f2)), above)


def tap_decay(x: np.ndarray, dt_s: float, window_s: float) -> tuple[FloorDecay, tuple[float, float | None]] | None:
    """The tapped mode's decay in a free response x (samples every dt_s, s; windows of window_s, s) and the band
    it was taken in (Hz); None when there is no band, no fit, no decay (sigma >= 0) or the decay stands above its
    floor in fewer than MIN_DECAY_WINDOWS windows (the caller keeps its plain envelope rate)."""
    n_w = max(2, int(round(window_s / dt_s)))
    # too short for the fit's windows, or for the filter's padding (sosfiltfilt raised on 10 samples)
    if np.size(x) < max(MIN_WINDOWS * n_w, FILTER_PAD_SAMPLES + 1):
        return None
    band = mode_band_hz(x, dt_s)
    if band is None:
        return None
    env = window_std(band_limited(x, dt_s, band), n_w)
    fit = fit_floor_decay(env, (np.arange(env.size) + 0.5) * n_w * dt_s)
    if fit is None or fit.rate_per_s >= 0 or fit.decay_windows < MIN_DECAY_WINDOWS:
        return None
    return fit, band
