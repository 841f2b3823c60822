"""Reduced-order aerodynamics: vortex-lattice eigenmodes with static correction (Eq. 25; Hall 1994).

The discrete aerodynamic system A g^{n+1} + B g^n = w^{n+1} (Eq. 3) is split into its quasi-steady
solution g_s = (A + B)^{-1} w and a dynamic remainder in Ra eigenmodes, g = g_s + X xi. With
Y^T A X = I and the eigenvalue matrix Z, premultiplying by Y^T gives

    xi^{n+1} = Z xi^n + Y^T [I - A (A+B)^{-1}] w^{n+1} - Y^T B (A+B)^{-1} w^n = Z xi^n + R (w^{n+1} - w^n),

because I - A (A+B)^{-1} = B (A+B)^{-1} =: the input matrix R = Y^T B (A+B)^{-1}.

Complex-conjugate pairs are carried as real 2x2 blocks [[Re f, Im f], [-Im f, Re f]] of any function
f of the eigenvalue, so every matrix here is real. For time steps other than dt_a = dx/U the modes
are converted to continuous time with Lambda = ln Z per aerodynamic step and a ramp-invariant input
G = [ln Z / (Z - I)] R, which reproduces the discrete model exactly for downwash varying linearly over
each aerodynamic step:  d xi / dt = (U / dx) Lambda xi + G dw/dt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from panel_rig.model.aerodynamics import VortexLattice

ZERO_EIGENVALUE = 1e-9  # |z| below this: a vortex slaved to the downwash within one step (no dynamics)


@dataclass(frozen=True)
class AeroModes:
    """The dynamic eigenmodes of Eq. (3), sorted by |ln z| (slowest first; the 'first branch')."""

    z: np.ndarray  # (m,) complex discrete eigenvalues per aerodynamic step
    X: np.ndarray  # (kmm, m) right eigenvectors
    Y: np.ndarray  # (kmm, m) left eigenvectors, Y^T A X = I

    @property
    def continuous(self) -> np.ndarray:
        """ln z: eigenvalues per aerodynamic step (multiply by U/dx for 1/s)."""
        return np.log(self.z)


def aero_eigenmodes(lat: VortexLattice) -> AeroModes:
    """Solve (z A + B) x = 0 with left vectors; drop the z = 0 (algebraic) modes."""
    z, vl, vr = scipy.linalg.eig(-lat.B, lat.A, left=True, right=True)
    keep = np.abs(z) > ZERO_EIGENVALUE
    z, X, Y = z[keep], vr[:, keep], np.conj(vl[:, keep])
    norm = np.einsum("im,ij,jm->m", Y, lat.A, X)
    Y = Y / norm
    order = np.lexsort((np.imag(z), np.abs(np.log(z))))
    return AeroModes(z[order], X[:, order], Y[:, order])


def select_modes(modes: AeroModes, n_modes: int) -> np.ndarray:
    """Indices of the first n_modes modes, closed under complex conjugation (a split pair is dropped
    and the next real mode, if any, taken), so the real ROM has at most n_modes states."""
    chosen: list[int] = []
    used = np.zeros(len(modes.z), bool)
    for i, zi in enumerate(modes.z):
        if used[i]:
            continue
        if abs(zi.imag) <= 1e-12 * max(1.0, abs(zi)):
            group = [i]
        else:
            partner = np.flatnonzero(~used & (np.abs(modes.z - np.conj(zi)) < 1e-9))
            partner = [p for p in partner if p != i]
            if not partner:
                continue
            group = [i, partner[0]] if zi.imag > 0 else [partner[0], i]
        if len(chosen) + len(group) > n_modes:
            continue
        chosen.extend(group)
        used[group] = True
        if len(chosen) == n_modes:
            break
    return np.array(chosen, dtype=int)


def _real_blocks(values: np.ndarray, groups: list[list[int]]) -> np.ndarray:
    """Block-diagonal real matrix of the complex numbers f(z), one 1x1 or 2x2 block per group."""
    n = sum(len(g) for g in groups)
    out = np.zeros((n, n))
    k = 0
    for g in groups:
        v = values[g[0]]
        if len(g) == 1:
            out[k, k] = v.real
        else:
            out[k : k + 2, k : k + 2] = [[v.real, v.imag], [-v.imag, v.real]]
        k += len(g)
    return out


@dataclass(frozen=True)
class AeroROM:
    """Real reduced-order aerodynamic model with static correction (Eq. 25), Ra states."""

    static: np.ndarray  # (kmm, km) (A+B)^{-1}: quasi-steady vortex strengths per unit downwash
    X: np.ndarray  # (kmm, r) real mode shapes
    Yt: np.ndarray  # (r, kmm) real projection, Yt A X = I
    Z: np.ndarray  # (r, r) discrete transition per aerodynamic step
    Lam: np.ndarray  # (r, r) ln Z, per aerodynamic step
    R: np.ndarray  # (r, km) input of the downwash increment
    G: np.ndarray  # (r, km) continuous-time input of dw/dt, [ln Z / (Z - I)] R

    @property
    def n_states(self) -> int:
        return self.X.shape[1]


def build_rom(lat: VortexLattice, n_modes: int | None, modes: AeroModes | None = None) -> AeroROM:
    """ROM with the first n_modes aerodynamic eigenmodes (None: every dynamic mode, the full model)."""
    modes = modes if modes is not None else aero_eigenmodes(lat)
    if n_modes is not None and not 1 <= n_modes <= len(modes.z):
        raise ValueError(f"the ROM takes 1 to {len(modes.z)} aerodynamic eigenmodes (all {len(modes.z)}: the full "
                         f"model), not {n_modes} (aero.rom_modes, --rom-modes)")
    idx = select_modes(modes, len(modes.z) if n_modes is None else n_modes)
    groups: list[list[int]] = []
    cols_x, rows_y = [], []
    k = 0
    while k < len(idx):
        i = idx[k]
        if abs(modes.z[i].imag) <= 1e-12 * max(1.0, abs(modes.z[i])):
            groups.append([i])
            cols_x.append(modes.X[:, i].real)
            rows_y.append(modes.Y[:, i].real)
            k += 1
        else:  # pair (x, conj x): real basis [Re x, Im x], projections [2 Re y, -2 Im y]
            groups.append([i, idx[k + 1]])
            cols_x += [modes.X[:, i].real, modes.X[:, i].imag]
            rows_y += [2 * modes.Y[:, i].real, -2 * modes.Y[:, i].imag]
            k += 2
    z = modes.z
    X = np.array(cols_x).T
    Yt = np.array(rows_y)
    static = lat.static_inverse()
    R = Yt @ lat.B @ static
    ln_z = np.log(z)
    ramp = np.where(np.abs(z - 1) > 1e-12, ln_z / np.where(np.abs(z - 1) > 1e-12, z - 1, 1.0), 1.0)
    return AeroROM(
        static=static,
        X=X,
        Yt=Yt,
        Z=_real_blocks(z, groups),
        Lam=_real_blocks(ln_z, groups),
        R=R,
        G=_real_blocks(ramp, groups) @ R,
    )
