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
The continuation's steps on these (tangent, the grid and arc-length correctors, a grid step in
one call) are compiled in :mod:`dmf_sim.solvers.hbm.continuation_kernels`.

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

from dmf_sim.core.compiled import jit
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.solvers.hbm.dense_kernels import lu_solve, max_abs
from dmf_sim.solvers.spring_kernels import (
    friction_parts,
    law_active,
    primary_range,
    region_of,
    stop_parts,
    travel_range,
)

__all__ = ['CONVERGED', 'STALLED', 'MAX_ITER', 'SINGULAR', 'NOT_FINITE', 'ENGINE_FAILED',
           'BACKTRACK_MIN', 'aft', 'aft_law', 'assemble', 'nonlinear', 'times_h_into',
           'times_h_matrix', 'residual_jacobian',
           'residual_jacobian_py', 'speed_derivative', 'residual_jacobians_py', 'harmonics_py',
           'newton', 'deflated_newton', 'deflated_newton_first']

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
    knees, slopes, offsets, primary = spring[0], spring[1], spring[2], spring[3]
    lo, hi = primary_range(knees, primary)
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
        assemble(Cm, Sm, M, H, dG)
    return count


def assemble(Cm, Sm, M, H, dG):
    """dG <- F diag(c_j) E on the real layout from the sums ``Cm[m] = sum_j c_j cos(m phi_j)``,
    ``Sm[m] = sum_j c_j sin(m phi_j)``, m = 0..2H (divided by M here, in place): the products
    of two harmonics n, p are harmonics n + p and n - p."""
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


def aft_law(x, omega, aft_mats, spring, G, dG, jac):
    """:func:`aft` of the whole non-linear DMF torque with friction and end stops,
    ``g(w) + N(w, w_dot, Omega)`` (eq. 8a-8b, 9; doc/theory.md §2, §7): on each sample the wind-up
    ``w_j = E_j x`` and its rate ``w_dot_j = (omega/2) sum_n n (-Re w_n sin n phi_j - Im w_n
    cos n phi_j)`` (harmonic n turns at n omega / 2, omega [rad/s] the engine speed), N from the
    spring's compiled law (:func:`dmf_sim.solvers.spring_kernels.friction_parts` and
    ``stop_parts`` on ``spring[4]`` = ``law_array()``, the sliding torque T0 + c_Omega omega^2).

    Writes G[:n] = the harmonics of g + N [Nm], G[n:2n] = their derivative with respect to omega
    at fixed x [Nm s/rad] (w_dot scales with omega, the friction amplitude with omega^2: what the
    continuation's dr/ds adds), and with ``jac`` dG = dG/dx = F diag(dg/dw + dN/dw) E +
    F diag(dN/dw_dot) dw_dot/dx, both by the cosine/sine sums of :func:`assemble`; the rate's
    row ``dw_dot_j/dx`` is (omega/2) n times E's sine column for Re w_n and minus its cosine
    column for Im w_n, so its part is :func:`assemble` of dN/dw_dot with columns swapped and
    scaled. Every sample carries friction torque, so the samples of w and w_dot are one matrix
    product ``E [x, y]`` and the harmonics of the torque and of dN/domega one product with
    ``E^T`` (BLAS), not a sum per sample. Returns the number of samples with a non-zero torque."""
    E, weights, Tc, Ts = aft_mats
    knees, slopes, offsets, primary, law = spring
    lo, hi = primary_range(knees, primary)
    slo, shi = travel_range(law)
    M = E.shape[0]
    n = E.shape[1]
    H = (n - 1) // 2
    n2 = 2 * H + 1
    half = 0.5 * omega
    amp = law[0] + law[1] * omega * omega
    damp = 2.0 * law[1] * omega                 # d(amp)/d(omega)
    XY = np.zeros((n, 2))                        # [x, y]: E y = w_dot / (omega / 2)
    for a in range(n):
        XY[a, 0] = x[a]
    for q in range(1, H + 1):
        XY[q, 1] = -q * x[H + q]
        XY[H + q, 1] = q * x[q]
    WU = np.dot(E, XY)                           # (M, 2): w_j, w_dot_j / (omega / 2)
    TD = np.empty((M, 2))                        # g + N and dN/domega on each sample
    Cm = np.zeros(n2)
    Sm = np.zeros(n2)
    Cv = np.zeros(n2)
    Sv = np.zeros(n2)
    count = 0
    for j in range(M):
        w = WU[j, 0]
        unit = WU[j, 1]
        wd = half * unit
        s = 0.0
        g = 0.0
        if w > hi or w < lo:
            r = region_of(w, knees, primary)
            s = slopes[r]
            g = s * w + offsets[r]
        tf, dtf, th = friction_parts(wd, amp, law)
        ts = dws = dvs = 0.0
        if w > shi or w < slo:
            ts, dws, dvs = stop_parts(w, wd, law)
        tot = g + tf + ts
        cv = dtf + dvs                           # dN/dw_dot [Nms/rad]
        TD[j, 0] = tot
        TD[j, 1] = cv * 0.5 * unit + damp * th
        if tot == 0.0 and s == 0.0 and cv == 0.0:
            continue
        count += 1
        if not jac:
            continue
        kw = s + dws
        if kw != 0.0:                            # else (inside the primary stage) no part
            for m in range(n2):
                Cm[m] += kw * Tc[j, m]
                Sm[m] += kw * Ts[j, m]
        if cv != 0.0:                            # else (friction saturated) no part
            for m in range(n2):
                Cv[m] += cv * Tc[j, m]
                Sv[m] += cv * Ts[j, m]
    GT = np.dot(E.T, TD)                         # (n, 2): the sums over the samples
    for a in range(n):
        G[a] = GT[a, 0] * weights[a]
        G[n + a] = GT[a, 1] * weights[a]
    if jac:
        dV = np.empty((n, n))
        assemble(Cm, Sm, M, H, dG)
        assemble(Cv, Sv, M, H, dV)
        for a in range(n):
            for q in range(1, H + 1):
                f = half * q
                dG[a, q] += f * dV[a, H + q]
                dG[a, H + q] -= f * dV[a, q]
    return count


