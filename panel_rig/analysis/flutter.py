"""Linear flutter: aeroelastic eigenvalues versus airspeed and the flutter boundary (Sec. 3.2.1, Fig. 3)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.optimize import brentq, minimize_scalar

from panel_rig.model.aerodynamics import MAX_AIRSPEED_MPS
from panel_rig.model.aeroelastic import AeroelasticModel

FORMULATIONS = ("discrete", "continuous")


@dataclass(frozen=True)
class Eigen:
    """Continuous-time eigenvalues s (1/s) and the modal part |q| of each eigenvector."""

    s: np.ndarray
    q_part: np.ndarray  # (n_modes, len(s)) magnitudes of the structural coordinates


def _pencil(model: AeroelasticModel, airspeed_mps: float, aero: str, rom_modes: int | None,
            formulation: str) -> tuple[np.ndarray, np.ndarray, float | None]:
    """(A, B, dt): the eigenproblem A v = z B v at U; dt the step (s) of the discrete formulation, whose
    eigenvalues z map to s = ln(z) / dt, None for the continuous one (z = s)."""
    if formulation == "discrete":
        if aero == "full":
            LHS, RHS, dt = model.discrete_full(airspeed_mps)
        else:
            LHS, RHS, dt = model.discrete_rom(airspeed_mps, rom_modes)
        return RHS, LHS, dt
    if formulation == "continuous":
        Mc, Ac = model.continuous_matrices(airspeed_mps, None if aero == "full" else rom_modes)
        return Ac, Mc, None
    raise ValueError(f"formulation must be one of {FORMULATIONS}")


def _kept(z: np.ndarray, dt: float | None) -> np.ndarray:
    """The finite eigenvalues of the pencil (and, discrete, nonzero: ln z finite)."""
    return np.isfinite(z) & (np.abs(z) > 1e-12) if dt is not None else np.ones(z.shape, bool)


def roots(model: AeroelasticModel, airspeed_mps: float, aero: str = "full", rom_modes: int | None = None,
          formulation: str = "discrete") -> np.ndarray:
    """The continuous-time eigenvalues s (1/s) of :func:`eigenvalues`, without the eigenvectors (half the work)."""
    A, B, dt = _pencil(model, airspeed_mps, aero, rom_modes, formulation)
    z = scipy.linalg.eigvals(A, B)
    z = z[_kept(z, dt)]
    return np.log(z) / dt if dt is not None else z


def eigenvalues(model: AeroelasticModel, airspeed_mps: float, aero: str = "full",
                rom_modes: int | None = None, formulation: str = "discrete") -> Eigen:
    """Eigenvalues of the linear aeroelastic system at U.

    formulation 'discrete': Eq. (24) (aero 'full') or Eq. (25) (aero 'rom') at dt = dx/U, s = ln(z)/dt,
    as the paper does; 'continuous': the continuous-time model of the stepper.
    """
    n = model.structure.n_modes
    A, B, dt = _pencil(model, airspeed_mps, aero, rom_modes, formulation)
    z, vec = scipy.linalg.eig(A, B)
    ok = _kept(z, dt)
    z, vec = z[ok], vec[:, ok]
    if dt is not None:
        s = np.log(z) / dt
        q = np.abs(vec[-n:])  # (v, q) at the end; q part
    else:
        s = z
        q = np.abs(vec[:n])
    return Eigen(s=s, q_part=q / np.maximum(q.max(axis=0), 1e-300))


def growth_rate(model: AeroelasticModel, airspeed_mps: float, **kw) -> float:
    """Largest real part of the eigenvalues (1/s): positive means unstable."""
    return float(np.max(roots(model, airspeed_mps, **kw).real))


class UnstableAtScanStart(ValueError):
    """The system is already unstable at the lowest airspeed of the flutter scan (no crossing to find)."""


@dataclass(frozen=True)
class FlutterPoint:
    speed_mps: float
    frequency_hz: float
    dominant_mode: int  # 1-based structural mode with the largest share of the flutter eigenvector
    mode_shares: np.ndarray  # |q_i| of the flutter eigenvector, normalised to max 1


#: the flutter scan's default airspeed step (m/s): from 1 m/s to MAX_AIRSPEED_MPS, every command's range
SCAN_STEP_MPS = 1.0
#: the airspeed step (m/s) over which each eigenvalue's d Re s / dU is taken at a scan sample
SLOPE_STEP_MPS = 1e-3


RootsAt = Callable[[float], np.ndarray]  # the eigenvalues s (1/s) at an airspeed (m/s)


def _real_parts_and_slopes(roots_at: RootsAt, airspeed_mps: float) -> tuple[np.ndarray, np.ndarray]:
    """Re s (1/s) of every eigenvalue at U and its slope d Re s / dU (1/m), each root matched to the nearest root at
    U + SLOPE_STEP_MPS; 0 where that root is more than 1 % of |s| away (no match: the step moves a root by about
    SLOPE_STEP_MPS / U of |s|, 1e-4 at 10 m/s; the far, heavily damped roots of the discrete lattice do not pair)."""
    s0 = roots_at(airspeed_mps)
    s1 = roots_at(airspeed_mps + SLOPE_STEP_MPS)
    dist = np.abs(s0[:, None] - s1[None, :])
    nearest = np.argmin(dist, axis=1)
    paired = dist[np.arange(s0.size), nearest] <= 1e-2 * np.maximum(np.abs(s0), 1.0)
    return s0.real, np.where(paired, (s1[nearest].real - s0.real) / SLOPE_STEP_MPS, 0.0)


def _may_turn_unstable(real: np.ndarray, slope: np.ndarray, span_mps: float) -> bool:
    """Whether a stable root's straight-line extrapolation over ``span_mps`` (signed: back from the interval's upper
    end when negative) reaches Re s > 0: a window of instability may open and close between two scan samples."""
    return bool(np.any((real < 0) & (real + slope * span_mps > 0)))


def instability_edges(roots_at: RootsAt, speeds_mps: np.ndarray, xtol_mps: float = 1e-6) -> Iterator[float]:
    """The airspeeds (m/s) where a system turns unstable (an eigenvalue crosses into Re s > 0) and stable again,
    alternately and in order, over the scan ``speeds_mps``: found on its samples, then by Brent's method; each is
    yielded as soon as it is found. Unstable at the first sample: that sample is the first edge.

    A window of instability narrower than the scan step is found when a root stable at a sample heads for Re s > 0
    within the step (:func:`_may_turn_unstable`, from either end): the growth rate's maximum in that interval is then
    sought. A stable gap narrower than the step inside an unstable range is not looked for."""
    def growth(u: float) -> float:
        return float(np.max(roots_at(u).real))

    def unstable_between(lo_mps: float, hi_mps: float) -> float | None:
        res = minimize_scalar(lambda u: -growth(u), bounds=(lo_mps, hi_mps), method="bounded",
                              options={"xatol": 1e-4 * (hi_mps - lo_mps)})
        return float(res.x) if -res.fun > 0 else None

    def crossing(lo_mps: float, hi_mps: float) -> float:
        return float(brentq(growth, lo_mps, hi_mps, xtol=xtol_mps))

    prev_u = float(speeds_mps[0])
    real, slope = _real_parts_and_slopes(roots_at, prev_u)
    unstable_at = None  # the last airspeed seen unstable, None while stable
    if real.max() > 0:
        yield prev_u
        unstable_at = prev_u
    for u in map(float, speeds_mps[1:]):
        if unstable_at is None:
            real_u, slope_u = _real_parts_and_slopes(roots_at, u)
            hi = u if real_u.max() > 0 else None
            if hi is None and (_may_turn_unstable(real, slope, u - prev_u)
                               or _may_turn_unstable(real_u, slope_u, prev_u - u)):
                hi = unstable_between(prev_u, u)
            if hi is not None:
                yield crossing(prev_u, hi)
                unstable_at = hi
                if hi < u:  # a window that closes before this sample
                    yield crossing(hi, u)
                    unstable_at = None
            real, slope = real_u, slope_u
        elif growth(u) > 0:
            unstable_at = u
        else:
            yield crossing(unstable_at, u)
            unstable_at = None
            real, slope = _real_parts_and_slopes(roots_at, u)
        prev_u = u


def edges_to_ranges(edges: list[float]) -> list[tuple[float, float | None]]:
    """Alternating edges (unstable from, stable from, ...) as ranges (start, end); end None: to the scan's end."""
    return [(edges[i], edges[i + 1] if i + 1 < len(edges) else None) for i in range(0, len(edges), 2)]


