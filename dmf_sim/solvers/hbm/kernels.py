"""Compiled hot paths of a harmonic-balance sweep point (numba: nopython, cached, no Python
objects in the loops), beside the readable numpy reference they are tested against.

What is compiled, and its reference (same equations, same numbering):

* :func:`aft` — alternating frequency-time pass of the condensed system (eq. 9, 15): wind-up
  samples ``w_j = E x``, the spring's extra torque ``g(w_j)`` and tangent ``g'(w_j)`` from the
  SAME arrays the Newmark kernel reads (``PiecewiseLinearSpring.arrays()`` + primary index; the
  region lookup is :func:`dmf_sim.solvers.newmark_kernel.region_of`, so the law is written once),
  harmonics ``G = F g`` and ``dG/dx = F diag(g') E``.
  Reference: ``CondensedHBM.nonlinear_harmonics``.
* :func:`residual_jacobian` — ``r = x - wlin + h g``, ``dr/dx = I + h dG/dx`` (eq. 15) on the
  real layout. Reference: ``CondensedHBM.residual_and_jacobian``.
* :func:`newton` — damped Newton at fixed speed with its step control (backtracking on the max
  norm, stall detection). Reference: ``CondensedHBM.newton``.
* :func:`deflated_newton` — Newton on the deflated residual. Reference:
  ``dmf_sim.solvers.hbm.deflation.DeflatedNewton.solve``; :func:`deflated_newton_first` runs it
  from a pass's seeds in turn (reference ``DeflatedNewton.solve_first``).
* :func:`corrector_fixed_speed` — the continuation corrector of a step that lands on a grid
  speed (natural parameter, s fixed). Reference: ``dmf_sim.solvers.continuation.correct``.
* :func:`tangent` — the continuation's unit tangent at a converged point. Reference:
  ``dmf_sim.solvers.continuation._tangent``.
* :func:`step_fixed_speed` — the two in one call: a continuation step in grid mode. Reference:
  ``continuation.correct`` then ``continuation.tangent_of``.

The Floquet multipliers of a sweep point are compiled beside their reference too:
:mod:`dmf_sim.solvers.stability_kernel`; the linear parts and the engine query in
:mod:`dmf_sim.solvers.hbm.linear_kernels`; the LU solve the Newton steps use in
:mod:`dmf_sim.solvers.hbm.dense_kernels`.

Packed arguments:

* ``aft_mats`` = (E (M, 2H+1), weights (2H+1,), cos and sin tables (M, 2H+1) of m phi_j for
  m = 0..2H): the AFT matrices of ``CondensedHBM`` (F = diag(weights) E^T);
* ``spring`` = (knees, slopes, offsets, primary_index) exactly as the Newmark kernel gets them;
* ``lin`` = (wlin_r (2H+1,), h (H+1,) complex): linear parts of one speed on the real layout;
* ``newton_opts`` = (tol, max_iter, stall_iter, stall_ratio).

Status codes returned by the solvers: :data:`CONVERGED`, :data:`STALLED`, :data:`MAX_ITER`,
:data:`SINGULAR`, :data:`NOT_FINITE`.
"""
from __future__ import annotations

import math

import numpy as np

from dmf_sim.solvers.compiled import jit
from dmf_sim.solvers.hbm.dense_kernels import lu_solve, lu_work, max_abs
from dmf_sim.solvers.hbm.layout import to_real
from dmf_sim.solvers.hbm.linear_kernels import (
    ENGINE_OK,
    linear_parts,
    linear_parts_at,
    linear_parts_many_at,
    modal_sums,
)
from dmf_sim.solvers.newmark_kernel import region_of

__all__ = ['BACKTRACK_MIN', 'aft', 'times_h_into',
           'times_h_matrix', 'residual_jacobian', 'residual_jacobian_py', 'speed_derivative',
           'residual_jacobians_py', 'harmonics_py', 'newton', 'deflated_newton',
           'deflated_newton_first', 'tangent', 'corrector_fixed_speed', 'residual_jacobians_at',
           'corrector_arclength', 'TANGENT_SINGULAR', 'step_fixed_speed', 'warm_up']

CONVERGED, STALLED, MAX_ITER, SINGULAR, NOT_FINITE, ENGINE_FAILED = 0, 1, 2, 3, 4, 5
BACKTRACK_MIN = 1e-3      # smallest backtracking factor of the plain Newton (as the reference)


