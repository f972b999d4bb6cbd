"""Pseudo-arc-length continuation of r(x, s) = 0 over one parameter s (engine speed) [Keller].

The branch is a curve y(a) = (x(a), s(a)) in scaled coordinates X = x / x_scale, S = s / s_scale,
parametrized by its arc length a. From a point y_k with unit tangent t_k (the null vector of the
augmented Jacobian [r_X r_S]):

    predictor:  y_p = y_k + h t_k
    corrector:  Newton on   r(y) = 0,   n . (y - y_p) = 0

with n = t_k (pseudo-arc-length: passes turning points, where ds/da changes sign) or, where the
branch runs mainly along s, n = e_S and h chosen so that s_p lands on the next speed of the output
grid (natural-parameter stepping on a regular grid, so tables come out at round speeds). The
tangent keeps its orientation (t_{k+1} . t_k > 0), which is what carries the continuation around a
fold and onto the coexisting solutions behind it.

Step control: the step h grows after easy corrections (few Newton iterations) and is halved after a
failed one or a sharp turn of the tangent, between ``step_min`` and ``step_max``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np
from scipy.linalg.lapack import dgesv

from dmf_sim.core.errors import OperatingRangeError

__all__ = ['solve_small', 'ContinuationProblem', 'ContinuationOptions', 'ContinuationPoint',
           'CorrectorFailed', 'LeftRange', 'correct', 'tangent_of', 'correct_step',
           'continue_branch', 'on_grid', 'next_grid']


def solve_small(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """LU solve (LAPACK dgesv directly: these systems are small and solved very often)."""
    _, _, x, info = dgesv(A, b)
    if info != 0:
        raise np.linalg.LinAlgError('singular matrix')
    return x


class ContinuationProblem(Protocol):
    def residual_and_jacobians(self, x: np.ndarray, s: float
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r, dr/dx, dr/ds)."""


@dataclass(frozen=True)
class ContinuationOptions:
    """Settings of the speed continuation (scaled units: one arc unit ~ s_scale or x_scale).

    Attributes:
        s_scale: parameter unit [rpm] (default 10 rpm, the output grid step).
        x_scale: unknown unit [rad].
        step: initial arc step; step_min / step_max: bounds.
        grid: output grid spacing in s [rpm] for natural-parameter landing (None: pure arc-length).
        grid_mode_min_ts: use grid landing only while |dS/da| exceeds this (away from folds).
        tol: corrector tolerance on max|r| [rad]; max_iter: corrector iterations.
        max_turn: largest accepted angle between successive tangents [rad] (else the step is
            halved).
        max_correction: largest accepted corrector displacement, relative to the step (guards
            against jumping onto another branch).
        max_steps: safety limit of steps per branch.
        loop_skip, loop_tol: the branch has closed on itself (an isola, or a loop back onto its
            own earlier part) when a new point lies within ``loop_tol`` x step_max of the
            polyline through the points more than ``loop_skip`` back, moving the same way; it
            ends there (reason 'closed') instead of going round until ``max_steps``. (Distinct
            coexisting solutions at one speed are farther apart than that in scaled units.)
    """

    s_scale: float = 10.0
    x_scale: float = 0.01
    step: float = 1.0
    step_min: float = 1e-4
    step_max: float = 1.0
    grid: float | None = 10.0
    grid_mode_min_ts: float = 0.2
    tol: float = 1e-10
    max_iter: int = 12
    easy_iter: int = 3
    max_turn: float = 0.6
    max_correction: float = 0.5
    max_steps: int = 5000
    loop_skip: int = 20
    loop_tol: float = 0.05


@dataclass
class ContinuationPoint:
    x: np.ndarray
    s: float
    tangent: np.ndarray        # unit tangent in scaled coordinates (last entry: dS/da)
    iterations: int
    residual: float
    on_grid: bool


class CorrectorFailed(RuntimeError):
    """The corrector did not converge (or left the problem's data range)."""

    @classmethod
    def not_converged(cls, res: float, max_iter: int) -> CorrectorFailed:
        """The error of a corrector still at max|r| = ``res`` after ``max_iter`` iterations."""
        return cls(f'corrector: max|r| = {res:.2e} after {max_iter} iterations')


class LeftRange(CorrectorFailed):
    """The corrector asked the problem for a parameter outside its data (e.g. an engine speed the
    engine has no data for): the branch ends there."""


