"""Freestream turbulence of the tunnel: a seeded random gust field, frozen (Taylor) and convected at the airspeed.

Two components at the airfoil leading edge, independent of each other (isotropic turbulence):
  u' streamwise (the airspeed of the step is U + u')     w' vertical (upwash, positive up)
with standard deviation sigma = intensity * U each and the spectra, in spatial frequency Omega = omega / U (rad/m),
L the longitudinal integral scale (``tunnel.turbulence.length_scale_m``; the vertical integral scale is L / 2):

  Dryden      Phi_u = sigma^2 (2L/pi) / (1 + (L Omega)^2)
              Phi_w = sigma^2 (L/pi) (1 + 3 (L Omega)^2) / (1 + (L Omega)^2)^2
  von Karman  Phi_u = sigma^2 (2L/pi) / (1 + (a L Omega)^2)^(5/6)                          a = 1.339
              Phi_w = sigma^2 (L/pi) (1 + 8/3 (a L Omega)^2) / (1 + (a L Omega)^2)^(11/6)

Both are sums of independent isotropic Dryden components with scales L_k and variance fractions c_k (sum 1):
Dryden is one component, von Karman a fixed fit of 6 components (max error 2.0 % in Phi_u and Phi_w for
L Omega in 1e-3..1e3; six, not more, because each costs three normal draws per step). For an isotropic field
Phi_w = (Phi_u - Omega dPhi_u/dOmega) / 2, so the same c_k serve both components.

Each Dryden component is advanced by its exact discrete-time solution over the step dt with tau = L_k / U:
u: AR(1) with a = exp(-dt/tau); w: the filter (1 + sqrt(3) tau s) / (1 + tau s)^2 as two cascaded lags with the
exact transition and the noise covariance P - Phi P Phi^T of the stationary covariance P. The sampled series
therefore has the continuous process's statistics for any dt (and any U).

Frozen field: the gust at chordwise position x is the leading-edge series delayed by x / U (linear interpolation
between steps), so the phase lag along the chord is physical. The seed fixes the series: the same seed and the same
airspeed history give the same field, whatever the block sizes it is drawn in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numba import njit

SPECTRA: tuple[str, ...] = ("dryden", "von_karman", "off")
VK_A = 1.339
#: log10(L_k / L) of the von Karman fit: six scales placed once by minimising (Nelder-Mead) the largest relative
#: error of both spectra over L Omega = 1e-3..1e3, the weights by non-negative least squares (max error 2.0 %)
VK_LOG_SCALES = (-4.281, -2.724, -1.876, -1.043, -0.225, 0.135)
#: below this airspeed the convection delay is capped (sigma = intensity * U is ~0 there anyway)
MIN_CONVECTION_SPEED_MPS = 0.5


@dataclass(frozen=True)
class TurbulenceSettings:
    """``tunnel.turbulence.*``: intensity sigma / U, integral length scale L (m), spectrum, seed."""

    intensity: float = 0.0
    length_scale_m: float = 0.1
    spectrum: str = "dryden"
    seed: int = 0

    @property
    def on(self) -> bool:
        return self.spectrum != "off" and self.intensity > 0

    @staticmethod
    def from_config(cfg) -> "TurbulenceSettings":
        return TurbulenceSettings(cfg.turbulence_intensity, cfg.turbulence_length_scale_m, cfg.turbulence_spectrum,
                                  cfg.turbulence_seed)


# ---- target spectra ------------------------------------------------------------------------------------------
def _dryden_u(x: np.ndarray) -> np.ndarray:
    return 2.0 / np.pi / (1.0 + x**2)


def _dryden_w(x: np.ndarray) -> np.ndarray:
    return (1.0 + 3.0 * x**2) / (1.0 + x**2) ** 2 / np.pi


def _vk_u(x: np.ndarray) -> np.ndarray:
    return 2.0 / np.pi / (1.0 + (VK_A * x) ** 2) ** (5.0 / 6.0)


def _vk_w(x: np.ndarray) -> np.ndarray:
    y = (VK_A * x) ** 2
    return (1.0 + 8.0 / 3.0 * y) / (1.0 + y) ** (11.0 / 6.0) / np.pi


def target_psd(spectrum: str, component: str, sigma: float, length_m: float, airspeed_mps: float,
               f_hz: np.ndarray) -> np.ndarray:
    """One-sided PSD in (m/s)^2 / Hz at frequency f of the time series at a fixed point (Taylor: Omega = 2 pi f / U)."""
    x = 2.0 * np.pi * np.asarray(f_hz, dtype=float) / airspeed_mps * length_m
    shape = {("dryden", "u"): _dryden_u, ("dryden", "w"): _dryden_w,
             ("von_karman", "u"): _vk_u, ("von_karman", "w"): _vk_w}[(spectrum, component)]
    return sigma**2 * length_m * shape(x) * 2.0 * np.pi / airspeed_mps


@lru_cache(maxsize=None)
def components(spectrum: str) -> tuple[np.ndarray, np.ndarray]:
    """(L_k / L, c_k): the Dryden components of a spectrum (variance fractions summing to 1)."""
    if spectrum == "dryden":
        return np.array([1.0]), np.array([1.0])
    if spectrum != "von_karman":
        raise ValueError(f"spectrum must be one of {SPECTRA[:2]} here, got {spectrum!r}")
    from scipy.optimize import nnls

    x = np.logspace(-3, 3, 400)  # L Omega
    scales = 10.0 ** np.array(VK_LOG_SCALES)
    Au = np.array([s * _dryden_u(x * s) for s in scales]).T / _vk_u(x)[:, None]
    Aw = np.array([s * _dryden_w(x * s) for s in scales]).T / _vk_w(x)[:, None]
    c, _ = nnls(np.vstack([Au, Aw]), np.ones(2 * x.size))
    keep = c > 0
    return scales[keep], c[keep] / np.sum(c[keep])


# ---- the compiled recursions -----------------------------------------------------------------------------------
@njit(cache=True)
def _generate(U_seq, dt, scales_m, amp, rng, y_u, y_w1, y_w2, out_u, out_w):
    """Advance every component over len(U_seq) steps; unit-intensity u'/U and w'/U at the end of each step.

    rng: the field's numpy Generator, three standard normal draws per component and step, drawn here in the order
    of ``rng.standard_normal((n, K, 3))`` (numba's Generator draws are numpy's, bit for bit, and advance its state
    alike; drawing here saves numpy's array round trip, ~0.1 us a step of the 18 von Karman draws);
    y_* (K,) normalised states (unit stationary variance of u, of w's output).
    The exact transition and noise factors depend on U dt / L_k only: recomputed when the airspeed changes."""
    s3 = math.sqrt(3.0)
    cw1 = s3 / math.sqrt(2.0)
    cw2 = (1.0 - s3) / math.sqrt(2.0)
    K = scales_m.shape[0]
    e = np.zeros(K)
    eh = np.zeros(K)
    gu = np.zeros(K)
    l11 = np.zeros(K)
    l21 = np.zeros(K)
    l22 = np.zeros(K)
    U_prev = -1.0
    for i in range(U_seq.shape[0]):
        U = U_seq[i]
        if U != U_prev:
            for k in range(K):
                h = U * dt / scales_m[k]
                ek = math.exp(-h)
                e[k] = ek
                eh[k] = ek * h
                gu[k] = math.sqrt(max(1.0 - ek * ek, 0.0))  # u: AR(1)
                # w: cascade x1' = (-x1 + n)/tau, x2' = (-x2 + x1)/tau; normalised stationary P = [[1, 1/2], [1/2, 1/2]],
                # transition e^{-h} [[1, 0], [h, 1]], noise covariance Q = P - Phi P Phi^T, Cholesky factor (l11, l21, l22)
                q11 = 1.0 - ek * ek
                q12 = 0.5 - ek * ek * (h + 0.5)
                q22 = 0.5 - ek * ek * (h * h + h + 0.5)
                a = math.sqrt(max(q11, 0.0))
                b = q12 / a if a > 0 else 0.0
                l11[k] = a
                l21[k] = b
                l22[k] = math.sqrt(max(q22 - b * b, 0.0))
            U_prev = U
        su = 0.0
        sw = 0.0
        for k in range(K):
            n0 = rng.standard_normal()
            n1 = rng.standard_normal()
            n2 = rng.standard_normal()
            y_u[k] = e[k] * y_u[k] + gu[k] * n0
            x1 = e[k] * y_w1[k]
            x2 = eh[k] * y_w1[k] + e[k] * y_w2[k]
            y_w1[k] = x1 + l11[k] * n1
            y_w2[k] = x2 + l21[k] * n1 + l22[k] * n2
            su += amp[k] * y_u[k]
            sw += amp[k] * (cw1 * y_w1[k] + cw2 * y_w2[k])
        out_u[i] = su
        out_w[i] = sw


@njit(cache=True)
def _convect(U_seq, dt, x_m, x_u_m, hist_u, hist_w, head, src_u, src_w, out_u, out_w, min_speed):
    """Frozen field: at step i the value at x is the leading-edge series delayed by x / U (linear interpolation in
    a ring buffer of past leading-edge values). Returns the new head. Delays are recomputed when U changes.

    The ring buffers hold H = len / 2 values twice (at head and head + H), so the delayed pair (base - n, base - n - 1)
    with base = head + H never wraps: no branch in the loop over the collocation points."""
    H = hist_w.shape[0] // 2
    m = x_m.shape[0]
    n0 = np.zeros(m + 1, np.int64)
    fr = np.zeros(m + 1)
    U_prev = -1.0
    for i in range(U_seq.shape[0]):
        head += 1
        if head == H:
            head = 0
        hist_u[head] = src_u[i]
        hist_u[head + H] = src_u[i]
        hist_w[head] = src_w[i]
        hist_w[head + H] = src_w[i]
        if U_seq[i] != U_prev:
            U_prev = U_seq[i]
            speed = max(U_prev, min_speed)
            for j in range(m + 1):
                d = min((x_m[j] if j < m else x_u_m) / (speed * dt), H - 2.0)
                n0[j] = int(math.floor(d))
                fr[j] = d - n0[j]
        base = head + H
        for j in range(m):
            a = base - n0[j]
            out_w[i, j] = (1.0 - fr[j]) * hist_w[a] + fr[j] * hist_w[a - 1]
        a = base - n0[m]
        out_u[i] = (1.0 - fr[m]) * hist_u[a] + fr[m] * hist_u[a - 1]
    return head


class Turbulence:
    """The seeded gust field over airfoil + panel, advanced in blocks of physics steps.

    ``block(U_seq)`` returns (u' at mid-chord (n,), w' at the collocation points (n, km)), in m/s, for the end of
    each step, with sigma = intensity * U of each step. ``reference(U_seq)`` returns the leading-edge series only.
    """

    def __init__(self, settings: TurbulenceSettings, dt_s: float, x_colloc_m: np.ndarray, chord_m: float):
        self.settings = settings
        self.dt_s = float(dt_s)
        self.x_colloc_m = np.ascontiguousarray(x_colloc_m, dtype=float)
        self.x_u_m = 0.5 * float(chord_m)
        self.on = settings.on
        if self.on:
            rel, c = components(settings.spectrum)
            self.scales_m = rel * settings.length_scale_m
            self.amp = np.sqrt(c)
        else:
            self.scales_m = np.zeros(0)
            self.amp = np.zeros(0)
        n_hist = int(math.ceil(chord_m / (MIN_CONVECTION_SPEED_MPS * self.dt_s))) + 4
        self._hist_u = np.zeros(2 * n_hist)  # each value twice, see _convect
        self._hist_w = np.zeros(2 * n_hist)
        self._warm()
        self.reset()

    def _warm(self) -> None:
        """Compile (or load from numba's cache) the recursions now, not inside the rig's first tick."""
        one, k = np.ones(1), max(self.scales_m.shape[0], 1)
        z = np.zeros(k)
        _generate(one, self.dt_s, np.ones(k), z, np.random.default_rng(0), z.copy(), z.copy(), z.copy(), np.zeros(1),
                  np.zeros(1))
        _convect(one, self.dt_s, self.x_colloc_m, self.x_u_m, np.zeros(8), np.zeros(8), 0, np.zeros(1), np.zeros(1),
                 np.zeros(1), np.zeros((1, self.x_colloc_m.shape[0])), MIN_CONVECTION_SPEED_MPS)

    def reset(self) -> None:
        """Back to the seed's start: the same series again."""
        self.rng = np.random.Generator(np.random.PCG64(self.settings.seed))
        k = self.scales_m.shape[0]
        # start in the stationary distribution (no transient): y_u ~ N(0, 1), (y_w1, y_w2) ~ N(0, P)
        z = self.rng.standard_normal((3, k))
        self._y_u = z[0].copy()
        self._y_w1 = z[1].copy()
        self._y_w2 = 0.5 * z[1] + 0.5 * z[2]  # P = [[1, 1/2], [1/2, 1/2]] = L L^T with L = [[1, 0], [1/2, 1/2]]
        self._hist_u[:] = 0.0
        self._hist_w[:] = 0.0
        self._head = 0
        self._primed = False

    def snapshot(self) -> tuple:
        """Everything that determines the future field (to replay a block)."""
        return (self.rng.bit_generator.state, self._y_u.copy(), self._y_w1.copy(), self._y_w2.copy(),
                self._hist_u.copy(), self._hist_w.copy(), self._head, self._primed)

    def restore(self, snap: tuple) -> None:
        state, yu, yw1, yw2, hu, hw, head, primed = snap
        self.rng.bit_generator.state = state
        self._y_u[:], self._y_w1[:], self._y_w2[:], self._hist_u[:], self._hist_w[:] = yu, yw1, yw2, hu, hw
        self._head, self._primed = head, primed

    def reference(self, U_seq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """u', w' (m/s) at the leading edge at the end of each step."""
        U = np.ascontiguousarray(U_seq, dtype=float)
        n = U.shape[0]
        out_u, out_w = np.zeros(n), np.zeros(n)
        if not self.on or n == 0:
            return out_u, out_w
        _generate(U, self.dt_s, self.scales_m, self.amp, self.rng, self._y_u, self._y_w1, self._y_w2, out_u, out_w)
        sigma = self.settings.intensity * U
        return out_u * sigma, out_w * sigma

    def block(self, U_seq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """u' at mid-chord (n,) and w' at the collocation points (n, km), m/s, at the end of each step."""
        U = np.ascontiguousarray(U_seq, dtype=float)
        n = U.shape[0]
        out_u, out_w = np.zeros(n), np.zeros((n, self.x_colloc_m.shape[0]))
        if not self.on or n == 0:
            return out_u, out_w
        if not self._primed:  # the field already over the chord at start: run the process for one transit first
            lead = min(int(math.ceil(self.x_colloc_m[-1] / (max(U[0], MIN_CONVECTION_SPEED_MPS) * self.dt_s))) + 2,
                       self._hist_w.shape[0] // 2 - 1)
            lu, lw = self.reference(np.full(lead, U[0]))
            self._head = _convect(np.full(lead, U[0]), self.dt_s, self.x_colloc_m[:0], self.x_u_m, self._hist_u,
                                  self._hist_w, self._head, lu, lw, np.zeros(lead), np.zeros((lead, 0)),
                                  MIN_CONVECTION_SPEED_MPS)
            self._primed = True
        src_u, src_w = self.reference(U)
        self._head = _convect(U, self.dt_s, self.x_colloc_m, self.x_u_m, self._hist_u, self._hist_w, self._head,
                              src_u, src_w, out_u, out_w, MIN_CONVECTION_SPEED_MPS)
        return out_u, out_w
