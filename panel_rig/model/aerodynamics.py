"""2-D unsteady vortex lattice of the airfoil + panel and its wake (Tang & Dowell 2002, Eqs. 1-5).

Lengths are in units of the element length dx; vortex strengths are stored as gamma_j = Gamma_j / dx
(m/s), so that the discrete aerodynamic system (Eq. 3)

    A gamma^{n+1} + B gamma^n = w^{n+1}

holds with pure-number matrices A, B for any airspeed; U enters only through the aerodynamic step
dt_a = dx / U. Rows 0..km-1 are the downwash conditions at the 3/4-chord collocation points with the
kernel K_ij = 1 / (2 pi (x_i - xi_j)) (Eqs. 1-2); row km is Kelvin's theorem (the first wake vortex
carries the change of bound circulation); the remaining rows convect the wake one element per step,
the last vortex keeping a fraction (the relaxation factor, Hall 1994) of its previous strength.

Sign convention: gamma > 0 gives lift (upward pressure difference); the "downwash" is
w = -(dw_s/dt + U dw_s/dx) for a surface displacement w_s positive up, so a nose-up plate has w > 0.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

#: Eq. (4)'s running sum of the potential jump at element j: the share of element j's own vortex it includes.
#: "inclusive" is Eq. (4) as printed (all of it: first order in dx); "midpoint" counts half of it (the jump at the
#: element centre, as for a vortex sheet of uniform strength over each element: second order); "vortex" counts
#: the part of the element behind its quarter-point vortex, 3/4 (the exact integral of the jump of point vortices).
RUNNING_SUM_OWN = {"inclusive": 1.0, "midpoint": 0.5, "vortex": 0.75}
#: the highest airspeed the lattice is run at (m/s): it is incompressible (the paper's "low subsonic flow"), which
#: holds to about Mach 0.3, 103 m/s in air at 20 C (speed of sound 343 m/s); every entry point refuses more
MAX_AIRSPEED_MPS = 100.0


@dataclass(frozen=True)
class VortexLattice:
    """Geometry and matrices of the discrete vortex lattice (Eqs. 1-3)."""

    n_body: int  # km: elements on airfoil + panel
    n_wake: int  # kmm - km
    dx_m: float  # element length
    x_vortex_m: np.ndarray  # (kmm,) vortex positions (1/4 of each element), m from the leading edge
    x_colloc_m: np.ndarray  # (km,) collocation points (3/4 of each body element), m
    A: np.ndarray  # (kmm, kmm)
    B: np.ndarray  # (kmm, kmm)
    running_sum: str = "inclusive"  # Eq. (4)'s running sum, a key of RUNNING_SUM_OWN

    @property
    def own(self) -> float:
        """Share of element j's own vortex in the potential jump at element j (Eq. 4)."""
        return RUNNING_SUM_OWN[self.running_sum]

    @property
    def size(self) -> int:
        """kmm: total number of vortices."""
        return self.n_body + self.n_wake

    def static_inverse(self) -> np.ndarray:
        """(A + B)^{-1} restricted to the body downwash columns, (kmm, km): the quasi-steady solution."""
        return np.linalg.solve(self.A + self.B, np.eye(self.size)[:, : self.n_body])


#: dense n x n float64 matrices a lattice's analysis holds at its peak (A, B and the solves': 2.2 measured for the
#: gust's frequency response, the ROM's eigen-analysis more)
LATTICE_PEAK_MATRICES = 4


def lattice_memory_problem(n_body: int, n_wake: int, memory_bytes: float | None = None) -> str | None:
    """Why a lattice of ``n_body`` + ``n_wake`` elements cannot be analysed here: its dense matrices would need more
    than half of ``memory_bytes`` (default: this machine's physical memory). None when it can. (`gust --set
    aero.elements=2000` asked 111 GiB for its 60-chord wake and ended in a traceback.)"""
    n = n_body + n_wake
    need = LATTICE_PEAK_MATRICES * 8.0 * n * n
    if memory_bytes is None:
        memory_bytes = physical_memory_bytes()
    if memory_bytes is None or need <= 0.5 * memory_bytes:
        return None
    return (f"a lattice of {n_body} body + {n_wake} wake elements needs about {need / 2**30:.0f} GiB (dense "
            f"{n} x {n} matrices), more than half of this machine's {memory_bytes / 2**30:.0f} GiB: use fewer "
            "elements or a shorter wake")


