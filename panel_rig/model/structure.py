"""Cantilevered panel: modes, modal matrices and the nonlinear tensors (Tang & Dowell 2002, Eqs. 6-22).

Coordinates are non-dimensional: x_bar = x/L along the panel, w/L = sum_m q_m phi_m(x_bar) (Eq. 20).
Modes are normalised so that the integral of phi_m^2 over [0, 1] is 1 (then |phi_m(1)| = 2).

With T = (m_p L^3 / 2) int (u_dot^2 + w_dot^2) and V = (D / 2L) int w''^2 (1 + w'^2) (Eqs. 7-11, with
the inextensibility u = -1/2 int w'^2 of Eq. 8, all in bar units), Lagrange's equations give Eq. (21):

    m_p L^3 [q_dd + dM(q) q_dd / (m_p L^3) + F_M] + (D / L) [beta^4 q + F_K] = Q

with the stiffness tensor K_inrs (F_K,i = K_inrs q_n q_r q_s) and the inertia tensor P_abcd
(dM_bd = m_p L^3 P_abcd q_a q_c) of Eq. (22), here in the weak (integrated-by-parts) form, which needs
only second derivatives of the modes and is exactly equivalent for cantilever boundary conditions.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.integrate import cumulative_simpson, simpson
from scipy.optimize import brentq

from panel_rig.config import PanelConfig

N_GRID = 2001  # quadrature points on [0, 1] for the tensors (Simpson: error ~1e-10)


@lru_cache(maxsize=None)
def cantilever_root(n: int) -> float:
    """beta_n L: the n-th root (1-based) of 1 + cos(b) cosh(b) = 0."""
    f = lambda b: np.cos(b) + 1.0 / np.cosh(b)  # noqa: E731  (same roots, well scaled)
    centre = (2 * n - 1) * np.pi / 2
    return float(brentq(f, centre - 1.0, centre + 1.0, xtol=1e-15))


def mode_derivatives(n: int, x_bar: np.ndarray) -> np.ndarray:
    """phi_n and its first three x_bar-derivatives at x_bar, shape (4, len(x_bar)).

    Uses the overflow-free form phi = e^{-bx} + (1 - s) sinh(bx) - cos(bx) + s sin(bx), with
    1 - s = (sin b - cos b - e^{-b}) / (sinh b + sin b), s the usual cantilever ratio.
    """
    b = cantilever_root(n)
    x = np.asarray(x_bar, dtype=float)
    one_minus_s = (np.sin(b) - np.cos(b) - np.exp(-b)) / (np.sinh(b) + np.sin(b))
    s = 1.0 - one_minus_s
    e, sh, ch = np.exp(-b * x), np.sinh(b * x), np.cosh(b * x)
    c, sn = np.cos(b * x), np.sin(b * x)
    return np.array([
        e + one_minus_s * sh - c + s * sn,
        b * (-e + one_minus_s * ch + sn + s * c),
        b**2 * (e + one_minus_s * sh + c - s * sn),
        b**3 * (-e + one_minus_s * ch - sn - s * c),
    ])


def mode_shapes(n_modes: int, x_bar: np.ndarray, derivative: int = 0) -> np.ndarray:
    """phi_m^(derivative)(x_bar) for m = 1..n_modes, shape (n_modes, len(x_bar))."""
    return np.array([mode_derivatives(m, x_bar)[derivative] for m in range(1, n_modes + 1)])


def stiffness_tensor(n_modes: int, n_grid: int = N_GRID) -> np.ndarray:
    """K_inrs = int_0^1 (phi_i'' phi_n'' phi_r' phi_s' + phi_i' phi_n'' phi_r'' phi_s') dx_bar (Eq. 22).

    F_K,i = K_inrs q_n q_r q_s is the gradient of (1/2) int w''^2 w'^2, in units of D/L.
    """
    x = np.linspace(0.0, 1.0, n_grid)
    d1, d2 = mode_shapes(n_modes, x, 1), mode_shapes(n_modes, x, 2)
    integrand = np.einsum("ix,nx,rx,sx->inrsx", d2, d2, d1, d1) + np.einsum(
        "ix,nx,rx,sx->inrsx", d1, d2, d2, d1
    )
    return simpson(integrand, x=x, axis=-1)


def inertia_tensor(n_modes: int, n_grid: int = N_GRID) -> np.ndarray:
    """P_abcd = int_0^1 G_ab(x) G_cd(x) dx_bar with G_ab(x) = int_0^x phi_a' phi_b' (Eq. 22).

    The in-plane kinetic energy is T_u = (m_p L^3 / 2) P_abcd q_a qdot_b q_c qdot_d.
    """
    x = np.linspace(0.0, 1.0, n_grid)
    d1 = mode_shapes(n_modes, x, 1)
    g = cumulative_simpson(np.einsum("ax,bx->abx", d1, d1), x=x, axis=-1, initial=0.0)
    return simpson(np.einsum("abx,cdx->abcdx", g, g), x=x, axis=-1)


@dataclass(frozen=True)
class Structure:
    """Modal model of the panel in SI units (per metre of span); q is w/L."""

    n_modes: int
    beta: np.ndarray  # beta_m L, cantilever roots
    omega_rps: np.ndarray  # natural circular frequencies, rad/s
    modal_mass_kg: float  # m_p L^3 (identical for every mode)
    modal_stiffness_npm: np.ndarray  # (D/L) beta^4 (diagonal), N/m... times q (dimensionless)
    modal_damping_kgps: np.ndarray  # 2 zeta omega m_p L^3 (diagonal)
    stiffness_scale_n: float  # D / L, multiplies F_K
    K_nl: np.ndarray  # K_inrs, (n, n, n, n)
    P_nl: np.ndarray  # P_abcd, (n, n, n, n)
    length_m: float

    @property
    def natural_frequencies_hz(self) -> np.ndarray:
        return self.omega_rps / (2 * np.pi)

    def nonlinear_stiffness_force(self, q: np.ndarray) -> np.ndarray:
        """(D/L) F_K(q), N per metre span (Eq. 22, K_inrs q_n q_r q_s). Batch: q (..., n)."""
        return self.stiffness_scale_n * np.einsum("inrs,...n,...r,...s->...i", self.K_nl, q, q, q)

    def nonlinear_mass(self, q: np.ndarray) -> np.ndarray:
        """dM(q)_bd = m_p L^3 P_abcd q_a q_c, kg (the state-dependent mass of Eq. 24). Batch (..., n, n)."""
        return self.modal_mass_kg * np.einsum("abcd,...a,...c->...bd", self.P_nl, q, q)

    def nonlinear_inertia_force(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """F_M(q, qdot): velocity-quadratic inertia force, d/dt(dM) qdot - dT_u/dq (Eqs. 21-22), N."""
        P = self.P_nl
        dM_dot = np.einsum("aicd,...a,...c->...id", P, qdot, q) + np.einsum("aicd,...a,...c->...id", P, q, qdot)
        first = np.einsum("...id,...d->...i", dM_dot, qdot)
        grad = 0.5 * (
            np.einsum("ibcd,...b,...d,...c->...i", P, qdot, qdot, q)
            + np.einsum("cbid,...b,...d,...c->...i", P, qdot, qdot, q)
        )
        return self.modal_mass_kg * (first - grad)

    def potential_energy_j(self, q: np.ndarray) -> np.ndarray:
        """V(q) = (1/2) q K q + (D/L)/4 K_inrs q_i q_n q_r q_s, J per metre span."""
        lin = 0.5 * np.einsum("...i,i,...i->...", q, self.modal_stiffness_npm, q)
        quartic = 0.25 * self.stiffness_scale_n * np.einsum("inrs,...i,...n,...r,...s->...", self.K_nl, q, q, q, q)
        return lin + quartic

    def kinetic_energy_j(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """T(q, qdot) = (1/2) qdot (M + dM(q)) qdot, J per metre span."""
        M = self.modal_mass_kg * np.eye(self.n_modes) + self.nonlinear_mass(q)
        return 0.5 * np.einsum("...i,...ij,...j->...", qdot, M, qdot)


def build_structure(cfg: PanelConfig) -> Structure:
    """Modal mass, stiffness, damping and nonlinear tensors of the cantilevered panel (Eqs. 19-22)."""
    n = cfg.n_modes
    beta = np.array([cantilever_root(m) for m in range(1, n + 1)])
    L = cfg.panel_length_m
    m_modal = cfg.mass_per_area_kgpm2 * L**3
    k_scale = cfg.bending_stiffness_nm / L
    k_modal = k_scale * beta**4
    omega = np.sqrt(k_modal / m_modal)
    return Structure(
        n_modes=n,
        beta=beta,
        omega_rps=omega,
        modal_mass_kg=m_modal,
        modal_stiffness_npm=k_modal,
        modal_damping_kgps=2.0 * cfg.damping_ratio * omega * m_modal,
        stiffness_scale_n=k_scale,
        K_nl=stiffness_tensor(n),
        P_nl=inertia_tensor(n),
        length_m=L,
    )
