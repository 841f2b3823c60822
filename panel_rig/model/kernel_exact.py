"""Compiled (numba) evaluation of the exact (elastica) structure at one state; see elastica.py for the equations.

Per call, at the quadrature points s_p: theta = q . psi, theta_dot = v . psi, the running integrals
A_i = -int sin(theta) psi_i, B_i = int cos(theta) psi_i; then the mass matrix M(q) = m int (A A^T + B B^T),
the convective inertia force h(q, v) = m int (A a_x + B a_w) (a_x = -int cos(theta) theta_dot^2,
a_w = -int sin(theta) theta_dot^2), its velocity Jacobian dh/dv (for the Newton iteration of the step) and
the tip-force vector B(1) = int cos(theta) psi.
Work arrays are passed in so that the time loop allocates nothing.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
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


@njit(cache=True)
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


@njit(cache=True)
def exact_eval(q, v, psi, w, run, w_elem, n_elem, m_scale, with_mass, M_out, h_out, btip_out, Jv_out, work):
    """M_out += m M(q) (if with_mass), h_out += m h(q, v), Jv_out += m dh/dv, btip_out = B(1; q).

    h by reversing the order of the double integrals: int_0^1 A_i(s) int_0^s g = int_0^1 g(s') Abar_i(s') with
    Abar_i(s') = int_{s'}^1 A_i, so h_i = -m int theta_dot^2 G_i and dh_i/dv_j = -2 m int theta_dot psi_j G_i,
    G_i = cos(theta) Abar_i + sin(theta) Bbar_i. ``work`` is scratch of shape (3 n + 5, N)."""
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
    # rows 5 .. 5+n-1 of work hold A_i, 5+n .. 5+2n-1 hold B_i, 5+2n .. 5+3n-1 hold G_i
    for i in range(n):
        Ai = work[5 + i]
        Bi = work[5 + n + i]
        Gi = work[5 + 2 * n + i]
        for p in range(npts):
            f[p] = -s[p] * psi[i, p]
        cumulative(f, run, w_elem, n_elem, Ai)
        bt = 0.0
        for p in range(npts):
            f[p] = c[p] * psi[i, p]
            bt += w[p] * f[p]
        btip_out[i] = bt
        cumulative(f, run, w_elem, n_elem, Bi)
        # Abar = int_s^1 A = total - running; G accumulates cos * Abar, then sin * Bbar
        cumulative(Ai, run, w_elem, n_elem, f)
        tot = 0.0
        for p in range(npts):
            tot += w[p] * Ai[p]
        for p in range(npts):
            Gi[p] = c[p] * (tot - f[p])
        cumulative(Bi, run, w_elem, n_elem, f)
        tot = 0.0
        for p in range(npts):
            tot += w[p] * Bi[p]
        hb = 0.0
        for p in range(npts):
            Gi[p] += s[p] * (tot - f[p])
            hb += w[p] * thd[p] * thd[p] * Gi[p]
        h_out[i] -= m_scale * hb
    for i in range(n):
        Gi = work[5 + 2 * n + i]
        for j in range(n):
            acc = 0.0
            for p in range(npts):
                acc += w[p] * thd[p] * psi[j, p] * Gi[p]
            Jv_out[i, j] -= 2.0 * m_scale * acc
    if with_mass:
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
