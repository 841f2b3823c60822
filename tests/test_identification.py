"""Modal identification and flutter-boundary prediction (issue 10, part A).

Sensor assumption (until issue 9's sensor model lands): a lab laser displacement sensor on the trailing edge,
white noise of 5 um RMS; tip deflection ~0.3 mm RMS under turbulence, ~0.5 mm peak after a tap.
Turbulence stand-in: band-limited (0-100 Hz) white trailing-edge force on the stepper.
"""

import numpy as np
import pytest
import scipy.signal

from panel_rig.analysis.flutter_margin import (
    damping_trend_speed,
    flutter_margin_speed,
    predict_by_damping_trend,
    predict_by_flutter_margin,
    zimmerman_weissenburger,
)
from panel_rig.analysis.identification import (
    ModalEstimate,
    SegmentCovariances,
    SSISettings,
    combine_estimates,
    decimate,
    identify_free_decay,
    identify_ssi,
    identify_ssi_covariances,
)
from panel_rig.analysis.vg import model_flutter_speed, pole_damping_ratio, pole_from_modal, vg_diagram
from panel_rig.config import load_config
from panel_rig.model.aeroelastic import AeroelasticModel
from panel_rig.model.stepper import Stepper

NOISE_M = 5e-6  # sensor noise, m RMS
TURB_RMS_M = 3e-4  # tip RMS under turbulence
TAP_PEAK_M = 5e-4  # tip peak after a tap
DT = 1 / 2048
# panel-like modes: heavily aero-damped first, lightly damped flutter mode, third
MODES = ((5.5, 0.40), (23.0, 0.005), (69.0, 0.009))
BANDS = ((3.0, 9.0), (20.0, 26.0), (60.0, 80.0))


def modal_response(modes, T, rng):
    """Tip response of uncoupled modes to one white force (exact zero-order-hold discretisation), scaled to
    TURB_RMS_M, plus sensor noise."""
    n = int(T / DT)
    f = rng.standard_normal(n)
    y = np.zeros(n)
    for fr, z in modes:
        w = 2 * np.pi * fr
        b, a, _ = scipy.signal.cont2discrete(([w * w], [1, 2 * z * w, w * w]), DT, method="zoh")
        y += scipy.signal.lfilter(b.ravel(), a, f)
    return y * TURB_RMS_M / np.std(y) + NOISE_M * rng.standard_normal(n)


def free_decay(modes, T, rng, amplitudes=(1.0, 0.6, 0.2)):
    t = np.arange(int(T / DT)) * DT
    y = np.zeros_like(t)
    for (fr, z), a in zip(modes, amplitudes):
        s = complex(pole_from_modal(fr, z))
        y += a * np.exp(s.real * t) * np.cos(s.imag * t + 0.3)
    return y * TAP_PEAK_M / np.max(np.abs(y)) + NOISE_M * rng.standard_normal(t.size)


# ---- Zimmerman–Weissenburger -----------------------------------------------------------------------
def _zw_sign_error(b1, b2, w1, w2):
    """The variant found in public code: "- 2((b1+b2)/2)^2" inside the last bracket."""
    bm, dw = (b1 + b2) / 2, (w2**2 - w1**2) / 2
    return ((dw + (b2**2 - b1**2) / 2) ** 2 + 4 * b1 * b2 * ((w1**2 + w2**2) / 2 + 2 * bm**2)
            - ((b2 - b1) / (b2 + b1) * dw - 2 * bm**2) ** 2)


