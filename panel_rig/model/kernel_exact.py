"""Compiled (numba) evaluation of the exact (elastica) structure at one state; see elastica.py for the equations.

The time step (kernel.march) uses :func:`exact_force`: the inertia force M(q) a + h(q, v) in d'Alembert form
(the running integrals taken twice, as one dense operator S = R^T diag(w) R) and the step's exact Newton matrix.
:func:`exact_eval` is the mass-matrix form of the same Lagrangian (M(q), h, dh/dv): the reference the tests hold
exact_force to, and the linearisation's check.

exact_eval, per call, at the quadrature points s_p: theta = q . psi, theta_dot = v . psi, the running integrals
A_i = -int sin(theta) psi_i, B_i = int cos(theta) psi_i; then the mass matrix M(q) = m int (A A^T + B B^T),
the convective inertia force h(q, v) = m int (A a_x + B a_w) (a_x = -int cos(theta) theta_dot^2,
a_w = -int sin(theta) theta_dot^2), on request its velocity Jacobian dh/dv (for the Newton matrix of a step),
and the tip-force vector B(1) = int cos(theta) psi.
Work arrays are passed in so that the time loop allocates nothing. fastmath: these sums may be reassociated
(the exact path only; the cubic kernel is unaffected).

Development note: numba's on-disk cache of ``kernel.march`` does not notice edits to this module (it keys on
kernel.py only): after changing a function here, delete ``panel_rig/model/__pycache__/*.nb[ic]``.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, fastmath=True)
def cumulative(f, run, w_elem, n_elem, out):
    """out[p] = int_0^{s_p} f: within the element by ``run`` (interpolating polynomial), plus the Gauss totals
    of the elements before it."""
    g = run.shape[0]
    base = 0.0
    for e in range(n_elem):
        o = e * g
        for i in range(g):
            acc = base
            for k in range(g):
                acc += run[i, k] * f[o + k]
            out[o + i] = acc
        for k in range(g):
            base += w_elem[k] * f[o + k]


@njit(cache=True, fastmath=True)
def exact_tip(q, psi, w):
    """w(1)/L = int sin(theta)."""
    n, npts = psi.shape
    acc = 0.0
    for p in range(npts):
        th = 0.0
        for i in range(n):
            th += q[i] * psi[i, p]
        acc += w[p] * np.sin(th)
    return acc


@njit(cache=True, fastmath=True)
def cumulative_T(y, run, w_elem, n_elem, out):
    """The transpose of :func:`cumulative`: out_k = sum_p R_pk y_p, R the running-integral matrix
    (within element e: run; for points of later elements: the weights of k)."""
    g = run.shape[0]
    later = 0.0  # sum of y over the elements after the current one
    for e in range(n_elem - 1, -1, -1):
        o = e * g
        for k in range(g):
            acc = w_elem[k] * later
            for i in range(g):
                acc += run[i, k] * y[o + i]
            out[o + k] = acc
        for i in range(g):
            later += y[o + i]


@njit(cache=True, fastmath=True)
def exact_eval(q, v, psi, w, run, w_elem, n_elem, m_scale, with_jv, M_out, h_out, btip_out, Jv_out, work):
    """M_out += m M(q), h_out += m h(q, v), btip_out = B(1; q) and, if with_jv, Jv_out += m dh/dv.

    The discrete kinetic energy is T = (m/2) sum_p w_p (x_dot_p^2 + w_dot_p^2) with x_dot_p = sum_i A_i(s_p) v_i,
    A_i(s_p) = (R f_i)_p, R the running-integral matrix; h is exactly its Lagrangian convective force,
    h_i = m sum_p w_p (A_ip a_x,p + B_ip a_w,p), a_x = R(-cos(theta) theta_dot^2), a_w = R(-sin(theta) theta_dot^2).
    With with_jv the same h is summed in transposed order, h_i = -m sum_k theta_dot_k^2 G_ik with
    G_i = cos(theta) R^T(w A_i) + sin(theta) R^T(w B_i), which also gives dh_i/dv_j = -2 m sum_k theta_dot_k psi_jk G_ik.
    ``work`` is scratch of shape (3 n + 7, N)."""
    n, npts = psi.shape
    th, thd, c, s, f = work[0], work[1], work[2], work[3], work[4]
    for p in range(npts):
        a = 0.0
        b = 0.0
        for i in range(n):
            a += q[i] * psi[i, p]
            b += v[i] * psi[i, p]
        th[p] = a
        thd[p] = b
        c[p] = np.cos(a)
        s[p] = np.sin(a)
    # rows 5 .. 5+n-1 of work hold A_i, 5+n .. 5+2n-1 hold B_i, 5+2n .. 5+3n-1 hold G_i; 5+3n, 6+3n: a_x, a_w
    for i in range(n):
        Ai = work[5 + i]
        Bi = work[5 + n + i]
        for p in range(npts):
            f[p] = -s[p] * psi[i, p]
        cumulative(f, run, w_elem, n_elem, Ai)
        bt = 0.0
        for p in range(npts):
            f[p] = c[p] * psi[i, p]
            bt += w[p] * f[p]
        btip_out[i] = bt
        cumulative(f, run, w_elem, n_elem, Bi)
    if with_jv:
        for i in range(n):
            Ai = work[5 + i]
            Bi = work[5 + n + i]
            Gi = work[5 + 2 * n + i]
            for p in range(npts):
                f[p] = w[p] * Ai[p]
            cumulative_T(f, run, w_elem, n_elem, Gi)
            for p in range(npts):
                Gi[p] *= c[p]
                f[p] = w[p] * Bi[p]
            cumulative_T(f, run, w_elem, n_elem, th)  # theta is no longer needed: scratch
            hb = 0.0
            for p in range(npts):
                Gi[p] += s[p] * th[p]
                hb += thd[p] * thd[p] * Gi[p]
            h_out[i] -= m_scale * hb
        for i in range(n):
            Gi = work[5 + 2 * n + i]
            for j in range(n):
                acc = 0.0
                for p in range(npts):
                    acc += thd[p] * psi[j, p] * Gi[p]
                Jv_out[i, j] -= 2.0 * m_scale * acc
    else:
        ax = work[5 + 3 * n]
        aw = work[6 + 3 * n]
        for p in range(npts):
            f[p] = -c[p] * thd[p] * thd[p]
        cumulative(f, run, w_elem, n_elem, ax)
        for p in range(npts):
            f[p] = -s[p] * thd[p] * thd[p]
        cumulative(f, run, w_elem, n_elem, aw)
        for i in range(n):
            Ai = work[5 + i]
            Bi = work[5 + n + i]
            hb = 0.0
            for p in range(npts):
                hb += w[p] * (Ai[p] * ax[p] + Bi[p] * aw[p])
            h_out[i] += m_scale * hb
    for i in range(n):
        Ai = work[5 + i]
        Bi = work[5 + n + i]
        for j in range(i, n):
            Aj = work[5 + j]
            Bj = work[5 + n + j]
            acc = 0.0
            for p in range(npts):
                acc += w[p] * (Ai[p] * Aj[p] + Bi[p] * Bj[p])
            M_out[i, j] += m_scale * acc
            if j != i:
                M_out[j, i] += m_scale * acc


#: |angle change| (rad) up to which :func:`_rotated` uses its series (truncation below 1e-22)
NEAR_RAD = 0.1


@njit(cache=True, fastmath=True)
def _rotated(c, s, d, th):
    """(cos, sin) of th = th0 + d from c = cos th0, s = sin th0: the angle-sum formulas with the Taylor series of
    cos d and sin d (to d^12, d^13) when |d| <= NEAR_RAD, else cos th and sin th directly."""
    if abs(d) > NEAR_RAD:
        return np.cos(th), np.sin(th)
    d2 = d * d
    sd = d * (1.0 - d2 / 6.0 * (1.0 - d2 / 20.0 * (1.0 - d2 / 42.0 * (1.0 - d2 / 72.0 * (1.0 - d2 / 110.0 * (
        1.0 - d2 / 156.0))))))
    cd = 1.0 - d2 / 2.0 * (1.0 - d2 / 12.0 * (1.0 - d2 / 30.0 * (1.0 - d2 / 56.0 * (1.0 - d2 / 90.0 * (
        1.0 - d2 / 132.0)))))
    return c * cd - s * sd, s * cd + c * sd


@njit(cache=True, fastmath=True)
def exact_tip_near(q, psi, w, work):
    """w(1)/L = int sin(theta) for q near the state of the last :func:`exact_force` call with ``work``."""
    n, npts = psi.shape
    c, s, TH = work[3], work[4], work[12]
    acc = 0.0
    for p in range(npts):
        th = 0.0
        for i in range(n):
            th += q[i] * psi[i, p]
        acc += w[p] * _rotated(c[p], s[p], th - TH[p], th)[1]
    return acc


#: rows of the scratch array of :func:`exact_force` (columns: the quadrature points)
FORCE_WORK_ROWS = 13


@njit(cache=True, fastmath=True)
def exact_force(q, v, a, f_tip_n, psi, w, S, m_scale, jac, cq, cv, ca, F_out, J_out, work, jwork, near):
    """F_out = m_p L^3 [M(q) a + h(q, v)] - f_tip_n B(1; q): the strip's inertia force at acceleration a, less
    the generalised dead tip force (f_tip_n = F L, N/m x m). If ``jac``, also J_out = dF/dx along the
    line q = q0 + cq x, v = v0 + cv x, a = a0 + ca x (the time step's dependence on its unknown x = q_dot^{n+1};
    midpoint rule: cq = dt/4, cv = 1/2, ca = 1/dt), i.e. the exact Newton matrix of the structural terms.

    The same discrete Lagrangian as :func:`exact_eval`, summed the other way round (d'Alembert along the
    strip): the point accelerations x_dd = R xi, w_dd = R eta with xi = -sin(theta) alpha - cos(theta) omega^2,
    eta = cos(theta) alpha - sin(theta) omega^2 (alpha = a . psi, omega = v . psi, R the running integral), and
    F_i = m sum_k psi_ik [-sin(theta_k) (S xi)_k + cos(theta_k) (S eta)_k] since A_i = R(-sin(theta) psi_i),
    B_i = R(cos(theta) psi_i); S = R^T diag(w) R (``S``, elastica.Quadrature.inertia_operator) is applied as one
    dense (N, N) product, whatever the number of modes; the Jacobian applies it to the 2 n directions. (Dense
    products over the N points vectorise: half the time of the element-wise running integrals, the same sums to
    round-off.) Scratch: ``work`` (FORCE_WORK_ROWS, N), ``jwork`` (2, 2 n, N). ``near``: the angles are close to
    those of the previous call with this ``work`` (a Newton iteration): cos and sin by rotating the previous ones
    (:func:`_rotated`)."""
    n, npts = psi.shape
    xi, om, al, c, s = work[0], work[1], work[2], work[3], work[4]
    eta, Xt, Wt, P1, P2, P3, TH = work[5], work[6], work[7], work[8], work[9], work[10], work[12]
    for p in range(npts):
        th = 0.0
        b = 0.0
        d = 0.0
        for i in range(n):
            th += q[i] * psi[i, p]
            b += v[i] * psi[i, p]
            d += a[i] * psi[i, p]
        om[p] = b
        al[p] = d
        if near:
            c[p], s[p] = _rotated(c[p], s[p], th - TH[p], th)
        else:
            c[p] = np.cos(th)
            s[p] = np.sin(th)
        TH[p] = th
    for p in range(npts):
        o2 = om[p] * om[p]
        xi[p] = -s[p] * al[p] - c[p] * o2
        eta[p] = c[p] * al[p] - s[p] * o2
        Xt[p] = 0.0
        Wt[p] = 0.0
    for k in range(npts):  # Xt = S xi, Wt = S eta (S symmetric: row k is column k, the point p innermost)
        xk = xi[k]
        ek = eta[k]
        for p in range(npts):
            Xt[p] += S[k, p] * xk
            Wt[p] += S[k, p] * ek
    for p in range(npts):
        al[p] = m_scale * (c[p] * Wt[p] - s[p] * Xt[p]) - f_tip_n * w[p] * c[p]  # G_p: alpha is no longer needed
    for i in range(n):
        acc = 0.0
        for p in range(npts):
            acc += psi[i, p] * al[p]
        F_out[i] = acc
    if not jac:
        return
    # d xi / dx_j = psi_j P1, d eta / dx_j = psi_j P2 (theta, omega, alpha move by cq, cv, ca psi_j), and
    # d G_p = m (c dWt - s dXt) + psi_j P3 (the rotation of theta at p itself)
    for p in range(npts):
        P1[p] = -cq * eta[p] - ca * s[p] - 2.0 * cv * c[p] * om[p]
        P2[p] = cq * xi[p] + ca * c[p] - 2.0 * cv * s[p] * om[p]
        P3[p] = cq * (f_tip_n * w[p] * s[p] - m_scale * (c[p] * Xt[p] + s[p] * Wt[p]))
    D, E = jwork[0], jwork[1]  # rows j < n: d xi / dx_j, rows n + j: d eta / dx_j; E = S D (row by row)
    for j in range(n):
        for p in range(npts):
            D[j, p] = psi[j, p] * P1[p]
            D[n + j, p] = psi[j, p] * P2[p]
    for j in range(2 * n):
        for p in range(npts):
            E[j, p] = 0.0
        for k in range(npts):
            d = D[j, k]
            for p in range(npts):
                E[j, p] += d * S[k, p]
    for j in range(n):
        for p in range(npts):  # d G_p / dx_j (into D's row j, no longer needed)
            D[j, p] = m_scale * (c[p] * E[n + j, p] - s[p] * E[j, p]) + psi[j, p] * P3[p]
        for i in range(n):
            acc = 0.0
            for p in range(npts):
                acc += psi[i, p] * D[j, p]
            J_out[i, j] = acc
