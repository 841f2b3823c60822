"""The nonlinear aeroelastic stepper: the one object the rig, the sweeps and the paper report run on.

State: modal coordinates q (w/L), velocities q_dot (1/s) and the aerodynamic ROM coordinates xi.
Each call advances a fixed physical time step dt (default 1/2048 s, independent of the vortex
spacing) with the airspeed and the trailing-edge force as inputs of that step. All aero-sized algebra
is done once at construction, in convective form, and only scaled by U per step (see kernel.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from panel_rig.config import PanelConfig
from panel_rig.model import kernel
from panel_rig.model.aeroelastic import AeroelasticModel
from panel_rig.model.elastica import exact_kinematics, shape_sampler
from panel_rig.model.elastica import shape as exact_shape
from panel_rig.model.kernel_exact import exact_tip
from panel_rig.model.options import EXACT_VARIANT, SCHEMES, VARIANTS, stepper_problem
from panel_rig.model.structure import mode_shapes

MASS_MODES = dict(zip(SCHEMES, (kernel.MASS_MIDPOINT, kernel.MASS_AT_START, kernel.MASS_LITERAL)))
NEWTON_TOL = 1e-12


class DivergenceError(RuntimeError):
    """The march left the physical range (non-finite state or |tip w/L| over the bound)."""

    def __init__(self, reason: str, time_s: float):
        super().__init__(f"model diverged at t = {time_s:.4f} s: {reason}")
        self.reason = reason
        self.time_s = time_s
        self.tip_w_over_L = np.zeros(0)  # :meth:`Stepper.advance`: the tip after each step it did before this


@dataclass(frozen=True)
class StepperMatrices:
    """Constant arrays handed to the kernel (all SI, see kernel.py for the equations)."""

    M0: np.ndarray
    Ma: np.ndarray
    C: np.ndarray
    Ca: np.ndarray
    K: np.ndarray
    Ka: np.ndarray
    Qxi: np.ndarray
    Gv: np.ndarray
    Gs: np.ndarray
    blk_off: np.ndarray
    blk_len: np.ndarray
    lam_a: np.ndarray
    lam_b: np.ndarray
    dx_m: float
    # gust input (ContinuousAero.Qg, Qgd, Gg)
    Qg: np.ndarray
    Qgd: np.ndarray
    Gg: np.ndarray


def _blocks(Lam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Offsets, sizes and (a, b) of the 1x1 / 2x2 blocks of a block-diagonal Lam."""
    off, size, a, b = [], [], [], []
    k, r = 0, Lam.shape[0]
    while k < r:
        pair = k + 1 < r and (Lam[k, k + 1] != 0.0 or Lam[k + 1, k] != 0.0)
        off.append(k)
        size.append(2 if pair else 1)
        a.append(Lam[k, k])
        b.append(Lam[k, k + 1] if pair else 0.0)
        k += 2 if pair else 1
    return (np.array(off, dtype=np.int64), np.array(size, dtype=np.int64),
            np.array(a, dtype=float), np.array(b, dtype=float))


def stepper_matrices(model: AeroelasticModel, aero: str) -> StepperMatrices:
    """Assemble the kernel's constant arrays for aero 'rom' (Ra modes), 'full' (all modes) or 'none'."""
    s = model.structure
    n = s.n_modes
    M = s.modal_mass_kg * np.eye(n)
    if aero == "none":
        z = np.zeros((n, n))
        e = np.zeros((0, n))
        nb = model.lattice.n_body
        return StepperMatrices(M, z, np.diag(s.modal_damping_kgps), z, np.diag(s.modal_stiffness_npm), z,
                               np.zeros((n, 0)), e, e, np.zeros(0, np.int64), np.zeros(0, np.int64),
                               np.zeros(0), np.zeros(0), model.lattice.dx_m,
                               np.zeros((n, nb)), np.zeros((n, nb)), np.zeros((0, nb)))
    ca = model.continuous(model.cfg.rom_modes if aero == "rom" else None)
    off, size, a, b = _blocks(ca.Lam)
    return StepperMatrices(M + ca.Ma, ca.Ma, np.diag(s.modal_damping_kgps), ca.Ca, np.diag(s.modal_stiffness_npm),
                           ca.Ka, ca.Qxi, ca.Gv, ca.Gs, off, size, a, b, ca.dx_m, ca.Qg, ca.Qgd, ca.Gg)