def _tangent(Jx: np.ndarray, rs: np.ndarray, prev: np.ndarray, xs: float, ss: float) -> np.ndarray:
    """Unit null vector of [r_X r_S] (scaled), oriented along ``prev``."""
    n = Jx.shape[0]
    A = np.empty((n + 1, n + 1))
    A[:n, :n] = Jx * xs
    A[:n, n] = rs * ss
    A[n] = prev
    b = np.zeros(n + 1)
    b[n] = 1.0
    t = solve_small(A, b)
    t /= np.linalg.norm(t)
    if t @ prev < 0:
        t = -t
    return t


def tangent_of(problem: ContinuationProblem, Jx: np.ndarray, rs: np.ndarray, prev: np.ndarray,
               xs: float, ss: float) -> np.ndarray:
    """:func:`_tangent`, by the problem's own compiled ``problem.tangent(Jx, rs, prev, xs, ss)``
    where it has one (None from it: use :func:`_tangent`)."""
    own = getattr(problem, 'tangent', None)
    t = own(Jx, rs, prev, xs, ss) if own is not None else None
    return _tangent(Jx, rs, prev, xs, ss) if t is None else t


def _evaluate(problem: ContinuationProblem, x: np.ndarray, s: float):
    """problem.residual_and_jacobians, with a parameter outside the problem's data as LeftRange."""
    try:
        return problem.residual_and_jacobians(x, s)
    except OperatingRangeError as exc:
        raise LeftRange(f'parameter {s:g} outside the data: {exc}') from None


def correct(problem: ContinuationProblem, y_pred: np.ndarray, normal: np.ndarray,
            xs: float, ss: float, tol: float, max_iter: int
            ) -> tuple[np.ndarray, int, float, tuple]:
    """Newton on [r(x, s); normal . (y - y_pred)] = 0 in scaled coordinates.

    A problem may do the whole corrector in one call (same iteration, compiled; each returns
    None to use this one): with the normal e_S (s fixed on a grid speed)
    ``problem.corrector_at(y_pred, xs, ss, tol, max_iter)``, with any other normal
    ``problem.corrector_arc(y_pred, normal, xs, ss, tol, max_iter)``."""
    y = y_pred.copy()
    n = len(y) - 1
    fixed_s = normal[n] == 1.0 and not np.any(normal[:n])
    if fixed_s:
        compiled = getattr(problem, 'corrector_at', None)
        args = (y_pred, xs, ss, tol, max_iter)
    else:
        compiled = getattr(problem, 'corrector_arc', None)
        args = (y_pred, normal, xs, ss, tol, max_iter)
    if compiled is not None:        # the problem's own compiled corrector
        try:
            out = compiled(*args)
        except OperatingRangeError as exc:
            raise LeftRange(f'parameter {y_pred[n] * ss:g} outside the data: {exc}') from None
        if out is not None:
            return out
    A = np.empty((n + 1, n + 1))
    res = np.inf
    for it in range(max_iter + 1):
        x, s = y[:n] * xs, y[n] * ss
        r, Jx, rs = _evaluate(problem, x, s)
        res = float(np.abs(r).max())
        g = float(normal @ (y - y_pred))
        if res <= tol and abs(g) <= 1e-12:
            return y, it, res, (r, Jx, rs)
        if it == max_iter or not np.isfinite(res):
            break
        try:
            if fixed_s:        # natural parameter: s stays exactly on the grid speed
                dy = np.zeros(n + 1)
                dy[:n] = solve_small(Jx * xs, -r)
            else:
                A[:n, :n] = Jx * xs
                A[:n, n] = rs * ss
                A[n] = normal
                dy = solve_small(A, np.concatenate([-r, [-g]]))
        except np.linalg.LinAlgError:
            break
        y = y + dy
        if np.abs(dy).max() < 1e-13 and res < 1e3 * tol:
            x, s = y[:n] * xs, y[n] * ss
            r, Jx, rs = _evaluate(problem, x, s)
            return y, it + 1, float(np.abs(r).max()), (r, Jx, rs)
    raise CorrectorFailed.not_converged(res, max_iter)


