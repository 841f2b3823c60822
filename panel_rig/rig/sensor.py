"""The tip displacement sensor between the model's truth and the published reading.

A laboratory laser triangulation sensor looking at the trailing edge: the true tip w passes a first-order low-pass
of bandwidth f_c (``sensor.bandwidth_hz``, exact discrete-time for a tip held over each step: a = exp(-2 pi f_c dt)), then a pure delay
(``sensor.latency_s``, linear interpolation between physics steps); each reading then gets white noise of standard
deviation ``sensor.tip_noise_m`` and is rounded to the resolution ``sensor.resolution_m``. 0 switches a stage off.
The noise is seeded (from ``tunnel.turbulence.seed``), so a run is reproducible.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit


@njit(cache=True)
def _filter_delay(x, a, y0, buf, d_int, d_frac, out):
    """First-order low-pass y_k = a y_{k-1} + (1 - a) x_k, then the delay: out_k = y at d steps ago (linear
    interpolation); buf holds the last len(buf) filtered values, newest last (updated). Returns the last y."""
    nb = buf.shape[0]
    y = y0
    for k in range(x.shape[0]):
        y = a * y + (1.0 - a) * x[k]
        for j in range(nb - 1):
            buf[j] = buf[j + 1]
        buf[nb - 1] = y
        out[k] = (1.0 - d_frac) * buf[nb - 1 - d_int] + d_frac * buf[nb - 2 - d_int]
    return y


@dataclass(frozen=True)
class SensorSettings:
    """``sensor.*`` (SI); all zero: a perfect sensor (the reading is the truth)."""

    tip_noise_m: float = 0.0
    resolution_m: float = 0.0
    bandwidth_hz: float = 0.0
    latency_s: float = 0.0
    seed: int = 0

    @property
    def perfect(self) -> bool:
        return not (self.tip_noise_m or self.resolution_m or self.bandwidth_hz or self.latency_s)

    @staticmethod
    def from_config(cfg) -> "SensorSettings":
        return SensorSettings(cfg.sensor_tip_noise_m, cfg.sensor_resolution_m, cfg.sensor_bandwidth_hz,
                              cfg.sensor_latency_s, cfg.turbulence_seed)


class TipSensor:
    """Feed it the true tip of every physics step (:meth:`push`); :meth:`measure` gives readings at sample steps."""

    def __init__(self, settings: SensorSettings, dt_s: float):
        self.settings = settings
        self.dt_s = float(dt_s)
        self._a = math.exp(-2.0 * math.pi * settings.bandwidth_hz * self.dt_s) if settings.bandwidth_hz > 0 else 0.0
        self._delay_steps = settings.latency_s / self.dt_s
        self._n_buf = int(math.floor(self._delay_steps)) + 2
        self.reset()
        self.push(np.zeros(1))  # compile / load the filter now
        self.reset()

    def reset(self) -> None:
        self.rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([self.settings.seed, 0x5E9])))
        self._y = 0.0
        self._buf = np.zeros(self._n_buf)  # filtered tip of the last steps, newest last

    def push(self, tip_m: np.ndarray) -> np.ndarray:
        """Advance over the true tip of consecutive steps; returns the filtered, delayed tip after each step."""
        x = np.ascontiguousarray(tip_m, dtype=float).ravel()
        out = np.empty(x.shape[0])
        d_int = int(math.floor(self._delay_steps))
        self._y = _filter_delay(x, self._a, self._y, self._buf, d_int, self._delay_steps - d_int, out)
        return out

    def measure(self, delayed_m: np.ndarray) -> np.ndarray:
        """Readings from the filtered, delayed tip at the sample steps: + noise, rounded to the resolution."""
        v = np.asarray(delayed_m, dtype=float)
        s = self.settings
        if s.tip_noise_m > 0:
            v = v + s.tip_noise_m * self.rng.standard_normal(v.shape)
        if s.resolution_m > 0:
            v = np.round(v / s.resolution_m) * s.resolution_m
        return v