def test_flutter_margin_is_the_routh_discriminant_of_the_two_mode_quartic():
    """F = Delta_3 / a1^2 of (s^2 + 2b1 s + b1^2 + w1^2)(s^2 + 2b2 s + b2^2 + w2^2) for random pole pairs (one
    may be unstable), and F = 0 when a mode sits on the imaginary axis; the common variant with the sign of
    2((b1+b2)/2)^2 flipped in the last bracket gives -2 b1^2 (w2^2 - w1^2)/2 there instead of 0."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        w1, w2 = rng.uniform(5, 200, 2)
        b1, b2 = rng.uniform(0.01, 20), rng.uniform(-20, 20)
        a = np.poly([-b1 + 1j * w1, -b1 - 1j * w1, -b2 + 1j * w2, -b2 - 1j * w2]).real
        a1, a2, a3, a4 = a[1:]
        delta3 = a1 * a2 * a3 - a3**2 - a1**2 * a4
        F = zimmerman_weissenburger(complex(-b1, w1), complex(-b2, w2))
        assert F == pytest.approx(delta3 / a1**2, rel=1e-9, abs=1e-9 * (w1 * w2) ** 2)
        assert zimmerman_weissenburger(complex(-b1, w1), complex(0.0, w2)) == pytest.approx(
            0.0, abs=1e-9 * (w1 * w2) ** 2)

        assert _zw_sign_error(b1, 0.0, w1, w2) == pytest.approx(-b1**2 * (w2**2 - w1**2), rel=1e-6)


def _binary(kappa, c1, c2, w1, w2):
    """2-DOF system x'' + diag(c) x' + [[w1^2, k U^2], [-k U^2, w2^2]] x = 0 (circulatory coupling growing with
    dynamic pressure). Its quartic: (s^2 + c1 s + w1^2)(s^2 + c2 s + w2^2) + (k U^2)^2; Routh Delta_3 = 0 gives
    (k U_f^2)^2 = (a1 a2 a3 - a3^2 - a1^2 w1^2 w2^2) / a1^2 in closed form."""
    a1, a2, a3 = c1 + c2, w1**2 + w2**2 + c1 * c2, c1 * w2**2 + c2 * w1**2
    uf = ((a1 * a2 * a3 - a3**2 - a1**2 * w1**2 * w2**2) / a1**2) ** 0.25 / np.sqrt(kappa)

    def poles(u):
        A = np.block([[np.zeros((2, 2)), np.eye(2)],
                      [-np.array([[w1**2, kappa * u * u], [-kappa * u * u, w2**2]]), -np.diag([c1, c2])]])
        s = np.linalg.eigvals(A)
        s = s[s.imag > 0]
        return s[np.argsort(s.imag)]

    return uf, poles


def test_flutter_margin_predicts_the_analytic_flutter_speed_of_a_binary_system():
    """Exact poles at 0.5-0.9 U_f: F is exactly quadratic in U^2 for this system, so the degree-2 fit returns
    the closed-form U_f to 1e-6; F > 0 below U_f and < 0 above; the bootstrap interval of slightly noisy points
    contains U_f."""
    uf, poles = _binary(kappa=3.0, c1=0.8, c2=0.3, w1=2 * np.pi * 4, w2=2 * np.pi * 6)
    # check the closed form itself: one pole has zero real part at uf
    assert np.min(np.abs(poles(uf).real)) < 1e-6 * np.max(np.abs(poles(uf)))
    u = uf * np.array([0.5, 0.6, 0.7, 0.8, 0.9])
    P = np.array([poles(x) for x in u])
    assert flutter_margin_speed(u, P[:, 0], P[:, 1], degree=2) == pytest.approx(uf, rel=1e-6)
    below, above = poles(0.95 * uf), poles(1.05 * uf)
    assert zimmerman_weissenburger(*below) > 0 > zimmerman_weissenburger(*above)
    est = [[ModalEstimate(float(np.abs(p[m]) / 2 / np.pi), float(pole_damping_ratio(p[m])),
                          2e-4 * np.abs(p[m]) / 2 / np.pi, 0.005 * abs(pole_damping_ratio(p[m])), 9, "exact")
            for p in P] for m in (0, 1)]
    pred = predict_by_flutter_margin(u, est[0], est[1], degree=2, n_boot=400)
    assert pred.speed_mps == pytest.approx(uf, rel=1e-6)
    assert pred.ci_mps[0] < uf < pred.ci_mps[1]
    assert pred.ci_mps[1] - pred.ci_mps[0] < 0.2 * uf


# ---- identification on synthetic signals --------------------------------------------------------
def test_ssi_on_synthetic_turbulence_response():
    """600 s of response to white noise with 5 um sensor noise on 0.3 mm RMS: for the lightly damped modes
    (zeta = 0.005, 0.009) frequency within 0.5 % and damping ratio within 10 % (the statistical error of a damping
    estimate falls as 1/sqrt(zeta omega T): 600 s gives ~5 % standard error at zeta = 0.005, docs/validation.md).
    The heavily damped first mode (zeta = 0.4, identified at 320 Hz so that its covariance decay is resolved)
    cannot meet 0.5 % in frequency from 600 s: its statistical scatter is several per cent (jackknife standard
    errors 3-8 % over seeds); checked against its own interval (3 standard errors) and 10 % in damping."""
    y = modal_response(MODES, 600.0, np.random.default_rng(10))
    est = identify_ssi(y, DT, BANDS[1:])
    for (f, z), e in zip(MODES[1:], est):
        assert e is not None and e.n_stable >= 6
        assert e.frequency_hz == pytest.approx(f, rel=5e-3)
        assert e.damping_ratio == pytest.approx(z, rel=0.10)
        lo, hi = e.damping_ci()
        assert lo < z < hi
    (f, z), e = MODES[0], identify_ssi(y, DT, BANDS[:1], max_rate_hz=320)[0]
    assert abs(e.frequency_hz - f) < 3 * e.frequency_se_hz
    assert e.damping_ratio == pytest.approx(z, rel=0.10)


def test_ssi_interval_matches_the_scatter_over_records():
    """The jackknife standard error is the real scatter: over 8 independent 200 s records the flutter-like mode's
    damping estimates scatter with a standard deviation within a factor 2 of the mean reported standard error, and
    their mean is within 2 standard errors of the truth (no bias beyond the noise)."""
    ests = [identify_ssi(modal_response(MODES, 200.0, np.random.default_rng(100 + k)), DT, BANDS[1:2])[0]
            for k in range(8)]
    z = np.array([e.damping_ratio for e in ests])
    se = np.mean([e.damping_se for e in ests])
    assert 0.5 < np.std(z, ddof=1) / se < 2.0
    assert abs(z.mean() - MODES[1][1]) < 2 * np.std(z, ddof=1) / np.sqrt(z.size) + 1e-4


def test_ssi_stabilisation_rejects_a_band_without_a_mode():
    """Pure measurement noise (white) has no physical pole: no stable pole in a band without a mode."""
    rng = np.random.default_rng(5)
    y = modal_response(MODES, 100.0, rng)
    est = identify_ssi(y, DT, [(35.0, 55.0)])
    assert est == [None]


def test_a_record_with_a_nan_is_refused_by_name():
    """A NaN in a 20 s record raised LinAlgError ("SVD did not converge") from deep in identify_ssi (an all-NaN
    record did in identify_free_decay): both now refuse it, naming the first sample that is not finite."""
    y = modal_response(MODES, 20.0, np.random.default_rng(3))
    y[1234] = np.nan
    for identify in (identify_ssi, identify_free_decay):
        with pytest.raises(ValueError, match="1 non-finite sample.*the first at index 1234"):
            identify(y, DT, BANDS[1:2])
    with pytest.raises(ValueError, match="50 non-finite sample.*index 0"):
        identify_free_decay(np.full(50, np.nan), DT, BANDS[1:2])


def test_incremental_covariances_equal_the_batch_call():
    """A monitor adding segments one by one gets the batch result: same covariances, same estimate."""
    y = modal_response(MODES, 200.0, np.random.default_rng(7))
    s = SSISettings()
    batch = identify_ssi(y, DT, BANDS[1:2], s)[0]
    yd, dtd = decimate(y, DT, 8.0 * BANDS[1][1])
    acc = SegmentCovariances(dtd, 2 * s.rows(dtd, BANDS[1:2]))
    n = yd.size // s.n_segments
    for k in range(s.n_segments):
        acc.add(yd[k * n : (k + 1) * n])
    inc = identify_ssi_covariances(acc.covs, dtd, BANDS[1:2], s)[0]
    assert inc == batch


def test_free_decay_on_synthetic_taps():
    """A tap's free decay (0.5 mm peak, 5 um noise, 8 s, subsampled to 409.6 Hz): frequency within 0.5 % and
    damping within 10 % for each mode; over 8 taps the reported standard error of the flutter-like mode matches the
    scatter (factor 2) and combine_estimates' interval contains the truth."""
    taps = [identify_free_decay(free_decay(MODES, 8.0, np.random.default_rng(200 + k)), DT, BANDS, max_rate_hz=400)
            for k in range(8)]
    for (f, z), e in zip(MODES, taps[0]):
        assert e.frequency_hz == pytest.approx(f, rel=5e-3)
        assert e.damping_ratio == pytest.approx(z, rel=0.10)
    flutter_mode = [t[1] for t in taps]
    z = np.array([e.damping_ratio for e in flutter_mode])
    assert 0.5 < np.std(z, ddof=1) / np.mean([e.damping_se for e in flutter_mode]) < 2.0
    comb = combine_estimates(flutter_mode)
    lo, hi = comb.damping_ci()
    assert lo < MODES[1][1] < hi and comb.dof == 7


