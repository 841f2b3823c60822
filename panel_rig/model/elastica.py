"""The geometrically exact (elastica) panel: slope-angle kinematics, quadrature, statics.

Formulation (variant ``exact``). The panel is an inextensible Euler-Bernoulli strip; its slope angle is
expanded in the derivatives of the cantilever modes,

    theta(s, t) = sum_i q_i psi_i(s),   psi_i = phi_i'   (s = arc length / L, in [0, 1])

and the position follows exactly: x(s) = int_0^s cos theta, w(s) = int_0^s sin theta (both / L). At small
amplitude w ~ int theta = sum q_i phi_i, so q keeps the meaning of the cubic model (w/L per mode) and the
linearisation is the same. Energies (per metre span):

    V = (D / 2L) int theta_s^2 ds = (1/2) q^T K q          (K = (D/L) diag(beta^4): the linear one, exactly)
    T = (m_p L^3 / 2) int (x_dot^2 + w_dot^2) ds = (1/2) q_dot^T M(q) q_dot

with x_dot = sum_j A_j(s) q_dot_j, A_j(s) = -int_0^s sin(theta) psi_j, and w_dot = sum_j B_j(s) q_dot_j,
B_j(s) = int_0^s cos(theta) psi_j; M_ij(q) = m_p L^3 int (A_i A_j + B_i B_j) ds. Lagrange's equations
(equivalently d'Alembert along the strip) give

    M(q) q_dd + h(q, q_dot) + K q = Q,   h_i = m_p L^3 int (A_i a_x + B_i a_w) ds,
    a_x(s) = -int_0^s cos(theta) theta_dot^2,  a_w(s) = -int_0^s sin(theta) theta_dot^2

(the convective accelerations of the points of the strip). A dead transverse force P (N/m) at the trailing
edge does the work P L delta w(1), i.e. Q_i = P L B_i(1). All of this is evaluated by Gauss-Legendre
quadrature on ``n_elem`` equal elements of ``n_gauss`` points; the running integrals int_0^s use the exact
integration matrix of the element's interpolating polynomial (spectral within an element). The compiled
evaluation is in :mod:`panel_rig.model.kernel_exact`; this module holds the precomputation, the
numpy-side geometry (shape, tip, energies) and the static solver of ``panel-rig static``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.polynomial import legendre
from scipy.integrate import cumulative_simpson
from scipy.optimize import fsolve

from panel_rig.model.structure import build_structure, cantilever_root, mode_shapes

#: default quadrature: elements x Gauss points per element (see docs/validation.md for the convergence); with
#: more than 8 modes the number of elements grows so that each element spans about two of the highest mode's
#: half-waves
N_ELEM, N_GAUSS = 4, 6


def default_elements(n_modes: int) -> int:
    return max(N_ELEM, -(-n_modes // 2))


@lru_cache(maxsize=None)
def _reference_element(n_gauss: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss points x_k and weights on [-1, 1] and the running-integral matrix R[g, k] = int_{-1}^{x_g} l_k,
    l_k the Lagrange polynomial through the points (so int_{-1}^{x_g} f = sum_k R[g, k] f(x_k), exact for
    polynomials of degree < n_gauss)."""
    x, w = legendre.leggauss(n_gauss)
    V = legendre.legvander(x, n_gauss - 1)  # V[g, m] = P_m(x_g)
    Vint = np.empty_like(V)
    for m in range(n_gauss):
        c = np.zeros(n_gauss)
        c[m] = 1.0
        Vint[:, m] = legendre.legval(x, legendre.legint(c, lbnd=-1.0))
    return x, w, Vint @ np.linalg.inv(V)