# ------------------------------------------------------------------------------------------------
# AFT, residual, Jacobian
# ------------------------------------------------------------------------------------------------

def aft(x, aft_mats, spring, G, dG, jac):
    """G = harmonics of g(w(psi)) on the real layout [Nm]; with ``jac`` also dG = dG/dx
    [Nm/rad]. Returns the number of samples beyond a knee (0: G = 0, the linear problem).
    ``G = F g`` with ``F = diag(weights) E^T`` is summed row by row of E (contiguous).

    The Jacobian F diag(g') E is assembled from the cosine and sine sums of g' alone,
    ``C_m = (1/M) sum_j g'_j cos(m phi_j)``, ``S_m = (1/M) sum_j g'_j sin(m phi_j)``, m = 0..2H
    (products of two harmonics n, p are harmonics n + p and n - p), instead of one rank-one
    update per sample: O(M H) instead of O(M H^2)."""
    E, weights, Tc, Ts = aft_mats
    knees, slopes, offsets, primary = spring
    nk = knees.shape[0]
    lo = knees[primary - 1] if primary > 0 else -np.inf
    hi = knees[primary] if primary < nk else np.inf
    M = E.shape[0]
    n = E.shape[1]
    H = (n - 1) // 2
    n2 = 2 * H + 1
    for a in range(n):
        G[a] = 0.0
    Cm = np.zeros(n2)
    Sm = np.zeros(n2)
    count = 0
    for j in range(M):
        w = 0.0
        for k in range(n):
            w += E[j, k] * x[k]
        if w > hi or w < lo:
            count += 1
            r = region_of(w, knees, primary)
            s = slopes[r]
            g = s * w + offsets[r]
            for a in range(n):
                G[a] += E[j, a] * g
            if jac and s != 0.0:
                for m in range(n2):
                    Cm[m] += s * Tc[j, m]
                    Sm[m] += s * Ts[j, m]
    for a in range(n):
        G[a] *= weights[a]
    if jac:
        for m in range(2 * H + 1):
            Cm[m] /= M
            Sm[m] /= M
        dG[0, 0] = Cm[0]
        for q in range(1, H + 1):
            dG[0, q] = Cm[q]
            dG[0, H + q] = -Sm[q]
            dG[q, 0] = 2.0 * Cm[q]
            dG[H + q, 0] = -2.0 * Sm[q]
        for p in range(1, H + 1):
            for q in range(1, H + 1):
                d = p - q
                cd = Cm[d] if d >= 0 else Cm[-d]
                sd = Sm[d] if d >= 0 else -Sm[-d]          # S_(p-q)
                dG[p, q] = cd + Cm[p + q]
                dG[p, H + q] = -(Sm[q + p] - sd)            # -(S_(q+p) + S_(q-p))
                dG[H + p, q] = -(Sm[p + q] + sd)
                dG[H + p, H + q] = cd - Cm[p + q]
    return count


def times_h_into(h, v, out):
    """out <- h_n * v_n on the real layout (complex product per harmonic): the compiled
    :func:`dmf_sim.solvers.hbm.layout.times_h` of a vector."""
    H = h.shape[0] - 1
    out[0] = h[0].real * v[0]
    for k in range(1, H + 1):
        hr = h[k].real
        hi = h[k].imag
        re = v[k]
        im = v[H + k]
        out[k] = hr * re - hi * im
        out[H + k] = hr * im + hi * re


def times_h_matrix(h, V):
    """Rows of V (2H+1, m) <- h_n * rows_n on the real layout, in place."""
    H = h.shape[0] - 1
    m = V.shape[1]
    h0 = h[0].real
    for j in range(m):
        V[0, j] = h0 * V[0, j]
    for k in range(1, H + 1):
        hr = h[k].real
        hi = h[k].imag
        for j in range(m):
            re = V[k, j]
            im = V[H + k, j]
            V[k, j] = hr * re - hi * im
            V[H + k, j] = hr * im + hi * re


