"""Compiled (numba) time-step kernel of the nonlinear aeroelastic equations.

Unknowns per step: the new modal velocity x = q_dot^{n+1}; everything else follows. The scheme is the
trapezoidal / implicit-midpoint rule on

    (M + Ma + s_M dM(q*)) q_dd + (C + U Ca) q_dot + (K + U^2 Ka) q + s_K F_K(q) + s_M F_M(q, q_dot)
        - U Qxi xi = f_tip L phi(1)                                             (Eqs. 21, 25)
    d xi/dt = (U/dx) Lam xi - Gv q_dd - U Gs q_dot

with every term at the midpoint t + dt/2 except the nonlinear mass, taken at q* = q(t + dt/2)
('implicit'), at q* = q(t) ('paper': Eq. 24 with dM(q^t)), or at q(t) multiplying only the new
velocity ('paper_literal': [D2 + dM] z^{t+1} + D1 z^t read literally, which adds
dM(q) q_dot / dt). The aero blocks of Lam are 1x1 or 2x2
([[a, b], [-b, a]]), so the aerodynamic solve is closed-form and the airspeed may change every step.
The 3x3 structural system is solved by a chord-Newton iteration.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from panel_rig.model.kernel_exact import FORCE_WORK_ROWS, exact_force, exact_tip_near

OK, NON_FINITE, OVER_BOUND = 0, 1, 2
MASS_MIDPOINT, MASS_AT_START, MASS_LITERAL = 0, 1, 2  # where the nonlinear mass dM(q) is evaluated
MAX_ITER = 30
# the Newton test is relative to the new velocity, floored at REST_SCALE |q| / dt: near a static deflection (a held
# force in a quiet tunnel) the velocity decays towards 0 while the residual's round-off stays at the static load's
# (~1e-16 omega^2 |q| dt), so a purely relative test was never met and every step ran all MAX_ITER iterations
# (12-14 us a step instead of 1.5); the floor is a velocity that moves q by 1e-3 |q| / 2 in a step, far below any
# motion's (LCO: ~|q| omega, omega dt ~ 0.07), so a moving panel's test is unchanged
REST_SCALE = 1e-3
# exact (elastica) structure, the step's Newton iteration (profile and measurements: docs/validation.md, section 5):
EX_RHO = 0.03  # a fresh structural Newton matrix when an update contracts by less than this factor
EX_KEEP, EX_WAIT = 1e-3, 64  # a step first tries the last step's matrix; if an iteration then contracts by less
# than EX_KEEP, a fresh one is evaluated and the next EX_WAIT steps evaluate their own at the first iteration
# (small motion: the matrix hardly changes and is kept; in a large LCO it changes by 1-5 % a step)
# the estimated-error stop (below) of the cubic structure's chord Newton: its ratio from two updates is less steady
# than the exact structure's (Newton matrix exact at the first iteration); at EST_CHORD = 1 a step of a growing LCO
# was up to 8 tolerances off the converged solution (300 states), at 0.1 within 0.24
EST_CHORD = 0.1
EX_PRED = 3  # the Newton predictor extrapolates the last EX_PRED step accelerations (degree EX_PRED - 1)


class KernelModel(NamedTuple):
    """Everything constant in a march, handed to the compiled kernels as one argument (SI units).

    Structure (Eqs. 19-22): ``M0`` = M + Ma (kg/m, modal), ``C`` structural damping (kg/(m s)), ``K`` structural
    stiffness (N/m^2 per unit modal coordinate), ``K_nl``/``P_nl`` the nonlinear stiffness and inertia tensors
    scaled by ``k_scale`` (D/L) and ``m_scale`` (m_p L^3), ``T_nl`` the inertia force's tensor
    (:func:`inertia_force_tensor`); ``use_k``/``use_m`` switch them (the variant);
    ``mass_mode`` where dM(q) is evaluated (MASS_*). Aero ROM (Eq. 25, convective form): ``Ca`` and ``Ka``
    (scaled by U and U^2 per step), ``Qxi``, ``Gv``, ``Gs`` and the block-diagonal aero eigenvalues
    (``blk_off``, ``blk_len``, ``lam_a``, ``lam_b``, scaled by U/dx per step). ``f_vec``: generalised force per
    N/m at the trailing edge; ``tip_vec``: tip w/L per modal coordinate; ``tip_bound``: |tip w/L| that stops a
    march; ``tol``: Newton tolerance; ``dt`` the step (s) and ``dx`` the vortex spacing (m). Gust input
    (appended): ``Qg``, ``Qgd``, ``Gg``.
    """

    dt: float
    dx: float
    M0: np.ndarray
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
    K_nl: np.ndarray
    P_nl: np.ndarray
    T_nl: np.ndarray  # inertia_force_tensor(P_nl)
    k_scale: float
    m_scale: float
    use_k: bool
    use_m: bool
    mass_mode: int
    f_vec: np.ndarray
    tip_vec: np.ndarray
    tip_bound: float
    tol: float
    # gust input (see ContinuousAero in aeroelastic.py): a vertical gust w_g at the km collocation points adds
    # to the downwash; Q += U Qg w_g + Qgd dw_g/dt and d xi/dt += Gg dw_g/dt, at the step midpoint like the rest
    Qg: np.ndarray  # (n, km)
    Qgd: np.ndarray  # (n, km)
    Gg: np.ndarray  # (r, km)
    # exact (elastica) structure: theta = q . psi at Gauss points (kernel_exact.py, elastica.py); when ``exact``
    # the cubic terms are off (use_k = use_m = False), M(q), h(q, v) and the dead tip force L B(1; q) replace
    # them and the reported tip is the exact w(1)/L = int sin(theta). ``ex_S``: the inertia operator R^T diag(w) R
    # of the quadrature (elastica.Quadrature.inertia_operator); ``ex_length``: L (m).
    exact: bool = False
    ex_psi: np.ndarray = np.zeros((0, 0))
    ex_w: np.ndarray = np.zeros(0)
    ex_S: np.ndarray = np.zeros((0, 0))
    ex_length: float = 0.0


@njit(cache=True)
def inertia_force_tensor(P_nl):
    """T_iacd = P_aicd + P_ciad - (P_iacd + P_caid) / 2, the nonlinear inertia force of Eq. (22) as one tensor:
    F_M,i = m sum_acd T_iacd v_a q_c v_d (formed once per model: one gather per term instead of three)."""
    n = P_nl.shape[0]
    T = np.zeros((n, n, n, n))
    for i in range(n):
        for a in range(n):
            for c in range(n):
                for d in range(n):
                    T[i, a, c, d] = P_nl[a, i, c, d] + P_nl[c, i, a, d] - 0.5 * (P_nl[i, a, c, d] + P_nl[c, a, i, d])
    return T


@njit(cache=True)
def _nl_force(q, v, K_nl, T_nl, k_scale, m_scale, use_k, use_m, f):
    """f += s_K (D/L) K_inrs q_n q_r q_s + s_M F_M(q, v) (Eq. 22), F_M,i = m T_iacd v_a q_c v_d
    (:func:`inertia_force_tensor`)."""
    n = q.shape[0]
    if use_k:
        for i in range(n):
            acc = 0.0
            for a in range(n):
                for b in range(n):
                    qab = q[a] * q[b]
                    for c in range(n):
                        acc += K_nl[i, a, b, c] * qab * q[c]
            f[i] += k_scale * acc
    if use_m:
        for i in range(n):
            acc = 0.0
            for a in range(n):
                for c in range(n):
                    vq = v[a] * q[c]
                    for d in range(n):
                        acc += T_nl[i, a, c, d] * vq * v[d]
            f[i] += m_scale * acc


@njit(cache=True)
def _nl_mass(q, P_nl, m_scale, out):
    """out += dM(q)_bd = m_p L^3 P_abcd q_a q_c."""
    n = q.shape[0]
    for b in range(n):
        for d in range(n):
            acc = 0.0
            for a in range(n):
                for c in range(n):
                    acc += P_nl[a, b, c, d] * q[a] * q[c]
            out[b, d] += m_scale * acc
    return out


@njit(cache=True)
def _solve_inplace(J, rhs):
    """Gaussian elimination with partial pivoting of a small dense system; rhs becomes the solution."""
    n = rhs.shape[0]
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(J[i, k]) > abs(J[p, k]):
                p = i
        if p != k:
            for j in range(n):
                J[k, j], J[p, j] = J[p, j], J[k, j]
            rhs[k], rhs[p] = rhs[p], rhs[k]
        for i in range(k + 1, n):
            f = J[i, k] / J[k, k]
            for j in range(k, n):
                J[i, j] -= f * J[k, j]
            rhs[i] -= f * rhs[k]
    for k in range(n - 1, -1, -1):
        acc = rhs[k]
        for j in range(k + 1, n):
            acc -= J[k, j] * rhs[j]
        rhs[k] = acc / J[k, k]


@njit(cache=True)
def _block_apply(blk_off, blk_len, a, b, vec, out, inverse, h):
    """out = (I - h Lam)^{-1} vec (inverse=True) or (I + h Lam) vec (inverse=False), Lam block-diagonal."""
    for k in range(blk_off.shape[0]):
        o = blk_off[k]
        ak, bk = h * a[k], h * b[k]
        if blk_len[k] == 1:
            if inverse:
                out[o] = vec[o] / (1.0 - ak)
            else:
                out[o] = (1.0 + ak) * vec[o]
        else:
            x0, x1 = vec[o], vec[o + 1]
            if inverse:  # [[1-a, -b], [b, 1-a]]^{-1} = [[1-a, b], [-b, 1-a]] / det
                det = (1.0 - ak) ** 2 + bk**2
                out[o] = ((1.0 - ak) * x0 + bk * x1) / det
                out[o + 1] = (-bk * x0 + (1.0 - ak) * x1) / det
            else:
                out[o] = (1.0 + ak) * x0 + bk * x1
                out[o + 1] = -bk * x0 + (1.0 + ak) * x1


@njit(cache=True)
def _extrapolate(a, m, i):
    """Polynomial extrapolation one step ahead of the equally spaced sequence a[m-1, i], ..., a[0, i] (a[0] the
    newest): the degree m-1 polynomial through them, sum_k (-1)^k C(m, k+1) a[k, i] (0 with no history)."""
    acc = 0.0
    binom = float(m)  # C(m, k + 1)
    sign = 1.0
    for k in range(m):
        acc += sign * binom * a[k, i]
        binom = binom * (m - k - 1) / (k + 2)
        sign = -sign
    return acc


@njit(cache=True)
def newton_scale(x, q, dt):
    """The velocity scale of the step's Newton test |update| <= tol * scale: the largest new velocity, floored at
    REST_SCALE |q| / dt (see REST_SCALE) and at 1e-12."""
    scale = 1e-12
    for i in range(x.shape[0]):
        scale = max(scale, abs(x[i]), REST_SCALE * abs(q[i]) / dt)
    return scale


@njit(cache=True)
def march(q, v, xi, U_seq, F_seq, km, tip_out, pg, Pg_seq):
    """Advance (q, v, xi) in place over len(U_seq) steps of the :class:`KernelModel` ``km``; tip w/L of each
    step into tip_out.

    Gust: the vertical gust w_g at the km collocation points enters only through its projections
    p = [Gg w_g, Qg w_g, Qgd w_g] (r + 2n numbers, see :func:`gust_projection`): ``pg`` (r + 2n,) is p now (state,
    updated in place) and ``Pg_seq`` (n_steps, r + 2n) p at the end of each step. Width 0 (empty arrays) is no gust,
    and then not a single operation differs from the gust-free kernel.

    Returns (status, steps_done): status OK, NON_FINITE or OVER_BOUND (state left at the last good step).
    """
    none = np.zeros((0, q.shape[0]))
    none_xi = np.zeros((0, xi.shape[0]))
    status, done, _ = _march(q, v, xi, U_seq, F_seq, km, tip_out, pg, Pg_seq, np.zeros(0, np.int64),
                             none, none, none_xi, none, none, none_xi)
    return status, done


@njit(cache=True)
def _march(q, v, xi, U_seq, F_seq, km, tip_out, pg, Pg_seq, ends, q_pre, v_pre, xi_pre, q_post, v_post, xi_post):
    """:func:`march`, keeping the state before and after the step ends[s] - 1 for each s (``ends`` increasing,
    every end >= 1; empty: no samples). One loop over all steps: the scratch arrays, the airspeed-dependent
    matrices and the exact structure's predictor history and Newton matrix carry on across the samples.

    Returns (status, steps_done, samples_done)."""
    dt, dx, M0, C, Ca, K, Ka, Qxi, Gv, Gs = km.dt, km.dx, km.M0, km.C, km.Ca, km.K, km.Ka, km.Qxi, km.Gv, km.Gs
    blk_off, blk_len, lam_a, lam_b = km.blk_off, km.blk_len, km.lam_a, km.lam_b
    K_nl, P_nl, k_scale, m_scale, use_k, use_m = km.K_nl, km.P_nl, km.k_scale, km.m_scale, km.use_k, km.use_m
    mass_mode, f_vec, tip_vec, tip_bound, tol = km.mass_mode, km.f_vec, km.tip_vec, km.tip_bound, km.tol
    exact, ex_psi, ex_w, ex_S = km.exact, km.ex_psi, km.ex_w, km.ex_S
    T_nl = km.T_nl
    est_tol = tol * (1.0 if exact else EST_CHORD)
    ex_work = np.zeros((FORCE_WORK_ROWS, ex_psi.shape[1]))
    ex_jwork = np.zeros((2, 2 * q.shape[0], ex_psi.shape[1]))
    ex_J = np.zeros((q.shape[0], q.shape[0]))
    ex_F = np.zeros(q.shape[0])
    ex_a = np.zeros(q.shape[0])
    q_new = np.zeros(q.shape[0])
    # exact: the step-mean accelerations (x - v)/dt of the last EX_PRED steps of this march (row 0 the newest), the
    # Newton predictor extrapolates them
    ex_acc = np.zeros((EX_PRED, q.shape[0]))
    ex_hist = 0
    ex_new_j = True  # exact: evaluate the structural Newton matrix at the next iteration (else keep the last one)
    # exact: a step may try the previous step's matrix (ex_kept) unless a try failed within the last ex_wait steps
    ex_kept = False
    ex_wait = 1
    n = q.shape[0]
    r = xi.shape[0]
    h = 0.5 * dt
    tmp_r = np.zeros(r)
    c0 = np.zeros(r)
    W = np.zeros((r, n))
    Cu = np.zeros((n, n))
    Ku = np.zeros((n, n))
    QW = np.zeros((n, n))
    J_lin = np.zeros((n, n))
    Mt = np.zeros((n, n))
    J = np.zeros((n, n))
    res = np.zeros(n)
    x = np.zeros(n)
    vm = np.zeros(n)
    qm = np.zeros(n)
    xi_part = np.zeros(n)
    la = np.zeros(lam_a.shape[0])
    lb = np.zeros(lam_a.shape[0])
    inv_a = np.zeros(lam_a.shape[0])
    inv_b = np.zeros(lam_a.shape[0])
    U_prev = -1.0
    ng = Pg_seq.shape[1]
    fg = np.zeros(n)
    n_ends = ends.shape[0]
    sample = 0
    for step in range(U_seq.shape[0]):
        capture = sample < n_ends and step == ends[sample] - 1
        if capture:
            q_pre[sample] = q
            v_pre[sample] = v
            xi_pre[sample] = xi
        U = U_seq[step]
        if U != U_prev:  # airspeed-dependent matrices: W = (I-hL)^{-1}(Gv + U h Gs), Cu, Ku, QW
            # (in turbulence u' changes U every step: the block inverses are formed once here, one division per
            # block, and applied to the n columns by multiplication)
            for k in range(la.shape[0]):
                la[k] = lam_a[k] * (U / dx)
                lb[k] = lam_b[k] * (U / dx)
                ak, bk = h * la[k], h * lb[k]
                if blk_len[k] == 1:
                    inv_a[k] = 1.0 / (1.0 - ak)
                    inv_b[k] = 0.0
                else:  # [[1-a, -b], [b, 1-a]]^{-1} = [[1-a, b], [-b, 1-a]] / det
                    det = 1.0 / ((1.0 - ak) ** 2 + bk**2)
                    inv_a[k] = (1.0 - ak) * det
                    inv_b[k] = bk * det
            for j in range(n):
                for k in range(blk_off.shape[0]):
                    o = blk_off[k]
                    x0 = Gv[o, j] + U * h * Gs[o, j]
                    if blk_len[k] == 1:
                        W[o, j] = inv_a[k] * x0
                    else:
                        x1 = Gv[o + 1, j] + U * h * Gs[o + 1, j]
                        W[o, j] = inv_a[k] * x0 + inv_b[k] * x1
                        W[o + 1, j] = inv_a[k] * x1 - inv_b[k] * x0
            for i in range(n):
                for j in range(n):
                    Cu[i, j] = C[i, j] + U * Ca[i, j]
                    Ku[i, j] = K[i, j] + U * U * Ka[i, j]
                    acc = 0.0
                    for k in range(r):
                        acc += Qxi[i, k] * W[k, j]
                    QW[i, j] = 0.5 * U * acc
                    J_lin[i, j] = 0.5 * Cu[i, j] + 0.5 * h * Ku[i, j] + QW[i, j]
            U_prev = U
        # c0 = (I-hL)^{-1}[(I+hL) xi + (Gv - U h Gs) v]; xi' = c0 - W x
        _block_apply(blk_off, blk_len, la, lb, xi, tmp_r, False, h)
        for k in range(r):
            acc = tmp_r[k]
            for j in range(n):
                acc += (Gv[k, j] - U * h * Gs[k, j]) * v[j]
            tmp_r[k] = acc
        if ng > 0:  # gust: xi input Gg (w_g' - w_g), force U Qg (w_g + w_g')/2 + Qgd (w_g' - w_g)/dt (projected)
            for k in range(r):
                tmp_r[k] += Pg_seq[step, k] - pg[k]
            for i in range(n):
                fg[i] = (0.5 * U * (pg[r + i] + Pg_seq[step, r + i])
                         + (Pg_seq[step, r + n + i] - pg[r + n + i]) / dt)
        _block_apply(blk_off, blk_len, la, lb, tmp_r, c0, True, h)
        for i in range(n):
            acc = 0.0
            for k in range(r):
                acc += Qxi[i, k] * (xi[k] + c0[k])
            if exact:  # the dead tip force is state dependent: in the residual
                xi_part[i] = 0.5 * U * acc
            else:
                xi_part[i] = 0.5 * U * acc + F_seq[step] * f_vec[i]
            if ng > 0:
                xi_part[i] += fg[i]
        big_prev = 0.0
        ex_kept = ex_wait == 0
        ex_new_j = not ex_kept
        for i in range(n):
            x[i] = v[i]
            if exact:
                x[i] += dt * _extrapolate(ex_acc, ex_hist, i)
        for it in range(MAX_ITER):
            for i in range(n):
                vm[i] = 0.5 * (x[i] + v[i])
                qm[i] = q[i] + h * vm[i]
            Mt[:, :] = M0
            if exact:  # M0 holds m I + Ma: the strip's m I goes into its inertia force M(q*) a + h(q*, v*)
                # (midpoint, a = (x - v)/dt), with the dead tip force; its exact Newton matrix at the first iteration
                for i in range(n):
                    Mt[i, i] -= m_scale
                    ex_a[i] = (x[i] - v[i]) / dt
                exact_force(qm, vm, ex_a, F_seq[step] * km.ex_length, ex_psi, ex_w, ex_S, m_scale, ex_new_j,
                            0.25 * dt, 0.5, 1.0 / dt, ex_F, ex_J, ex_work, ex_jwork, it > 0)
                ex_new_j = False
            if use_m:
                _nl_mass(qm if mass_mode == MASS_MIDPOINT else q, P_nl, m_scale, Mt)
            for i in range(n):
                acc = -xi_part[i]
                for j in range(n):
                    acc += Mt[i, j] * (x[j] - v[j]) / dt + Cu[i, j] * vm[j] + Ku[i, j] * qm[j] + QW[i, j] * x[j]
                    if mass_mode == MASS_LITERAL:  # [D2 + dM] z^{t+1} + D1 z^t: dM multiplies the new state only
                        acc += (Mt[i, j] - M0[i, j]) * v[j] / dt
                if exact:
                    acc += ex_F[i]
                res[i] = acc
            if use_k or use_m:
                _nl_force(qm, vm, K_nl, T_nl, k_scale, m_scale, use_k, use_m, res)
            for i in range(n):
                for j in range(n):
                    J[i, j] = Mt[i, j] / dt + J_lin[i, j]
            if exact:
                for i in range(n):
                    for j in range(n):
                        J[i, j] += ex_J[i, j]
            _solve_inplace(J, res)
            big = 0.0
            for i in range(n):
                x[i] -= res[i]
                big = max(big, abs(res[i]))
            scale = newton_scale(x, q, dt)
            if exact and it > 0 and big > (EX_KEEP if ex_kept else EX_RHO) * big_prev:
                ex_new_j = True  # slow contraction: a fresh Newton matrix (and no kept one for a while)
                if ex_kept:
                    ex_kept = False
                    ex_wait = EX_WAIT + 1
            if big <= tol * scale:
                break
            # linear convergence with ratio r = big / big_prev leaves an error of about big r / (1 - r) after this
            # update; stop when that is below est_tol (saves the confirming evaluation: a moving panel's step
            # is two iterations, not three; the chord matrix leaves out only the small cubic forces' derivatives)
            if it > 0 and big < 0.5 * big_prev and big * big <= est_tol * scale * (big_prev - big):
                break
            big_prev = big
        tip = 0.0
        finite = True
        for j in range(n):
            qn = q[j] + h * (x[j] + v[j])
            tip += tip_vec[j] * qn
            q_new[j] = qn
            finite = finite and np.isfinite(qn) and np.isfinite(x[j])
        for k in range(r):
            acc = c0[k]
            for j in range(n):
                acc -= W[k, j] * x[j]
            tmp_r[k] = acc
            finite = finite and np.isfinite(acc)
        if exact and finite:
            tip = exact_tip_near(q_new, ex_psi, ex_w, ex_work)
        if not finite:
            return NON_FINITE, step, sample
        if abs(tip) > tip_bound:
            return OVER_BOUND, step, sample
        for j in range(n):
            q[j] += h * (x[j] + v[j])
            if exact:
                for k in range(EX_PRED - 1, 0, -1):
                    ex_acc[k, j] = ex_acc[k - 1, j]
                ex_acc[0, j] = (x[j] - v[j]) / dt
            v[j] = x[j]
        for k in range(r):
            xi[k] = tmp_r[k]
        for j in range(ng):
            pg[j] = Pg_seq[step, j]
        ex_hist = min(ex_hist + 1, EX_PRED)
        ex_wait = max(ex_wait - 1, 0)
        tip_out[step] = tip
        if capture:
            q_post[sample] = q
            v_post[sample] = v
            xi_post[sample] = xi
            sample += 1
    return OK, U_seq.shape[0], sample


def gust_projection(km: KernelModel) -> np.ndarray:
    """(r + 2n, km) matrix [Gg; Qg; Qgd]: the gust upwash at the collocation points as the kernel sees it."""
    return np.ascontiguousarray(np.vstack([km.Gg, km.Qg, km.Qgd]))


@njit(cache=True, fastmath=True)
def project_gust(G, P, out):
    """out[s] = P @ G[s] for each step s, row by row (the same arithmetic whatever the number of rows, so a block
    march and step-by-step marches see bit-identical inputs)."""
    for s in range(G.shape[0]):
        for i in range(P.shape[0]):
            acc = 0.0
            for j in range(P.shape[1]):
                acc += P[i, j] * G[s, j]
            out[s, i] = acc


@njit(cache=True)
def march_batch(q, v, xi, U_runs, F_runs, active, km, tip_out, status_out, pg, Pg_runs):
    """Advance independent runs along the leading axis; U_runs, F_runs (B, n_steps), projected gust pg (B, k) and
    Pg_runs (B, n_steps, k) (k = 0: none; see :func:`march`). Runs with active[b] False are skipped; a run that leaves the physical
    range gets its status and is deactivated."""
    for b in range(q.shape[0]):
        if not active[b]:
            continue
        st, _ = march(q[b], v[b], xi[b], U_runs[b], F_runs[b], km, tip_out[b], pg[b], Pg_runs[b])
        status_out[b] = st
        if st != OK:
            active[b] = False


@njit(cache=True)
def march_sampled(q, v, xi, U_seq, F_seq, ends, km, tip_out, q_pre, v_pre, xi_pre, q_post, v_post, xi_post,
                  pg, Pg_seq):
    """:func:`march` over segments ending at the increasing step counts ``ends`` (each >= 1 step), keeping
    the state before and after the last step of each segment (for the aero force at a sample). Gust ``pg``,
    ``Pg_seq`` as in :func:`march`. One march over all the steps (see :func:`_march`).

    Returns (status, steps_done, segments_done); on failure the state is at the last good step.
    """
    return _march(q, v, xi, U_seq, F_seq, km, tip_out, pg, Pg_seq, ends, q_pre, v_pre, xi_pre, q_post, v_post,
                  xi_post)