@dataclass(frozen=True)
class Quadrature:
    """Points s (N = n_elem * n_gauss) on [0, 1], weights, and the element running-integral matrix (scaled)."""

    s: np.ndarray
    w: np.ndarray
    w_elem: np.ndarray  # weights of one element (n_gauss,)
    run: np.ndarray  # (n_gauss, n_gauss): int from the element start to point g of f = run @ f_elem
    n_elem: int
    n_gauss: int

    def running(self, f: np.ndarray) -> np.ndarray:
        """int_0^{s_p} f along the last axis (numpy twin of the compiled routine)."""
        g = self.n_gauss
        fe = f.reshape(f.shape[:-1] + (self.n_elem, g))
        within = np.einsum("gk,...ek->...eg", self.run, fe)
        totals = np.einsum("k,...ek->...e", self.w_elem, fe)
        before = np.cumsum(totals, axis=-1) - totals
        return (within + before[..., None]).reshape(f.shape)

    def running_matrix(self) -> np.ndarray:
        """R (N, N): (R f)_p = int_0^{s_p} f, the matrix form of :meth:`running`."""
        return self.running(np.eye(self.s.shape[0])).T

    def inertia_operator(self) -> np.ndarray:
        """S = R^T diag(w) R (N, N, symmetric): the kinetic energy's running integrals taken twice, the kernel's
        inertia force applies it as one dense product (kernel_exact.exact_force)."""
        R = self.running_matrix()
        return np.ascontiguousarray(R.T @ (self.w[:, None] * R))


@lru_cache(maxsize=None)
def quadrature(n_elem: int = N_ELEM, n_gauss: int = N_GAUSS) -> Quadrature:
    if n_elem < 1 or n_gauss < 1:
        raise ValueError("quadrature needs n_elem >= 1 and n_gauss >= 1")
    x, w, R = _reference_element(n_gauss)
    h = 1.0 / n_elem
    s = np.concatenate([e * h + 0.5 * h * (x + 1.0) for e in range(n_elem)])
    return Quadrature(s, np.tile(0.5 * h * w, n_elem), 0.5 * h * w, 0.5 * h * R, n_elem, n_gauss)