def _crossings(model: AeroelasticModel, u_min: float, u_max: float, n_scan: int | None, aero: str,
               **kw) -> Iterator[float]:
    """:func:`instability_edges` of the model's eigenvalues; raises UnstableAtScanStart when unstable at u_min."""
    if n_scan is None:
        n_scan = int(round((u_max - u_min) / SCAN_STEP_MPS)) + 1
    speeds = np.linspace(u_min, u_max, n_scan)
    edges = instability_edges(lambda u: roots(model, u, aero=aero, **kw), speeds)
    first = next(edges, None)
    if first is not None and growth_rate(model, u_min, aero=aero, **kw) > 0:
        hint = (" (the aero ROM is least accurate at low airspeed, where the reduced frequency is high: compare "
                "--aero full)") if aero == "rom" else ""
        raise UnstableAtScanStart(f"unstable already at {u_min} m/s{hint}")
    if first is not None:
        yield first
        yield from edges


def flutter_point(model: AeroelasticModel, airspeed_mps: float, aero: str = "full", rom_modes: int | None = None,
                  formulation: str = "discrete") -> FlutterPoint:
    """The root that crosses at ``airspeed_mps`` (the unstable-side root of largest real part, Im s > 0): its
    frequency and the structural modes' shares of its eigenvector."""
    eig = eigenvalues(model, airspeed_mps, aero=aero, rom_modes=rom_modes, formulation=formulation)
    i = int(np.argmax(np.where(eig.s.imag > 0, eig.s.real, -np.inf)))
    shares = eig.q_part[:, i]
    return FlutterPoint(airspeed_mps, float(eig.s[i].imag / (2 * np.pi)), int(np.argmax(shares)) + 1, shares)


