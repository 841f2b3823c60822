"""The geometrically exact (elastica) panel, variant ``exact``: statics against the classical elastica,
linearisation identical to the cubic model's, energy, boundedness and the weakly nonlinear backbone."""

import numpy as np
import pytest
from scipy.integrate import cumulative_simpson, simpson

from panel_rig.config import load_config
from panel_rig.model.aeroelastic import AeroelasticModel
from panel_rig.model.elastica import exact_kinematics, static_tip_load, static_tip_moment
from panel_rig.model.kernel_exact import FORCE_WORK_ROWS, exact_eval, exact_force, exact_tip, exact_tip_near
from panel_rig.model.stepper import Stepper
from panel_rig.model.structure import mode_shapes

# Bisshopp & Drucker (1945): dead transverse tip load P L^2 / EI -> tip w/L, axial shortening u/L
BISSHOPP_DRUCKER = {1.0: (0.30172, 0.05643), 2.0: (0.49346, 0.16064), 5.0: (0.71379, 0.38763),
                    10.0: (0.81061, 0.55500)}


@pytest.mark.parametrize("n_modes", [3, 12])
def test_static_dead_tip_load_matches_bisshopp_drucker(n_modes):
    """exact: w/L and u/L within 0.5 % for P L^2/D = 1, 2, 5, 10 (3 and 12 cantilever modes)."""
    for alpha, (w_ref, u_ref) in BISSHOPP_DRUCKER.items():
        r = static_tip_load(alpha, "exact", n_modes=n_modes)
        assert r.tip_w_over_L == pytest.approx(w_ref, rel=5e-3), alpha
        assert r.tip_u_over_L == pytest.approx(u_ref, rel=5e-3), alpha
        assert abs(r.tip_w_over_L) <= 1.0


def test_cubic_structure_departs_from_the_elastica_at_large_load():
    """The third-order expansion is good at alpha = 1 (1 %) and far off at alpha = 10 (w/L > 1: impossible)."""
    small = static_tip_load(1.0, "full", n_modes=3)
    large = static_tip_load(10.0, "full", n_modes=3)
    assert small.tip_w_over_L == pytest.approx(BISSHOPP_DRUCKER[1.0][0], rel=0.015)
    assert large.tip_w_over_L > 1.0


def test_pure_tip_moment_gives_the_circular_arc():
    """M L / D = mu: theta = mu s, w/L = (1 - cos mu)/mu, u/L = 1 - sin(mu)/mu, within 0.5 % (12 modes)."""
    for mu in (0.5, 1.0, 2.0):
        w, u, _ = static_tip_moment(mu, n_modes=12)
        assert w == pytest.approx((1 - np.cos(mu)) / mu, rel=5e-3)
        assert u == pytest.approx(1 - np.sin(mu) / mu, rel=5e-3)


def test_linearisation_equals_the_cubic_models_matrices():
    """At q = 0: M(0) = m_p L^3 I (quadrature of phi_i phi_j), dh/dv = 0, B(1) = phi(1); so natural
    frequencies (N1) are those of the existing model to 1e-6 relative."""
    cfg = load_config()
    s = AeroelasticModel(cfg).structure
    kin = exact_kinematics(s.n_modes)
    n = s.n_modes
    M, h, b, Jv = np.zeros((n, n)), np.zeros(n), np.zeros(n), np.zeros((n, n))
    work = np.zeros((3 * n + 7, kin.psi.shape[1]))
    exact_eval(np.zeros(n), np.ones(n), kin.psi, kin.quad.w, kin.quad.run, kin.quad.w_elem, kin.quad.n_elem, 1.0,
               True, M, h, b, Jv, work)
    np.testing.assert_allclose(M, np.eye(n), atol=1e-9)
    np.testing.assert_allclose(b, mode_shapes(n, np.array([1.0]))[:, 0], rtol=1e-9)
    np.testing.assert_allclose(Jv, 0.0, atol=1e-12)
    f = np.sqrt(np.linalg.eigvalsh(np.diag(s.modal_stiffness_npm) / (s.modal_mass_kg * M)))[::-1][::-1] / (2 * np.pi)
    np.testing.assert_allclose(np.sort(f), s.natural_frequencies_hz, rtol=1e-6)


