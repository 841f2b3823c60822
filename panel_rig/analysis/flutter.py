"""Linear flutter: aeroelastic eigenvalues versus airspeed and the flutter boundary (Sec. 3.2.1, Fig. 3)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.optimize import brentq

from panel_rig.model.aeroelastic import AeroelasticModel

FORMULATIONS = ("discrete", "continuous")


@dataclass(frozen=True)
class Eigen:
    """Continuous-time eigenvalues s (1/s) and the modal part |q| of each eigenvector."""

    s: np.ndarray
    q_part: np.ndarray  # (n_modes, len(s)) magnitudes of the structural coordinates


def eigenvalues(model: AeroelasticModel, airspeed_mps: float, aero: str = "full",
                rom_modes: int | None = None, formulation: str = "discrete") -> Eigen:
    """Eigenvalues of the linear aeroelastic system at U.

    formulation 'discrete': Eq. (24) (aero 'full') or Eq. (25) (aero 'rom') at dt = dx/U, s = ln(z)/dt,
    as the paper does; 'continuous': the continuous-time model of the stepper.
    """
    n = model.structure.n_modes
    if formulation == "discrete":
        if aero == "full":
            LHS, RHS, dt = model.discrete_full(airspeed_mps)
        else:
            LHS, RHS, dt = model.discrete_rom(airspeed_mps, rom_modes)
        z, vec = scipy.linalg.eig(RHS, LHS)
        ok = np.isfinite(z) & (np.abs(z) > 1e-12)
        z, vec = z[ok], vec[:, ok]
        s = np.log(z) / dt
        q = np.abs(vec[-n:])  # (v, q) at the end; q part
    elif formulation == "continuous":
        Mc, Ac = model.continuous_matrices(airspeed_mps, None if aero == "full" else rom_modes)
        s, vec = scipy.linalg.eig(Ac, Mc)
        q = np.abs(vec[:n])
    else:
        raise ValueError(f"formulation must be one of {FORMULATIONS}")
    return Eigen(s=s, q_part=q / np.maximum(q.max(axis=0), 1e-300))


def growth_rate(model: AeroelasticModel, airspeed_mps: float, **kw) -> float:
    """Largest real part of the eigenvalues (1/s): positive means unstable."""
    return float(np.max(eigenvalues(model, airspeed_mps, **kw).s.real))


class UnstableAtScanStart(ValueError):
    """The system is already unstable at the lowest airspeed of the flutter scan (no crossing to find)."""


@dataclass(frozen=True)
class FlutterPoint:
    speed_mps: float
    frequency_hz: float
    dominant_mode: int  # 1-based structural mode with the largest share of the flutter eigenvector
    mode_shares: np.ndarray  # |q_i| of the flutter eigenvector, normalised to max 1


def find_flutter(model: AeroelasticModel, aero: str = "full", rom_modes: int | None = None,
                 formulation: str = "discrete", u_min: float = 1.0, u_max: float = 60.0,
                 n_scan: int = 60) -> FlutterPoint | None:
    """Lowest airspeed where an eigenvalue crosses into Re s > 0: coarse scan, then Brent's method."""
    kw = dict(aero=aero, rom_modes=rom_modes, formulation=formulation)
    speeds = np.linspace(u_min, u_max, n_scan)
    prev_u, prev_g = speeds[0], growth_rate(model, speeds[0], **kw)
    if prev_g > 0:
        hint = (" (the aero ROM is least accurate at low airspeed, where the reduced frequency is high: compare "
                "--aero full)") if aero == "rom" else ""
        raise UnstableAtScanStart(f"unstable already at {u_min} m/s{hint}")
    for u in speeds[1:]:
        g = growth_rate(model, u, **kw)
        if g > 0:
            uf = brentq(lambda x: growth_rate(model, x, **kw), prev_u, u, xtol=1e-6)
            eig = eigenvalues(model, uf, **kw)
            i = int(np.argmax(np.where(eig.s.imag > 0, eig.s.real, -np.inf)))
            shares = eig.q_part[:, i]
            return FlutterPoint(uf, float(eig.s[i].imag / (2 * np.pi)), int(np.argmax(shares)) + 1, shares)
        prev_u, prev_g = u, g
    return None