def residual_jacobian(x, lin, aft_mats, spring, r, J, G, jac):
    """r = x - wlin + h G (eq. 15) and, with ``jac``, J = I + h dG/dx, in place; G keeps the
    harmonics of g. Returns the number of AFT samples beyond a knee."""
    wlin_r, h = lin
    n = x.shape[0]
    count = aft(x, aft_mats, spring, G, J, jac)
    times_h_into(h, G, r)
    for i in range(n):
        r[i] += x[i] - wlin_r[i]
    if jac:
        if count == 0:
            for a in range(n):
                for b in range(n):
                    J[a, b] = 0.0
        else:
            times_h_matrix(h, J)
        for a in range(n):
            J[a, a] += 1.0
    return count


def residual_jacobian_py(x, lin, aft_mats, spring, jac):
    """(r, J or None, count) as new arrays: the entry point for Python callers."""
    n = x.shape[0]
    r = np.empty(n)
    J = np.empty((n, n))
    G = np.empty(n)
    count = residual_jacobian(x, lin, aft_mats, spring, r, J, G, jac)
    return r, J, count


def speed_derivative(dlin, G, rs):
    """rs <- dr/ds = -dwlin + dh G at fixed x (``dlin`` = (dwlin_r, dh), G the harmonics of g):
    reference ``CondensedHBM.residual_speed_derivative``."""
    dwlin_r, dh = dlin
    times_h_into(dh, G, rs)
    for i in range(rs.shape[0]):
        rs[i] -= dwlin_r[i]


def residual_jacobians_py(x, lin, dlin, aft_mats, spring):
    """(r, dr/dx, dr/ds) as new arrays in one AFT pass: what the continuation asks at a point
    off the grid (reference: ``CondensedHBM.residual_and_jacobian_reference`` and
    ``residual_speed_derivative``)."""
    n = x.shape[0]
    r = np.empty(n)
    J = np.empty((n, n))
    G = np.empty(n)
    rs = np.empty(n)
    residual_jacobian(x, lin, aft_mats, spring, r, J, G, True)
    speed_derivative(dlin, G, rs)
    return r, J, rs


def harmonics_py(x, aft_mats, spring, jac):
    """(G, dG/dx, count) as new arrays (the non-linear torque harmonics alone)."""
    n = x.shape[0]
    G = np.empty(n)
    dG = np.empty((n, n))
    count = aft(x, aft_mats, spring, G, dG, jac)
    return G, dG, count


# ------------------------------------------------------------------------------------------------
# Newton at fixed speed, plain and deflated
# ------------------------------------------------------------------------------------------------

def _newton_start(x0, x):
    """x <- x0 and the work arrays of a Newton solve of size n: r, J, G, r_new, J_new, x_new,
    step, -r, LU factors, pivots."""
    n = x0.shape[0]
    for i in range(n):
        x[i] = x0[i]
    return (np.empty(n), np.empty((n, n)), np.empty(n), np.empty(n), np.empty((n, n)),
            np.empty(n), np.empty(n), np.empty(n), np.empty((n, n)), np.empty(n, dtype=np.int64))


def _accept(xn, rn, Jn, x, r, J):
    """The trial point becomes the iterate: x, r, J <- xn, rn, Jn."""
    n = x.shape[0]
    for i in range(n):
        x[i] = xn[i]
        r[i] = rn[i]
        for j in range(n):
            J[i, j] = Jn[i, j]


def newton(x0, lin, aft_mats, spring, newton_opts, x):
    """Damped Newton from x0 into x (reference ``CondensedHBM.newton``).
    Returns (status, iterations, max|r|)."""
    tol, max_iter, stall_iter, stall_ratio = newton_opts
    n = x0.shape[0]
    r, J, G, rn, Jn, xn, dx, mr, LU, piv = _newton_start(x0, x)
    history = np.empty(max_iter + 2)
    residual_jacobian(x, lin, aft_mats, spring, r, J, G, True)
    nr = max_abs(r)
    history[0] = nr
    nh = 1
    for it in range(1, max_iter + 1):
        if nr <= tol:
            return CONVERGED, it - 1, nr
        if nh > stall_iter and nr > stall_ratio * history[nh - 1 - stall_iter]:
            return STALLED, it - 1, nr
        for i in range(n):
            mr[i] = -r[i]
        if not lu_solve(J, mr, dx, LU, piv):
            return SINGULAR, it - 1, nr
        lam = 1.0
        while True:   # backtracking on the max norm (the residual is only piecewise smooth)
            for i in range(n):
                xn[i] = x[i] + lam * dx[i]
            # the Jacobian with the full step's residual (most steps keep it), not with the
            # shortened trials': it is formed for the one accepted
            residual_jacobian(xn, lin, aft_mats, spring, rn, Jn, G, lam == 1.0)
            nn = max_abs(rn)
            if nn < nr or lam < BACKTRACK_MIN:
                break
            lam *= 0.5
        if lam != 1.0:
            residual_jacobian(xn, lin, aft_mats, spring, rn, Jn, G, True)
        _accept(xn, rn, Jn, x, r, J)
        nr = nn
        history[nh] = nr
        nh += 1
    if nr <= tol:
        return CONVERGED, max_iter, nr
    return MAX_ITER, max_iter, nr