@pytest.mark.parametrize("n", [1, 3, 5])
def test_step_force_and_newton_matrix_equal_the_lagrangian_terms(n):
    """The kernel's step terms at a large-amplitude state (tip angles of radians): exact_force = M(q) a + h(q, v)
    - F L B(1; q) of exact_eval (the mass-matrix form) to 1e-12; its Newton matrix along the midpoint step's line
    (q, v, a move by dt/4, 1/2, 1/dt per unit x) equals central differences to 1e-7; a Newton iteration's rotated
    cos/sin (near=True) and the step's tip from them equal the direct evaluation."""
    kin = exact_kinematics(n)
    quad = (kin.psi, kin.quad.w, kin.quad.run, kin.quad.w_elem, kin.quad.n_elem)
    dense = (kin.psi, kin.quad.w, kin.quad.inertia_operator())  # exact_force's quadrature: S = R^T diag(w) R
    rng = np.random.default_rng(n)
    q, v, a = rng.normal(size=n), 100.0 * rng.normal(size=n), 1e4 * rng.normal(size=n)
    m, fl, dt = 0.02, 3.0, 1 / 2048
    M, h, b, Jv = np.zeros((n, n)), np.zeros(n), np.zeros(n), np.zeros((n, n))
    exact_eval(q, v, *quad, m, False, M, h, b, Jv, np.zeros((3 * n + 7, kin.psi.shape[1])))
    ref = M @ a + h - fl * b
    work, jwork = np.zeros((FORCE_WORK_ROWS, kin.psi.shape[1])), np.zeros((2, 2 * n, kin.psi.shape[1]))
    F, J = np.zeros(n), np.zeros((n, n))
    line = (dt / 4, 0.5, 1 / dt)
    exact_force(q, v, a, fl, *dense, m, True, *line, F, J, work, jwork, False)
    np.testing.assert_allclose(F, ref, rtol=1e-12, atol=1e-12 * np.max(np.abs(ref)))
    fd = np.zeros((n, n))
    for j in range(n):
        e = np.zeros(n)
        e[j] = 1e-3
        Fp, Fm = np.zeros(n), np.zeros(n)
        exact_force(q + line[0] * e, v + line[1] * e, a + line[2] * e, fl, *dense, m, False, 0, 0, 0, Fp, J * 0, work,
                    jwork, False)
        exact_force(q - line[0] * e, v - line[1] * e, a - line[2] * e, fl, *dense, m, False, 0, 0, 0, Fm, J * 0, work,
                    jwork, False)
        fd[:, j] = (Fp - Fm) / 2e-3
    np.testing.assert_allclose(J, fd, rtol=0, atol=1e-7 * np.max(np.abs(fd)))
    for dq in (1e-6, 0.03, 0.5):  # a Newton correction, a time step's change, a jump past the series' range
        exact_force(q, v, a, fl, *dense, m, False, 0, 0, 0, F, J, work, jwork, False)
        q2 = q + dq * rng.normal(size=n)
        Fn, Fd = np.zeros(n), np.zeros(n)
        assert exact_tip_near(q2, kin.psi, kin.quad.w, work) == pytest.approx(exact_tip(q2, kin.psi, kin.quad.w),
                                                                              rel=1e-13, abs=1e-15)
        exact_force(q2, v, a, fl, *dense, m, False, 0, 0, 0, Fn, J, work, jwork, True)
        exact_force(q2, v, a, fl, *dense, m, False, 0, 0, 0, Fd, J, work, jwork, False)
        np.testing.assert_allclose(Fn, Fd, rtol=1e-13, atol=1e-13 * np.max(np.abs(Fd)))


def _step_map(st: Stepper, U: float, eps: float = 1e-7) -> np.ndarray:
    """Jacobian of one step of the stepper at the rest state (central differences on (q, v, xi))."""
    n, r = st.n_modes, st.xi.shape[0]
    cols = []
    for k in range(2 * n + r):
        out = []
        for sgn in (1.0, -1.0):
            x = np.zeros(2 * n + r)
            x[k] = sgn * eps
            st.reset(q=x[:n], qdot=x[n:2 * n])
            st.xi[:] = x[2 * n:]
            st.advance(1, U)
            out.append(np.concatenate([st.q, st.qdot, st.xi]))
        cols.append((out[0] - out[1]) / (2 * eps))
    return np.array(cols).T


def _flutter_speed(st: Stepper, lo: float, hi: float) -> tuple[float, float]:
    """Bisection of the step map's spectral radius through 1; returns (speed, frequency of that root)."""
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if np.max(np.abs(np.linalg.eigvals(_step_map(st, mid)))) > 1.0:
            hi = mid
        else:
            lo = mid
    z = np.linalg.eigvals(_step_map(st, hi))
    k = np.argmax(np.abs(z))
    return hi, abs(np.angle(z[k])) / (2 * np.pi * st.dt_s)


