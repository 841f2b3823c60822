"""Flutter-boundary predictors from subcritical test points: damping-trend extrapolation and the
Zimmerman–Weissenburger flutter margin, each with a parametric-bootstrap interval.

Pure functions on arrays. Inputs are the test points' airspeeds and the identified modes
(``panel_rig.analysis.identification.ModalEstimate``: frequency, damping ratio and their standard errors).

**Damping trend.** Fit the flutter mode's damping ratio against dynamic pressure, zeta(q) with q ∝ U^2, by a
polynomial (default degree 2) and take the lowest root above the fastest test point. A straight line in U is the
classic choice but fails on this panel: the flutter mode's damping first *rises* with airspeed (aerodynamic
damping) and then falls (the "hump"), so a line through 0.5–0.9 U_f overshoots U_f by ~30 % even on the model's
exact poles; a quadratic in U is 1–3 % off, a quadratic in q 0.1–0.6 % (table in docs/validation.md): the
aerodynamic terms scale with q, so zeta is smoother in q.

**Zimmerman–Weissenburger flutter margin** (Zimmerman & Weissenburger 1964, J. Aircraft 1(4):190–202). For two
modes with poles -beta_i ± i omega_i (beta = decay rate = zeta omega_n, omega = damped frequency) the quartic
p(s) = (s^2 + 2 beta_1 s + beta_1^2 + omega_1^2)(s^2 + 2 beta_2 s + beta_2^2 + omega_2^2) = s^4 + a1 s^3 + a2 s^2
+ a3 s + a4 is Hurwitz-stable iff (all a_i > 0 and) the Routh term Delta_3 = a1 a2 a3 - a3^2 - a1^2 a4 > 0. The
flutter margin is F = Delta_3 / a1^2 = a2 (a3/a1) - (a3/a1)^2 - a4, which expands to

    F = [ (omega2^2 - omega1^2)/2 + (beta2^2 - beta1^2)/2 ]^2
        + 4 beta1 beta2 [ (omega2^2 + omega1^2)/2 + 2 ((beta1 + beta2)/2)^2 ]
        - [ (beta2 - beta1)/(beta2 + beta1) (omega2^2 - omega1^2)/2 + 2 ((beta1 + beta2)/2)^2 ]^2

(checked in tests/test_identification.py against Delta_3/a1^2 of the expanded quartic). F = 0 exactly when one of
the two poles reaches the imaginary axis. Public code often carries "- 2((beta1+beta2)/2)^2" inside the last
bracket (the sign of its second term flipped); that F does not vanish at flutter. For a binary system with
quasi-steady aerodynamics F is a quadratic in dynamic pressure q = rho U^2 / 2 (ZW 1964), so F is fitted against
U^2 (the density cancels in the root) and its lowest root above the fastest test point is the predicted flutter
speed. Default degree 1: on this panel (unsteady aero, three modes) F(q) is close to a line over 0.5–0.9 U_f
(exact poles: 0.3–0.5 % error, quadratic 0.3–3 %), and the quadratic coefficient amplifies identification errors of
the heavily damped first mode (measured in docs/validation.md).

**Uncertainty.** Parametric bootstrap: each test point's frequency and damping are redrawn from normal
distributions with the identified standard errors, the fit and root are repeated, and the 2.5 / 97.5 percentiles
of the roots give the interval (a draw with no crossing counts as +inf, so an open upper bound shows).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from panel_rig.analysis.identification import ModalEstimate
from panel_rig.analysis.vg import pole_from_modal

CI_LEVEL = 0.95


@dataclass(frozen=True)
class BoundaryPrediction:
    """Predicted flutter speed (inf when the fitted trend does not cross zero) and its bootstrap interval."""

    speed_mps: float
    ci_mps: tuple[float, float]
    method: str
    degree: int
    samples_mps: np.ndarray = field(repr=False)

    def margin(self, airspeed_mps: float) -> float:
        """Speed margin 1 - U / U_f_predicted at an airspeed (1 when no crossing is predicted)."""
        return float(1.0 - airspeed_mps / self.speed_mps) if np.isfinite(self.speed_mps) else 1.0

    def as_dict(self) -> dict:
        """JSON-ready: an infinite speed or interval bound (no crossing: the bound is open) as None (null)."""
        return {"predicted_flutter_speed_mps": finite_or_none(self.speed_mps),
                "predicted_flutter_speed_ci_mps": [finite_or_none(x) for x in self.ci_mps],
                "method": self.method, "degree": self.degree}


def finite_or_none(x: float) -> float | None:
    """A number for JSON: None (null) when it is not a finite number (an open interval bound, no predicted crossing,
    a value missing from a message)."""
    return float(x) if isinstance(x, (int, float, np.number)) and np.isfinite(x) else None


def zimmerman_weissenburger(s1: np.ndarray | complex, s2: np.ndarray | complex) -> np.ndarray:
    """Flutter margin F of two modes from their (upper-half-plane) poles s = -beta + i omega (vectorised)."""
    s1, s2 = np.asarray(s1), np.asarray(s2)
    b1, b2, w1, w2 = -s1.real, -s2.real, np.abs(s1.imag), np.abs(s2.imag)
    bm = 0.5 * (b1 + b2)
    dw = 0.5 * (w2**2 - w1**2)
    return ((dw + 0.5 * (b2**2 - b1**2)) ** 2 + 4 * b1 * b2 * (0.5 * (w2**2 + w1**2) + 2 * bm**2)
            - ((b2 - b1) / (b2 + b1) * dw + 2 * bm**2) ** 2)


def flutter_margins(mode_a: Sequence[ModalEstimate], mode_b: Sequence[ModalEstimate]) -> np.ndarray:
    """ZW flutter margin F ((rad/s)^4) of each test point from its identified modes a and b."""
    pa = pole_from_modal([e.frequency_hz for e in mode_a], [e.damping_ratio for e in mode_a])
    pb = pole_from_modal([e.frequency_hz for e in mode_b], [e.damping_ratio for e in mode_b])
    return zimmerman_weissenburger(pa, pb)


def extrapolated_root(x: np.ndarray, y: np.ndarray, degree: int) -> float:
    """Lowest real root above max(x) of the least-squares polynomial of y(x); inf if there is none."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.size < degree + 1:
        raise ValueError(f"a degree-{degree} fit needs at least {degree + 1} points, got {x.size}")
    scale = np.max(np.abs(x))
    c = np.polyfit(x / scale, y, degree)
    r = np.roots(c)
    r = r[np.abs(r.imag) < 1e-9].real * scale
    r = r[r > np.max(x)]
    return float(r.min()) if r.size else float("inf")


