"""The model's V-g / V-f diagram: frequency and damping ratio of each structural mode versus airspeed.

The poles are those of the continuous-time linear model that the stepper marches
(``AeroelasticModel.continuous_matrices``: structure + ROM aero, ``Mc y' = Ac y``), so that a modal
identification on stepper data can be compared with them directly. The stepper's implicit-midpoint rule maps a
pole s to z = (1 + s dt/2)/(1 - s dt/2): at dt = 1/2048 s and 23 Hz this shifts frequency and damping by about
(omega dt)^2/12 = 4e-4 (relative), far below any identification tolerance.

Structural modes are *tracked by continuity* from U = 0 (where they are the in-vacuo modes with added mass,
numbered by frequency) through sub-steps in airspeed, with a linear predictor and an optimal assignment of the
new poles to the predicted ones; a step is halved when the assignment is ambiguous. Sorting by frequency at
each airspeed would swap labels where branches cross.

Conventions (used by panel_rig.analysis.identification too): for a pole s, the natural frequency is
f = |s| / (2 pi) and the damping ratio zeta = -Re(s) / |s| (negative: unstable).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.optimize import brentq, linear_sum_assignment

from panel_rig.model.aeroelastic import AeroelasticModel


def pole_frequency_hz(s: np.ndarray | complex) -> np.ndarray:
    """Natural frequency |s| / 2 pi of continuous-time poles s (1/s)."""
    return np.abs(s) / (2 * np.pi)


def pole_damping_ratio(s: np.ndarray | complex) -> np.ndarray:
    """Damping ratio -Re(s) / |s| of continuous-time poles s (negative when the pole is unstable)."""
    s = np.asarray(s)
    return -s.real / np.maximum(np.abs(s), 1e-300)


def pole_from_modal(frequency_hz: np.ndarray | float, damping_ratio: np.ndarray | float) -> np.ndarray:
    """Upper-half-plane pole of a mode with natural frequency f and damping ratio zeta (|zeta| < 1)."""
    w = 2 * np.pi * np.asarray(frequency_hz, float)
    z = np.asarray(damping_ratio, float)
    return w * (-z + 1j * np.sqrt(1 - z * z))


@dataclass(frozen=True)
class VGDiagram:
    """Poles of the structural modes at each airspeed, columns in mode order (mode 1 = lowest at U = 0)."""

    airspeed_mps: np.ndarray  # (k,)
    poles: np.ndarray  # (k, n_modes) complex, Im >= 0

    @property
    def frequency_hz(self) -> np.ndarray:
        return pole_frequency_hz(self.poles)

    @property
    def damping_ratio(self) -> np.ndarray:
        return pole_damping_ratio(self.poles)

    def as_json(self) -> list[dict]:
        """``[{"airspeed_mps", "modes": [{"frequency_hz", "damping_ratio"}]}]`` (the CLI's ``vg`` key)."""
        f, z = self.frequency_hz, self.damping_ratio
        return [{"airspeed_mps": float(u),
                 "modes": [{"frequency_hz": float(fi), "damping_ratio": float(zi)} for fi, zi in zip(f[k], z[k])]}
                for k, u in enumerate(self.airspeed_mps)]

    def mode_at(self, mode: int, airspeed_mps: float) -> complex:
        """Pole of a (1-based) mode at an airspeed of the grid (exact grid value, no interpolation)."""
        k = int(np.argmin(np.abs(self.airspeed_mps - airspeed_mps)))
        if abs(self.airspeed_mps[k] - airspeed_mps) > 1e-9:
            raise ValueError(f"{airspeed_mps} m/s is not on the V-g grid")
        return complex(self.poles[k, mode - 1])


class ModalTracker:
    """Structural poles of the stepper's continuous-time model, followed by continuity in airspeed.

    ``poles(U)`` returns the n structural poles at U (mode order fixed at U = 0); calls in increasing or
    decreasing U reuse the last state, so a sweep costs a few eigenvalue problems per grid point.
    """

    def __init__(self, model: AeroelasticModel, aero: str = "rom", rom_modes: int | None = None,
                 max_step_mps: float = 0.5, min_step_mps: float = 1e-4):
        if aero not in ("rom", "full"):
            raise ValueError(f"aero must be 'rom' or 'full', got {aero!r}")
        self.model = model
        self.rom_modes = (rom_modes if rom_modes is not None else model.cfg.rom_modes) if aero == "rom" else None
        self.n = model.structure.n_modes
        self.max_step, self.min_step = max_step_mps, min_step_mps
        s0 = self._structural_at_zero()
        self._u, self._s, self._ds = 0.0, s0, np.zeros_like(s0)  # last airspeed, poles, d poles / dU

    def all_poles(self, airspeed_mps: float) -> np.ndarray:
        """Every pole of the continuous-time model at U with Im >= 0 (aero and structural)."""
        Mc, Ac = self.model.continuous_matrices(airspeed_mps, self.rom_modes)
        s = scipy.linalg.eigvals(Ac, Mc)
        return s[np.isfinite(s) & (s.imag >= -1e-9)]

    def _structural_at_zero(self) -> np.ndarray:
        # At U = 0 the aero states have s = 0 exactly; the n structural poles are the others.
        s = self.all_poles(0.0)
        s = s[np.abs(s) > 1e-6 * np.max(np.abs(s))]
        s = s[np.argsort(np.abs(s))]
        if s.size < self.n:
            raise RuntimeError("could not find the structural poles at U = 0")
        return s[: self.n]

    def _match(self, u: float) -> tuple[np.ndarray, bool]:
        """Assign poles at u to the tracked modes; ok False when the assignment is ambiguous."""
        pred = self._s + self._ds * (u - self._u)
        cand = self.all_poles(u)
        cost = np.abs(pred[:, None] - cand[None, :])
        rows, cols = linear_sum_assignment(cost)
        new = cand[cols[np.argsort(rows)]]
        ok = True
        scale = np.abs(pred) + 1.0
        for i in range(self.n):
            d = np.sort(cost[i])
            # unambiguous: the chosen pole is the nearest one and clearly nearer than the runner-up
            if cost[i, cols[rows == i][0]] > d[0] + 1e-12 or (d.size > 1 and d[0] > 0.3 * d[1]
                                                              and d[0] > 1e-6 * scale[i]):
                ok = False
        return new, ok

    def poles(self, airspeed_mps: float) -> np.ndarray:
        """Structural poles (mode order) at this airspeed, reached from the last one by sub-steps."""
        target = float(airspeed_mps)
        if target < 0 or not np.isfinite(target):
            raise ValueError(f"airspeed must be finite and >= 0, got {airspeed_mps}")
        while abs(target - self._u) > 1e-12:
            h = float(np.clip(target - self._u, -self.max_step, self.max_step))
            while True:
                u = self._u + h
                new, ok = self._match(u)
                if ok or abs(h) <= self.min_step:
                    break
                h *= 0.5
            self._ds = (new - self._s) / (u - self._u)
            self._u, self._s = u, new
        return self._s.copy()


def vg_diagram(model: AeroelasticModel, airspeeds_mps: np.ndarray, aero: str = "rom",
               rom_modes: int | None = None) -> VGDiagram:
    """V-g / V-f diagram of the structural modes at the given airspeeds (any order; returned as given)."""
    speeds = np.asarray(airspeeds_mps, float)
    order = np.argsort(speeds)
    tracker = ModalTracker(model, aero, rom_modes)
    poles = np.empty((speeds.size, tracker.n), complex)
    for k in order:
        poles[k] = tracker.poles(speeds[k])
    return VGDiagram(speeds, poles)


def model_flutter_speed(model: AeroelasticModel, aero: str = "rom", rom_modes: int | None = None,
                        u_max: float = 60.0, step_mps: float = 0.5) -> tuple[float, int] | None:
    """Lowest airspeed where a tracked structural mode's damping crosses zero, and that mode (1-based).

    Same linear model as ``vg_diagram`` (the stepper's); agrees with ``flutter.find_flutter(...,
    formulation='continuous')`` when the flutter root is structural."""
    tracker = ModalTracker(model, aero, rom_modes)
    u_prev = 0.0
    for u in np.arange(step_mps, u_max + 1e-9, step_mps):
        z = pole_damping_ratio(tracker.poles(u))
        if np.any(z < 0):
            mode = int(np.argmin(z))

            def zeta(x: float, i: int = mode) -> float:
                return float(pole_damping_ratio(ModalTracker(model, aero, rom_modes).poles(x))[i])

            if zeta(u_prev) <= 0:  # undamped in still air (structure.damping_ratio 0): 0 or a round-off below it,
                return u_prev, mode + 1  # no sign change for Brent (it raised "f(a) and f(b) must have ...")
            return brentq(zeta, u_prev, u, xtol=1e-6), mode + 1
        u_prev = u
    return None


def stable_again_mps(model: AeroelasticModel, mode: int, flutter_speed_mps: float, aero: str = "rom",
                     rom_modes: int | None = None, u_max: float = 60.0, step_mps: float = 0.5) -> float | None:
    """The first airspeed of the scan (every ``step_mps`` up to ``u_max``) above ``flutter_speed_mps`` where the
    tracked ``mode`` (1-based) is stable again: the crossing opened only a window of instability. None when the
    mode stays unstable, as past a flutter boundary (every configuration of docs/validation.md up to 60 m/s).

    With little structural damping the aero ROM takes the second mode's damping below zero at 1-2 m/s (a dip of
    ~0.0035, where the reduced frequency is high and the ROM least accurate; the full lattice has no such window)."""
    tracker = ModalTracker(model, aero, rom_modes)
    for u in np.arange(step_mps, u_max + 1e-9, step_mps):
        zeta = pole_damping_ratio(tracker.poles(u))[mode - 1]
        if u > flutter_speed_mps and zeta > 0:
            return float(u)
    return None


#: modes whose damping ratio stays below this over the diagram set the V-g panel's (linear) limits
LIGHT_DAMPING = 0.1


def damping_limits(damping_ratio: np.ndarray) -> tuple[tuple[float, float], list[int]]:
    """Linear y limits of a V-g panel (n_airspeeds, n_modes) and the modes drawn entirely outside them: the limits
    span the lightly damped modes (max zeta <= LIGHT_DAMPING; all modes if none is) and 0, with 8 % of room."""
    z = np.asarray(damping_ratio, float)
    light = [i for i in range(z.shape[1]) if np.nanmax(z[:, i]) <= LIGHT_DAMPING] or list(range(z.shape[1]))
    lo = min(0.0, float(np.nanmin(z[:, light])))
    hi = max(0.0, float(np.nanmax(z[:, light])))
    pad = 0.08 * (hi - lo) if hi > lo else 0.01
    lo, hi = lo - pad, hi + pad
    outside = [i for i in range(z.shape[1]) if np.nanmin(z[:, i]) > hi or np.nanmax(z[:, i]) < lo]
    return (lo, hi), outside


def mode_label(mode: int, airspeeds_mps: np.ndarray, damping_ratio: np.ndarray, limits: tuple[float, float]) -> str:
    """A V-g panel's legend entry for a mode: with its damping range when the panel's ``limits`` cut it, and where it
    leaves the panel if it is partly inside (a first mode leaving it at 5 m/s was drawn cut off without a word)."""
    lo, hi = limits
    z = np.asarray(damping_ratio, float)
    off = (z < lo) | (z > hi)
    if not np.any(off):
        return f"mode {mode}"
    span = f"mode {mode}: zeta {np.nanmin(z):.2f}..{np.nanmax(z):.2f}"
    if np.all(off):
        return f"{span}, {'above' if np.nanmin(z) > hi else 'below'} the panel"
    return f"{span}, off the panel from {airspeeds_mps[np.argmax(off)]:g} m/s"


def plot_vg(vg: VGDiagram, path, flutter_speed_mps: float | None = None, title: str = ""):
    """V-g (damping ratio) and V-f (frequency) of the tracked structural modes, one line per mode; PNG. The damping
    axis is linear and spans the lightly damped modes (the flutter mode's slope is what a reader takes from it); a
    heavily damped mode outside it is named in the legend with its range."""
    from panel_rig.analysis.plots import _save, plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    u = vg.airspeed_mps
    (lo, hi), _ = damping_limits(vg.damping_ratio)
    for i in range(vg.poles.shape[1]):
        z = vg.damping_ratio[:, i]
        ax1.plot(u, z, "o-", ms=3, label=mode_label(i + 1, u, z, (lo, hi)))
        ax2.plot(u, vg.frequency_hz[:, i], "o-", ms=3, label=f"mode {i + 1}")
    for ax in (ax1, ax2):
        if flutter_speed_mps is not None:
            ax.axvline(flutter_speed_mps, color="k", ls=":", lw=1, label=f"U_f = {flutter_speed_mps:.3f} m/s")
        ax.set_xlabel("airspeed, m/s")
        ax.legend(fontsize=8)
    ax1.axhline(0, color="k", lw=0.5)
    # linear: a symlog axis (linear within 0.01) put a knee into the flutter mode's curve at -0.01 and left its
    # slope unreadable; the first mode (zeta ~0.4) is named instead of setting the scale
    ax1.set_ylim(lo, hi)
    ax1.set(ylabel="damping ratio zeta = -Re s / |s|", title=f"V-g {title}".strip())
    ax2.set(ylabel="natural frequency |s| / 2 pi, Hz", title=f"V-f {title}".strip())
    return _save(fig, path)
