"""The nonlinear stepper: forced response (F0-F4), LCO (C3), ROM vs full aero, dt convergence, divergence."""

import numpy as np
import pytest

from panel_rig.analysis import published as paper
from panel_rig.analysis.flutter import find_flutter
from panel_rig.analysis.forced import forced_sweep
from panel_rig.analysis.lco import run_lco
from panel_rig.model.stepper import DivergenceError, Stepper

PAPER_UF_MPS = paper.FLUTTER_SPEED_MPS


@pytest.fixture(scope="module")
def u_c3(model):
    """13.5 m/s scaled to our flutter speed: the paper's overspeed ratio 13.5 / 12.5 (ROM Ra = 12)."""
    return paper.overspeed_ratio(paper.LCO_AIRSPEED_MPS) * find_flutter(model, aero="rom", rom_modes=12).speed_mps


def test_linear_forced_response_peaks_at_natural_frequencies(cfg, model):
    """F2: linear peaks at the natural frequencies within the 0.1 Hz sweep step (protocol F0, f0 = 0.05 N/m)."""
    fn = model.structure.natural_frequencies_hz
    for band, f_nat in (((2.0, 7.0), fn[0]), ((23.0, 28.0), fn[1])):
        r = forced_sweep(cfg, *band, 0.1, "linear", model=model)
        assert abs(r.peak_frequency_hz - f_nat) <= 0.1, (r.peak_frequency_hz, f_nat)


@pytest.fixture(scope="module")
def second_band_peaks(cfg, model):
    """Peak frequencies near the 2nd mode for each variant, f0 = 0.5 N/m (amplitudes of Fig. 2b)."""
    return {v: forced_sweep(cfg, 23.0, 28.0, 0.1, v, f0_npm=0.5, model=model).peak_frequency_hz
            for v in ("linear", "full", "stiffness", "inertia")}


@pytest.mark.parametrize("variant,direction", [("full", -1), ("stiffness", +1), ("inertia", -1)])
def test_second_peak_shift_direction_matches_paper(second_band_peaks, variant, direction):
    """F1 (25.3 < 25.85 Hz: down), F3 (26.4: up), F4 (25.1: down) relative to the linear peak."""
    shift = second_band_peaks[variant] - second_band_peaks["linear"]
    assert np.sign(round(shift, 2)) == direction, second_band_peaks


def test_C3_stiffness_only_lco(cfg, model, u_c3):
    """C3: RMS tip w/L 0.093 within 25 %, frequency 22.55 Hz within 5 %, at U/U_f = 13.5/12.5."""
    res, _, _ = run_lco(cfg, u_c3, 30.0, "stiffness", model=model)
    assert not res.diverged
    assert res.rms_tip_w_over_L == pytest.approx(paper.C3_STIFFNESS_RMS_W_OVER_L, rel=0.25)
    assert res.dominant_frequency_hz == pytest.approx(paper.C3_STIFFNESS_FREQUENCY_HZ, rel=0.05)
    assert res.steady_after_s is not None and res.steady_after_s < 25


def test_rom_and_full_aero_lco_agree(cfg, model, u_c3):
    """ROM (Ra = 12) and full-order (all aero modes) LCO within 5 % in RMS and frequency."""
    rom, _, _ = run_lco(cfg, u_c3, 30.0, "stiffness", "rom", model=model)
    full, _, _ = run_lco(cfg, u_c3, 30.0, "stiffness", "full", model=model)
    assert full.rms_tip_w_over_L == pytest.approx(rom.rms_tip_w_over_L, rel=0.05)
    assert full.dominant_frequency_hz == pytest.approx(rom.dominant_frequency_hz, rel=0.05)


def test_lco_converges_as_dt_halves(cfg, model, u_c3):
    """Implicit scheme, dt = 1/2048, 1/4096, 1/8192 s: second-order convergence of the LCO RMS (each change
    at least 3x smaller than the previous), and 1/4096 vs 1/8192 within 1 % (RMS) and 0.5 % (frequency)."""
    runs = [run_lco(cfg, u_c3, 40.0, "stiffness", model=model, dt_s=1 / (2048 * k))[0] for k in (1, 2, 4)]
    rms = [r.rms_tip_w_over_L for r in runs]
    assert abs(rms[2] - rms[1]) * 3 < abs(rms[1] - rms[0]), rms
    assert rms[2] == pytest.approx(rms[1], rel=0.01)
    assert runs[2].dominant_frequency_hz == pytest.approx(runs[1].dominant_frequency_hz, rel=0.005)