def correct_step(problem: ContinuationProblem, y_pred: np.ndarray, normal: np.ndarray,
                 prev: np.ndarray, xs: float, ss: float, tol: float, max_iter: int,
                 fixed_s: bool | None = None) -> tuple[np.ndarray, int, float, np.ndarray]:
    """:func:`correct`, then the unit tangent there oriented along ``prev`` (:func:`tangent_of`):
    (y, iterations, max|r|, tangent), the tangent None where its system is singular (the caller
    decides: continue_branch first checks how far the corrector moved). With the normal e_S a
    problem may do both in one compiled call, ``problem.step_at(y_pred, prev, xs, ss, tol,
    max_iter)`` (None from it: the two calls). ``fixed_s``: whether ``normal`` is e_S, if the
    caller knows."""
    n = len(y_pred) - 1
    if fixed_s is None:
        fixed_s = bool(normal[n] == 1.0 and not normal[:n].any())
    if fixed_s:
        compiled = getattr(problem, 'step_at', None)
        out = compiled(y_pred, prev, xs, ss, tol, max_iter) if compiled is not None else None
        if out is not None:
            return out
    y, it, res, (r, Jx, rs) = correct(problem, y_pred, normal, xs, ss, tol, max_iter)
    try:
        t = tangent_of(problem, Jx, rs, prev, xs, ss)
    except np.linalg.LinAlgError:
        t = None
    return y, it, res, t


class _LoopDetector:
    """Tells when a branch has come back onto its own earlier part (see
    ``ContinuationOptions.loop_skip``): the new point lies within ``loop_tol`` x step_max of the
    polyline through the points more than ``loop_skip`` back, travelling the same way along it.

    Points are kept scaled, (x / x_scale, s / s_scale), in one growing array. A point can only lie
    that close to the earlier polyline if its s lies within that part's s-range widened by the
    tolerance, so a branch that has not turned back in s (most of them) costs two float
    comparisons per point; the polyline distances are computed only inside that range.
    """

    def __init__(self, y0: np.ndarray, o: ContinuationOptions):
        self.o = o
        self.tol = o.loop_tol * o.step_max
        self.points = np.empty((64, y0.size))
        self.points[0] = y0
        self.count = 1
        self.s_lo = self.s_hi = float(y0[-1])   # s-range of the points that are far enough back
        self.ranged = 0                         # how many points s_lo/s_hi cover

    def __call__(self, p: ContinuationPoint) -> bool:
        o = self.o
        if self.count == len(self.points):
            self.points = np.concatenate([self.points, np.empty_like(self.points)])
        q = self.points[self.count]
        np.divide(p.x, o.x_scale, out=q[:-1])
        s_q = q[-1] = p.s / o.s_scale
        self.count += 1
        far = self.count - 1 - o.loop_skip      # points[:far] form the earlier part
        if far < 2:
            return False
        while self.ranged < far:
            s_k = float(self.points[self.ranged, -1])
            if s_k < self.s_lo:
                self.s_lo = s_k
            elif s_k > self.s_hi:
                self.s_hi = s_k
            self.ranged += 1
        if not self.s_lo - self.tol <= s_q <= self.s_hi + self.tol:
            return False
        a = self.points[:far]
        seg = a[1:] - a[:-1]
        a = a[:-1]
        length2 = np.einsum('ij,ij->i', seg, seg)
        safe = np.where(length2 > 0, length2, 1.0)
        u = np.clip(np.einsum('ij,ij->i', q - a, seg) / safe, 0.0, 1.0)
        gap = np.linalg.norm(a + u[:, None] * seg - q, axis=1)
        along = seg @ p.tangent / np.sqrt(safe)
        return bool(np.any((gap < self.tol) & (along > 0.9)))