@pytest.mark.parametrize("aero", ["rom", "full"])
def test_linear_flutter_of_exact_equals_existing_model(model, aero):
    """L1 (full aero) and L2 (ROM): the linearised exact stepper flutters at the speed and frequency of the
    cubic model's linearisation (variant linear) to 1e-6 relative."""
    cfg = model.cfg
    res = {}
    for variant in ("linear", "exact"):
        st = Stepper(cfg, variant=variant, aero=aero, model=model)
        res[variant] = _flutter_speed(st, 8.0, 14.0)
    np.testing.assert_allclose(res["exact"], res["linear"], rtol=1e-6)
    assert 9.0 < res["exact"][0] < 12.0  # and it is the model's flutter point (10.4-10.5 m/s)


def _field_energy_j(cfg, q, qdot, n_fine=4001):
    """T + V of the exact panel from the fields theta(s), x_dot(s), w_dot(s) on a fine Simpson grid
    (independent of the kernel's Gauss quadrature)."""
    s = np.linspace(0, 1, n_fine)
    psi, psi_s = mode_shapes(len(q), s, 1), mode_shapes(len(q), s, 2)
    th, thd = q @ psi, qdot @ psi
    xd = cumulative_simpson(-np.sin(th) * thd, x=s, initial=0.0)
    wd = cumulative_simpson(np.cos(th) * thd, x=s, initial=0.0)
    L, m, D = cfg.panel_length_m, cfg.mass_per_area_kgpm2, cfg.bending_stiffness_nm
    return 0.5 * m * L**3 * simpson(xd**2 + wd**2, x=s) + 0.5 * D / L * simpson((q @ psi_s) ** 2, x=s)


def test_free_undamped_exact_panel_conserves_energy_at_half_length_amplitude():
    """No air, no damping, tip released at w/L = 0.5 (plus some mode 2): field T + V constant to 1e-4 over 2 s
    at the default step, and |w/L| <= 1 at every step."""
    cfg = load_config(overrides=["structure.damping_ratio=0.0"])
    st = Stepper(cfg, variant="exact", aero="none")
    st.reset(q=[0.26, -0.01, 0.0])
    assert st.tip_w_over_L == pytest.approx(0.5, abs=0.01)
    e0 = _field_energy_j(cfg, st.q, st.qdot)
    drift, tips = [], []
    for _ in range(20):
        tips.append(st.advance(int(0.1 / st.dt_s), 0.0))
        drift.append(_field_energy_j(cfg, st.q, st.qdot) / e0 - 1)
    assert np.max(np.abs(drift)) < 1e-4, drift
    tips = np.concatenate(tips)
    assert np.max(np.abs(tips)) <= 1.0 and np.max(np.abs(tips)) > 0.45


def test_tip_is_bounded_by_the_panel_length_even_when_wound_up():
    """A slope field winding past 90 degrees: the exact tip stays within L (the cubic w/L would exceed it)."""
    cfg = load_config(overrides=["structure.damping_ratio=0.0"])
    st = Stepper(cfg, variant="exact", aero="none")
    st.reset(q=[1.0, 0.0, 0.0])  # theta(1) = 2.75 rad
    tips = st.advance(2048, 0.0)
    assert np.all(np.abs(tips) <= 1.0)
    assert abs(mode_shapes(3, np.array([1.0]))[0, 0] * 1.0) > 1.0


def _free_frequency_hz(cfg, model, variant, mode, amp, dt=1 / 4096, periods=10):
    st = Stepper(cfg, variant=variant, aero="none", model=model, dt_s=dt)
    q0 = np.zeros(st.n_modes)
    q0[mode] = amp / abs(mode_shapes(st.n_modes, np.array([1.0]))[mode, 0])
    st.reset(q=q0)
    n = int(periods / model.structure.natural_frequencies_hz[mode] / dt)
    run = st.advance_sampled(np.zeros(n), np.zeros(n), np.arange(1, n + 1))
    qs = run.q[:, mode]
    idx = np.where(np.sign(qs[:-1]) != np.sign(qs[1:]))[0]
    tz = (idx + qs[idx] / (qs[idx] - qs[idx + 1])) * dt
    return (len(tz) - 1) / 2 / (tz[-1] - tz[0])


def backbone_coefficient(cfg, model, variant, mode, amps=(0.01, 0.02, 0.05, 0.1)):
    """Gamma in f(a) = f0 (1 + Gamma a^2 + O(a^4)), a the tip amplitude w/L (least squares with the a^4 term)."""
    a = np.asarray(amps)
    f = np.array([_free_frequency_hz(cfg, model, variant, mode, x) for x in a])
    c = np.linalg.lstsq(np.vstack([np.ones_like(a), a**2, a**4]).T, f, rcond=None)[0]
    return c[1] / c[0]