def test_paper_scheme_full_lco_depends_on_dt(cfg, model, u_c3):
    """Item 3 evidence: with dM at t (Eq. 24 as printed) the full-nonlinear LCO amplitude changes by more
    than 20 % when dt halves: the scheme's first-order error acts as an amplitude-dependent damping."""
    a, _, _ = run_lco(cfg, u_c3, 30.0, "full", scheme="paper", model=model)
    b, _, _ = run_lco(cfg, u_c3, 30.0, "full", scheme="paper", model=model, dt_s=1 / 4096)
    assert not (a.diverged or b.diverged)
    assert abs(b.rms_tip_w_over_L / a.rms_tip_w_over_L - 1) > 0.2


def test_diverging_run_raises_typed_error(cfg, model):
    st = Stepper(cfg, "inertia", "rom", model=model)
    st.reset(q=[0.0, 1e-3, 0.0])
    with pytest.raises(DivergenceError) as info:
        st.advance(2048 * 20, 20.0)
    assert np.all(np.isfinite(st.q)) and abs(st.tip_w_over_L) <= cfg.max_tip_w_over_L
    assert info.value.time_s > 0


def test_bad_inputs_are_rejected(cfg, model):
    st = Stepper(cfg, model=model)
    for bad in (float("nan"), -1.0, float("inf")):
        with pytest.raises(ValueError):
            st.advance(3, bad)
    with pytest.raises(ValueError):
        Stepper(cfg, variant="quadratic", model=model)


def test_airspeed_may_change_every_step(cfg, model):
    """A ramp input per step is accepted and subcritical motion decays."""
    st = Stepper(cfg, "full", "rom", model=model)
    st.reset(q=[0.0, 1e-3, 0.0])
    tip = st.advance(4096, np.linspace(0.0, 8.0, 4096))
    assert np.all(np.isfinite(tip))
    assert np.max(np.abs(tip[-512:])) < np.max(np.abs(tip[:512]))


def test_batch_form_matches_single_runs(cfg, model):
    """BatchStepper (leading run axis) gives the single-run results bit for bit, and flags a diverging run."""
    from panel_rig.model.stepper import BatchStepper

    speeds = np.array([8.0, 11.3, 20.0])
    template = Stepper(cfg, "inertia", "rom", model=model)
    batch = BatchStepper(template, speeds.size)
    batch.q[:, 1] = 1e-3
    tips = np.concatenate([batch.advance(2048, speeds) for _ in range(10)], axis=1)
    for k, u in enumerate(speeds):
        st = Stepper(cfg, "inertia", "rom", model=model)
        st.reset(q=[0.0, 1e-3, 0.0])
        try:
            single = st.advance(2048 * 10, u)
        except DivergenceError:
            assert batch.diverged[k]
            continue
        assert not batch.diverged[k]
        np.testing.assert_array_equal(tips[k], single)
    assert batch.diverged[-1] and not batch.diverged[0]