def _log_m(x, known, defl, grad):
    """ln M(x) of the deflation operator and its gradient into ``grad`` (reference
    ``DeflatedNewton._log_m``)."""
    power, sigma, scale = defl[0], defl[1], defl[2]
    n = x.shape[0]
    for i in range(n):
        grad[i] = 0.0
    lm = 0.0
    for k in range(known.shape[0]):
        dist2 = 0.0
        for i in range(n):
            d = (x[i] - known[k, i]) / scale
            dist2 += d * d
        if dist2 < 1e-300:
            dist2 = 1e-300
        m = dist2 ** (-0.5 * power) + sigma
        coef = -power * dist2 ** (-0.5 * power - 1.0) / (m * scale)
        lm += math.log(m)
        for i in range(n):
            grad[i] += coef * ((x[i] - known[k, i]) / scale)
    return lm


def _log_floor(v):
    """log(max(v, 1e-300)) with Python's max (a NaN stays NaN)."""
    return math.log(1e-300 if 1e-300 > v else v)


def deflated_newton(x0, known, lin, aft_mats, spring, tol, defl, x):
    """Newton on M(x) r(x) avoiding the rows of ``known`` (reference ``DeflatedNewton.solve``);
    ``defl`` = [power, shift, scale, max_iter, min_step, stagnation]. Returns (found,
    iterations, max|r|); the solution in x."""
    max_iter = int(defl[3])
    min_step = defl[4]
    stagnation = int(defl[5])
    n = x0.shape[0]
    r, J, G, rn, Jn, xn, d, mr, LU, piv = _newton_start(x0, x)
    g = np.empty(n)
    gn = np.empty(n)
    residual_jacobian(x, lin, aft_mats, spring, r, J, G, True)
    nr = max_abs(r)
    lm = _log_m(x, known, defl, g)
    best = nr
    since = 0
    for it in range(1, max_iter + 1):
        if nr <= tol:
            return True, it - 1, nr
        if nr < 0.5 * best:
            best = nr
            since = 0
        else:
            since += 1
            if since >= stagnation:
                return False, it - 1, nr
        for i in range(n):
            mr[i] = -r[i]
        if not lu_solve(J, mr, d, LU, piv):
            return False, it - 1, nr
        denom = 1.0
        for i in range(n):
            denom -= g[i] * d[i]
        if abs(denom) > 1e-12:
            for i in range(n):
                d[i] = d[i] / denom
        merit = _log_floor(nr) + lm
        lam = 1.0
        while True:             # backtracking on the deflated residual ln(M max|r|)
            for i in range(n):
                xn[i] = x[i] + lam * d[i]
            residual_jacobian(xn, lin, aft_mats, spring, rn, Jn, G, lam == 1.0)
            nn = max_abs(rn)
            lmn = _log_m(xn, known, defl, gn)
            if _log_floor(nn) + lmn < merit or lam <= min_step:
                break
            lam *= 0.5
        if not math.isfinite(nn):
            return False, it, nn
        if lam != 1.0:          # a shortened step: its Jacobian now (see newton)
            residual_jacobian(xn, lin, aft_mats, spring, rn, Jn, G, True)
        _accept(xn, rn, Jn, x, r, J)
        for i in range(n):
            g[i] = gn[i]
        nr = nn
        lm = lmn
    return nr <= tol, max_iter, nr



def deflated_newton_first(X0, start, known, lin, aft_mats, spring, tol, defl, x):
    """:func:`deflated_newton` from the seeds X0[start], X0[start + 1], ... in turn until one
    converges (a search pass's seeds in one call). Returns (its index, or -1 if none did,
    iterations, max|r|); the solution in x."""
    for i in range(start, X0.shape[0]):
        found, it, nr = deflated_newton(X0[i], known, lin, aft_mats, spring, tol, defl, x)
        if found:
            return i, it, nr
    return -1, 0, 0.0

