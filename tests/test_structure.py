"""Cantilever modes and the nonlinear tensors (Eqs. 19-22) against exact and published values."""

import numpy as np
import pytest
from scipy.integrate import cumulative_simpson, simpson

from panel_rig.analysis import published as paper
from panel_rig.config import load_config
from panel_rig.model.options import CUBIC_VARIANTS
from panel_rig.model.stepper import Stepper
from panel_rig.model.structure import build_structure, mode_shapes, stiffness_tensor

PAPER_HZ = np.array(paper.NATURAL_FREQUENCIES_HZ)  # N1


def test_cantilever_roots_match_euler_bernoulli(cfg):
    """beta_n L against the exact Euler-Bernoulli roots, 0.1 %."""
    s = build_structure(cfg)
    np.testing.assert_allclose(s.beta, [1.8751, 4.6941, 7.8548], rtol=1e-3)
    D, m, L = cfg.bending_stiffness_nm, cfg.mass_per_area_kgpm2, cfg.panel_length_m
    exact = np.array([1.8751, 4.6941, 7.8548]) ** 2 * np.sqrt(D / (m * L**4)) / (2 * np.pi)
    np.testing.assert_allclose(s.natural_frequencies_hz, exact, rtol=1e-3)


def test_natural_frequencies_match_paper_N1(cfg):
    """N1: 4.13, 25.85, 71.67 Hz within 2.5 % (E read as kgf/m^2, see docs/validation.md)."""
    f = build_structure(cfg).natural_frequencies_hz
    np.testing.assert_allclose(f, PAPER_HZ, rtol=0.025)


def test_modes_are_orthonormal_and_satisfy_boundary_conditions():
    x = np.linspace(0, 1, 4001)
    phi = mode_shapes(5, x)
    np.testing.assert_allclose(simpson(phi[:, None] * phi[None], x=x), np.eye(5), atol=1e-8)
    for d in (0, 1):
        np.testing.assert_allclose(mode_shapes(5, np.array([0.0]), d), 0, atol=1e-9)
    for d in (2, 3):  # free end: no moment, no shear
        np.testing.assert_allclose(mode_shapes(5, np.array([1.0]), d)[:, 0] / np.array(
            [1.875, 4.694, 7.855, 10.996, 14.137]) ** d, 0, atol=1e-7)


def test_single_mode_coefficients_match_literature():
    """Mode 1 of the inextensible cantilever: cubic curvature coefficient 40.44 and inertia coefficient
    4.597 (Crespo da Silva & Glynn 1978; Nayfeh & Pai 2004; Malatkar & Nayfeh 2003), 0.1 %."""
    s = build_structure(load_config())
    assert s.K_nl[0, 0, 0, 0] == pytest.approx(40.44, rel=1e-3)
    assert s.P_nl[0, 0, 0, 0] == pytest.approx(4.597, rel=1e-3)


def test_weak_form_equals_strong_form_of_eq19():
    """K_inrs (weak form) equals phi_i [phi_n'''' phi_r' phi_s' + 4 phi_n' phi_r'' phi_s''' + phi_n'' phi_r'' phi_s'']
    contracted with q (the printed Eq. 22 integrand), for random q."""
    n, x = 3, np.linspace(0, 1, 4001)
    d = [mode_shapes(n, x, k) for k in range(4)]
    beta4 = np.array([1.8751040687, 4.6940911330, 7.8547574382]) ** 4
    d4 = d[0] * beta4[:, None]  # phi'''' = beta^4 phi
    rng = np.random.default_rng(1)
    K = stiffness_tensor(n)
    for _ in range(3):
        q = rng.normal(size=n) * 0.1
        w = [q @ dk for dk in d]
        w4 = q @ d4
        strong = w4 * w[1] ** 2 + 4 * w[1] * w[2] * w[3] + w[2] ** 3
        lhs = simpson(d[0] * strong, x=x)
        rhs = np.einsum("inrs,n,r,s->i", K, q, q, q)
        np.testing.assert_allclose(rhs, lhs, rtol=1e-6, atol=1e-10)


def field_energy_j(cfg, q, qdot, stiffness_nl=True, inertia_nl=True):
    """T + V of the panel from the fields w, u (Eqs. 7-11), not from the modal tensors; a variant
    without a nonlinearity drops the in-plane kinetic energy or the w'^2 curvature term."""
    x = np.linspace(0, 1, 2001)
    L, m, D = cfg.panel_length_m, cfg.mass_per_area_kgpm2, cfg.bending_stiffness_nm
    n = q.shape[0]
    w1, w2 = q @ mode_shapes(n, x, 1), q @ mode_shapes(n, x, 2)
    wdot, wdot1 = qdot @ mode_shapes(n, x, 0), qdot @ mode_shapes(n, x, 1)
    udot = -cumulative_simpson(w1 * wdot1, x=x, initial=0.0)  # u = -1/2 int w'^2 (Eq. 8)
    T = 0.5 * m * L**3 * simpson(inertia_nl * udot**2 + wdot**2, x=x)
    V = 0.5 * D / L * simpson(w2**2 * (1 + stiffness_nl * w1**2), x=x)
    return T + V


@pytest.mark.parametrize("variant", list(CUBIC_VARIANTS))
def test_free_nonlinear_structure_conserves_field_energy(variant):
    """Free, undamped, no air: T + V from the fields stays constant (implicit scheme), 1e-4 relative."""
    cfg = load_config(overrides=["structure.damping_ratio=0.0"])
    st = Stepper(cfg, variant=variant, aero="none", dt_s=1 / 8192)
    st.reset(q=[0.05, 0.02, 0.002])
    flags = dict(zip(("stiffness_nl", "inertia_nl"), CUBIC_VARIANTS[variant]))
    e0 = field_energy_j(cfg, st.q, st.qdot, **flags)
    energies = []
    for _ in range(20):
        st.advance(400, 0.0)
        energies.append(field_energy_j(cfg, st.q, st.qdot, **flags))
    drift = np.max(np.abs(np.array(energies) / e0 - 1))
    assert drift < 1e-4, drift


def test_paper_scheme_does_not_conserve_energy():
    """The nonlinear mass at t (Eq. 24 as printed) is first order: its energy error is far larger."""
    cfg = load_config(overrides=["structure.damping_ratio=0.0"])
    drifts = {}
    for scheme in ("implicit", "paper"):
        st = Stepper(cfg, variant="full", aero="none", scheme=scheme, dt_s=1 / 2048)
        st.reset(q=[0.05, 0.02, 0.002])
        e0 = field_energy_j(cfg, st.q, st.qdot)
        st.advance(4096, 0.0)
        drifts[scheme] = abs(field_energy_j(cfg, st.q, st.qdot) / e0 - 1)
    assert drifts["paper"] > 10 * drifts["implicit"], drifts