@pytest.mark.parametrize("gusty", [False, True])
def test_sampled_march_equals_plain_march(cfg, model, gusty):
    """advance_sampled (the node's block march) gives advance's tip and states bit for bit, and its aero force (with
    a gust: from the kernel's projected upwash) to round-off."""
    rng = np.random.default_rng(3)
    n = 3000
    U = np.linspace(9.0, 12.0, n)
    F = 0.05 * rng.standard_normal(n)
    ends = np.array([1, 7, 500, 1501, 2999, 3000])
    a, b = (Stepper(cfg, "full", "rom", model=model) for _ in range(2))
    G = 0.01 * np.cumsum(rng.standard_normal((n, a.n_colloc)), axis=0) / np.sqrt(n) if gusty else None
    for st in (a, b):
        st.reset(q=[0.0, 2e-3, 0.0])
    run = a.advance_sampled(U, F, ends, gust_upwash_mps=G)
    assert run.ok and run.steps_done == n and run.samples_done == ends.size
    tips, start = [], 0
    for k, end in enumerate(ends):
        tips.append(b.advance(end - start, U[start:end], F[start:end],
                              gust_upwash_mps=None if G is None else G[start:end]))
        start = end
        np.testing.assert_array_equal(run.q[k], b.q)
        np.testing.assert_array_equal(run.qdot_per_s[k], b.qdot)
        np.testing.assert_allclose(run.aero_force_npm[k], b.aero_force_npm, rtol=1e-12,
                                   atol=1e-13 * np.max(np.abs(b.aero_force_npm)))
    np.testing.assert_array_equal(run.tip_w_over_L, np.concatenate(tips))
    np.testing.assert_array_equal(a.xi, b.xi)
    assert a.time_s == pytest.approx(b.time_s)


def test_C2_lco_mode_shape_has_node_near_tip(cfg, model, u_c3):
    """C2: the RMS of w/L along the panel has an interior node near x/L = 0.8 (tolerance 0.1)."""
    from panel_rig.analysis.lco import rms_shape
    from panel_rig.analysis.report import node_of

    _, _, st = run_lco(cfg, u_c3, 20.0, "stiffness", model=model)
    x = np.linspace(0, 1, 81)
    node = node_of(x, rms_shape(st, u_c3, 1.0, x))
    assert node is not None and abs(node - 0.8) <= 0.1, node


def test_full_nonlinearity_is_subcritical_stiffness_alone_is_not(cfg, model):
    """Item 3 evidence: 9 % below the flutter speed, a finite disturbance (q2 = 0.1) grows into a large LCO
    with the full nonlinearity (bistable, subcritical), but decays with the stiffness nonlinearity alone."""
    from panel_rig.analysis.signals import window_rms

    final = {}
    for variant in ("full", "stiffness"):
        st = Stepper(cfg, variant, "rom", model=model)
        st.reset(q=[0.0, 0.1, 0.0])
        final[variant] = window_rms(st.advance(2048 * 20, 9.5), 2048)[-1]
    assert final["full"] > 0.3 and final["stiffness"] < 0.01, final


def test_newton_test_is_met_at_a_static_deflection(cfg, model):
    """Near rest under a held force in a quiet tunnel the velocity decays towards 0 while the residual's round-off
    stays at the static load's: the Newton test's scale is floored (REST_SCALE |q| / dt) so that it can be met
    (it was relative to the velocity alone: after ~60 s every step ran all 30 iterations, 8x slower); a moving
    panel's scale is its velocity, as before."""
    from panel_rig.model.kernel import REST_SCALE, newton_scale
    from panel_rig.model.stepper import NEWTON_TOL

    st = Stepper(cfg, "full", "rom", model=model)
    st.reset()
    st.advance(int(80.0 / st.dt_s), 10.0, 0.05)  # 80 s at 10 m/s (below flutter) with a held tip force
    q, v, dt = st.q.copy(), st.qdot.copy(), st.dt_s
    # round-off of the velocity update at this state: eps times the static load's terms, through M/dt
    roundoff = np.finfo(float).eps * np.max(np.abs(st.mats.K @ q)) * dt / np.min(np.diag(st.mats.M0))
    assert NEWTON_TOL * np.max(np.abs(v)) < roundoff  # the velocity-only scale: below round-off, never met
    assert NEWTON_TOL * newton_scale(v, q, dt) > 10 * roundoff
    lco = np.array([0.3, -0.05, 0.01])
    moving = 2 * np.pi * 22.0 * lco[::-1]  # velocities of an LCO: ~omega |q|
    assert newton_scale(moving, lco, dt) == np.max(np.abs(moving)) > REST_SCALE * np.max(np.abs(lco)) / dt


