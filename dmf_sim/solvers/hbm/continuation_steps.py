"""The condensed harmonic balance as a continuation problem
(:class:`dmf_sim.solvers.continuation.ContinuationProblem`): r, dr/dx and dr/ds at any speed, and
the compiled corrector, tangent and grid steps handed to the continuation
(:class:`~dmf_sim.solvers.continuation.CompiledSteps`, from
:mod:`dmf_sim.solvers.hbm.continuation_kernels`). :class:`CondensedSteps` is a collaborator of
:class:`dmf_sim.solvers.hbm.condensed.CondensedHBM` (its ``steps``): it reads of its host only
what :class:`StepsHost` lists; each method returns None where the reference is to be used.
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from dmf_sim.solvers.continuation import CompiledSteps, CorrectorFailed, GridRun
from dmf_sim.solvers.hbm import continuation_kernels, kernels, linear_kernels
from dmf_sim.solvers.hbm.point import LinearParts

__all__ = ['StepsHost', 'CondensedSteps']


@runtime_checkable
class StepsHost(Protocol):
    """What :class:`CondensedSteps` reads of the condensed problem (``CondensedHBM``).

    1. ``compiled``: whether the compiled kernels are used; when False every method of
       :class:`CondensedSteps` but ``residual_and_jacobians`` returns None.
    2. ``linear_parts(speed_rpm)`` gives the :class:`~dmf_sim.solvers.hbm.point.LinearParts` of a
       speed (cached in ``_cache``, a mapping keyed by the speed [rpm] as a float), and
       ``_linear_parts_one(speed_rpm)`` computes them in Python (raising the engine's
       OperatingRangeError outside its data, computing the engine's grid nodes there).
    3. ``_engine_kernel_args()`` gives (fd, table, statics, modal) for the kernels that query the
       engine themselves, or None (an engine without a compiled table); it is cached in the
       host's ``_kernel_engine`` entry, which is dropped to read the table anew.
    4. ``_aft_mats`` and ``_spring_arrays`` are the packed AFT tables and spring arrays of
       :mod:`dmf_sim.solvers.hbm.kernels`.
    5. ``residual_and_jacobian(x, lp)`` and ``residual_speed_derivative(x, lp)`` are the
       reference (numpy) residual, Jacobian and dr/ds.
    """

    compiled: bool
    _cache: dict
    _aft_mats: tuple
    _spring_arrays: tuple

    def linear_parts(self, speed_rpm: float) -> LinearParts: ...

    def _linear_parts_one(self, speed_rpm: float) -> LinearParts: ...

    def _engine_kernel_args(self) -> tuple | None: ...

    def residual_and_jacobian(self, x: np.ndarray, lp: LinearParts
                              ) -> tuple[np.ndarray, np.ndarray]: ...

    def residual_speed_derivative(self, x: np.ndarray, lp: LinearParts) -> np.ndarray: ...


class CondensedSteps:
    """What ``continuation.continue_branch`` calls on a condensed HBM problem, given the
    problem (``host``, a :class:`StepsHost`)."""

    def __init__(self, host: StepsHost):
        self.host = host

    def compiled_steps(self) -> CompiledSteps:
        """The compiled steps to hand the continuation (``BranchHooks.steps``): the methods
        below, or none of them when the host's ``compiled`` is off."""
        if not self.host.compiled:
            return CompiledSteps()
        return CompiledSteps(tangent=self.tangent, corrector_at=self.corrector_at,
                             corrector_arc=self.corrector_arc, step_at=self.step_at,
                             grid_run=self.grid_run)

    def residual_and_jacobians(self, x: np.ndarray, speed_rpm: float):
        """(r, dr/dx, dr/ds) at wind-up harmonics x and speed [rpm]."""
        key = float(speed_rpm)
        if self.host.compiled and key not in self.host._cache:
            out = self._residual_jacobians_at(x, key)
            if out is not None:
                return out
        lp = self.host.linear_parts(speed_rpm)
        if self.host.compiled:               # one kernel call: one AFT pass for all three
            return kernels.residual_jacobians_py(np.ascontiguousarray(x, dtype=float), lp.lin,
                                                 lp.dlin, self.host._aft_mats,
                                                 self.host._spring_arrays)
        r, Jx = self.host.residual_and_jacobian(x, lp)
        return r, Jx, self.host.residual_speed_derivative(x, lp)

    def _residual_jacobians_at(self, x: np.ndarray, s: float):
        """(r, dr/dx, dr/ds) at a speed not in the cache, the linear parts computed in the same
        kernel call (the arc-length corrector: each iteration a new speed); None where the
        engine has no compiled table or its grid nodes there are not computed yet (then the
        Python path computes them, and the table is read again next time)."""
        args = self.host._engine_kernel_args()
        if args is None:
            return None
        fd, table, statics, modal = args
        st, r, J, rs = continuation_kernels.residual_jacobians_at(
            np.ascontiguousarray(x, dtype=float), s, fd, table, statics, modal,
            self.host._aft_mats, self.host._spring_arrays)
        if st == linear_kernels.ENGINE_OK:
            return r, J, rs
        if st == linear_kernels.ENGINE_NOT_READY:
            self.host.__dict__.pop('_kernel_engine', None)
        return None                     # outside the data: the Python path raises as usual

    def corrector_arc(self, y_pred: np.ndarray, normal: np.ndarray, xs: float, ss: float,
                      tol: float, max_iter: int):
        """The continuation corrector of a pseudo-arc-length step, compiled
        (:func:`continuation_kernels.corrector_arclength`: continuation.correct with the normal
        ``normal``, the linear parts of each iterate's speed in the same call). Returns (y,
        iterations, max|r|, (r, dr/dx, dr/ds)); raises CorrectorFailed when it does not
        converge and OperatingRangeError when an iterate's speed lies outside the engine data;
        None when the reference corrector is to be used (``compiled`` off, or an engine without
        a compiled table)."""
        if not self.host.compiled:
            return None
        n1 = len(y_pred)
        y_pred = np.ascontiguousarray(y_pred, dtype=float)
        normal = np.ascontiguousarray(normal, dtype=float)
        while True:
            args = self.host._engine_kernel_args()
            if args is None:
                return None
            fd, table, statics, modal = args
            y = np.empty(n1)
            r = np.empty(n1 - 1)
            Jx = np.empty((n1 - 1, n1 - 1))
            rs = np.empty(n1 - 1)
            status, it, res, est = continuation_kernels.corrector_arclength(
                y_pred, normal, float(xs), float(ss), float(tol), int(max_iter), fd, table,
                statics, modal, self.host._aft_mats, self.host._spring_arrays, y, r, Jx, rs)
            if status == kernels.CONVERGED:
                return y, it, res, (r, Jx, rs)
            if status != kernels.ENGINE_FAILED:
                raise CorrectorFailed.not_converged(res, max_iter)
            # the speed of the failing iterate: its linear parts in Python raise the engine's
            # own error outside the data, or compute the grid nodes not computed yet (then the
            # kernel runs again with the table read anew)
            s = float(y[n1 - 1] * ss)
            self.host.__dict__.pop('_kernel_engine', None)
            self.host._linear_parts_one(s)
            if est != linear_kernels.ENGINE_NOT_READY:  # outside, though Python found it inside
                return None

    def corrector_at(self, y_pred: np.ndarray, xs: float, ss: float, tol: float, max_iter: int):
        """The continuation corrector of a step landing on a grid speed, compiled
        (continuation.correct with the normal e_S; scaled unknowns y = [x / xs, s / ss]).
        Returns (y, iterations, max|r|, (r, dr/dx, dr/ds)); raises CorrectorFailed when it does
        not converge; None when the reference corrector is to be used (``compiled`` off)."""
        if not self.host.compiled:
            return None
        n = len(y_pred) - 1
        lp = self.host.linear_parts(float(y_pred[n] * ss))
        y = np.empty(n)
        r = np.empty(n)
        Jx = np.empty((n, n))
        rs = np.empty(n)
        status, it, res = continuation_kernels.corrector_fixed_speed(
            np.ascontiguousarray(y_pred[:n]), float(xs), lp.lin, lp.dlin, self.host._aft_mats,
            self.host._spring_arrays, float(tol), int(max_iter), y, r, Jx, rs)
        if status != kernels.CONVERGED:
            raise CorrectorFailed.not_converged(res, max_iter)
        return np.concatenate([y, y_pred[n:]]), it, res, (r, Jx, rs)

    def step_at(self, y_pred: np.ndarray, prev: np.ndarray, xs: float, ss: float, tol: float,
                max_iter: int):
        """A continuation step landing on a grid speed in one compiled call
        (:func:`continuation_kernels.step_fixed_speed`): :meth:`corrector_at`, then
        :meth:`tangent` at the corrected point oriented along ``prev``. Returns (y, iterations,
        max|r|, t), t None on a singular tangent system (``continuation.correct_step``); raises
        CorrectorFailed when the corrector does not converge; None when the reference is to be
        used (``compiled`` off)."""
        if not self.host.compiled:
            return None
        n = len(y_pred) - 1
        lp = self.host.linear_parts(float(y_pred[n] * ss))
        y = np.empty(n + 1)
        t = np.empty(n + 1)
        r = np.empty(n)
        Jx = np.empty((n, n))
        rs = np.empty(n)
        status, it, res = continuation_kernels.step_fixed_speed(
            y_pred, prev, float(xs), float(ss), lp.lin, lp.dlin, self.host._aft_mats,
            self.host._spring_arrays, float(tol), int(max_iter), y, t, r, Jx, rs)
        if status == continuation_kernels.TANGENT_SINGULAR:
            return y, it, res, None
        if status != kernels.CONVERGED:
            raise CorrectorFailed.not_converged(res, max_iter)
        return y, it, res, t

    def grid_run(self, s: float, y: np.ndarray, t: np.ndarray, h: float,
                 s_bounds: tuple[float, float], options, check_linear: bool, budget: int):
        """The grid step ``continuation.continue_branch`` has chosen from its last point, at speed
        s [rpm] (y, t, h the loop's scaled unknowns, unit tangent and arc step there), and the
        grid steps after it, in one compiled call
        (:func:`continuation_kernels.grid_run`: the loop's own steps and step control, until a
        step it leaves to the loop). With ``check_linear`` it stops at every later on-grid
        point whose non-linear torque harmonics are all zero (where the sweep's fast-forward
        may apply). Returns a :class:`~dmf_sim.solvers.continuation.GridRun`: the new points'
        rows (x [rad], s [rpm], unit tangent, iterations, max|r|, on the grid), the last state
        and a ``RUN_*`` code; None where the loop is to take every step itself (``compiled``
        off, an engine without a compiled table, or no steps allowed)."""
        if not self.host.compiled or budget < 1:
            return None
        args = self.host._engine_kernel_args()
        if args is None:
            return None
        n1 = len(y)
        size = min(budget, self._run_rows(s_bounds, options.grid))
        X = np.empty((size, n1 - 1))
        S = np.empty(size)
        T = np.empty((size, n1))
        IT = np.empty(size, dtype=np.int64)
        RES = np.empty(size)
        ONG = np.empty(size, dtype=np.bool_)
        y = np.array(y, dtype=float)
        t = np.array(t, dtype=float)
        opts = np.array([float(getattr(options, f)) for f in continuation_kernels.RUN_OPTIONS])
        k, h, why = continuation_kernels.grid_run(
            float(s), y, t, float(h), float(s_bounds[0]), float(s_bounds[1]), opts,
            int(options.max_iter), int(options.easy_iter), bool(check_linear), size, args,
            self.host._aft_mats, self.host._spring_arrays, (X, S, T, IT, RES, ONG))
        return GridRun(X[:k], S[:k], T[:k], IT[:k], RES[:k], ONG[:k], y, t, h, why)

    @staticmethod
    def _run_rows(s_bounds: tuple[float, float], grid: float) -> int:
        """Rows for one grid run: every grid speed of the range once, plus one (at least one
        row: the run the loop has chosen takes its step, whatever the range)."""
        return max(int((s_bounds[1] - s_bounds[0]) / grid) + 2, 1)

    def tangent(self, Jx: np.ndarray, rs: np.ndarray, prev: np.ndarray, xs: float, ss: float
                ) -> np.ndarray | None:
        """The continuation's unit tangent at a point with Jacobians (Jx, rs), oriented along
        ``prev``, compiled (:func:`continuation_kernels.tangent`; reference
        ``continuation._tangent``). Raises numpy's LinAlgError on a singular system, as the
        reference; None when the reference is to be used (``compiled`` off)."""
        if not self.host.compiled:
            return None
        t = np.empty(len(prev))
        if not continuation_kernels.tangent(np.ascontiguousarray(Jx, dtype=float),
                               np.ascontiguousarray(rs, dtype=float),
                               np.ascontiguousarray(prev, dtype=float), float(xs), float(ss), t):
            raise np.linalg.LinAlgError('singular matrix')
        return t
