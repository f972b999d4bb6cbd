"""Compiled continuation steps of a harmonic-balance sweep (numba: nopython, cached), beside the
readable reference in :mod:`dmf_sim.solvers.continuation` they are tested against: the
predictor-corrector step of ``continuation.continue_branch`` on the condensed system, built on
the residual and Jacobian of :mod:`dmf_sim.solvers.hbm.kernels`.

* :func:`tangent` — the continuation's unit tangent at a converged point. Reference:
  ``continuation._tangent``.
* :func:`corrector_fixed_speed` — the corrector of a step that lands on a grid speed (natural
  parameter, s fixed). Reference: ``continuation.correct`` with the normal e_S.
* :func:`step_fixed_speed` — the two in one call: a continuation step in grid mode. Reference:
  ``continuation.correct`` then ``continuation.tangent_of``.
* :func:`residual_jacobians_at` — r, dr/dx and dr/ds at a speed off the grid, its linear parts
  (engine query included) computed in the same call.
* :func:`corrector_arclength` — the pseudo-arc-length corrector, every iterate at a new speed.
  Reference: ``continuation.correct`` with any other normal.
* :func:`grid_run` — consecutive grid steps of ``continuation.continue_branch`` in one call,
  with its step control, until a step it does not take the same way (reference: the loop of
  ``continue_branch`` itself).

Packed arguments and status codes are those of :mod:`dmf_sim.solvers.hbm.kernels`, plus
:data:`TANGENT_SINGULAR`.
"""
from __future__ import annotations

import math

import numpy as np

from dmf_sim.core.compiled import jit
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.solvers.hbm.dense_kernels import lu_solve, lu_work, max_abs
from dmf_sim.solvers.hbm.kernels import (
    CONVERGED,
    ENGINE_FAILED,
    MAX_ITER,
    NOT_FINITE,
    SINGULAR,
    nonlinear,
    residual_jacobian,
    speed_derivative,
)
from dmf_sim.solvers.hbm.linear_kernels import ENGINE_OK, linear_parts_at, one_speed_work
from dmf_sim.solvers.step_control import (
    grid_step,
    moved_too_far,
    next_step,
    on_bound,
    on_grid,
    tangent_turn,
    turned_too_far,
)

__all__ = ['TANGENT_SINGULAR', 'tangent', 'add_step', 'corrector_fixed_speed',
           'step_fixed_speed', 'residual_jacobians_at', 'corrector_arclength', 'grid_run',
           'RUN_LINEAR', 'RUN_NOT_GRID', 'RUN_RETRY', 'RUN_BOUND', 'RUN_BUDGET', 'RUN_OPTIONS']

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
    G = np.empty(2 * n)
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
    speed_derivative(lin, dlin, spring, G, rs)
    return status, it, res


def residual_jacobians_at(x, s, fd, table, statics, modal, aft_mats, spring):
    """(status, r, dr/dx, dr/ds) at wind-up harmonics x and speed s [rpm], the linear parts
    computed here (:func:`linear_parts_at`) and one AFT pass: what the arc-length corrector asks
    at every iteration (each a new speed). status: the engine's (r etc. unset unless
    ENGINE_OK)."""
    n = x.shape[0]
    A, A2, dA, h, dh, wlin, dw, wr, dwr = one_speed_work(n)
    r = np.empty(n)
    J = np.empty((n, n))
    rs = np.empty(n)
    st = linear_parts_at(s, fd, table, statics, modal, A, A2, dA, h, dh, wlin, dw, wr, dwr)
    if st != ENGINE_OK:
        return st, r, J, rs
    G = np.empty(2 * n)
    lin = (wr[0], h[0], s * RPM_TO_RAD_S)
    residual_jacobian(x, lin, aft_mats, spring, r, J, G, True)
    speed_derivative(lin, (dwr[0], dh[0]), spring, G, rs)
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


# ------------------------------------------------------------------------------------------------
# Consecutive grid steps in one call
# ------------------------------------------------------------------------------------------------

# why grid_run returned (the continuation takes the next step itself, as it would have)
RUN_LINEAR = 1     # an on-grid point whose AFT samples reach no knee: the fast-forward may apply
RUN_NOT_GRID = 2   # the next step is not a grid step (|dS/da| small, or the grid speed too far)
RUN_RETRY = 3      # a step not accepted as it stands (the corrector failed or moved too far,
#                    the tangent turned too much or is singular, the engine data not at hand)
RUN_BOUND = 4      # the last point lies on a bound of the speed range
RUN_BUDGET = 5     # as many steps as allowed

RUN_OPTIONS = ('s_scale', 'x_scale', 'step_min', 'step_max', 'grid', 'grid_mode_min_ts',
               'max_correction', 'max_turn', 'tol')
"""The ``ContinuationOptions`` fields in grid_run's float array ``opts``, in this order."""


