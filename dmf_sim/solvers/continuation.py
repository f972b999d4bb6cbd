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

Step control (:mod:`dmf_sim.solvers.step_control`, compiled, shared with the compiled grid
steps): the step h grows after easy corrections (few Newton iterations) and is halved after a
failed one or a sharp turn of the tangent, between ``step_min`` and ``step_max``.

The caller hands :func:`continue_branch` a :class:`BranchStart`, the options and a
:class:`BranchHooks` (its callbacks, and the problem's compiled steps, :class:`CompiledSteps`):
the contract of each is in its docstring.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, NamedTuple, Protocol

import numpy as np
from scipy.linalg.lapack import dgesv

from dmf_sim.core.errors import OperatingRangeError

__all__ = ['solve_small', 'ContinuationProblem', 'ContinuationOptions', 'ContinuationPoint',
           'Corrected', 'Step', 'GridRun', 'CompiledSteps', 'BranchStart', 'BranchHooks',
           'CorrectorFailed', 'LeftRange', 'correct', 'tangent_of', 'correct_step',
           'continue_branch']


def _step_control():
    """:mod:`dmf_sim.solvers.step_control`, imported when a branch is continued: it is
    compiled (numba), and importing this module (``dmf-sim --help``, ``import dmf_sim``) must
    not load numba."""
    from dmf_sim.solvers import step_control
    return step_control


def __getattr__(name: str):
    if name in ('next_grid', 'on_grid'):          # re-exported from the step control
        return getattr(_step_control(), name)
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')


def solve_small(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """LU solve (LAPACK dgesv directly: these systems are small and solved very often)."""
    _, _, x, info = dgesv(A, b)
    if info != 0:
        raise np.linalg.LinAlgError('singular matrix')
    return x




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
    """A point of a branch: unknowns x and parameter s, the unit tangent in scaled coordinates
    (last entry: dS/da), the corrector's iterations and max|r|, whether s lies on the output
    grid, and ``point``: the caller's own finished point where a fast-forward made it (else
    None)."""

    x: np.ndarray
    s: float
    tangent: np.ndarray
    iterations: int
    residual: float
    on_grid: bool
    point: object = None


class ContinuationProblem(Protocol):
    """What :func:`continue_branch` asks of a problem r(x, s) = 0.

    1. ``residual_and_jacobians(x, s)`` returns (r, dr/dx, dr/ds) at unknowns x and parameter s
       (r of the length of x, dr/dx square, dr/ds a vector), unscaled.
    2. It raises :class:`dmf_sim.core.errors.OperatingRangeError` for a parameter outside the
       problem's data (the branch then ends with 'left_range'), nothing else for a bad point
       (a non-finite r makes the corrector fail and the step shrink).
    3. It does not keep state between calls that changes its answers: the continuation may ask
       the same point twice and any point in any order.
    4. A problem with compiled versions of the steps hands them over in :class:`CompiledSteps`
       (in :class:`BranchHooks`); the continuation never looks for them on the problem.
    """

    def residual_and_jacobians(self, x: np.ndarray, s: float
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(r, dr/dx, dr/ds)."""


class Corrected(NamedTuple):
    """A converged corrector: scaled point y = [x / x_scale, s / s_scale], iterations, max|r|,
    and (r, dr/dx, dr/ds) there."""

    y: np.ndarray
    iterations: int
    residual: float
    jacobians: tuple


class Step(NamedTuple):
    """A corrected step and its unit tangent (None where the tangent's system is singular)."""

    y: np.ndarray
    iterations: int
    residual: float
    tangent: np.ndarray | None


class GridRun(NamedTuple):
    """Grid steps taken in one compiled call (:attr:`CompiledSteps.grid_run`): the new points'
    rows (x [unknown units], s [parameter units], unit tangent, iterations, max|r|, on the grid)
    and the state after the last one (scaled point y, tangent t, arc step h), and why the run
    stopped (a ``RUN_*`` code of :mod:`dmf_sim.solvers.hbm.continuation_kernels`)."""

    x: np.ndarray
    s: np.ndarray
    tangent: np.ndarray
    iterations: np.ndarray
    residual: np.ndarray
    on_grid: np.ndarray
    y: np.ndarray
    t: np.ndarray
    h: float
    why: int


@dataclass(frozen=True)
class CompiledSteps:
    """A problem's own (compiled) versions of the continuation's steps; a field left None, or a
    call that returns None, means the reference in this module is used.

    1. ``tangent(Jx, rs, prev, xs, ss)`` is :func:`_tangent`: the unit tangent oriented along
       ``prev``; raises numpy's LinAlgError on a singular system.
    2. ``corrector_at(y_pred, xs, ss, tol, max_iter)`` is :func:`correct` with the normal e_S
       (s fixed on a grid value) and ``corrector_arc(y_pred, normal, xs, ss, tol, max_iter)``
       with any other normal: each returns a :class:`Corrected` (or a tuple in its order),
       raises :class:`CorrectorFailed` when it does not converge and OperatingRangeError for a
       parameter outside the data.
    3. ``step_at(y_pred, prev, xs, ss, tol, max_iter)`` is ``corrector_at`` and then ``tangent``
       in one call: a :class:`Step`, its tangent None on a singular system.
    4. ``grid_run(s, y, t, h, s_bounds, options, check_linear, budget)`` takes the grid step the
       loop of :func:`continue_branch` has chosen and the grid steps after it, each as the loop
       takes it (the decisions of :mod:`dmf_sim.solvers.step_control`), and returns a
       :class:`GridRun` before any other step: at every on-grid point where the fast-forward may
       apply (``check_linear``), before an arc-length step, before a step it would not accept
       as it stands, after a point on a bound and after ``budget`` steps.
    5. Each gives the reference's result to the tolerance its parity test states
       (:mod:`dmf_sim.solvers.kernel_registry`); ``grid_run`` the loop's points bitwise.
    """

    tangent: Callable | None = None
    corrector_at: Callable | None = None
    corrector_arc: Callable | None = None
    step_at: Callable | None = None
    grid_run: Callable | None = None


@dataclass(frozen=True)
class BranchStart:
    """Where :func:`continue_branch` starts: the converged solution x0 at parameter s0, the
    parameter range ``s_bounds`` (lo, hi) and the direction (+1 / -1: toward higher / lower s;
    ignored when ``tangent0``, the first tangent's orientation in scaled coordinates, is
    given)."""

    x0: np.ndarray
    s0: float
    s_bounds: tuple[float, float]
    direction: float = 1.0
    tangent0: np.ndarray | None = None


@dataclass(frozen=True)
class BranchHooks:
    """What :func:`continue_branch` tells the caller and asks of it during a branch (each
    optional).

    1. ``on_point(point)`` is called with every new point, the first one included, before the
       end tests.
    2. ``stop(point, points)`` returning True ends the branch at that point (reason 'stop').
    3. ``fast_forward(point, sign)``, called at on-grid points away from turning points, may
       return further grid points (in the direction ``sign`` of s) whose solutions it knows
       without iterating; the last one must carry the exact tangent; it must return none where
       the problem's non-linear part is active (where ``steps.grid_run`` would not stop).
    4. ``on_end(reason, last_point)`` is told why the branch ended (see :func:`continue_branch`).
    5. ``steps``: the problem's compiled steps (:class:`CompiledSteps`).
    """

    stop: Callable[[ContinuationPoint, list[ContinuationPoint]], bool] | None = None
    on_point: Callable[[ContinuationPoint], None] | None = None
    fast_forward: Callable[[ContinuationPoint, float], list[ContinuationPoint]] | None = None
    on_end: Callable[[str, ContinuationPoint], None] | None = None
    steps: CompiledSteps = field(default_factory=CompiledSteps)


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


def tangent_of(Jx: np.ndarray, rs: np.ndarray, prev: np.ndarray, xs: float, ss: float,
               steps: CompiledSteps | None = None) -> np.ndarray:
    """:func:`_tangent`, by the problem's compiled ``steps.tangent`` where it has one (None
    from it: :func:`_tangent`)."""
    own = steps.tangent if steps is not None else None
    t = own(Jx, rs, prev, xs, ss) if own is not None else None
    return _tangent(Jx, rs, prev, xs, ss) if t is None else t


def _evaluate(problem: ContinuationProblem, x: np.ndarray, s: float):
    """problem.residual_and_jacobians, with a parameter outside the problem's data as LeftRange."""
    try:
        return problem.residual_and_jacobians(x, s)
    except OperatingRangeError as exc:
        raise LeftRange(f'parameter {s:g} outside the data: {exc}') from None


def _is_e_s(normal: np.ndarray) -> bool:
    """Whether ``normal`` is e_S (the last unit vector: s fixed)."""
    n = len(normal) - 1
    return bool(normal[n] == 1.0 and not np.any(normal[:n]))


def correct(problem: ContinuationProblem, y_pred: np.ndarray, normal: np.ndarray,
            xs: float, ss: float, tol: float, max_iter: int,
            steps: CompiledSteps | None = None) -> Corrected:
    """Newton on [r(x, s); normal . (y - y_pred)] = 0 in scaled coordinates.

    The problem's compiled corrector does the whole iteration in one call where ``steps`` has
    one (each returns None to use this one): ``steps.corrector_at`` with the normal e_S (s fixed
    on a grid speed), ``steps.corrector_arc`` with any other normal."""
    y = y_pred.copy()
    n = len(y) - 1
    fixed_s = _is_e_s(normal)
    steps = steps or _NO_STEPS
    if fixed_s:
        compiled = steps.corrector_at
        args = (y_pred, xs, ss, tol, max_iter)
    else:
        compiled = steps.corrector_arc
        args = (y_pred, normal, xs, ss, tol, max_iter)
    if compiled is not None:        # the problem's own compiled corrector
        try:
            out = compiled(*args)
        except OperatingRangeError as exc:
            raise LeftRange(f'parameter {y_pred[n] * ss:g} outside the data: {exc}') from None
        if out is not None:
            return Corrected(*out)
    A = np.empty((n + 1, n + 1))
    res = np.inf
    for it in range(max_iter + 1):
        x, s = y[:n] * xs, y[n] * ss
        r, Jx, rs = _evaluate(problem, x, s)
        res = float(np.abs(r).max())
        g = float(normal @ (y - y_pred))
        if res <= tol and abs(g) <= 1e-12:
            return Corrected(y, it, res, (r, Jx, rs))
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
            return Corrected(y, it + 1, float(np.abs(r).max()), (r, Jx, rs))
    raise CorrectorFailed.not_converged(res, max_iter)


def correct_step(problem: ContinuationProblem, y_pred: np.ndarray, normal: np.ndarray,
                 prev: np.ndarray, xs: float, ss: float, tol: float, max_iter: int,
                 fixed_s: bool | None = None, steps: CompiledSteps | None = None) -> Step:
    """:func:`correct`, then the unit tangent there oriented along ``prev`` (:func:`tangent_of`),
    the tangent None where its system is singular (the caller decides: continue_branch first
    checks how far the corrector moved). With the normal e_S the problem's ``steps.step_at``
    does both in one compiled call (None from it: the two calls). ``fixed_s``: whether
    ``normal`` is e_S, if the caller knows."""
    if fixed_s is None:
        fixed_s = _is_e_s(normal)
    steps = steps or _NO_STEPS
    if fixed_s and steps.step_at is not None:
        out = steps.step_at(y_pred, prev, xs, ss, tol, max_iter)
        if out is not None:
            return Step(*out)
    y, it, res, (r, Jx, rs) = correct(problem, y_pred, normal, xs, ss, tol, max_iter, steps)
    try:
        t = tangent_of(Jx, rs, prev, xs, ss, steps)
    except np.linalg.LinAlgError:
        t = None
    return Step(y, it, res, t)


_NO_STEPS = CompiledSteps()


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


class _Branch:
    """The points of a branch being followed, and why it ended: appending a point tells the
    caller (``hooks.on_point``) and runs the end tests (:meth:`_ends`)."""

    def __init__(self, first: ContinuationPoint, s_bounds: tuple[float, float],
                 hooks: BranchHooks, closes: _LoopDetector):
        self.points = [first]
        self.lo, self.hi = s_bounds
        self.hooks = hooks
        self.closes = closes
        self.done = False
        self.reason = 'max_steps'
        if hooks.on_point:
            hooks.on_point(first)

    def extend(self, new) -> int:
        """Append the new points in turn (on_point, then the end tests) until the branch ends;
        how many were appended."""
        for k, p in enumerate(new):
            self.points.append(p)
            if self.hooks.on_point:
                self.hooks.on_point(p)
            why = self._ends(p)
            if why is not None:
                self.done, self.reason = True, why
                return k + 1
        return len(new)

    def _ends(self, p: ContinuationPoint) -> str | None:
        """Why the branch ends at its new point p: 'bound' (p on a bound of the range), 'stop'
        (``hooks.stop(p, points)``) or 'closed' (the loop detector); None where it goes on."""
        if _step_control().on_bound(p.s, self.lo, self.hi):
            return 'bound'
        if self.hooks.stop is not None and self.hooks.stop(p, self.points):
            return 'stop'
        if self.closes(p):
            return 'closed'
        return None


def continue_branch(problem: ContinuationProblem, start: BranchStart,
                    options: ContinuationOptions | None = None,
                    hooks: BranchHooks | None = None) -> list[ContinuationPoint]:
    """Follow the solution branch through (start.x0, start.s0) (a converged solution) until s
    leaves ``start.s_bounds``, ``hooks.stop(point, branch)`` returns True, or ``max_steps``.

    The last point of a branch that reaches a bound lies exactly on the bound. Every decision
    of the step control (grid step or arc-length step, accepted or not, the next step size) is
    a function of :mod:`dmf_sim.solvers.step_control`, which the problem's compiled grid runs
    (``hooks.steps.grid_run``, :class:`CompiledSteps`) call too.
    ``hooks.on_end(reason, last_point)`` is told why the branch ended: 'bound' (s reached a
    bound), 'stop', 'closed' (the branch came back onto its own earlier part: see
    ``ContinuationOptions.loop_skip``), 'left_range' (the corrector needed parameters outside
    the problem's data), 'corrector_failed' (no step, however small, converged) or
    'max_steps'.
    """
    sc = _step_control()
    o = options or ContinuationOptions()
    hooks = hooks or BranchHooks()
    steps = hooks.steps
    xs, ss = o.x_scale, o.s_scale
    s_bounds = start.s_bounds
    lo, hi = float(s_bounds[0]), float(s_bounds[1])
    step_min, step_max = float(o.step_min), float(o.step_max)
    x0, s0 = np.asarray(start.x0, float), start.s0
    n = len(x0)
    y = np.concatenate([x0 / xs, [s0 / ss]])
    r, Jx, rs = problem.residual_and_jacobians(x0, s0)
    if start.tangent0 is None:
        prev = np.zeros(n + 1)
        prev[n] = 1.0 if start.direction >= 0 else -1.0
    else:
        prev = np.asarray(start.tangent0, float)
    t = tangent_of(Jx, rs, prev, xs, ss, steps)
    branch = _Branch(ContinuationPoint(x0.copy(), float(s0), t, 0, float(np.abs(r).max()),
                                       _on_grid(s0, o.grid)), (lo, hi), hooks, _LoopDetector(y, o))
    pts = branch.points
    h = o.step
    e_s = np.zeros(n + 1)
    e_s[n] = 1.0
    fast_forward = hooks.fast_forward
    run = steps.grid_run if o.grid is not None else None
    force_arc = False
    last_failure: CorrectorFailed | None = None
    count = 0
    while count < o.max_steps and not branch.done:
        count += 1
        s = pts[-1].s
        if (fast_forward is not None and pts[-1].on_grid and not force_arc
                and abs(t[n]) >= o.grid_mode_min_ts):
            jump = fast_forward(pts[-1], 1.0 if t[n] > 0 else -1.0)
            branch.extend(jump)
            if jump:
                y = np.concatenate([pts[-1].x / xs, [pts[-1].s / ss]])
                t = pts[-1].tangent if pts[-1].tangent @ t > 0 else -pts[-1].tangent
                continue
        # --- choose the step: land on the next grid speed, or a plain arc-length step ----------
        grid_mode = False
        if not force_arc and o.grid is not None:
            grid_mode, target, h_grid = sc.grid_step(float(s), float(t[n]), float(h), lo, hi,
                                                     float(o.grid), float(ss), step_max,
                                                     float(o.grid_mode_min_ts))
        if grid_mode and run is not None:
            # this grid step and those after it in one call, each as this loop takes it; the
            # call returns before any other step (none made: the loop takes this one itself)
            ran = run(s, y, t, h, s_bounds, o, fast_forward is not None, o.max_steps - count + 1)
            if ran is not None and len(ran.s):
                y, t, h = ran.y, ran.t, ran.h
                count += branch.extend([
                    ContinuationPoint(ran.x[k], float(ran.s[k]), ran.tangent[k],
                                      int(ran.iterations[k]), float(ran.residual[k]),
                                      bool(ran.on_grid[k]))
                    for k in range(len(ran.s))]) - 1
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
                                                 o.max_iter, normal is e_s, steps)
            step_len = abs(h_grid) if grid_mode else h
            moved = y_new - y_pred
            if sc.moved_too_far(math.sqrt(moved @ moved), float(step_len),
                                float(o.max_correction), step_min):
                # converged far from the prediction: maybe onto another branch (e.g. a grid
                # speed beyond a turning point); retry with a smaller arc-length step
                raise CorrectorFailed('corrector moved too far from the predictor')
            if t_new is None:
                raise np.linalg.LinAlgError('singular matrix')
            turn = sc.tangent_turn(float(t_new @ t))
            if sc.turned_too_far(turn, grid_mode, float(h), float(o.max_turn), step_min):
                raise CorrectorFailed(f'tangent turned by {turn:.2f} rad')
        except CorrectorFailed as exc:
            last_failure = exc
            action, h = sc.after_failure(float(h), h_grid if grid_mode else math.nan, grid_mode,
                                         step_min)
            if action == sc.RETRY_ARC:     # retry the same stretch with arc-length steps
                force_arc = True
                continue
            if action == sc.RETRY_HALF:
                continue
            # The step cannot be made small enough: a (near) branch point, where the tangent is
            # ill-defined. Jump over it along the last good tangent; orient the new tangent by
            # the secant. If that fails too, the branch ends here.
            jumped = _jump(problem, y, t, xs, ss, o, steps)
            if jumped is None:
                branch.reason = ('left_range' if isinstance(last_failure, LeftRange)
                                 else 'corrector_failed')
                break
            y_new, it, res, t_new = jumped
            h = o.step
        force_arc = False
        y, t = y_new, t_new
        x_new, s_new = y[:n] * xs, float(y[n] * ss)
        h = sc.next_step(float(h), int(it), int(o.easy_iter), step_min, step_max)
        branch.extend([ContinuationPoint(x_new, s_new, t.copy(), it, res,
                                         _on_grid(s_new, o.grid))])
    if hooks.on_end is not None:
        hooks.on_end(branch.reason, pts[-1])
    return pts


def _jump(problem, y, t, xs, ss, o: ContinuationOptions, steps: CompiledSteps) -> Step | None:
    """Try arc steps of growing length along t with relaxed checks (passing a branch point)."""
    for hj in (0.05, 0.2, 0.5):
        y_pred = y + hj * t
        try:
            y_new, it, res, jac = correct(problem, y_pred, t, xs, ss, o.tol, o.max_iter, steps)
        except CorrectorFailed:
            continue
        if np.linalg.norm(y_new - y_pred) > hj:
            continue
        secant = y_new - y
        t_new = tangent_of(jac[1], jac[2], secant / np.linalg.norm(secant), xs, ss, steps)
        return Step(y_new, it, res, t_new)
    return None


def _on_grid(s: float, grid: float | None) -> bool:
    return grid is not None and _step_control().on_grid(float(s), float(grid))
