"""Modal identification from a measured tip signal: frequency and damping with confidence intervals.

Pure functions on arrays (no ROS, no files), used alike by a live monitor, by bag replay and by the flutter-test
procedure. Two methods:

* **Output-only, covariance-driven SSI** (``identify_ssi``) for the response to turbulence (unmeasured,
  broadband excitation). The record is cut into segments; each segment contributes its output covariances
  (``output_covariances``, one FFT); the block-Toeplitz matrix of the averaged covariances gives a state-space
  model at every order of a stabilisation diagram (``ssi_poles``); the mode in each requested frequency band is
  the median of the *stable* poles across orders (``stable_poles``). The confidence interval is a jackknife over
  the segments (leave one segment's covariances out, re-identify). A live monitor keeps one covariance array per
  finished segment (``SegmentCovariances``): adding a segment costs one FFT, an identification a few small SVDs
  and eigenvalue problems (milliseconds), independent of the record length.
  Additive white sensor noise changes only the lag-0 covariance, which SSI-cov does not use.
* **Free decay after a tap** (``identify_free_decay``) for shaker data: ERA (eigensystem realisation) on the
  decay gives starting poles, a nonlinear least-squares fit of a sum of damped sinusoids refines them, and the
  interval comes from the fit's Jacobian and residual variance (white-noise assumption; with turbulence during the
  decay, repeat the tap and use ``combine_estimates`` over taps, whose scatter is honest).

Conventions (as ``panel_rig.analysis.vg``): pole s; natural frequency |s|/2pi; damping ratio -Re s/|s|.
Intervals are two-sided 95 % (Student t with the stated degrees of freedom).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.linalg
import scipy.signal
import scipy.stats
from scipy.optimize import least_squares

from panel_rig.analysis.vg import pole_damping_ratio, pole_frequency_hz, pole_from_modal

CI_LEVEL = 0.95


@dataclass(frozen=True)
class ModalEstimate:
    """Identified mode: point estimate, standard errors and the degrees of freedom behind them."""

    frequency_hz: float
    damping_ratio: float
    frequency_se_hz: float
    damping_se: float
    dof: int  # degrees of freedom of the standard errors (segments - 1, taps - 1, residual dof)
    method: str
    n_stable: int = 0  # SSI: stable poles behind the estimate (stabilisation diagram)

    @property
    def pole(self) -> complex:
        return complex(pole_from_modal(self.frequency_hz, self.damping_ratio))

    def _half(self, se: float, level: float) -> float:
        return float(scipy.stats.t.ppf(0.5 + level / 2, max(self.dof, 1)) * se)

    def damping_ci(self, level: float = CI_LEVEL) -> tuple[float, float]:
        h = self._half(self.damping_se, level)
        return self.damping_ratio - h, self.damping_ratio + h

    def frequency_ci_hz(self, level: float = CI_LEVEL) -> tuple[float, float]:
        """Normal interval of the frequency, its lower end at 0 Hz at least (a frequency is not negative)."""
        h = self._half(self.frequency_se_hz, level)
        return max(0.0, self.frequency_hz - h), self.frequency_hz + h

    def as_dict(self) -> dict:
        return {"frequency_hz": self.frequency_hz, "damping_ratio": self.damping_ratio,
                "frequency_ci_hz": list(self.frequency_ci_hz()), "damping_ci": list(self.damping_ci()),
                "frequency_se_hz": self.frequency_se_hz, "damping_se": self.damping_se, "dof": self.dof,
                "method": self.method, "n_stable": self.n_stable}


# ---- pre-processing --------------------------------------------------------------------------------
def decimate(y: np.ndarray, dt_s: float, max_rate_hz: float) -> tuple[np.ndarray, float]:
    """Low-pass (zero-phase FIR, so no filter poles enter the identification) and keep every q-th sample, with
    the largest integer q whose rate is still >= max_rate_hz. Returns (signal, new dt)."""
    y = np.asarray(y, float)
    q = int(np.floor(1.0 / (dt_s * max_rate_hz)))
    while q > 1:
        step = next(k for k in (8, 7, 6, 5, 4, 3, 2, q) if q % k == 0)  # stages of at most 8
        y = scipy.signal.decimate(y, step, ftype="fir", zero_phase=True, axis=0)
        dt_s *= step
        q //= step
    return y, dt_s


# ---- covariance-driven SSI ---------------------------------------------------------------------------
def output_covariances(y: np.ndarray, n_lags: int) -> np.ndarray:
    """Unbiased output covariances R_k = E[y_{t+k} y_t^T], k = 0 .. n_lags-1, of a (N,) or (N, l) record
    (mean removed), by FFT. Returns (n_lags, l, l)."""
    y = np.asarray(y, float)
    y = (y[:, None] if y.ndim == 1 else y) - np.mean(y, axis=0)
    N, nch = y.shape
    if N <= n_lags:
        raise ValueError(f"record of {N} samples is too short for {n_lags} lags")
    nfft = 1 << int(np.ceil(np.log2(N + n_lags)))
    Y = np.fft.rfft(y, nfft, axis=0)
    R = np.empty((n_lags, nch, nch))
    for a in range(nch):
        for b in range(nch):
            R[:, a, b] = np.fft.irfft(Y[:, a] * np.conj(Y[:, b]), nfft)[:n_lags]
    return R / (N - np.arange(n_lags))[:, None, None]


def ssi_poles(R: np.ndarray, dt_s: float, orders: Sequence[int], block_rows: int) -> dict[int, np.ndarray]:
    """Continuous-time poles (Im >= 0) of covariance-driven SSI at each model order.

    R: (>= 2*block_rows, l, l) output covariances. The block-Toeplitz matrix T = [R_{i+a-b}] (a, b = 0..i-1,
    lags 1..2i-1) factors as O C; O from its SVD truncated to the order, A from the shift of O."""
    i = block_rows
    if R.shape[0] < 2 * i:
        raise ValueError(f"need {2 * i} covariance lags for {i} block rows, got {R.shape[0]}")
    nch = R.shape[1]
    a = np.arange(i)
    # block (a, b) = R[i + a - b], gathered at once (np.block over i^2 blocks costs more than the SVD)
    T = R[i + a[:, None] - a[None, :]].transpose(0, 2, 1, 3).reshape(i * nch, i * nch)
    U, S, _ = np.linalg.svd(T)
    out = {}
    for n in orders:
        if n > U.shape[1]:
            break
        obs = U[:, :n] * np.sqrt(S[:n])
        A = np.linalg.lstsq(obs[:-nch], obs[nch:], rcond=None)[0]
        lam = np.linalg.eigvals(A)
        lam = lam[(np.abs(lam) > 1e-12) & (lam.imag >= 0)]
        out[n] = np.log(lam) / dt_s
    return out


def stable_poles(poles_by_order: dict[int, np.ndarray], band_hz: tuple[float, float], freq_tol: float = 0.01,
                 damping_tol: float = 0.05, damping_abs_tol: float = 0.002, max_damping: float = 0.8
                 ) -> np.ndarray:
    """Poles in the band that are stable in the stabilisation-diagram sense: a pole at the next lower order lies
    within freq_tol (relative) in frequency and max(damping_tol * |zeta|, damping_abs_tol) in damping ratio.
    Poles with |zeta| >= max_damping or on the real axis are discarded (noise modes)."""
    lo, hi = band_hz
    orders = sorted(poles_by_order)
    keep = []
    for prev, cur in zip(orders[:-1], orders[1:]):
        p, c = poles_by_order[prev], poles_by_order[cur]
        c = c[(c.imag > 0) & (pole_frequency_hz(c) >= lo) & (pole_frequency_hz(c) <= hi)
              & (np.abs(pole_damping_ratio(c)) < max_damping)]
        if c.size == 0 or p.size == 0:
            continue
        fp, zp = pole_frequency_hz(p), pole_damping_ratio(p)
        for s in c:
            f, z = pole_frequency_hz(s), pole_damping_ratio(s)
            ok = (np.abs(fp - f) <= freq_tol * f) & (np.abs(zp - z) <= max(damping_tol * abs(z), damping_abs_tol))
            if np.any(ok):
                keep.append(s)
    return np.array(keep, complex)


@dataclass
class SegmentCovariances:
    """Covariances of consecutive segments of one test point, kept for incremental SSI.

    A live monitor calls ``add`` with each finished segment (already decimated) and ``identify_ssi_covariances``
    when it wants an estimate; bag replay does the same over the whole plateau."""

    dt_s: float
    n_lags: int
    covs: list[np.ndarray] = field(default_factory=list)

    def add(self, segment: np.ndarray) -> None:
        self.covs.append(output_covariances(segment, self.n_lags))


@dataclass(frozen=True)
class SSISettings:
    """Defaults suit one sensor channel sampled at ~4-10 times the highest frequency of interest."""

    def rows(self, dt_s: float, bands_hz: Sequence[tuple[float, float]]) -> int:
        if self.block_rows is not None:
            return self.block_rows
        return max(40, int(np.ceil(1.0 / (dt_s * min(b[0] for b in bands_hz)))))


    #: block rows i of the Toeplitz matrix (lags 1 .. 2i-1); None: enough to span one period of the lowest band
    #: edge and at least 40 (a heavily damped low mode is biased when the lags cover less than its period)
    block_rows: int | None = None
    orders: tuple[int, ...] = tuple(range(4, 41, 2))
    n_segments: int = 10
    #: a mode needs stable poles at this fraction of the order steps at least (physical modes: nearly all;
    #: noise poles that happen to repeat: a few)
    min_stable_fraction: float = 0.3


def _band_estimate(poles_by_order: dict[int, np.ndarray], band: tuple[float, float], min_stable: int
                   ) -> tuple[complex, int] | None:
    st = stable_poles(poles_by_order, band)
    if st.size == 0 or st.size < min_stable:
        return None
    f, z = np.median(pole_frequency_hz(st)), np.median(pole_damping_ratio(st))
    return complex(pole_from_modal(f, z)), st.size


def identify_ssi_covariances(covs: Sequence[np.ndarray], dt_s: float, bands_hz: Sequence[tuple[float, float]],
                             settings: SSISettings = SSISettings()) -> list[ModalEstimate | None]:
    """SSI-cov on the mean of per-segment covariances; per band the stable-pole median and a leave-one-segment-
    out jackknife standard error (None for a band without a mode: fewer stable poles than
    ``settings.min_stable_fraction`` of the order steps)."""
    covs = np.asarray(covs)
    nseg = covs.shape[0]
    if nseg < 2:
        raise ValueError("need at least two segments for an interval")

    def run(R: np.ndarray) -> list[tuple[complex, int] | None]:
        pbo = ssi_poles(R, dt_s, settings.orders, min(settings.rows(dt_s, bands_hz), R.shape[0] // 2))
        min_stable = int(np.ceil(settings.min_stable_fraction * (len(pbo) - 1)))
        return [_band_estimate(pbo, b, min_stable) for b in bands_hz]

    full = run(covs.mean(axis=0))
    total = covs.sum(axis=0)
    jack = [run((total - covs[k]) / (nseg - 1)) for k in range(nseg)]
    out: list[ModalEstimate | None] = []
    for b, est in enumerate(full):
        if est is None:
            out.append(None)
            continue
        reps = np.array([j[b][0] for j in jack if j[b] is not None])
        if reps.size < 2:
            out.append(None)
            continue
        m = reps.size
        f_se = np.sqrt((m - 1) / m * np.sum((pole_frequency_hz(reps) - pole_frequency_hz(reps).mean()) ** 2))
        z_se = np.sqrt((m - 1) / m * np.sum((pole_damping_ratio(reps) - pole_damping_ratio(reps).mean()) ** 2))
        out.append(ModalEstimate(float(pole_frequency_hz(est[0])), float(pole_damping_ratio(est[0])), float(f_se),
                                 float(z_se), m - 1, "ssi-cov", est[1]))
    return out


def identify_ssi(y: np.ndarray, dt_s: float, bands_hz: Sequence[tuple[float, float]],
                 settings: SSISettings = SSISettings(), max_rate_hz: float | None = None
                 ) -> list[ModalEstimate | None]:
    """Output-only identification of the mode in each band from a response record (e.g. the tip under
    turbulence). Each band is processed on its own: decimated to the lowest integer-factor rate >= ``max_rate_hz``
    (default 8 x the band's upper edge), cut into ``settings.n_segments`` equal segments, one covariance array per
    segment (as a live monitor keeps them, see SegmentCovariances), then identify_ssi_covariances. Per-band rates
    keep a lightly damped mode well resolved by 40-odd block rows. A heavily damped mode (zeta ~ 0.4) needs a
    higher rate than 8 x its band (its covariance dies within 1/(zeta omega): pass ``max_rate_hz`` ~ 50-60 x its
    frequency) and even then its estimate scatters by ~5-10 % from a 600 s record (docs/validation.md)."""
    y = _finite_record(y)
    out: list[ModalEstimate | None] = []
    for band in bands_hz:
        yb, dtb = decimate(y, dt_s, max_rate_hz if max_rate_hz is not None else 8.0 * band[1])
        n = yb.shape[0] // settings.n_segments
        acc = SegmentCovariances(dtb, 2 * settings.rows(dtb, [band]))
        for k in range(settings.n_segments):
            acc.add(yb[k * n : (k + 1) * n])
        out += identify_ssi_covariances(acc.covs, dtb, [band], settings)
    return out


def _finite_record(y: np.ndarray) -> np.ndarray:
    """``y`` as floats; a ValueError naming the first non-finite sample (one NaN gave LinAlgError from deep in the
    SVD: "SVD did not converge")."""
    y = np.asarray(y, float)
    bad = np.flatnonzero(~np.isfinite(y.reshape(y.shape[0], -1)).all(axis=1)) if y.size else np.array([], int)
    if bad.size:
        raise ValueError(f"record has {bad.size} non-finite sample(s) (NaN or inf), the first at index {bad[0]}")
    return y


# ---- free decay ---------------------------------------------------------------------------------------
def era_poles(y: np.ndarray, dt_s: float, order: int, rows: int | None = None) -> np.ndarray:
    """Eigensystem realisation on a free response y (1-D): poles (Im >= 0, real ones included) of a model of the
    given order."""
    y = np.asarray(y, float)
    rows = rows if rows is not None else min(max(2 * order, y.size // 3), 6 * order)
    cols = min(y.size - rows, 10 * rows)  # ERA only starts the least-squares fit: a small Hankel matrix is enough
    if cols < order + 1:
        raise ValueError("free-decay record too short for ERA")
    H = scipy.linalg.hankel(y[:rows], y[rows - 1 : rows - 1 + cols])
    U, S, Vt = np.linalg.svd(H[:-1], full_matrices=False)
    obs = U[:, :order] * np.sqrt(S[:order])
    A = np.linalg.lstsq(obs[:-1], obs[1:], rcond=None)[0]
    lam = np.linalg.eigvals(A)
    lam = lam[(np.abs(lam) > 1e-12) & (lam.imag >= 0) & ~((lam.imag == 0) & (lam.real < 0))]
    return np.log(lam.astype(complex)) / dt_s


def _decay_model(p: np.ndarray, t: np.ndarray, n: int, r: int) -> np.ndarray:
    """n damped sinusoids exp(-sigma t)(a cos wt + b sin wt), r real exponentials c exp(-rho t) and an offset;
    p = (sigma, w, a, b) * n, (rho, c) * r, offset."""
    out = np.full_like(t, p[-1])
    for m in range(n):
        sig, w, a, b = p[4 * m : 4 * m + 4]
        out += np.exp(-sig * t) * (a * np.cos(w * t) + b * np.sin(w * t))
    for k in range(r):
        rho, c = p[4 * n + 2 * k : 4 * n + 2 * k + 2]
        out += c * np.exp(-rho * t)
    return out


def _decay_jacobian(p: np.ndarray, t: np.ndarray, n: int, r: int) -> np.ndarray:
    J = np.empty((t.size, p.size))
    J[:, -1] = 1.0
    for m in range(n):
        sig, w, a, b = p[4 * m : 4 * m + 4]
        e = np.exp(-sig * t)
        c, s = np.cos(w * t), np.sin(w * t)
        J[:, 4 * m] = -t * e * (a * c + b * s)
        J[:, 4 * m + 1] = t * e * (b * c - a * s)
        J[:, 4 * m + 2] = e * c
        J[:, 4 * m + 3] = e * s
    for k in range(r):
        rho, c = p[4 * n + 2 * k : 4 * n + 2 * k + 2]
        e = np.exp(-rho * t)
        J[:, 4 * n + 2 * k] = -t * c * e
        J[:, 4 * n + 2 * k + 1] = e
    return J


def identify_free_decay(y: np.ndarray, dt_s: float, bands_hz: Sequence[tuple[float, float]],
                        max_rate_hz: float | None = None, orders: Sequence[int] = (12, 16, 20),
                        min_amplitude: float = 0.02) -> list[ModalEstimate | None]:
    """Modes in the given bands from a free decay (the samples after a tap has ended, y[0] = first free sample).

    ERA at each of ``orders`` gives starting poles. Every oscillatory ERA pole with damping ratio in (-0.5, 0.8), and every
    real (non-oscillatory, e.g. aerodynamic-lag) pole, whose initial amplitude is at least ``min_amplitude`` of the
    largest, is kept in a nonlinear least-squares fit of damped sinusoids, real exponentials and an offset, so that
    the other modes do not bias the ones of interest. The band's pole comes with standard errors from the
    Jacobian and the residual variance (white-noise assumption), dof = samples - parameters. Of the fits from the
    ERA orders (multi-start against local minima) the one with the smallest residual is kept.

    ``max_rate_hz`` (default 16 x the highest band edge): keep every q-th sample, the largest q whose rate is still
    >= it (physical modes above the new Nyquist frequency must be absent or filtered by the sensor).
    """
    y = _finite_record(y)
    rate = max_rate_hz if max_rate_hz is not None else 16.0 * max(b[1] for b in bands_hz)
    q = max(1, int(np.floor(1.0 / (dt_s * rate))))
    # plain subsampling, no anti-alias filter: a filter's start-up transient would distort the first (and, for a
    # heavily damped mode, the only informative) part of the decay; white sensor noise stays white when folded
    y, dt_s = y[::q], dt_s * q
    best = None
    for order in orders:
        fit = _fit_decay(y, dt_s, order, min_amplitude)
        if fit is not None and (best is None or fit[0] < best[0]):
            best = fit
    if best is None:
        return [None] * len(bands_hz)
    _, x, cov, n, dof = best
    out: list[ModalEstimate | None] = []
    for lo, hi in bands_hz:
        pick = None
        for m in range(n):
            s = complex(-x[4 * m], abs(x[4 * m + 1]))
            amp = np.hypot(x[4 * m + 2], x[4 * m + 3])
            if lo <= pole_frequency_hz(s) <= hi and (pick is None or amp > pick[1]):
                pick = (m, amp, s)
        if pick is None:
            out.append(None)
            continue
        m, _, s = pick
        # delta method from (sigma, omega_d) to (f_n, zeta)
        sig, w = -s.real, s.imag
        wn = np.hypot(sig, w)
        J = np.array([[sig / wn / (2 * np.pi), w / wn / (2 * np.pi)],
                      [w * w / wn**3, -sig * w / wn**3]])
        V = J @ cov[4 * m : 4 * m + 2, 4 * m : 4 * m + 2] @ J.T
        out.append(ModalEstimate(float(wn / (2 * np.pi)), float(sig / wn), float(np.sqrt(V[0, 0])),
                                 float(np.sqrt(V[1, 1])), int(dof), "free-decay"))
    return out


def _fit_decay(y: np.ndarray, dt_s: float, order: int, min_amplitude: float
               ) -> tuple[float, np.ndarray, np.ndarray, int, int] | None:
    """ERA start + nonlinear least squares; (cost, parameters, covariance, oscillatory terms, dof) or None."""
    t = np.arange(y.size) * dt_s
    poles = era_poles(y - y[-y.size // 10 :].mean(), dt_s, order)
    f_min = 0.5 / (t[-1] + dt_s)
    real = poles[(np.abs(poles.imag) < 1e-9) & (poles.real < -1.0 / (t[-1] + dt_s))]
    osc = poles[poles.imag > 1e-9]
    zeta = pole_damping_ratio(osc)
    osc = osc[(zeta > -0.5) & (zeta < 0.8) & (pole_frequency_hz(osc) > f_min)]
    # linear amplitudes for the ERA poles, then the full nonlinear fit
    basis = []
    for s in osc:
        e = np.exp(s.real * t)
        basis += [e * np.cos(s.imag * t), e * np.sin(s.imag * t)]
    basis += [np.exp(s.real * t) for s in real] + [np.ones_like(t)]
    coef = np.linalg.lstsq(np.array(basis).T, y, rcond=None)[0]
    # keep the poles that carry the response (noise poles of the over-sized ERA model have tiny amplitudes)
    amp_osc = np.hypot(coef[0 : 2 * osc.size : 2], coef[1 : 2 * osc.size : 2])
    amp_real = np.abs(coef[2 * osc.size : -1])
    top = max(amp_osc.max(initial=0.0), amp_real.max(initial=0.0))
    if top == 0:
        return None
    keep_o, keep_r = amp_osc >= min_amplitude * top, amp_real >= min_amplitude * top
    ab = np.column_stack([coef[0 : 2 * osc.size : 2], coef[1 : 2 * osc.size : 2]])[keep_o]
    osc, real, c_real = osc[keep_o], real[keep_r], coef[2 * osc.size : -1][keep_r]
    n, r = osc.size, real.size
    if n == 0:
        return None
    p0 = []
    for s, (a, b) in zip(osc, ab):
        p0 += [-s.real, s.imag, a, b]
    for s, c in zip(real, c_real):
        p0 += [-s.real, c]
    p0 = np.array(p0 + [coef[-1]])
    with np.errstate(over="ignore", invalid="ignore"):
        fit = least_squares(lambda p: _decay_model(p, t, n, r) - y, p0, jac=lambda p: _decay_jacobian(p, t, n, r),
                            method="lm", x_scale="jac")
    if not np.all(np.isfinite(fit.x)):
        return None
    dof = y.size - p0.size
    s2 = float(np.sum(fit.fun**2) / max(dof, 1))
    cov = np.linalg.pinv(fit.jac.T @ fit.jac) * s2
    return float(fit.cost), fit.x, cov, n, dof


def combine_estimates(estimates: Sequence[ModalEstimate], method: str | None = None) -> ModalEstimate:
    """Mean of repeated independent estimates (e.g. several taps), standard error from their scatter."""
    est = list(estimates)
    if len(est) < 2:
        raise ValueError("need at least two estimates to combine")
    f = np.array([e.frequency_hz for e in est])
    z = np.array([e.damping_ratio for e in est])
    k = len(est)
    return ModalEstimate(float(f.mean()), float(z.mean()), float(f.std(ddof=1) / np.sqrt(k)),
                         float(z.std(ddof=1) / np.sqrt(k)), k - 1, method or est[0].method + "-combined")