def test_sampled_march_is_one_march_for_the_exact_structure(cfg, model):
    """The node's block march of the exact structure samples a single march: its tips equal one plain march of the
    whole block bit for bit (the Newton predictor's history and the kept Newton matrix carry on across samples;
    restarting them at every sample cost the fast node ~40 % per step). ``advance`` marches its last step in a
    call of its own (to keep the state before it): that step's Newton iteration starts afresh, the same solution
    to the Newton tolerance."""
    n = 1024
    U = np.full(n, 11.5)
    F = np.zeros(n)
    ends = np.arange(4, n + 1, 4)
    a, b = (Stepper(cfg, "exact", "rom", model=model) for _ in range(2))
    for st in (a, b):
        st.reset(q=[0.0, 0.05, 0.0])
    run = a.advance_sampled(U, F, ends)
    tips = b.advance(n, U, F)
    assert run.ok and run.samples_done == ends.size
    np.testing.assert_array_equal(run.tip_w_over_L[:-1], tips[:-1])
    np.testing.assert_allclose(run.tip_w_over_L[-1], tips[-1], rtol=1e-11)
    np.testing.assert_allclose(run.q[-1], b.q, rtol=1e-11, atol=1e-15)
    np.testing.assert_allclose(a.xi, b.xi, rtol=1e-11, atol=1e-15)


def test_newton_stop_on_the_estimated_error_leaves_the_step_converged(cfg, model):
    """A moving panel's step stops once the estimated error of a contracting update, |dx| r / (1 - r), is below a
    tenth of the tolerance (kernel.EST_CHORD; no confirming iteration): each step's new velocity is within
    2 tol x scale of the step's equations solved to round-off (the same kernel with a tolerance it cannot meet: all
    MAX_ITER chord-Newton iterations; measured worst 0.18 over these 100 states of a growing LCO, 1.5 with the full
    tolerance; 0 for the turbulence-sized motion)."""
    from panel_rig.model import kernel
    from panel_rig.model.stepper import NEWTON_TOL

    st = Stepper(cfg, "full", "rom", model=model)
    km = st.kernel_model
    U, none = np.full(1, 11.0), (np.zeros(0), np.zeros((1, 0)))

    def error_in_tolerances(q0, v0, xi0):
        out = []
        for tol in (NEWTON_TOL, 0.0):
            q, v, xi = q0.copy(), v0.copy(), xi0.copy()
            assert kernel.march(q, v, xi, U, np.zeros(1), km._replace(tol=tol), np.zeros(1), *none)[0] == kernel.OK
            out.append(v)
        return np.max(np.abs(out[0] - out[1])) / (NEWTON_TOL * kernel.newton_scale(out[1], q0, st.dt_s))

    small = error_in_tolerances(np.array([2e-4, 1e-5, 1e-6]), np.array([1e-3, -2e-3, 5e-4]), np.zeros(st.xi.shape[0]))
    st.reset(q=[0.0, 0.05, 0.0])
    errors = []
    for _ in range(100):
        st.advance(73, 11.0)
        errors.append(error_in_tolerances(st.q.copy(), st.qdot.copy(), st.xi.copy()))
    assert abs(st.tip_w_over_L) > 0.5  # the states span the LCO's growth
    assert max(errors) <= 2.0 and small <= 2.0


def test_kernel_nonlinear_forces_are_the_structure_s(cfg, model):
    """The kernel's nonlinear stiffness and inertia forces (Eq. 22; the inertia force as one precontracted tensor)
    equal the structure's einsum forms."""
    from panel_rig.model.kernel import _nl_force, inertia_force_tensor

    s = model.structure
    rng = np.random.default_rng(3)
    T = inertia_force_tensor(s.P_nl)
    for _ in range(4):
        q, v = rng.standard_normal(s.n_modes) * 0.3, rng.standard_normal(s.n_modes) * 20.0
        f = np.zeros(s.n_modes)
        _nl_force(q, v, s.K_nl, T, s.stiffness_scale_n, s.modal_mass_kg, True, True, f)
        ref = s.nonlinear_stiffness_force(q) + s.nonlinear_inertia_force(q, v)
        np.testing.assert_allclose(f, ref, rtol=1e-12, atol=1e-12 * np.max(np.abs(ref)))