# ---- against the model (stepper) ----------------------------------------------------------------
def _turbulence(cfg, model, u, T, seed, variant="linear"):
    """Stepper tip (m) under a band-limited (0-100 Hz) white trailing-edge force, scaled to TURB_RMS_M (exact for
    the linear model), plus sensor noise; 2 s of run-in dropped."""
    st = Stepper(cfg, variant, "rom", model=model)
    rng = np.random.default_rng(seed)
    n0, n = int(2.0 / st.dt_s), int(T / st.dt_s)
    sos = scipy.signal.butter(4, 100.0, fs=1 / st.dt_s, output="sos")
    force = 0.2 * scipy.signal.sosfilt(sos, rng.standard_normal(n0 + n))
    w = st.advance(n0 + n, u, force)[n0:] * cfg.panel_length_m
    return w * TURB_RMS_M / np.std(w) + NOISE_M * rng.standard_normal(n), st.dt_s


def _tap(cfg, model, u, rng):
    """Stepper free decay after a 5 ms half-sine tap at the trailing edge, scaled to TAP_PEAK_M, plus noise."""
    st = Stepper(cfg, "linear", "rom", model=model)
    k = int(0.005 / st.dt_s)
    st.advance(k, u, np.sin(np.pi * np.arange(k) / k))
    w = st.advance(int(8.0 / st.dt_s), u) * cfg.panel_length_m
    return w * TAP_PEAK_M / np.max(np.abs(w)) + NOISE_M * rng.standard_normal(w.size), st.dt_s


