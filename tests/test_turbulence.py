"""Tunnel turbulence (panel_rig/rig/turbulence.py): statistics independent of the time step, seeded, convected."""

import numpy as np
import pytest
from scipy.signal import welch

from panel_rig.rig.turbulence import Turbulence, TurbulenceSettings, components, target_psd

U, L, INT = 10.0, 0.05, 0.01  # corner frequency U / (2 pi L) = 32 Hz
X = np.linspace(0.0043, 0.339, 60)  # collocation points of the default lattice, m
CHORD = 0.342


def _folded(spec, comp, f, fs):
    """Target PSD of the sampled series: the continuous spectrum folded at the Nyquist frequency."""
    tot = target_psd(spec, comp, INT * U, L, U, f)
    for m in range(1, 200):
        tot = tot + target_psd(spec, comp, INT * U, L, U, m * fs - f) + target_psd(spec, comp, INT * U, L, U, m * fs + f)
    return tot


@pytest.mark.parametrize("spectrum", ["dryden", "von_karman"])
@pytest.mark.parametrize("dt", [1 / 1024, 1 / 2048, 1 / 4096])
def test_sigma_and_octave_band_psd_independent_of_dt(spectrum, dt):
    """600 s at 10 m/s, 1 % intensity: sigma of u' and w' within 3 % of intensity * U, and the Welch PSD averaged
    over each octave band from 4 to 512 Hz (below the Nyquist frequency of the coarsest step) within 10 % of the
    target (the continuous spectrum, folded at the step's Nyquist frequency as any sampled series is)."""
    tb = Turbulence(TurbulenceSettings(INT, L, spectrum, 7), dt, X, CHORD)
    u, w = tb.reference(np.full(int(600 / dt), U))
    for x in (u, w):
        assert abs(np.std(x) / (INT * U) - 1) < 0.03
    fs = 1 / dt
    for x, comp in ((u, "u"), (w, "w")):
        f, P = welch(x, fs=fs, nperseg=int(4 * fs))
        for lo in 2.0 ** np.arange(2, 9):
            sel = (f >= lo) & (f < 2 * lo)
            ratio = np.mean(P[sel]) / np.mean(_folded(spectrum, comp, f[sel], fs))
            assert abs(ratio - 1) < 0.10, (comp, lo, ratio)


def test_von_karman_fit():
    """The 6-component fit: variance fractions sum to 1 and the mixture is within 2.5 % of the von Karman spectra
    for L Omega in 1e-3..1e3 (both components)."""
    rel, c = components("von_karman")
    assert np.all(c > 0) and abs(np.sum(c) - 1) < 1e-12
    f = np.logspace(-3, 3, 200) * U / (2 * np.pi * L)
    for comp in ("u", "w"):
        mix = sum(ck * target_psd("dryden", comp, INT * U, L * rk, U, f) for rk, ck in zip(rel, c))
        assert np.max(np.abs(mix / target_psd("von_karman", comp, INT * U, L, U, f) - 1)) < 0.025


def test_seeded_and_block_size_independent():
    """Same seed and airspeed history -> identical field, whatever the blocks it is drawn in; another seed differs;
    reset starts the series again."""
    Us = np.linspace(8.0, 12.0, 3000)
    a = Turbulence(TurbulenceSettings(0.005, 0.1, "von_karman", 1), 1 / 2048, X, CHORD)
    b = Turbulence(TurbulenceSettings(0.005, 0.1, "von_karman", 1), 1 / 2048, X, CHORD)
    c = Turbulence(TurbulenceSettings(0.005, 0.1, "von_karman", 2), 1 / 2048, X, CHORD)
    ua, wa = a.block(Us)
    parts = [b.block(Us[i:j]) for i, j in ((0, 1), (1, 700), (700, 701), (701, 3000))]
    assert np.array_equal(ua, np.concatenate([p[0] for p in parts]))
    assert np.array_equal(wa, np.concatenate([p[1] for p in parts]))
    uc, wc = c.block(Us)
    assert not np.allclose(wa, wc)
    a.reset()
    assert np.array_equal(a.block(Us)[1], wa)


def test_frozen_field_is_convected_along_the_chord():
    """Taylor: the gust at x is the leading-edge series x / U later: points 0, 100 U dt and 60.5 U dt downstream
    (the last between steps: linear interpolation, so the correlation is a little below 1)."""
    dt = 1 / 2048
    xs = np.array([0.0, 100 * U * dt, 60.5 * U * dt])
    tb = Turbulence(TurbulenceSettings(0.01, 0.1, "dryden", 3), dt, xs, CHORD)
    u, w = tb.block(np.full(20000, U))
    assert np.allclose(w[100:, 1], w[:-100, 0], rtol=0, atol=1e-12)
    r = np.corrcoef(w[61:, 2], 0.5 * (w[:-61, 0] + w[1:-60, 0]))[0, 1]
    assert r > 0.999, r
    assert np.corrcoef(w[:, 1], w[:, 0])[0, 1] < 0.9  # not the same signal at the same time


def test_off_and_zero_intensity_are_silent():
    for s in (TurbulenceSettings(0.0, 0.1, "dryden", 0), TurbulenceSettings(0.01, 0.1, "off", 0)):
        tb = Turbulence(s, 1 / 2048, X, CHORD)
        assert not tb.on
        u, w = tb.block(np.full(100, U))
        assert not np.any(u) and not np.any(w)


def test_config_keys_one_home():
    """tunnel.turbulence.* and sensor.* live in the physics SCHEMA: the dataclass defaults are the YAML's, --set
    works offline, bad values name their key."""
    from panel_rig.config import ConfigError, PanelConfig, load_config

    assert PanelConfig() == load_config()
    c = load_config(overrides=["tunnel.turbulence.intensity=0.004", "tunnel.turbulence.spectrum=dryden",
                               "tunnel.turbulence.seed=9", "sensor.latency_s=0.002"])
    s = TurbulenceSettings.from_config(c)
    assert (s.intensity, s.spectrum, s.seed, c.sensor_latency_s) == (0.004, "dryden", 9, 0.002)
    for bad in ("tunnel.turbulence.spectrum=kolmogorov", "tunnel.turbulence.intensity=-0.1", "sensor.tip_noise_m=x"):
        with pytest.raises(ConfigError, match=bad.split("=")[0]):
            load_config(overrides=[bad])
