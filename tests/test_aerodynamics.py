"""The vortex lattice against classical thin-airfoil results, independent of the paper."""

import numpy as np
import pytest
from scipy.special import hankel2

from panel_rig.model.aerodynamics import build_lattice, harmonic_lift, indicial_lift, steady_lift_coefficient


def theodorsen(k):
    return hankel2(1, k) / (hankel2(1, k) + 1j * hankel2(0, k))


@pytest.mark.parametrize("n_body", [10, 60, 200])
def test_steady_flat_plate_lift_is_2_pi_alpha(n_body):
    """C_l = 2 pi alpha to 1e-9: the 1/4-3/4 rule is exact for the flat plate at any element count."""
    lat = build_lattice(1.0, n_body, n_body, 0.992)
    assert steady_lift_coefficient(lat, 0.02) == pytest.approx(2 * np.pi * 0.02, rel=1e-9)


def wagner_jones(s):
    """R. T. Jones' approximation of Wagner's function (accurate to about 0.5 %)."""
    return 1 - 0.165 * np.exp(-0.0455 * s) - 0.335 * np.exp(-0.3 * s)


def test_indicial_lift_follows_wagner_and_converges():
    """Lift build-up after a step in incidence against Wagner's function for s = 2Ut/c in [1, 30],
    long wake (40 chords): within 0.015 of the steady lift at 60 elements; the error shrinks from 30 to 60."""
    errors = {}
    for nb in (30, 60):
        lat = build_lattice(1.0, nb, 40 * nb, 0.999)
        lift = indicial_lift(lat, 15 * nb)
        s = 2 * (np.arange(lift.size) + 0.5) / nb
        sel = (s >= 1) & (s <= 30)
        errors[nb] = np.max(np.abs(lift[sel] - wagner_jones(s[sel])))
    assert errors[60] < 0.015, errors
    assert errors[60] <= errors[30] + 1e-3, errors


@pytest.mark.parametrize("k", [0.05, 0.1, 0.3, 0.5, 1.0])
def test_harmonic_lift_matches_theodorsen(k):
    """Plunge and pitch (about mid-chord) lift against Theodorsen: |ratio - 1| < 1.5 %, phase < 1 deg
    at 60 elements with a 60-chord wake."""
    r60 = _theodorsen_ratios(k, 60, 60)
    assert np.all(np.abs(np.abs(r60) - 1) < 0.015), r60
    assert np.all(np.abs(np.angle(r60, deg=True)) < 1.0), r60


def test_harmonic_lift_converges_in_element_count():
    """At k = 1 (where the element size, not the wake length, limits accuracy) the error falls as
    the element count grows: 30 -> 60 -> 120 elements, 10-chord wake."""
    errs = [np.max(np.abs(_theodorsen_ratios(1.0, nb, 10) - 1)) for nb in (30, 60, 120)]
    assert errs[2] < errs[1] < errs[0], errs


def _theodorsen_ratios(k, nb, wake_chords):
    """VLM / Theodorsen lift ratios for plunge and pitch about mid-chord."""
    lat = build_lattice(2.0, nb, wake_chords * nb, 0.999)
    xc = lat.x_colloc_m - 1.0  # semi-chord b = 1
    plunge = harmonic_lift(lat, k, np.ones(nb), np.zeros(nb)) / (np.pi * k**2 - 2j * np.pi * k * theodorsen(k))
    pitch = harmonic_lift(lat, k, -xc, -np.ones(nb)) / (np.pi * 1j * k + 2 * np.pi * theodorsen(k) * (1 + 0.5j * k))
    return np.array([plunge, pitch])