@pytest.fixture(scope="module")
def paper(cfg, model):
    uf, mode = model_flutter_speed(model)
    return cfg, model, uf, mode


def test_ssi_on_stepper_turbulence_matches_the_vg(paper):
    """At 0.6-0.9 U_f, 600 s of turbulence response each: the flutter mode's identified damping ratio within 20 %
    of the model's V-g and its frequency within 0.5 %; the V-g value inside the (widened x2) interval."""
    cfg, model, uf, mode = paper
    speeds = uf * np.array([0.6, 0.7, 0.8, 0.9])
    vg = vg_diagram(model, speeds)
    for k, u in enumerate(speeds):
        w, dt = _turbulence(cfg, model, u, 600.0, seed=20 + k)
        f, z = vg.frequency_hz[k, mode - 1], vg.damping_ratio[k, mode - 1]
        e = identify_ssi(w, dt, [(0.85 * f, 1.15 * f)])[0]
        assert e is not None
        assert e.frequency_hz == pytest.approx(f, rel=5e-3)
        assert e.damping_ratio == pytest.approx(z, rel=0.20)


@pytest.mark.parametrize("sets", [[], ["panel.thickness_m=0.0004"], ["structure.damping_ratio=0.01"]],
                         ids=["paper", "thickness_0.4mm", "damping_0.01"])
def test_prediction_from_subcritical_taps(sets):
    """Taps at 0.5-0.9 U_f (never above), free-decay identification of modes 1 and 2, then both predictors: U_f
    within 3 % of the model's linear U_f (stepper's continuous-time model); flutter-mode damping of every point
    within 20 % of the V-g; intervals finite and around the estimate."""
    cfg = load_config(None, sets)
    model = AeroelasticModel(cfg)
    uf, mode = model_flutter_speed(model)
    speeds = uf * np.array([0.5, 0.6, 0.7, 0.8, 0.9])
    vg = vg_diagram(model, speeds)
    rng = np.random.default_rng(30)
    m1, m2 = [], []
    for k, u in enumerate(speeds):
        w, dt = _tap(cfg, model, u, rng)
        f1, f2 = vg.frequency_hz[k, 0], vg.frequency_hz[k, mode - 1]
        e1, e2 = identify_free_decay(w, dt, [(0.6 * f1, 1.5 * f1), (0.85 * f2, 1.15 * f2)])
        assert e2.damping_ratio == pytest.approx(vg.damping_ratio[k, mode - 1], rel=0.20)
        m1.append(e1)
        m2.append(e2)
    trend = predict_by_damping_trend(speeds, m2, n_boot=500)
    zw = predict_by_flutter_margin(speeds, m1, m2, n_boot=500)
    for p in (trend, zw):
        assert p.speed_mps == pytest.approx(uf, rel=0.03), p
        assert p.ci_mps[0] <= p.speed_mps <= p.ci_mps[1] < np.inf
        assert 0 < p.margin(speeds[-1]) < 0.2


def test_damping_trend_in_airspeed_would_fail_by_the_hump(paper):
    """Why the trend is fitted against dynamic pressure with a quadratic: on the model's exact V-g at 0.5-0.9 U_f a
    straight line in U overshoots U_f by > 10 % (the flutter mode's damping rises, then falls), the quadratic in
    U^2 is within 1 %."""
    _, model, uf, mode = paper
    u = uf * np.array([0.5, 0.6, 0.7, 0.8, 0.9])
    z = vg_diagram(model, u).damping_ratio[:, mode - 1]
    from panel_rig.analysis.flutter_margin import extrapolated_root

    assert extrapolated_root(u, z, 1) > 1.10 * uf
    assert damping_trend_speed(u, z) == pytest.approx(uf, rel=0.01)


def test_finite_or_none_gives_null_for_anything_that_is_not_a_finite_number():
    """JSON numbers of a prediction or a monitor message: a missing, non-finite or non-numeric value is null (the
    live flutter test's summary takes them from parsed monitor messages, where a value may be a string)."""
    from panel_rig.analysis.flutter_margin import finite_or_none

    assert [finite_or_none(x) for x in (None, "nan", "10.2", np.nan, np.inf, -np.inf)] == [None] * 6
    assert finite_or_none(np.float64(10.5)) == 10.5 and finite_or_none(3) == 3.0