def nonlinear(x, omega, aft_mats, spring, G, dG, jac):
    """:func:`aft_law` when the spring has friction or end stops (``spring[4]``), else
    :func:`aft` (the elastic spring's pass, unchanged: G[n:] is not written and counts as
    zero). Returns the number of samples with a non-zero torque."""
    if law_active(spring[4]):
        return aft_law(x, omega, aft_mats, spring, G, dG, jac)
    return aft(x, aft_mats, spring, G, dG, jac)


def times_h_into(h, v, out):
    """out <- h_n * v_n on the real layout (complex product per harmonic): the compiled
    :func:`dmf_sim.solvers.hbm.unknowns.times_h` of a vector."""
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
    """r = x - wlin + h G (eq. 15) and, with ``jac``, J = I + h dG/dx, in place; G (2n) keeps the
    harmonics of the non-linear torque and their omega derivative (:func:`nonlinear`). Returns
    the number of AFT samples with a non-zero torque."""
    wlin_r, h, omega = lin
    n = x.shape[0]
    count = nonlinear(x, omega, aft_mats, spring, G, J, jac)
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
    G = np.empty(2 * n)
    count = residual_jacobian(x, lin, aft_mats, spring, r, J, G, jac)
    return r, J, count


def speed_derivative(lin, dlin, spring, G, rs):
    """rs <- dr/ds = -dwlin + dh G at fixed x (``dlin`` = (dwlin_r, dh), G the harmonics of the
    non-linear torque), plus h dG/ds with friction or end stops (``G[n:]``: dG/domega,
    omega = s RPM_TO_RAD_S): reference ``CondensedHBM.residual_speed_derivative``."""
    dwlin_r, dh = dlin
    times_h_into(dh, G, rs)
    n = rs.shape[0]
    for i in range(n):
        rs[i] -= dwlin_r[i]
    if law_active(spring[4]):
        hs = np.empty(n)
        times_h_into(lin[1], G[n:], hs)
        for i in range(n):
            rs[i] += RPM_TO_RAD_S * hs[i]


def residual_jacobians_py(x, lin, dlin, aft_mats, spring):
    """(r, dr/dx, dr/ds) as new arrays in one AFT pass: what the continuation asks at a point
    off the grid (reference: ``CondensedHBM.residual_and_jacobian_reference`` and
    ``residual_speed_derivative``)."""
    n = x.shape[0]
    r = np.empty(n)
    J = np.empty((n, n))
    G = np.empty(2 * n)
    rs = np.empty(n)
    residual_jacobian(x, lin, aft_mats, spring, r, J, G, True)
    speed_derivative(lin, dlin, spring, G, rs)
    return r, J, rs


def harmonics_py(x, omega, aft_mats, spring, jac):
    """(G, dG/dx, count) as new arrays (the non-linear torque harmonics alone, at engine speed
    omega [rad/s]; G has 2n entries, :func:`nonlinear`)."""
    n = x.shape[0]
    G = np.zeros(2 * n)
    dG = np.empty((n, n))
    count = nonlinear(x, omega, aft_mats, spring, G, dG, jac)
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
    return (np.empty(n), np.empty((n, n)), np.empty(2 * n), np.empty(n), np.empty((n, n)),
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


# reassociation lets LLVM vectorize the sums (rounding-level differences to the reference);
# no 'nnan' flag: the NaN checks of the solvers stay valid
aft = jit(aft, fastmath={'reassoc', 'contract'})
assemble = jit(assemble)
aft_law = jit(aft_law, fastmath={'reassoc', 'contract'})
nonlinear = jit(nonlinear)
times_h_into = jit(times_h_into)
times_h_matrix = jit(times_h_matrix)
residual_jacobian = jit(residual_jacobian)
residual_jacobian_py = jit(residual_jacobian_py)
speed_derivative = jit(speed_derivative)
residual_jacobians_py = jit(residual_jacobians_py)
harmonics_py = jit(harmonics_py)
_newton_start = jit(_newton_start)
_accept = jit(_accept)
newton = jit(newton)
_log_m = jit(_log_m)
_log_floor = jit(_log_floor)
deflated_newton = jit(deflated_newton)
deflated_newton_first = jit(deflated_newton_first)