# ------------------------------------------------------------------------------------------------
# Continuation tangent
# ------------------------------------------------------------------------------------------------

def tangent(Jx, rs, prev, xs, ss, t):
    """t <- unit null vector of [r_x xs, r_s ss] (scaled unknowns), oriented along ``prev``:
    the solution of the bordered system [[r_x xs, r_s ss], [prev]] t = e_(n+1), normalized
    (reference ``continuation._tangent``, solved by :func:`lu_solve` instead of LAPACK).
    Returns False on an exactly singular system."""
    n = Jx.shape[0]
    A, b, _, LU, piv = lu_work(n + 1)
    for i in range(n):
        for j in range(n):
            A[i, j] = Jx[i, j] * xs
        A[i, n] = rs[i] * ss
        b[i] = 0.0
    for j in range(n + 1):
        A[n, j] = prev[j]
    b[n] = 1.0
    if not lu_solve(A, b, t, LU, piv):
        return False
    norm = 0.0
    for i in range(n + 1):
        norm += t[i] * t[i]
    norm = math.sqrt(norm)
    dot = 0.0
    for i in range(n + 1):
        t[i] /= norm
        dot += t[i] * prev[i]
    if dot < 0.0:
        for i in range(n + 1):
            t[i] = -t[i]
    return True


# ------------------------------------------------------------------------------------------------
# Continuation corrector on a grid speed (natural parameter)
# ------------------------------------------------------------------------------------------------

def add_step(y, dy):
    """y <- y + dy; returns max |dy| (NaN if an entry is NaN)."""
    big = 0.0
    for i in range(y.shape[0]):
        y[i] = y[i] + dy[i]
        a = abs(dy[i])
        if a > big or a != a:
            big = a
    return big


def corrector_fixed_speed(y_pred, xs, lin, dlin, aft_mats, spring, tol, max_iter, y, r, J, rs):
    """Newton on r(x, s) = 0 at the fixed speed of ``lin`` in scaled unknowns y = x / xs
    (reference: ``continuation.correct`` with the normal e_S). ``dlin`` = (dwlin_r, dh) the
    speed derivatives. Writes y, r, J = dr/dx, rs = dr/ds; returns (status, iterations,
    max|r|)."""
    n = y_pred.shape[0]
    for i in range(n):
        y[i] = y_pred[i]
    x = np.empty(n)
    G = np.empty(n)
    A, mr, dy, LU, piv = lu_work(n)
    res = np.inf
    it = 0
    status = MAX_ITER
    for it in range(max_iter + 1):
        for i in range(n):
            x[i] = y[i] * xs
        residual_jacobian(x, lin, aft_mats, spring, r, J, G, True)
        res = max_abs(r)
        if res <= tol:
            status = CONVERGED
            break
        if it == max_iter or not math.isfinite(res):
            status = MAX_ITER if math.isfinite(res) else NOT_FINITE
            return status, it, res
        for i in range(n):
            mr[i] = -r[i]
            for j in range(n):
                A[i, j] = J[i, j] * xs
        if not lu_solve(A, mr, dy, LU, piv):
            return SINGULAR, it, res
        big = add_step(y, dy)
        if big < 1e-13 and res < 1e3 * tol:
            for i in range(n):
                x[i] = y[i] * xs
            residual_jacobian(x, lin, aft_mats, spring, r, J, G, True)
            res = max_abs(r)
            it += 1
            status = CONVERGED
            break
    # dr/ds at the solution: -dwlin + dh G (G: the harmonics of the last evaluation)
    speed_derivative(dlin, G, rs)
    return status, it, res