@dataclass(frozen=True)
class SampledRun:
    """Result of :meth:`Stepper.advance_sampled`: per-step tip w/L and the state at each completed sample."""

    ok: bool
    steps_done: int
    samples_done: int
    tip_w_over_L: np.ndarray
    q: np.ndarray
    qdot_per_s: np.ndarray
    aero_force_npm: np.ndarray


class Stepper:
    """Advance the panel by fixed steps; airspeed (m/s) and tip force (N per metre span) per step."""

    def __init__(self, cfg: PanelConfig, variant: str = "full", aero: str = "rom", scheme: str = "implicit",
                 model: AeroelasticModel | None = None, dt_s: float | None = None):
        problem = stepper_problem(variant, aero, scheme)
        if problem:
            raise ValueError(problem)
        self.cfg = cfg
        self.model = model if model is not None else AeroelasticModel(cfg)
        self.variant, self.aero, self.scheme = variant, aero, scheme
        self.dt_s = float(dt_s if dt_s is not None else cfg.dt_s)
        self.mats = stepper_matrices(self.model, aero)
        s = self.model.structure
        use_k, use_m = VARIANTS[variant]
        self._tip_vec = mode_shapes(s.n_modes, np.array([1.0]))[:, 0]
        m = self.mats
        self.exact = variant == EXACT_VARIANT
        self._shape_basis: dict[tuple[float, ...], np.ndarray] = {}  # stations x/L -> phi_m(x/L) (shape_w_over_L)
        kin = exact_kinematics(s.n_modes) if self.exact else None
        self._kin = kin
        self.kernel_model = kernel.KernelModel(
            self.dt_s, m.dx_m, m.M0, m.C, m.Ca, m.K, m.Ka, m.Qxi, m.Gv, m.Gs, m.blk_off, m.blk_len, m.lam_a, m.lam_b,
            s.K_nl, s.P_nl, kernel.inertia_force_tensor(s.P_nl), s.stiffness_scale_n, s.modal_mass_kg, use_k, use_m,
            MASS_MODES[scheme],
            cfg.panel_length_m * self._tip_vec,  # generalised force per N/m at the trailing edge
            self._tip_vec, cfg.max_tip_w_over_L, NEWTON_TOL,
            m.Qg, m.Qgd, m.Gg,  # gust input
            # exact (elastica) structure
            *((True, kin.psi, kin.quad.w, kin.quad.inertia_operator(), cfg.panel_length_m)
              if self.exact else ()))
        self._gust_proj = kernel.gust_projection(self.kernel_model)  # (r + 2n, km): what the kernel needs of w_g
        kernel.project_gust(np.zeros((1, self._gust_proj.shape[1])), self._gust_proj,
                            np.zeros((1, self._gust_proj.shape[0])))  # compile / load now
        self.reset()

    # ---- state ------------------------------------------------------------------------------------
    def reset(self, q: np.ndarray | None = None, qdot: np.ndarray | None = None) -> None:
        """Back to rest (or to the given modal state), aero wake at rest, time zero."""
        n = self.model.structure.n_modes
        self.q = np.zeros(n) if q is None else np.array(q, dtype=float)
        self.qdot = np.zeros(n) if qdot is None else np.array(qdot, dtype=float)
        self.xi = np.zeros(self.mats.Qxi.shape[1])
        self.wg = np.zeros(self.n_colloc)  # vertical gust at the collocation points now, m/s (part of the state)
        self._pg = np.zeros(self._gust_proj.shape[0])  # its projection [Gg; Qg; Qgd] w_g (the kernel's view)
        self.time_s = 0.0
        self.steps = 0
        # U, q, v, xi, w_g before the last step, and w_g after it
        self._last = (0.0, np.zeros(n), np.zeros(n), np.zeros_like(self.xi), self.wg.copy(), self.wg.copy())

    @property
    def n_modes(self) -> int:
        return self.q.shape[0]

    @property
    def n_colloc(self) -> int:
        """Number of collocation points (vortex elements on airfoil + panel): the gust input's width."""
        return self.model.lattice.n_body

    @property
    def x_colloc_m(self) -> np.ndarray:
        """Collocation points, m from the airfoil leading edge: where a gust field is sampled."""
        return self.model.lattice.x_colloc_m

    def _gust(self, gust_upwash_mps: np.ndarray | None, n_steps: int) -> np.ndarray:
        """The per-step gust upwash: (n_steps, km), or (n_steps, 0) for no gust at all."""
        if gust_upwash_mps is None:
            if not np.any(self.wg):
                return np.zeros((n_steps, 0))
            return np.zeros((n_steps, self.n_colloc))  # the gust stops: w_g returns to 0
        g = np.ascontiguousarray(gust_upwash_mps, dtype=float)
        if g.shape != (n_steps, self.n_colloc):
            raise ValueError(f"gust upwash must have shape ({n_steps}, {self.n_colloc}), got {g.shape}")
        return g

    def _projected(self, gust: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(kernel gust state, per-step projected gust) for a (n_steps, km or 0) upwash array."""
        if not gust.shape[1]:
            return np.zeros(0), np.zeros((gust.shape[0], 0))
        out = np.empty((gust.shape[0], self._gust_proj.shape[0]))
        kernel.project_gust(gust, self._gust_proj, out)
        return self._pg, out

    def _gust_done(self, gust: np.ndarray, done: int) -> None:
        """After ``done`` steps of a march with this gust array: the upwash state follows."""
        if gust.shape[1] and done:
            self.wg = gust[done - 1].copy()

    @property
    def tip_w_over_L(self) -> float:
        """Trailing-edge deflection w/L = sum q_i phi_i(1) (exact: int_0^1 sin theta, so |w/L| <= 1)."""
        if self.exact:
            return float(exact_tip(self.q, self._kin.psi, self._kin.quad.w))
        tip = 0.0  # the kernel's sum, term by term in mode order: numpy's dot may sum (or fuse) in another order
        for c, qj in zip(self._tip_vec.tolist(), self.q.tolist()):
            tip += c * qj
        return tip

    def shape_w_over_L(self, x_over_L: np.ndarray, q: np.ndarray | None = None) -> np.ndarray:
        """w/L along the panel at x/L (exact: at arc length s = x/L of the undeformed panel; the point's
        chordwise position is then :meth:`shape_xw_over_L`); of the present state, or of modal coordinates
        ``q`` (e.g. a sample of a marched block)."""
        q = self.q if q is None else np.asarray(q, dtype=float)
        x = np.asarray(x_over_L, dtype=float)
        if x.ndim != 1:
            return exact_shape(q, x)[1] if self.exact else q @ mode_shapes(self.n_modes, x)
        key = tuple(x.tolist())
        if self.exact:  # the precomputed sampler of the same shape (the live rig draws it ~1000 times/s)
            return shape_sampler(self.n_modes, key).w(q)
        basis = self._shape_basis.get(key)
        if basis is None:
            basis = self._shape_basis[key] = mode_shapes(self.n_modes, x)
        return q @ basis

    def shape_xw_over_L(self, s_over_L: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(x/L, w/L) of the material points at arc length s/L (cubic variants: x = s - 1/2 int w'^2 is not
        tracked by the kernel, so x = s is returned for them)."""
        s_ = np.asarray(s_over_L, dtype=float)
        if self.exact:
            return exact_shape(self.q, s_)
        return s_.copy(), self.shape_w_over_L(s_)

    @property
    def aero_force_npm(self) -> np.ndarray:
        """Generalised aerodynamic force on each mode over the last step (midpoint), N per metre span."""
        U, q0, v0, xi0, wg0, wg1 = self._last
        m = self.mats
        vm, qm = 0.5 * (self.qdot + v0), 0.5 * (self.q + q0)
        acc = (self.qdot - v0) / self.dt_s
        xim = 0.5 * (self.xi + xi0)
        force = -m.Ma @ acc - U * m.Ca @ vm - U * U * m.Ka @ qm + U * m.Qxi @ xim
        if np.any(wg0) or np.any(wg1):
            force = force + 0.5 * U * m.Qg @ (wg0 + wg1) + m.Qgd @ (wg1 - wg0) / self.dt_s
        return force

    # ---- marching ---------------------------------------------------------------------------------
    def advance(self, n_steps: int, airspeed_mps: float | np.ndarray, tip_force_npm: float | np.ndarray = 0.0,
                gust_upwash_mps: np.ndarray | None = None) -> np.ndarray:
        """Advance n_steps; inputs are scalars or per-step arrays. Returns tip w/L after each step.

        ``gust_upwash_mps`` (n_steps, km): the vertical gust (m/s, positive up) at each collocation point at the
        end of each step (the field is the caller's: e.g. a convected turbulence field); None: no gust.
        Raises DivergenceError (state kept at the last finite step, the tip after each step done before it in the
        error's ``tip_w_over_L``) if the march leaves the physical range.
        """
        U = np.broadcast_to(np.asarray(airspeed_mps, dtype=float), (n_steps,)).copy()
        F = np.broadcast_to(np.asarray(tip_force_npm, dtype=float), (n_steps,)).copy()
        if not (np.all(np.isfinite(U)) and np.all(U >= 0) and np.all(np.isfinite(F))):
            raise ValueError("airspeed must be finite and >= 0, tip force finite")
        G = self._gust(gust_upwash_mps, n_steps)
        if not np.all(np.isfinite(G)):
            raise ValueError("gust upwash must be finite")
        tip, start = np.empty(n_steps), self.steps
        try:
            if n_steps > 1:
                self._march(U[:-1], F[:-1], tip[:-1], G[:-1])
            if n_steps > 0:
                wg0 = self.wg.copy()
                self._last = (float(U[-1]), self.q.copy(), self.qdot.copy(), self.xi.copy(), wg0,
                              G[-1].copy() if G.shape[1] else wg0)
                self._march(U[-1:], F[-1:], tip[-1:], G[-1:])
        except DivergenceError as exc:  # the steps done before it (a plot of a diverged run ended a chunk early)
            exc.tip_w_over_L = tip[: self.steps - start].copy()
            raise
        return tip

    def _march(self, U: np.ndarray, F: np.ndarray, tip: np.ndarray, G: np.ndarray) -> None:
        pg, P = self._projected(G)
        status, done = kernel.march(self.q, self.qdot, self.xi, U, F, self.kernel_model, tip, pg, P)
        self._gust_done(G, done)
        self.steps += done
        self.time_s += done * self.dt_s
        if status != kernel.OK:
            reason = "non-finite state" if status == kernel.NON_FINITE else (
                f"|tip w/L| exceeded {self.cfg.max_tip_w_over_L}")
            raise DivergenceError(reason, self.time_s)

    def step(self, airspeed_mps: float, tip_force_npm: float = 0.0, gust_upwash_mps: np.ndarray | None = None) -> None:
        """One physics step dt with these inputs (gust: (km,) upwash at the end of the step, or None)."""
        self.advance(1, airspeed_mps, tip_force_npm,
                     None if gust_upwash_mps is None else np.asarray(gust_upwash_mps, float).reshape(1, -1))

    def advance_sampled(self, airspeed_mps: np.ndarray, tip_force_npm: np.ndarray, ends: np.ndarray,
                        tip_bound: float | None = None, gust_upwash_mps: np.ndarray | None = None) -> SampledRun:
        """Advance len(airspeed_mps) steps in one compiled call, sampling the state after each step count in
        ``ends`` (strictly increasing, last = number of steps). Per-step inputs are trusted (finite, U >= 0).

        Never raises on divergence: the march stops *before* the first step whose |tip w/L| would exceed
        ``tip_bound`` (default and upper limit: the model's bound) or that is not finite, and the state stays
        at the last good step (``ok`` False, ``steps_done`` steps applied).
        """
        U = np.ascontiguousarray(airspeed_mps, dtype=float)
        F = np.ascontiguousarray(tip_force_npm, dtype=float)
        ends = np.ascontiguousarray(ends, dtype=np.int64)
        bound = self.cfg.max_tip_w_over_L if tip_bound is None else min(tip_bound, self.cfg.max_tip_w_over_L)
        k, n, r = ends.shape[0], self.n_modes, self.xi.shape[0]
        tip = np.empty(U.shape[0])
        q_pre, v_pre, q_post, v_post = (np.empty((k, n)) for _ in range(4))
        xi_pre, xi_post = np.empty((k, r)), np.empty((k, r))
        m = self.mats
        G = self._gust(gust_upwash_mps, U.shape[0])
        wg_start = self.wg.copy()
        pg, P = self._projected(G)
        pg_start = pg.copy()
        status, done, segs = kernel.march_sampled(
            self.q, self.qdot, self.xi, U, F, ends, self.kernel_model._replace(tip_bound=bound), tip,
            q_pre, v_pre, xi_pre, q_post, v_post, xi_post, pg, P)
        self._gust_done(G, done)
        self.steps += done
        self.time_s += done * self.dt_s
        last_steps = ends[:segs] - 1
        if segs:
            last = last_steps[-1]
            self._last = (float(U[last]), q_pre[segs - 1].copy(), v_pre[segs - 1].copy(), xi_pre[segs - 1].copy(),
                          G[last - 1].copy() if G.shape[1] and last else wg_start.copy(),
                          G[last].copy() if G.shape[1] else wg_start.copy())
        # generalised aero force of each sample's last step (midpoint), as in aero_force_npm
        Us = U[last_steps][:, None]
        acc = (v_post[:segs] - v_pre[:segs]) / self.dt_s
        vm, qm = 0.5 * (v_post[:segs] + v_pre[:segs]), 0.5 * (q_post[:segs] + q_pre[:segs])
        xim = 0.5 * (xi_post[:segs] + xi_pre[:segs])
        aero = -acc @ m.Ma.T - Us * (vm @ m.Ca.T) - Us * Us * (qm @ m.Ka.T) + Us * (xim @ m.Qxi.T)
        if G.shape[1]:  # the gust's part from the projections [Gg; Qg; Qgd] w_g the kernel marched, before / after
            pre, post = P[np.maximum(last_steps - 1, 0)], P[last_steps]
            if segs and last_steps[0] == 0:
                pre[0] = pg_start
            r, n = self.xi.shape[0], self.n_modes
            aero += 0.5 * Us * (pre[:, r:r + n] + post[:, r:r + n]) + (post[:, r + n:] - pre[:, r + n:]) / self.dt_s
        return SampledRun(status == kernel.OK, int(done), int(segs), tip[:done], q_post[:segs], v_post[:segs], aero)


class BatchStepper:
    """Many independent runs of one model advanced together (leading axis = run), for sweeps.

    A run that diverges is frozen at its last good state and flagged in ``diverged``; the others go on.
    """

    def __init__(self, template: Stepper, n_runs: int):
        self.t = template
        n, r = template.n_modes, template.xi.shape[0]
        self.q = np.zeros((n_runs, n))
        self.qdot = np.zeros((n_runs, n))
        self.xi = np.zeros((n_runs, r))
        self.pg = np.zeros((n_runs, 0))  # no gust in sweeps (the kernel's width-0 path)
        self.active = np.ones(n_runs, dtype=np.bool_)
        self.status = np.zeros(n_runs, dtype=np.int64)
        self.time_s = 0.0

    @property
    def diverged(self) -> np.ndarray:
        return self.status != kernel.OK

    def advance(self, n_steps: int, airspeed_mps: np.ndarray, tip_force_npm: np.ndarray | float = 0.0) -> np.ndarray:
        """Advance every active run n_steps with per-run (B,) or per-run-per-step (B, n_steps) inputs.
        Returns tip w/L (B, n_steps); entries after a run's divergence are NaN."""
        B = self.q.shape[0]
        U = np.ascontiguousarray(np.broadcast_to(np.asarray(airspeed_mps, float).reshape(B, -1), (B, n_steps)))
        F = np.ascontiguousarray(np.broadcast_to(np.asarray(tip_force_npm, float).reshape(-1, 1) if np.ndim(
            tip_force_npm) < 2 else tip_force_npm, (B, n_steps)))
        if not (np.all(np.isfinite(U)) and np.all(U >= 0) and np.all(np.isfinite(F))):
            raise ValueError("airspeed must be finite and >= 0, tip force finite")
        tip = np.full((B, n_steps), np.nan)
        kernel.march_batch(self.q, self.qdot, self.xi, U, F, self.active, self.t.kernel_model, tip, self.status,
                           self.pg, np.zeros((B, n_steps, 0)))
        self.time_s += n_steps * self.t.dt_s
        return tip