def physical_memory_bytes() -> float | None:
    """This machine's physical memory (bytes), None where the system does not say."""
    try:
        return float(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def build_lattice(chord_m: float, n_body: int, n_wake: int, relaxation: float,
                  running_sum: str = "inclusive") -> VortexLattice:
    """Assemble A and B of Eq. (3) for equal elements dx = chord / n_body on body and wake; ``running_sum`` is the
    discretisation of Eq. (4)'s potential jump (a key of RUNNING_SUM_OWN)."""
    if n_body < 1 or n_wake < 2:
        raise ValueError("need at least 1 body element and 2 wake elements")
    if running_sum not in RUNNING_SUM_OWN:
        raise ValueError(f"running_sum must be one of {tuple(RUNNING_SUM_OWN)}, got {running_sum!r}")
    dx = chord_m / n_body
    n = n_body + n_wake
    problem = lattice_memory_problem(n_body, n_wake)
    if problem is not None:
        raise ValueError(problem)
    xv = np.arange(n) + 0.25  # in dx units
    xc = np.arange(n_body) + 0.75
    A = np.zeros((n, n))
    B = np.zeros((n, n))
    A[:n_body, :] = 1.0 / (2.0 * np.pi * (xc[:, None] - xv[None, :]))  # Eq. (2), lengths in dx
    k = n_body  # Kelvin: gamma_w1^{n+1} + sum gamma_b^{n+1} - sum gamma_b^n = 0
    A[k, :n_body] = 1.0
    A[k, k] = 1.0
    B[k, :n_body] = -1.0
    for j in range(n_body + 1, n):  # convection: gamma_j^{n+1} = gamma_{j-1}^n
        A[j, j] = 1.0
        B[j, j - 1] = -1.0
    B[n - 1, n - 1] = -relaxation  # last vortex: gamma^{n+1} = gamma_{n-2}^n + relaxation * gamma^n
    return VortexLattice(n_body, n_wake, dx, xv * dx, xc * dx, A, B, running_sum)


def lattice_for(cfg) -> VortexLattice:
    """The lattice of a PanelConfig (airfoil + panel, km elements, its wake and relaxation, Eq. 4's running sum)."""
    return build_lattice(cfg.chord_m, cfg.n_elements, cfg.n_wake, cfg.wake_relaxation, cfg.running_sum)


def cumulative_sum_matrix(n: int, own: float = 1.0) -> np.ndarray:
    """S with (S g)_j = sum_{i < j} g_i + own g_j: the potential jump at element j (Eq. 4; own = 1 as printed)."""
    return np.tril(np.ones((n, n))) - (1.0 - own) * np.eye(n)


def running_sum(lat: VortexLattice, d: np.ndarray) -> np.ndarray:
    """S d along the last axis (body elements): the running sum of Eq. (4) with the lattice's share of own vortex."""
    return np.cumsum(d, axis=-1) - (1.0 - lat.own) * d


def pressure_jump(lat: VortexLattice, airspeed_mps: float, rho_kgpm3: float,
                  gamma_new: np.ndarray, gamma_old: np.ndarray, dt_s: float) -> np.ndarray:
    """Delta p on each body element over one step (Eq. 4), Pa: rho [U gamma_mid + dx (S dgamma/dt)_j]."""
    nb = lat.n_body
    mid = 0.5 * (gamma_new[..., :nb] + gamma_old[..., :nb])
    rate = running_sum(lat, gamma_new[..., :nb] - gamma_old[..., :nb]) / dt_s
    return rho_kgpm3 * (airspeed_mps * mid + lat.dx_m * rate)


def steady_lift_coefficient(lat: VortexLattice, alpha_rad: float) -> float:
    """C_l of the flat plate (whole body) at incidence alpha from the steady solution (A + B) gamma = w."""
    w = np.zeros(lat.size)
    w[: lat.n_body] = alpha_rad  # w / U for a nose-up plate
    gamma = np.linalg.solve(lat.A + lat.B, w)  # gamma / U
    chord = lat.n_body * lat.dx_m
    return 2.0 * float(np.sum(gamma[: lat.n_body])) * lat.dx_m / chord


def indicial_lift(lat: VortexLattice, n_steps: int) -> np.ndarray:
    """Lift build-up C_l(step) / (2 pi alpha) after a step change of incidence at step 0 (Wagner problem).

    The plate is still; the downwash jumps to U alpha at every collocation point. Step n covers
    s = 2 U t / c in [2n/km, 2(n+1)/km]; the value returned is the mid-step pressure lift.
    """
    nb = lat.n_body
    w = np.zeros(lat.size)
    w[:nb] = 1.0
    Ainv = np.linalg.inv(lat.A)
    g_old = np.zeros(lat.size)
    out = np.empty(n_steps)
    chord = nb * lat.dx_m
    for n in range(n_steps):
        g_new = Ainv @ (w - lat.B @ g_old)
        dp = pressure_jump(lat, 1.0, 1.0, g_new, g_old, lat.dx_m)  # U = 1, rho = 1, dt = dx / U
        out[n] = np.sum(dp) * lat.dx_m / (0.5 * chord) / (2 * np.pi)
        g_old = g_new
    return out


def harmonic_lift(lat: VortexLattice, k_reduced: float, w_shape: np.ndarray, w_slope: np.ndarray) -> complex:
    """Complex lift per unit amplitude, L / (rho U^2 b), of a harmonic surface motion.

    The surface displacement is w_s(x, t) = Re[(w_shape(x)) e^{i omega t}] with w_shape in units of the
    semi-chord b at the collocation points and w_slope its x-derivative there; k = omega b / U.
    Solved in the frequency domain of the discrete system: (z A + B) gamma = z w with z = e^{i omega dt_a}.
    """
    nb = lat.n_body
    b = 0.5 * nb * lat.dx_m
    theta = k_reduced * lat.dx_m / b  # omega dt_a
    z = np.exp(1j * theta)
    # downwash / U = -(i k w_shape + b dw_s/dx) with lengths in b; w_slope is dimensionless
    w = np.zeros(lat.size, dtype=complex)
    w[:nb] = -(1j * k_reduced * w_shape + w_slope)
    gamma = np.linalg.solve(z * lat.A + lat.B, z * w)  # gamma / U at step n+1 relative to e^{i omega t}
    g_new, g_old = gamma, gamma / z
    dp = (0.5 * (g_new[:nb] + g_old[:nb]) + running_sum(lat, g_new[:nb] - g_old[:nb]))  # Eq. (4), / (rho U^2)
    # evaluate at mid-step: the pair (new, old) straddles t + dt_a / 2
    return complex(np.sum(dp) * lat.dx_m / b * np.exp(0.5j * theta))


# ---- gust input: a vertical gust field w_g(x, t) (upwash, m/s, positive up) adds to the downwash w of Eq. (3) at
# every collocation point; a gust is the same as the plate moving down through still air. ------------------------
def harmonic_body_circulation(lat: VortexLattice, theta: float, w_body: np.ndarray) -> np.ndarray:
    """Body vortex strengths of the discrete system (z A + B) g = z w, z = e^{i theta}, for a harmonic downwash
    w_body at the collocation points (theta = omega dt_a, the phase advance per aerodynamic step).

    The wake rows are solved in closed form (each wake vortex is its upstream neighbour one step earlier,
    g_j = g_{j-1} / z; the last keeps the relaxation fraction; Kelvin sheds the change of bound circulation),
    so only a km x km system is solved and any wake length costs the same.
    """
    nb, nw = lat.n_body, lat.n_wake
    z = np.exp(1j * theta)
    relax = -lat.B[-1, -1]
    decay = z ** -np.arange(nw - 1, dtype=float)
    shape = np.concatenate([decay, [decay[-1] / (z - relax)]])  # wake strengths per unit first wake vortex
    wake_influence = lat.A[:nb, nb:] @ shape  # downwash at the collocation points per unit first wake vortex
    kelvin = -(1.0 - 1.0 / z)  # first wake vortex per unit total bound circulation
    M = lat.A[:nb, :nb] + kelvin * np.outer(wake_influence, np.ones(nb))
    return np.linalg.solve(M, np.asarray(w_body, dtype=complex))


def sinusoidal_gust_lift(lat: VortexLattice, k_reduced: float, x_ref_m: float | None = None) -> complex:
    """Lift of the rigid lattice in a convected sinusoidal vertical gust, normalised by 2 pi rho U b w0 (Sears).

    Gust (Taylor's frozen field): w_g(x, t) = w0 Re exp[i omega (t - (x - x_ref) / U)], k = omega b / U with b
    the semi-chord of the whole body (airfoil + panel); the phase is referred to the gust at x_ref (default
    mid-chord). The pressure is the model's Eq. (4) with the lattice's running sum (``lat.running_sum``).
    """
    nb = lat.n_body
    b = 0.5 * nb * lat.dx_m
    x_ref = b if x_ref_m is None else x_ref_m
    theta = k_reduced * lat.dx_m / b
    z = np.exp(1j * theta)
    w = np.exp(-1j * k_reduced * (lat.x_colloc_m - x_ref) / b)  # w / w0 at t_{n+1}
    g_new = harmonic_body_circulation(lat, theta, w)  # gamma / w0
    g_old = g_new / z
    dp = 0.5 * (g_new + g_old) + running_sum(lat, g_new - g_old)  # Eq. (4) / (rho U w0), per element
    return complex(np.sum(dp) * lat.dx_m * np.exp(0.5j * theta) / (2.0 * np.pi * b))


def step_gust_lift(lat: VortexLattice, n_steps: int) -> np.ndarray:
    """Lift build-up L / (2 pi rho U b w0) after a sharp-edged vertical gust w0 reaches the leading edge at step 0
    and convects at U (Kuessner problem); the plate is still. Step n covers s = U t / b in [2n/km, 2(n+1)/km];
    the value is the mid-step pressure lift (as in :func:`indicial_lift`). At t_{n+1} the front is at (n+1) dx,
    past the collocation points (i + 3/4) dx of elements i <= n.

    Marches Eq. (3) with the wake rows done explicitly (shift by one element, relaxation on the last, Kelvin
    for the first), so a step costs one km x km solve and one pass over the wake.
    """
    nb, n = lat.n_body, lat.size
    relax = -lat.B[-1, -1]
    A_bw = lat.A[:nb, nb:]
    lu = _lu(lat.A[:nb, :nb] - np.outer(A_bw[:, 0], np.ones(nb)))  # first wake vortex = -(change of bound sum)
    g_old = np.zeros(n)
    out = np.empty(n_steps)
    b = 0.5 * nb * lat.dx_m
    for step in range(n_steps):
        g_new = np.zeros(n)
        g_new[nb + 1:] = g_old[nb:-1]
        g_new[-1] += relax * g_old[-1]
        w = np.zeros(nb)
        w[: min(step + 1, nb)] = 1.0
        rhs = w - A_bw[:, 1:] @ g_new[nb + 1:] - A_bw[:, 0] * np.sum(g_old[:nb])
        g_new[:nb] = _lu_solve(lu, rhs)
        g_new[nb] = np.sum(g_old[:nb]) - np.sum(g_new[:nb])
        dp = pressure_jump(lat, 1.0, 1.0, g_new, g_old, lat.dx_m)  # U = 1, rho = 1, w0 = 1, dt = dx / U
        out[step] = np.sum(dp) * lat.dx_m / (2 * np.pi * b)
        g_old = g_new
    return out


def _lu(a: np.ndarray):
    import scipy.linalg

    return scipy.linalg.lu_factor(a)


def _lu_solve(lu, rhs: np.ndarray) -> np.ndarray:
    import scipy.linalg

    return scipy.linalg.lu_solve(lu, rhs)
