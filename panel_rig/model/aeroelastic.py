"""Linear aeroelastic system of the panel: Eq. (24) (all vortices), Eq. (25) (ROM), and their
continuous-time form used by the stepper; eigenvalues versus airspeed.

Coupling of structure and lattice (Eqs. 1, 4, 5, 23):
  downwash at the collocation points   w = -(E_vel q_dot + U E_slope q)   (E_vel = L phi(x_c), E_slope = phi'(x_c),
                                                                           zero on the rigid airfoil)
  generalised aerodynamic force        Q = rho L dx Psi [U gamma_b + dx S dgamma_b/dt]
  a vertical gust w_g(x_c, t) (upwash, positive up) adds to w at every collocation point (airfoil and panel)
with Psi the mode shapes at the element load points (zero on the airfoil) and S the running sum of Eq. (4).
The structure is discretised by the trapezoidal rule, so Eq. (24) is centred at t + 1/2 as printed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from panel_rig.config import PanelConfig
from panel_rig.model.aerodynamics import VortexLattice, cumulative_sum_matrix, lattice_for
from panel_rig.model.rom import AeroModes, AeroROM, aero_eigenmodes, build_rom
from panel_rig.model.structure import Structure, build_structure, mode_shapes

LOAD_POINT_OFFSET = {"quarter": 0.25, "three_quarter": 0.75, "center": 0.5}


@dataclass(frozen=True)
class Coupling:
    """Matrices linking modal coordinates q (w/L) and the vortex lattice."""

    E_vel: np.ndarray  # (km, n) m: w contribution per unit q_dot
    E_slope: np.ndarray  # (km, n): w contribution per unit U q
    Psi: np.ndarray  # (n, km): mode shapes at the load points
    force_scale: float  # rho L dx, kg/m: Q = force_scale * Psi @ [U g + dx S g_dot] (Eqs. 4-5), N per m span


def panel_modes_at(cfg: PanelConfig, x_m: np.ndarray, derivative: int = 0) -> np.ndarray:
    """phi^(derivative) at chordwise positions x (m from the airfoil leading edge); 0 on the airfoil."""
    x_bar = (np.asarray(x_m) - cfg.airfoil_length_m) / cfg.panel_length_m
    on_panel = x_bar > 0
    out = np.zeros((cfg.n_modes, x_bar.size))
    out[:, on_panel] = mode_shapes(cfg.n_modes, x_bar[on_panel], derivative)
    return out


def build_coupling(cfg: PanelConfig, lat: VortexLattice) -> Coupling:
    """E (Eq. 23) and the load matrix of Eq. (5) for the configured load point."""
    x_load = (np.arange(lat.n_body) + LOAD_POINT_OFFSET[cfg.load_point]) * lat.dx_m
    return Coupling(
        E_vel=cfg.panel_length_m * panel_modes_at(cfg, lat.x_colloc_m).T,
        E_slope=panel_modes_at(cfg, lat.x_colloc_m, derivative=1).T,
        Psi=panel_modes_at(cfg, x_load),
        force_scale=cfg.air_density_kgpm3 * cfg.panel_length_m * lat.dx_m,
    )


@dataclass(frozen=True)
class ContinuousAero:
    """Aerodynamic terms of the continuous-time model, polynomial in U (computed once):

        Q = -Ma q_dd - U Ca q_dot - U^2 Ka q + U Qxi xi
        d xi/dt = (U/dx) Lam xi - Gv q_dd - U Gs q_dot
    """

    Ma: np.ndarray  # (n, n) kg, aerodynamic (added) mass
    Ca: np.ndarray  # (n, n) kg/m: damping per unit U
    Ka: np.ndarray  # (n, n) kg/m^2: stiffness per unit U^2
    Qxi: np.ndarray  # (n, r) force per unit U xi
    Lam: np.ndarray  # (r, r) per aerodynamic step
    Gv: np.ndarray  # (r, n)
    Gs: np.ndarray  # (r, n)
    dx_m: float
    # gust input: a vertical gust w_g (km,) at the collocation points adds to the downwash, so it enters through
    # the ROM's input matrix and its static correction like the motion does:
    #   Q += U Qg w_g + Qgd dw_g/dt,   d xi/dt += Gg dw_g/dt
    Qg: np.ndarray  # (n, km) kg/m^2: quasi-steady (static correction) force per unit U w_g
    Qgd: np.ndarray  # (n, km) kg/m: force per unit dw_g/dt (static part of the vortex rates, and the modes' input)
    Gg: np.ndarray  # (r, km) s/m: ROM input of the gust increment (the ROM's G)

    @property
    def n_aero(self) -> int:
        return self.Lam.shape[0]


def continuous_aero(cp: Coupling, lat: VortexLattice, rom: AeroROM) -> ContinuousAero:
    """Assemble the continuous-time ROM terms (see module docstring of rom.py for xi)."""
    nb, dx = lat.n_body, lat.dx_m
    S = cumulative_sum_matrix(nb, lat.own)
    Gs_b = rom.static[:nb]
    X_b = rom.X[:nb]
    H = Gs_b + X_b @ rom.G
    fs = cp.force_scale
    return ContinuousAero(
        Ma=fs * dx * cp.Psi @ S @ H @ cp.E_vel,
        Ca=fs * cp.Psi @ (Gs_b @ cp.E_vel + dx * S @ H @ cp.E_slope),
        Ka=fs * cp.Psi @ Gs_b @ cp.E_slope,
        Qxi=fs * cp.Psi @ (X_b + S @ X_b @ rom.Lam),
        Lam=rom.Lam,
        Gv=rom.G @ cp.E_vel,
        Gs=rom.G @ cp.E_slope,
        dx_m=dx,
        Qg=fs * cp.Psi @ Gs_b,
        Qgd=fs * dx * cp.Psi @ S @ H,
        Gg=rom.G,
    )


@dataclass
class AeroelasticModel:
    """Everything the linear analysis and the stepper need, built once from a PanelConfig."""

    cfg: PanelConfig
    #: the structural mass matrix of the linear analyses (kg/m, modal); None: m_p L^3 I. A variant's own
    #: linearisation (model/linearisation.py); the stepper builds its matrices itself and does not read this
    linear_mass_kg: np.ndarray | None = None
    structure: Structure = field(init=False)
    lattice: VortexLattice = field(init=False)
    coupling: Coupling = field(init=False)

    def __post_init__(self) -> None:
        self.structure = build_structure(self.cfg)
        self.lattice = lattice_for(self.cfg)
        self.coupling = build_coupling(self.cfg, self.lattice)
        self._roms: dict[int | None, AeroROM] = {}
        self._continuous: dict[int | None, ContinuousAero] = {}

    @cached_property
    def aero_modes(self) -> AeroModes:
        return aero_eigenmodes(self.lattice)

    def rom(self, n_modes: int | None) -> AeroROM:
        """ROM with n_modes aero eigenmodes; None keeps every dynamic mode (cached per n_modes)."""
        if n_modes not in self._roms:
            self._roms[n_modes] = build_rom(self.lattice, n_modes, self.aero_modes)
        return self._roms[n_modes]

    def continuous(self, n_modes: int | None) -> ContinuousAero:
        """Continuous-time aero terms of the ROM (cached per n_modes)."""
        if n_modes not in self._continuous:
            self._continuous[n_modes] = continuous_aero(self.coupling, self.lattice, self.rom(n_modes))
        return self._continuous[n_modes]

    @property
    def structural_mass_kg(self) -> np.ndarray:
        """Structural modal mass matrix of the linear analyses (``linear_mass_kg``, default m_p L^3 I)."""
        if self.linear_mass_kg is not None:
            return np.asarray(self.linear_mass_kg, dtype=float)
        return self.structure.modal_mass_kg * np.eye(self.structure.n_modes)

    # ---- Eq. (24)/(25): discrete-time linear systems at dt = dx / U -------------------------------
    def _structure_rows(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """D2 and -D1 of Eq. (24): trapezoidal structure rows (velocity, displacement) for (v, q)."""
        s = self.structure
        n = s.n_modes
        M, C, K = self.structural_mass_kg, np.diag(s.modal_damping_kgps), np.diag(s.modal_stiffness_npm)
        D2 = np.block([[M / dt + C / 2, K / 2], [-0.5 * np.eye(n), np.eye(n) / dt]])
        D1 = np.block([[-M / dt + C / 2, K / 2], [-0.5 * np.eye(n), -np.eye(n) / dt]])
        return D2, -D1

    def discrete_full(self, airspeed_mps: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Eq. (24), linear: LHS X^{n+1} = RHS X^n with X = (gamma, q_dot, q), dt = dx/U."""
        lat, cp, n = self.lattice, self.coupling, self.structure.n_modes
        U, N, nb = airspeed_mps, lat.size, lat.n_body
        dt = lat.dx_m / U
        S = cumulative_sum_matrix(nb, lat.own)
        D2, D1n = self._structure_rows(dt)
        LHS = np.zeros((N + 2 * n, N + 2 * n))
        RHS = np.zeros_like(LHS)
        LHS[:N, :N], RHS[:N, :N] = lat.A, -lat.B
        LHS[:nb, N : N + n] = cp.E_vel  # A g + E_vel v + U E_slope q = 0 (w moved left)
        LHS[:nb, N + n :] = U * cp.E_slope
        LHS[N:, N:], RHS[N:, N:] = D2, D1n
        C2 = cp.force_scale * cp.Psi @ (U / 2 * np.eye(nb) + lat.dx_m / dt * S)  # Eq. (24) C2, C1
        C1 = cp.force_scale * cp.Psi @ (U / 2 * np.eye(nb) - lat.dx_m / dt * S)
        LHS[N : N + n, :nb] = -C2
        RHS[N : N + n, :nb] = C1
        return LHS, RHS, dt

    def discrete_rom(self, airspeed_mps: float, n_modes: int | None) -> tuple[np.ndarray, np.ndarray, float]:
        """Eq. (25), linear: X = (xi, q_dot, q); g = (A+B)^{-1} w + X xi; dt = dx/U."""
        lat, cp, n = self.lattice, self.coupling, self.structure.n_modes
        rom = self.rom(n_modes)
        U, nb, r = airspeed_mps, lat.n_body, rom.n_states
        dt = lat.dx_m / U
        S = cumulative_sum_matrix(nb, lat.own)
        W = -np.hstack([cp.E_vel, U * cp.E_slope])  # w = W (v, q)
        D2, D1n = self._structure_rows(dt)
        C2 = cp.force_scale * cp.Psi @ (U / 2 * np.eye(nb) + lat.dx_m / dt * S)
        C1 = cp.force_scale * cp.Psi @ (U / 2 * np.eye(nb) - lat.dx_m / dt * S)
        Gs_b, X_b = rom.static[:nb], rom.X[:nb]
        LHS = np.zeros((r + 2 * n, r + 2 * n))
        RHS = np.zeros_like(LHS)
        LHS[:r, :r] = np.eye(r)
        LHS[:r, r:] = -rom.R @ W
        RHS[:r, :r] = rom.Z
        RHS[:r, r:] = -rom.R @ W
        LHS[r:, r:] = D2
        RHS[r:, r:] = D1n
        LHS[r : r + n, :r] = -C2 @ X_b
        LHS[r : r + n, r:] -= C2 @ Gs_b @ W
        RHS[r : r + n, :r] = C1 @ X_b
        RHS[r : r + n, r:] += C1 @ Gs_b @ W
        return LHS, RHS, dt

    def continuous_matrices(self, airspeed_mps: float, n_modes: int | None) -> tuple[np.ndarray, np.ndarray]:
        """Continuous-time linear system  Mc y_dot = Ac y,  y = (q, q_dot, xi)."""
        s, ca = self.structure, self.continuous(n_modes)
        n, r, U = s.n_modes, ca.n_aero, airspeed_mps
        M = self.structural_mass_kg + ca.Ma
        Mc = np.eye(2 * n + r)
        Mc[n : 2 * n, n : 2 * n] = M
        Mc[2 * n :, n : 2 * n] = ca.Gv
        Ac = np.zeros_like(Mc)
        Ac[:n, n : 2 * n] = np.eye(n)
        Ac[n : 2 * n, :n] = -(np.diag(s.modal_stiffness_npm) + U**2 * ca.Ka)
        Ac[n : 2 * n, n : 2 * n] = -(np.diag(s.modal_damping_kgps) + U * ca.Ca)
        Ac[n : 2 * n, 2 * n :] = U * ca.Qxi
        Ac[2 * n :, n : 2 * n] = -U * ca.Gs
        Ac[2 * n :, 2 * n :] = (U / ca.dx_m) * ca.Lam
        return Mc, Ac
