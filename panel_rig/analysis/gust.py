"""Gust response of the rigid lattice against the classical thin-airfoil results (Sears, Kuessner).

The lattice is the configuration's (airfoil + panel, ``aero.elements``, ``aero.wake_relaxation``) held rigid, with
a longer wake for this check (the rig's 1-chord wake is a modelling choice of the paper, not meant for k -> 0).
"""

from __future__ import annotations

import numpy as np
from scipy.special import hankel2, jv

from panel_rig.config import PanelConfig
from panel_rig.model.aerodynamics import build_lattice, sinusoidal_gust_lift

GUST_WAKE_CHORDS = 60.0  # as the Theodorsen check of docs/validation.md


def sears(k: np.ndarray | float) -> np.ndarray:
    """Sears function S(k) = [J0(k) - i J1(k)] C(k) + i J1(k), lift per 2 pi rho U b w0, gust referred to mid-chord."""
    k = np.asarray(k, dtype=float)
    C = hankel2(1, k) / (hankel2(1, k) + 1j * hankel2(0, k))
    return (jv(0, k) - 1j * jv(1, k)) * C + 1j * jv(1, k)


def kuessner(s: np.ndarray, k_max: float = 400.0, n: int = 400_001) -> np.ndarray:
    """Kuessner's function psi(s), s = U t / b after the gust front reaches the leading edge, by inverting the
    Sears function (step response of a causal system: psi(s) = 2/pi int_0^inf Re[S(k) e^{-ik}] sin(ks)/k dk).
    The truncation at k_max changes psi by < 1e-4 for s >= 0.5 (checked against k_max = 1600)."""
    k = np.linspace(1e-7, k_max, n)
    re = np.real(sears(k) * np.exp(-1j * k)) / k
    return np.array([2.0 / np.pi * np.trapezoid(re * np.sin(k * si), k) for si in np.atleast_1d(s)])


def gust_lattice(cfg: PanelConfig, wake_chords: float = GUST_WAKE_CHORDS):
    """The configuration's lattice with a wake of ``wake_chords`` chords."""
    n_wake = max(2, int(round(wake_chords * cfg.n_elements)))
    return build_lattice(cfg.chord_m, cfg.n_elements, n_wake, cfg.wake_relaxation, cfg.running_sum)


def sears_comparison(cfg: PanelConfig, ks, wake_chords: float = GUST_WAKE_CHORDS) -> list[dict]:
    """Per k: |lift| / (2 pi rho U b w0) and its phase (deg) against the gust at mid-chord, and Sears' values."""
    lat = gust_lattice(cfg, wake_chords)
    out = []
    for k in ks:
        lift = sinusoidal_gust_lift(lat, float(k))
        s = complex(sears(float(k)))
        out.append({"k": float(k), "lift_magnitude": abs(lift), "lift_phase_deg": float(np.degrees(np.angle(lift))),
                    "sears_magnitude": abs(s), "sears_phase_deg": float(np.degrees(np.angle(s)))})
    return out