def damping_trend_speed(airspeeds_mps: np.ndarray, damping_ratio: np.ndarray, degree: int = 2) -> float:
    """Flutter speed where the damping-ratio trend, fitted against U^2 (dynamic pressure), reaches zero (inf if it
    does not)."""
    u = np.asarray(airspeeds_mps, float)
    return float(np.sqrt(extrapolated_root(u**2, damping_ratio, degree)))


def flutter_margin_speed(airspeeds_mps: np.ndarray, poles_a: np.ndarray, poles_b: np.ndarray,
                         degree: int = 1) -> float:
    """Flutter speed where the fitted ZW margin F(U^2) of modes a, b reaches zero (inf if it does not)."""
    u = np.asarray(airspeeds_mps, float)
    F = zimmerman_weissenburger(np.asarray(poles_a), np.asarray(poles_b))
    return float(np.sqrt(extrapolated_root(u**2, F, degree)))


def _percentiles(samples: np.ndarray, level: float) -> tuple[float, float]:
    # no interpolation between order statistics: draws with no crossing (inf, or nan) give an open (inf) bound
    finite = np.nan_to_num(samples, nan=np.inf, posinf=np.inf)
    lo, hi = np.quantile(finite, [0.5 * (1 - level), 0.5 * (1 + level)], method="inverted_cdf")
    return float(lo), float(hi)


def _draw(est: Sequence[ModalEstimate], rng: np.random.Generator, n: int) -> np.ndarray:
    f = np.array([e.frequency_hz for e in est])
    z = np.array([e.damping_ratio for e in est])
    fs = np.array([e.frequency_se_hz for e in est])
    zs = np.array([e.damping_se for e in est])
    fd = f + fs * rng.standard_normal((n, f.size))
    zd = np.clip(z + zs * rng.standard_normal((n, z.size)), -0.99, 0.99)
    return fd, zd


def predict_by_damping_trend(airspeeds_mps: Sequence[float], flutter_mode: Sequence[ModalEstimate],
                             degree: int = 2, n_boot: int = 2000, rng: np.random.Generator | None = None,
                             level: float = CI_LEVEL) -> BoundaryPrediction:
    """Damping-trend extrapolation of the flutter mode with a parametric-bootstrap interval."""
    u = np.asarray(airspeeds_mps, float)
    rng = rng if rng is not None else np.random.default_rng(0)
    z = np.array([e.damping_ratio for e in flutter_mode])
    point = damping_trend_speed(u, z, degree)
    _, zd = _draw(flutter_mode, rng, n_boot)
    samples = np.array([damping_trend_speed(u, zz, degree) for zz in zd])
    return BoundaryPrediction(point, _percentiles(samples, level), "damping-trend", degree, samples)


def predict_by_flutter_margin(airspeeds_mps: Sequence[float], mode_a: Sequence[ModalEstimate],
                              mode_b: Sequence[ModalEstimate], degree: int = 1, n_boot: int = 2000,
                              rng: np.random.Generator | None = None, level: float = CI_LEVEL
                              ) -> BoundaryPrediction:
    """Zimmerman–Weissenburger flutter-margin extrapolation of two modes, parametric-bootstrap interval."""
    u = np.asarray(airspeeds_mps, float)
    rng = rng if rng is not None else np.random.default_rng(0)
    point = float(np.sqrt(extrapolated_root(u**2, flutter_margins(mode_a, mode_b), degree)))
    fa, za = _draw(mode_a, rng, n_boot)
    fb, zb = _draw(mode_b, rng, n_boot)
    samples = np.array([flutter_margin_speed(u, pole_from_modal(fa[k], za[k]), pole_from_modal(fb[k], zb[k]), degree)
                        for k in range(n_boot)])
    return BoundaryPrediction(point, _percentiles(samples, level), "flutter-margin", degree, samples)