def residual_jacobians_at(x, s, fd, table, statics, modal, aft_mats, spring):
    """(status, r, dr/dx, dr/ds) at wind-up harmonics x and speed s [rpm], the linear parts
    computed here (:func:`linear_parts_at`) and one AFT pass: what the arc-length corrector asks
    at every iteration (each a new speed). status: the engine's (r etc. unset unless
    ENGINE_OK)."""
    n = x.shape[0]
    H = (n - 1) // 2
    A = np.empty((1, H + 1), dtype=np.complex128)
    A2 = np.empty((1, H + 1), dtype=np.complex128)
    dA = np.empty((1, H + 1), dtype=np.complex128)
    h = np.empty((1, H + 1), dtype=np.complex128)
    dh = np.empty((1, H + 1), dtype=np.complex128)
    wlin = np.empty((1, H + 1), dtype=np.complex128)
    dw = np.empty((1, H + 1), dtype=np.complex128)
    wr = np.empty((1, n))
    dwr = np.empty((1, n))
    r = np.empty(n)
    J = np.empty((n, n))
    rs = np.empty(n)
    st = linear_parts_at(s, fd, table, statics, modal, A, A2, dA, h, dh, wlin, dw, wr, dwr)
    if st != ENGINE_OK:
        return st, r, J, rs
    G = np.empty(n)
    residual_jacobian(x, (wr[0], h[0]), aft_mats, spring, r, J, G, True)
    speed_derivative((dwr[0], dh[0]), G, rs)
    return st, r, J, rs


def _evaluate_scaled(y, xs, ss, fd, table, statics, modal, aft_mats, spring, r, J, rs):
    """r, J, rs <- :func:`residual_jacobians_at` at the scaled point y = [x / xs, s / ss];
    returns the engine status (r, J, rs unchanged unless ENGINE_OK)."""
    n = y.shape[0] - 1
    x = np.empty(n)
    for i in range(n):
        x[i] = y[i] * xs
    st, r1, J1, rs1 = residual_jacobians_at(x, y[n] * ss, fd, table, statics, modal, aft_mats,
                                            spring)
    if st == ENGINE_OK:
        r[:] = r1
        J[:, :] = J1
        rs[:] = rs1
    return st


def corrector_arclength(y_pred, normal, xs, ss, tol, max_iter, fd, table, statics, modal,
                        aft_mats, spring, y, r, J, rs):
    """The pseudo-arc-length corrector in one call (reference: ``continuation.correct`` with a
    normal other than e_S): Newton on [r(x, s); normal . (y - y_pred)] = 0 in scaled unknowns
    y = [x / xs, s / ss], the linear parts of every iterate's speed computed here
    (:func:`residual_jacobians_at`). Writes y (n + 1,), r, J = dr/dx, rs = dr/ds of the last
    evaluation; returns (status, iterations, max|r|, engine status): CONVERGED, or MAX_ITER /
    NOT_FINITE / SINGULAR (the corrector failed), or ENGINE_FAILED with the engine's status
    (a speed outside the data, or grid nodes not computed yet)."""
    n1 = y_pred.shape[0]
    n = n1 - 1
    for i in range(n1):
        y[i] = y_pred[i]
    A, b, dy, LU, piv = lu_work(n1)
    res = np.inf
    for it in range(max_iter + 1):
        st = _evaluate_scaled(y, xs, ss, fd, table, statics, modal, aft_mats, spring, r, J, rs)
        if st != ENGINE_OK:
            return ENGINE_FAILED, it, res, st
        res = max_abs(r)
        g = 0.0
        for i in range(n1):
            g += normal[i] * (y[i] - y_pred[i])
        if res <= tol and abs(g) <= 1e-12:
            return CONVERGED, it, res, ENGINE_OK
        if it == max_iter or not math.isfinite(res):
            return (MAX_ITER if math.isfinite(res) else NOT_FINITE), it, res, ENGINE_OK
        for i in range(n):
            for j in range(n):
                A[i, j] = J[i, j] * xs
            A[i, n] = rs[i] * ss
            b[i] = -r[i]
        for j in range(n1):
            A[n, j] = normal[j]
        b[n] = -g
        if not lu_solve(A, b, dy, LU, piv):
            return SINGULAR, it, res, ENGINE_OK
        big = add_step(y, dy)
        if big < 1e-13 and res < 1e3 * tol:
            st = _evaluate_scaled(y, xs, ss, fd, table, statics, modal, aft_mats, spring, r, J,
                                  rs)
            if st != ENGINE_OK:
                return ENGINE_FAILED, it + 1, res, st
            return CONVERGED, it + 1, max_abs(r), ENGINE_OK
    return MAX_ITER, max_iter, res, ENGINE_OK