@dataclass(frozen=True)
class ExactKinematics:
    """Slope-angle basis psi_i = phi_i' at the quadrature points, with the quadrature itself."""

    quad: Quadrature
    psi: np.ndarray  # (n, N)
    psi_tip: np.ndarray  # (n,) psi_i(1)

    @property
    def n_modes(self) -> int:
        return self.psi.shape[0]

    # ---- numpy-side geometry (the kernel has compiled twins) ---------------------------------------
    def theta(self, q: np.ndarray) -> np.ndarray:
        return np.asarray(q, float) @ self.psi

    def tip(self, q: np.ndarray) -> tuple[float, float, float]:
        """(w(1), x(1), theta(1)) over L for modal state q."""
        th = self.theta(q)
        return float(self.quad.w @ np.sin(th)), float(self.quad.w @ np.cos(th)), float(np.asarray(q) @ self.psi_tip)

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q) / (m_p L^3)."""
        th = self.theta(q)
        A = self.quad.running(-np.sin(th) * self.psi)
        B = self.quad.running(np.cos(th) * self.psi)
        return (A * self.quad.w) @ A.T + (B * self.quad.w) @ B.T

    def tip_force_vector(self, q: np.ndarray) -> np.ndarray:
        """B_i(1) = d w(1) / d q_i: generalised force of a unit dead transverse tip force, per (P L)."""
        return (np.cos(self.theta(q)) * self.psi) @ self.quad.w


@lru_cache(maxsize=None)
def exact_kinematics(n_modes: int, n_elem: int | None = None, n_gauss: int = N_GAUSS) -> ExactKinematics:
    quad = quadrature(default_elements(n_modes) if n_elem is None else n_elem, n_gauss)
    return ExactKinematics(quad, mode_shapes(n_modes, quad.s, 1), mode_shapes(n_modes, np.array([1.0]), 1)[:, 0])


def shape(q: np.ndarray, s: np.ndarray, n_fine: int = 2001) -> tuple[np.ndarray, np.ndarray]:
    """(x/L, w/L) of the exact panel at arc-length stations s (fine Simpson running integral); q (..., n)
    gives (..., len(s))."""
    q = np.asarray(q, float)
    grid = np.linspace(0.0, 1.0, n_fine)
    th = q @ mode_shapes(q.shape[-1], grid, 1)
    x = cumulative_simpson(np.cos(th), x=grid, initial=0.0, axis=-1)
    w = cumulative_simpson(np.sin(th), x=grid, initial=0.0, axis=-1)
    s = np.asarray(s, float)
    interp = lambda f: np.apply_along_axis(lambda row: np.interp(s, grid, row), -1, f)  # noqa: E731
    return interp(x), interp(w)


@lru_cache(maxsize=16)
def shape_sampler(n_modes: int, s: tuple[float, ...]) -> ShapeSampler:
    """The exact panel's (x/L, w/L) at fixed stations ``s`` as a precomputed linear map (cached: the live rig
    draws the panel at 30 Hz of simulated time, i.e. ~1000 times per wall second in fast mode)."""
    return ShapeSampler(n_modes, np.asarray(s, dtype=float))


class ShapeSampler:
    """(x/L, w/L) = (int_0^s cos theta, int_0^s sin theta) at stations s for a vector q, by Gauss-Legendre
    quadrature (``n_gauss`` points) on the sub-intervals between the stations and a uniform grid of spacing at
    most ``max_step``: within 1e-13 of adaptive quadrature for tip angles of a few radians (:func:`shape`, a 2001-point
    Simpson rule read at the stations by linear interpolation: ~4e-6), with ~4x fewer points (20 us a call for 31
    stations, was 94 us). theta at the nodes and the running sums up to each station are fixed: a call is one
    small matrix product for theta and two for the integrals."""

    def __init__(self, n_modes: int, s: np.ndarray, n_gauss: int = 10, max_step: float = 1.0 / 16.0) -> None:
        sc = np.clip(np.asarray(s, dtype=float).reshape(-1), 0.0, 1.0)
        edges = np.unique(np.concatenate((np.linspace(0.0, 1.0, int(np.ceil(1.0 / max_step)) + 1), sc)))
        xg, wg = legendre.leggauss(n_gauss)
        half, mid = 0.5 * np.diff(edges), 0.5 * (edges[1:] + edges[:-1])
        nodes = (mid[:, None] + half[:, None] * xg).reshape(-1)
        weights = (half[:, None] * wg).reshape(-1)
        self.psi = mode_shapes(n_modes, nodes, 1)  # (n_modes, n_nodes): theta = q @ psi
        # station j sums the sub-intervals that end at or before it (edges are the stations' own values)
        ends = np.repeat(edges[1:], n_gauss)
        self.op = np.ascontiguousarray(weights[:, None] * (ends[:, None] <= sc[None, :]))  # (n_nodes, len(s))

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        th = np.asarray(q, dtype=float) @ self.psi
        return np.cos(th) @ self.op, np.sin(th) @ self.op

    def w(self, q: np.ndarray) -> np.ndarray:
        """w/L alone (the second of :meth:`__call__`)."""
        return np.sin(np.asarray(q, dtype=float) @ self.psi) @ self.op


# ---- statics: dead transverse tip load (panel-rig static) ------------------------------------------
@dataclass(frozen=True)
class StaticResult:
    alpha: float  # P L^2 / D
    variant: str
    tip_w_over_L: float
    tip_u_over_L: float  # axial shortening of the tip, 1 - x(1)/L
    tip_angle_rad: float
    q: np.ndarray

    def as_dict(self) -> dict:
        return {"alpha": self.alpha, "variant": self.variant, "tip_w_over_L": self.tip_w_over_L,
                "tip_u_over_L": self.tip_u_over_L,
                "tip_angle_rad": self.tip_angle_rad if np.isfinite(self.tip_angle_rad) else None}


STATIC_VARIANTS = ("exact", "full", "stiffness", "linear")


def _continuation(residual, n: int, alpha: float, steps: int) -> np.ndarray:
    q = np.zeros(n)
    for a in np.linspace(alpha / steps, alpha, steps):
        q, info, _, msg = fsolve(residual, q, args=(a,), xtol=1e-12, full_output=True)
        if not np.max(np.abs(info["fvec"])) <= 1e-9 * max(1.0, abs(a)):
            raise RuntimeError(f"static equilibrium not found at alpha = {a:g}: {msg}")
    return q


MAX_ALPHA = 100.0  # |P L^2 / D| accepted by the static solver (tip angle ~ 1.5 rad at 100)


def static_tip_load(alpha: float, variant: str = "exact", n_modes: int = 12, n_elem: int | None = None,
                    n_gauss: int = N_GAUSS) -> StaticResult:
    """Equilibrium under a dead transverse tip force, alpha = P L^2 / D (dimensionless: the stiffness
    beta^4 and the load alpha B(1) are both per D/L).

    exact:  beta_i^4 q_i = alpha B_i(1; q)                       (B_i(1) = int cos(theta) psi_i)
    full / stiffness (statics have no inertia): beta_i^4 q_i + K_inrs q_n q_r q_s = alpha phi_i(1)
    linear: beta_i^4 q_i = alpha phi_i(1)
    Cubic variants: w' = sum q phi', u(1) = 1/2 int w'^2 (Eq. 8), angle asin(w'(1)) (nan if |w'(1)| > 1).
    """
    if variant not in STATIC_VARIANTS:
        raise ValueError(f"variant must be one of {STATIC_VARIANTS}, got {variant!r}")
    if not (np.isfinite(alpha) and abs(alpha) <= MAX_ALPHA):
        raise ValueError(f"the tip-load parameter P L^2/D must be finite and within +-{MAX_ALPHA:g}, got {alpha}")
    beta4 = np.array([cantilever_root(m) for m in range(1, n_modes + 1)]) ** 4
    steps = max(1, int(np.ceil(abs(alpha) / 0.25)))
    if variant == "exact":
        kin = exact_kinematics(n_modes, n_elem, n_gauss)
        q = _continuation(lambda q, a: beta4 * q - a * kin.tip_force_vector(q), n_modes, alpha, steps)
        w1, x1, th1 = kin.tip(q)
        return StaticResult(float(alpha), variant, w1, 1.0 - x1, th1, q)
    phi1 = mode_shapes(n_modes, np.array([1.0]))[:, 0]
    if variant == "linear":
        q = alpha * phi1 / beta4
    else:
        from panel_rig.config import load_config

        K = build_structure(load_config(overrides=[f"structure.modes={n_modes}"])).K_nl
        q = _continuation(lambda q, a: beta4 * q + np.einsum("inrs,n,r,s->i", K, q, q, q) - a * phi1,
                          n_modes, alpha, steps)
    grid = np.linspace(0.0, 1.0, 4001)
    w1p = q @ mode_shapes(n_modes, grid, 1)
    u1 = 0.5 * float(np.trapezoid(w1p**2, grid)) if hasattr(np, "trapezoid") else 0.5 * float(np.trapz(w1p**2, grid))
    slope = float(w1p[-1])
    angle = float(np.arcsin(slope)) if abs(slope) <= 1.0 else float("nan")
    return StaticResult(float(alpha), variant, float(q @ phi1), u1, angle, q)


def static_tip_moment(mu: float, n_modes: int = 12) -> tuple[float, float, float]:
    """Exact panel under a pure tip moment, mu = M L / D: the load Q_i = mu psi_i(1) is conservative and
    linear in q (the tip rotation is theta(1) = q . psi(1)), so beta^4 q = mu psi(1). Returns
    (w(1), 1 - x(1), theta(1)) over L; the elastica is the circular arc theta = mu s."""
    beta4 = np.array([cantilever_root(m) for m in range(1, n_modes + 1)]) ** 4
    psi1 = mode_shapes(n_modes, np.array([1.0]), 1)[:, 0]
    q = mu * psi1 / beta4
    x1, w1 = shape(q, np.array([1.0]), n_fine=4001)
    return float(w1[0]), float(1.0 - x1[0]), float(q @ psi1)