def find_flutter(model: AeroelasticModel, aero: str = "full", rom_modes: int | None = None,
                 formulation: str = "discrete", u_min: float = 1.0, u_max: float = MAX_AIRSPEED_MPS,
                 n_scan: int | None = None) -> FlutterPoint | None:
    """Lowest airspeed where an eigenvalue crosses into Re s > 0: scan (``n_scan`` samples, default every
    SCAN_STEP_MPS), then Brent's method (see :func:`instability_ranges`, whose first range starts there)."""
    for start in _crossings(model, u_min, u_max, n_scan, aero, rom_modes=rom_modes, formulation=formulation):
        return flutter_point(model, start, aero, rom_modes, formulation)
    return None


def instability_ranges(model: AeroelasticModel, aero: str = "full", rom_modes: int | None = None,
                       formulation: str = "discrete", u_min: float = 1.0, u_max: float = MAX_AIRSPEED_MPS,
                       n_scan: int | None = None) -> list[tuple[float, float | None]]:
    """Every airspeed range (start, end) in m/s up to ``u_max`` where the linear system is unstable; the last end
    is None when it stays unstable to ``u_max``. More than one range, or a closed one, is a window of instability
    (a hump mode, or the aero ROM's at low airspeed with little structural damping)."""
    return edges_to_ranges(list(_crossings(model, u_min, u_max, n_scan, aero, rom_modes=rom_modes,
                                           formulation=formulation)))