# ------------------------------------------------------------------------------------------------
# A continuation step on a grid speed: the corrector and the new tangent in one call
# ------------------------------------------------------------------------------------------------

TANGENT_SINGULAR = 6       # step_fixed_speed: converged, but the tangent's system is singular


def step_fixed_speed(y_pred, prev, xs, ss, lin, dlin, aft_mats, spring, tol, max_iter, y, t, r,
                     J, rs):
    """:func:`corrector_fixed_speed` on the scaled prediction ``y_pred`` = [x / xs, s / ss]
    (s on a grid speed, kept), then :func:`tangent` at the corrected point oriented along
    ``prev``: one continuation step of ``continuation.continue_branch`` in grid mode (reference:
    ``continuation.correct`` with the normal e_S, then ``continuation.tangent_of``). Writes y
    (n + 1,), the unit tangent t, and r, J = dr/dx, rs = dr/ds there; returns (status,
    iterations, max|r|): the corrector's status, or TANGENT_SINGULAR."""
    n = r.shape[0]
    status, it, res = corrector_fixed_speed(y_pred[:n], xs, lin, dlin, aft_mats, spring, tol,
                                            max_iter, y[:n], r, J, rs)
    y[n] = y_pred[n]
    if status != CONVERGED:
        return status, it, res
    if not tangent(J, rs, prev, xs, ss, t):
        return TANGENT_SINGULAR, it, res
    return status, it, res


# reassociation lets LLVM vectorize the sums (rounding-level differences to the reference);
# no 'nnan' flag: the NaN checks of the solvers stay valid
aft = jit(aft, fastmath={'reassoc', 'contract'})
times_h_into = jit(times_h_into)
times_h_matrix = jit(times_h_matrix)
residual_jacobian = jit(residual_jacobian)
residual_jacobian_py = jit(residual_jacobian_py)
speed_derivative = jit(speed_derivative)
residual_jacobians_py = jit(residual_jacobians_py)
tangent = jit(tangent)
add_step = jit(add_step)
corrector_fixed_speed = jit(corrector_fixed_speed)
harmonics_py = jit(harmonics_py)
_newton_start = jit(_newton_start)
_accept = jit(_accept)
newton = jit(newton)
_log_m = jit(_log_m)
_log_floor = jit(_log_floor)
deflated_newton = jit(deflated_newton)
deflated_newton_first = jit(deflated_newton_first)
residual_jacobians_at = jit(residual_jacobians_at)
_evaluate_scaled = jit(_evaluate_scaled)
corrector_arclength = jit(corrector_arclength)
step_fixed_speed = jit(step_fixed_speed)