@pytest.mark.parametrize("mode", [0, 1])
def test_backbone_coefficient_equals_the_cubic_models(mode):
    """Weakly nonlinear free vibration (tip 0.01-0.1 L): the same third-order physics in another basis, so the
    backbone coefficients of exact and full agree within 5 % (measured: 0.01 % mode 1, 0.8 % mode 2)."""
    cfg = load_config(overrides=["structure.damping_ratio=0.0"])
    model = AeroelasticModel(cfg)
    g_full = backbone_coefficient(cfg, model, "full", mode)
    g_exact = backbone_coefficient(cfg, model, "exact", mode)
    assert np.sign(g_full) == (1 if mode == 0 else -1)  # mode 1 hardens, mode 2 softens
    assert g_exact == pytest.approx(g_full, rel=0.05)


def test_exact_runs_only_the_consistent_midpoint_scheme(cfg, model):
    with pytest.raises(ValueError, match="implicit"):
        Stepper(cfg, variant="exact", scheme="paper", model=model)


def test_static_command_json_and_bad_input(capsys):
    import json

    from panel_rig.cli import main

    assert main(["static", "--tip-load-parameter", "5", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["variant"] == "exact" and out["alpha"] == 5.0
    assert out["tip_w_over_L"] == pytest.approx(BISSHOPP_DRUCKER[5.0][0], rel=5e-3)
    assert out["tip_u_over_L"] == pytest.approx(BISSHOPP_DRUCKER[5.0][1], rel=5e-3)
    assert 0 < out["tip_angle_rad"] < np.pi / 2
    cfg = load_config()
    P = 2.0 * cfg.bending_stiffness_nm / cfg.panel_length_m**2  # the same load as a force per metre span
    assert main(["static", "--tip-force", str(P), "--variant", "full", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["alpha"] == pytest.approx(2.0) and out["variant"] == "full"
    assert out["tip_w_over_L"] > BISSHOPP_DRUCKER[2.0][0] * 1.03  # the cubic overshoots the elastica
    for bad in (["--tip-load-parameter", "nan"], ["--tip-load-parameter", "1e6"], [],
                ["--tip-force", "1", "--tip-load-parameter", "1"], ["--tip-force", "1", "--variant", "inertia"]):
        assert main(["static", *bad]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("panel-rig: error:"), err


def test_lco_far_above_flutter_completes_bounded(model):
    """U/U_f = 1.05, 1.5, 2.0, 2.5 (ROM aero, 12 s from the standard small disturbance): no divergence, a
    limit cycle (RMS > 0.2) whose tip never leaves |w/L| <= 1; the cubic full model diverges at 1.5 U_f."""
    from panel_rig.analysis.exact_study import flutter_speed
    from panel_rig.analysis.lco import lco_sweep

    uf = flutter_speed(model)
    speeds = uf * np.array([1.05, 1.5, 2.0, 2.5])
    for r in lco_sweep(model.cfg, speeds, 24.0, "exact", model=model):
        assert not r.diverged, r
        assert 0.2 < r.rms_tip_w_over_L and r.peak_tip_w_over_L <= 1.0, r
    assert lco_sweep(model.cfg, speeds[1:2], 12.0, "full", model=model)[0].diverged


def test_exact_is_a_variant_of_the_run_commands(capsys):
    import json

    from panel_rig.cli import main

    assert main(["lco", "--airspeed", "5", "--duration", "0.5", "--variant", "exact", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["diverged"] is False
    assert main(["lco", "--airspeed", "5", "--duration", "0.5", "--variant", "exact", "--scheme", "paper"]) == 2
    assert "implicit" in capsys.readouterr().err


def test_exact_shape_is_inextensible_and_ends_at_the_reported_tip(cfg, model):
    """The material points at arc length s: polyline length 1 (to discretisation), last point = the tip."""
    st = Stepper(cfg, variant="exact", aero="none", model=model)
    st.reset(q=[0.5, -0.1, 0.02])
    s = np.linspace(0, 1, 401)
    x, w = st.shape_xw_over_L(s)
    assert np.sum(np.hypot(np.diff(x), np.diff(w))) == pytest.approx(1.0, abs=1e-4)
    assert w[-1] == pytest.approx(st.tip_w_over_L, abs=1e-6)
    np.testing.assert_allclose(st.shape_w_over_L(s), w)