def continue_branch(problem: ContinuationProblem, x0: np.ndarray, s0: float,
                    s_bounds: tuple[float, float],
                    direction: float = 1.0, options: ContinuationOptions | None = None,
                    tangent0: np.ndarray | None = None,
                    stop: (Callable[[ContinuationPoint, list[ContinuationPoint]], bool]
                           | None) = None,
                    on_point: Callable[[ContinuationPoint], None] | None = None,
                    fast_forward: (Callable[[ContinuationPoint, float], list[ContinuationPoint]]
                                   | None) = None,
                    on_end: Callable[[str, ContinuationPoint], None] | None = None
                    ) -> list[ContinuationPoint]:
    """Follow the solution branch through (x0, s0) (a converged solution) until s leaves
    ``s_bounds``, ``stop(point, branch)`` returns True, or ``max_steps``.

    ``direction`` +1/-1 starts toward higher/lower s (ignored if ``tangent0`` is given).
    The last point of a branch that reaches a bound lies exactly on the bound.
    ``fast_forward(point, sign)``, called at grid points away from turning points, may return
    further grid points (in the direction ``sign`` of s) whose solutions it knows without
    iterating (the HBM: stretches where the wind-up never reaches a knee, so the response is the
    linear one); the last one must carry the exact tangent.
    A problem with ``grid_run`` (the condensed HBM: ``ContinuationSteps.grid_run``) takes a grid
    step the loop has chosen and the grid steps after it in one call, each as the loop takes it,
    and returns before any other step: at every on-grid point where its non-linear torque
    harmonics are all zero (``fast_forward`` must return no points where they are not, as the
    sweep's does), before an arc-length step and before a step it would not accept as it stands.
    ``on_end(reason, last_point)`` is told why the branch ended: 'bound' (s reached a bound),
    'stop', 'closed' (the branch came back onto its own earlier part: see
    ``ContinuationOptions.loop_skip``), 'left_range' (the corrector needed parameters outside
    the problem's data), 'corrector_failed' (no step, however small, converged) or
    'max_steps'.
    """
    o = options or ContinuationOptions()
    xs, ss = o.x_scale, o.s_scale
    lo, hi = s_bounds
    n = len(x0)
    y = np.concatenate([np.asarray(x0, float) / xs, [s0 / ss]])
    r, Jx, rs = problem.residual_and_jacobians(np.asarray(x0, float), s0)
    if tangent0 is None:
        prev = np.zeros(n + 1)
        prev[n] = 1.0 if direction >= 0 else -1.0
    else:
        prev = np.asarray(tangent0, float)
    t = tangent_of(problem, Jx, rs, prev, xs, ss)
    pts = [ContinuationPoint(np.asarray(x0, float).copy(), float(s0), t, 0, float(np.abs(r).max()),
                             _on_grid(s0, o.grid))]
    if on_point:
        on_point(pts[0])
    h = o.step
    e_s = np.zeros(n + 1)
    e_s[n] = 1.0
    closes = _LoopDetector(y, o)

    force_arc = False
    done = False
    reason = 'max_steps'
    last_failure: CorrectorFailed | None = None
    run = getattr(problem, 'grid_run', None) if o.grid is not None else None
    steps = 0

    def extend(new) -> int:
        """Append the new points in turn (on_point, then the end tests) until the branch ends;
        how many were appended."""
        nonlocal done, reason
        for k, p in enumerate(new):
            pts.append(p)
            if on_point:
                on_point(p)
            why = _ends(p, pts, lo, hi, stop, closes)
            if why is not None:
                done, reason = True, why
                return k + 1
        return len(new)

    while steps < o.max_steps and not done:
        steps += 1
        s = pts[-1].s
        if (fast_forward is not None and pts[-1].on_grid and not force_arc
                and abs(t[n]) >= o.grid_mode_min_ts):
            jump = fast_forward(pts[-1], 1.0 if t[n] > 0 else -1.0)
            extend(jump)
            if jump:
                y = np.concatenate([pts[-1].x / xs, [pts[-1].s / ss]])
                t = pts[-1].tangent if pts[-1].tangent @ t > 0 else -pts[-1].tangent
                continue
        # --- choose the step: land on the next grid speed, or a plain arc-length step ----------
        grid_mode = (not force_arc) and o.grid is not None and abs(t[n]) >= o.grid_mode_min_ts
        if grid_mode:
            target = next_grid(s, 1.0 if t[n] > 0 else -1.0, o.grid)
            target = min(max(target, lo), hi)
            h_grid = (target - s) / ss / t[n]
            grid_mode = 0.0 < h_grid <= min(1.5 * o.step_max, 2.0 * h)
        if grid_mode and run is not None:
            # this grid step and those after it in one call, each as this loop takes it; the
            # call returns before any other step (none made: the loop takes this one itself)
            ran = run(s, y, t, h, s_bounds, o, fast_forward is not None, o.max_steps - steps + 1)
            if ran is not None and len(ran[1]):
                X, S, T, IT, RES, ONG, y, t, h, _ = ran
                steps += extend([ContinuationPoint(X[k], float(S[k]), T[k], int(IT[k]),
                                                   float(RES[k]), bool(ONG[k]))
                                 for k in range(len(S))]) - 1
                continue
        if grid_mode:
            y_pred = y + h_grid * t
            y_pred[n] = target / ss
            normal = e_s
        else:
            y_pred = y + h * t
            normal = t
            s_pred = y_pred[n] * ss
            if (s_pred > hi or s_pred < lo) and abs(t[n]) > 1e-3:   # finish exactly on the bound
                bound = hi if s_pred > hi else lo
                y_pred = y + ((bound - s) / ss / t[n]) * t
                y_pred[n] = bound / ss
                normal = e_s
        try:
            y_new, it, res, t_new = correct_step(problem, y_pred, normal, t, xs, ss, o.tol,
                                                 o.max_iter, normal is e_s)
            step_len = abs(h_grid) if grid_mode else h
            moved = y_new - y_pred
            if math.sqrt(moved @ moved) > o.max_correction * max(step_len, o.step_min):
                # converged far from the prediction: maybe onto another branch (e.g. a grid
                # speed beyond a turning point); retry with a smaller arc-length step
                raise CorrectorFailed('corrector moved too far from the predictor')
            if t_new is None:
                raise np.linalg.LinAlgError('singular matrix')
            turn = math.acos(min(max(float(t_new @ t), -1.0), 1.0))
            if turn > o.max_turn and (grid_mode or h > o.step_min * 1.01):
                raise CorrectorFailed(f'tangent turned by {turn:.2f} rad')
        except CorrectorFailed as exc:
            last_failure = exc
            if grid_mode:                  # retry the same stretch with arc-length steps
                force_arc = True
                h = max(min(h, 0.5 * h_grid), o.step_min)
                continue
            if h > o.step_min * 1.01:
                h = max(h * 0.5, o.step_min)
                continue
            # The step cannot be made small enough: a (near) branch point, where the tangent is
            # ill-defined. Jump over it along the last good tangent; orient the new tangent by
            # the secant. If that fails too, the branch ends here.
            jumped = _jump(problem, y, t, xs, ss, o)
            if jumped is None:
                reason = ('left_range' if isinstance(last_failure, LeftRange)
                          else 'corrector_failed')
                break
            y_new, it, res, t_new = jumped
            h = o.step
        force_arc = False
        y, t = y_new, t_new
        x_new, s_new = y[:n] * xs, float(y[n] * ss)
        if it <= o.easy_iter:
            h = min(h * 1.5, o.step_max)
        elif it > o.easy_iter + 3:
            h = max(h * 0.6, o.step_min)
        extend([ContinuationPoint(x_new, s_new, t.copy(), it, res, _on_grid(s_new, o.grid))])
    if on_end is not None:
        on_end(reason, pts[-1])
    return pts