def warm_up() -> float:
    """Load (or, the first time on a machine, compile) every compiled kernel of a sweep point —
    these and :mod:`dmf_sim.solvers.stability_kernel` — on a tiny problem with the argument types
    of the real ones, so no later first call pays for it (a design-study worker does this when it
    starts). Returns the seconds it took."""
    import time

    from dmf_sim.physics.spring import PiecewiseLinearSpring
    from dmf_sim.solvers import stability_kernel
    t0 = time.perf_counter()
    H, M = 2, 8
    n = 2 * H + 1
    phi = 2.0 * np.pi * np.arange(M) / M
    harm = np.arange(1, H + 1)
    E = np.hstack([np.ones((M, 1)), np.cos(np.outer(phi, harm)), -np.sin(np.outer(phi, harm))])
    weights = np.full(n, 2.0 / M)
    weights[0] = 1.0 / M
    m_all = np.arange(n)
    aft_mats = (E, weights, np.cos(np.outer(phi, m_all)), np.sin(np.outer(phi, m_all)))
    sp = PiecewiseLinearSpring.two_step(1.0, 0.5, 1.0)
    spring = (*sp.arrays(), int(sp.primary_index))
    h = np.full(H + 1, 0.5 + 0.1j)
    x0 = np.zeros(n)
    x0[1] = 1.0
    lin = (x0.copy(), h)
    out = np.empty(n)
    residual_jacobian_py(x0, lin, aft_mats, spring, True)
    residual_jacobians_py(x0, lin, lin, aft_mats, spring)
    harmonics_py(x0, aft_mats, spring, True)
    newton(x0, lin, aft_mats, spring, (1e-10, 5, 8, 0.5), out)
    deflated_newton(x0, np.zeros((1, n)), lin, aft_mats, spring, 1e-10,
                    np.array([2.0, 1.0, 1e-2, 5.0, 0.125, 6.0]), out)
    deflated_newton_first(x0[None], 0, np.zeros((1, n)), lin, aft_mats, spring, 1e-10,
                          np.array([2.0, 1.0, 1e-2, 5.0, 0.125, 6.0]), out)
    corrector_fixed_speed(x0, 1.0, lin, lin, aft_mats, spring, 1e-10, 3, out, np.empty(n),
                          np.empty((n, n)), np.empty(n))
    t1 = np.zeros(n + 1)
    t1[n] = 1.0
    tangent(np.eye(n), np.ones(n), t1, 1.0, 1.0, np.empty(n + 1))
    step_fixed_speed(t1, t1, 1.0, 1.0, lin, lin, aft_mats, spring, 1e-10, 3, np.empty(n + 1),
                     np.empty(n + 1), np.empty(n), np.empty((n, n)), np.empty(n))
    m = 2
    for K in (1, 2):     # one speed: h[:, 1:] is C-contiguous; a batch: it is not (two layouts)
        modal_sums(np.ones(K), np.ones(H), np.array([-1.0 + 1j, -1.0 - 1j]),
                   np.ones((H + 1, m), dtype=complex)[1:], np.ones(m, dtype=complex),
                   np.empty((K, H), dtype=complex), np.empty((K, H), dtype=complex),
                   np.empty((K, H + 1), dtype=complex)[:, 1:],
                   np.empty((K, H + 1), dtype=complex)[:, 1:])
        A = np.ones((K, H + 1), dtype=complex)
        linear_parts(np.ones(K), np.ones(H), np.array([-1.0 + 1j, -1.0 - 1j]),
                     np.ones((H + 1, m), dtype=complex)[1:], np.ones(m, dtype=complex), A, A,
                     np.ones(K), np.ones(K), 1.0, np.empty((K, H + 1), dtype=complex),
                     np.empty((K, H + 1), dtype=complex), np.empty((K, H + 1), dtype=complex),
                     np.empty((K, H + 1), dtype=complex), np.empty((K, n)), np.empty((K, n)))
    # the arc-length corrector and the off-grid linear parts with the engine query
    table = (np.array([0.0, 1.0, 2.0]), np.ones((3, H + 1), dtype=complex),
             np.ones(3, dtype=bool), np.zeros(H + 1, dtype=complex), 0.0, 0.0)
    statics = (1.0, 1.0, 1.0)
    modal = (np.ones(H), np.array([-1.0 + 1j, -1.0 - 1j]),
             np.ascontiguousarray(np.ones((H + 1, m), dtype=complex)[1:]),
             np.ones(m, dtype=complex), 1.0)
    residual_jacobians_at(x0, 1.0, 0.05, table, statics, modal, aft_mats, spring)
    K = 2
    linear_parts_many_at(np.ones(K), 0.05, table, statics, modal,
                         *[np.empty((K, H + 1), dtype=complex) for _ in range(7)],
                         np.empty((K, n)), np.empty((K, n)), np.empty(K, dtype=np.int64))
    y1 = np.zeros(n + 1)
    y1[n] = 1.0
    corrector_arclength(y1, y1.copy(), 1.0, 1.0, 1e-10, 2, 0.05, table, statics, modal,
                        aft_mats, spring, np.empty(n + 1), np.empty(n), np.empty((n, n)),
                        np.empty(n))
    ns = 2
    W = np.zeros((2, 2, ns, ns))
    W[:, :] = np.eye(ns)
    c = np.zeros(H + 1, dtype=complex)
    c[1] = 1.0
    fl_args = (spring[0], spring[3], 1, np.array([[1, 2], [1, 2]], dtype=np.int64),
               -np.ones((2, ns)), np.ones((2, ns)), W)
    stability_kernel.floquet(c, E @ to_real(c, H), 1.0, *fl_args)
    stability_kernel.floquet_many(c[None], (E @ to_real(c, H))[None], np.ones(1), *fl_args,
                                  np.empty(1, dtype=np.int64), np.empty(1, dtype=np.int64),
                                  np.empty(1), np.empty((1, ns)), np.empty((1, ns)),
                                  np.empty(1, dtype=np.int64))
    return time.perf_counter() - t0