def grid_run(s0, y, t, h, lo, hi, opts, max_iter, easy_iter, check_linear, budget, engine,
             aft_mats, spring, rows):
    """Grid steps of ``continuation.continue_branch`` one after the other, as its loop takes them
    (reference: that loop, the step in grid mode and its step control), from the last point at s0
    [rpm] with scaled unknowns y, unit tangent t and arc step h, the speed range [lo, hi] [rpm];
    the first step is one the loop has chosen (its fast-forward asked already). ``opts``: the
    floats of :data:`RUN_OPTIONS`; ``max_iter``, ``easy_iter`` the corrector's. Each step predicts
    the next grid speed along t (:func:`dmf_sim.solvers.step_control.grid_step`), corrects there
    (:func:`step_fixed_speed`, the linear parts by :func:`linear_parts_at`) and is accepted by
    the loop's tests (``step_control.moved_too_far``, ``step_control.turned_too_far``); then h
    changes as the loop's (``step_control.next_step``): every decision is the loop's own
    function.

    Stops before any step the loop would take otherwise, leaving it to the loop: at a new on-grid
    point whose non-linear torque harmonics are all zero when ``check_linear`` (there the
    fast-forward may apply), where the next step is not a grid step, and where a step is not
    accepted as it stands (the loop retries it its way). Stops after a point on a bound and
    after ``budget`` steps. ``engine``: (fd, table, statics, modal) of
    :func:`linear_parts_at`. Writes the points into the arrays ``rows`` = (X (x [rad]),
    S (s [rpm]), T (unit tangent), IT (iterations), RES (max|r|), ONG (on the grid)), and the
    last state into y, t; returns (points, h, why: a ``RUN_*`` code)."""
    ss, xs, step_min, step_max, grid, min_ts, max_corr, max_turn, tol = opts
    fd, table, statics, modal = engine
    X, S, T, IT, RES, ONG = rows
    n = y.shape[0] - 1
    A, A2, dA, hh, dh, wlin, dw, wr, dwr = one_speed_work(n)
    G = np.empty(2 * n)
    dG = np.empty((1, 1))
    y_pred = np.empty(n + 1)
    y_new = np.empty(n + 1)
    t_new = np.empty(n + 1)
    moved = np.empty(n + 1)
    r = np.empty(n)
    J = np.empty((n, n))
    rs = np.empty(n)
    s = s0
    count = 0
    while count < budget:
        tn = t[n]
        if check_linear and count > 0 and ONG[count - 1] and abs(tn) >= min_ts:
            nonlinear(X[count - 1], S[count - 1] * RPM_TO_RAD_S, aft_mats, spring, G, dG,
                      False)
            linear = True
            for i in range(n):
                if G[i] != 0.0:
                    linear = False
                    break
            if linear:
                return count, h, RUN_LINEAR
        grid_mode, target, h_grid = grid_step(s, tn, h, lo, hi, grid, ss, step_max, min_ts)
        if not grid_mode:
            return count, h, RUN_NOT_GRID
        for i in range(n + 1):
            y_pred[i] = y[i] + h_grid * t[i]
        y_pred[n] = target / ss
        if linear_parts_at(y_pred[n] * ss, fd, table, statics, modal, A, A2, dA, hh, dh, wlin,
                           dw, wr, dwr) != ENGINE_OK:
            return count, h, RUN_RETRY
        lin = (wr[0], hh[0], y_pred[n] * ss * RPM_TO_RAD_S)
        status, it, res = step_fixed_speed(y_pred, t, xs, ss, lin, (dwr[0], dh[0]),
                                           aft_mats, spring, tol, max_iter, y_new, t_new, r, J,
                                           rs)
        if status != CONVERGED:
            return count, h, RUN_RETRY
        for i in range(n + 1):
            moved[i] = y_new[i] - y_pred[i]
        if moved_too_far(math.sqrt(np.dot(moved, moved)), abs(h_grid), max_corr, step_min):
            return count, h, RUN_RETRY
        if turned_too_far(tangent_turn(np.dot(t_new, t)), True, h, max_turn, step_min):
            return count, h, RUN_RETRY
        for i in range(n + 1):
            y[i] = y_new[i]
            t[i] = t_new[i]
        s = y[n] * ss
        for i in range(n):
            X[count, i] = y[i] * xs
        for i in range(n + 1):
            T[count, i] = t[i]
        S[count] = s
        IT[count] = it
        RES[count] = res
        ONG[count] = on_grid(s, grid)
        count += 1
        h = next_step(h, it, easy_iter, step_min, step_max)
        if on_bound(s, lo, hi):
            return count, h, RUN_BOUND
    return count, h, RUN_BUDGET


tangent = jit(tangent)
add_step = jit(add_step)
corrector_fixed_speed = jit(corrector_fixed_speed)
residual_jacobians_at = jit(residual_jacobians_at)
_evaluate_scaled = jit(_evaluate_scaled)
corrector_arclength = jit(corrector_arclength)
step_fixed_speed = jit(step_fixed_speed)
grid_run = jit(grid_run)