def _ends(p: ContinuationPoint, pts: list[ContinuationPoint], lo: float, hi: float, stop,
          closes: _LoopDetector) -> str | None:
    """Why the branch ends at its new point p: 'bound' (p on a bound of the range), 'stop'
    (``stop(p, pts)``) or 'closed' (the loop detector); None where it goes on."""
    if p.s >= hi - 1e-9 or p.s <= lo + 1e-9:
        return 'bound'
    if stop is not None and stop(p, pts):
        return 'stop'
    if closes(p):
        return 'closed'
    return None


def _jump(problem, y, t, xs, ss, o: ContinuationOptions):
    """Try arc steps of growing length along t with relaxed checks (passing a branch point)."""
    for hj in (0.05, 0.2, 0.5):
        y_pred = y + hj * t
        try:
            y_new, it, res, jac = correct(problem, y_pred, t, xs, ss, o.tol, o.max_iter)
        except CorrectorFailed:
            continue
        if np.linalg.norm(y_new - y_pred) > hj:
            continue
        secant = y_new - y
        t_new = tangent_of(problem, jac[1], jac[2], secant / np.linalg.norm(secant), xs, ss)
        return y_new, it, res, t_new
    return None


def on_grid(s: float, grid: float) -> bool:
    """Whether the parameter s lies on the grid of spacing ``grid`` (within 1e-7 of s). Written
    once: the compiled grid steps use this function, compiled
    (:mod:`dmf_sim.solvers.hbm.continuation_kernels`)."""
    k = round(s / grid)
    return abs(s - k * grid) < 1e-7 * max(1.0, abs(s))


def next_grid(s: float, sign: float, grid: float) -> float:
    """The next grid value beyond s in the direction ``sign`` (a value within 1e-7 grid spacings
    of a grid value counts as on it). Compiled for the grid steps as :func:`on_grid` is."""
    k = s / grid
    if sign > 0:
        nxt = math.floor(k + 1e-7) + 1
    else:
        nxt = math.ceil(k - 1e-7) - 1
    return nxt * grid


def _on_grid(s: float, grid: float | None) -> bool:
    return grid is not None and on_grid(s, grid)
