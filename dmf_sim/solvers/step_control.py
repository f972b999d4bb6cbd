"""The step control of the speed continuation, written once: the decisions of
:func:`dmf_sim.solvers.continuation.continue_branch` — where the output grid lies, whether the
next step lands on a grid speed, whether a corrected step is accepted, how the arc step grows or
shrinks — as small compiled functions (:func:`dmf_sim.core.compiled.jit`) that the Python loop
calls and that the compiled grid steps (:func:`dmf_sim.solvers.hbm.continuation_kernels.grid_run`)
call inside their own loop, so both take every step the same way by construction.

All lengths are in the continuation's scaled units (one arc unit ~ ``s_scale`` in speed or
``x_scale`` in the unknowns; :class:`~dmf_sim.solvers.continuation.ContinuationOptions`).
"""
from __future__ import annotations

import math

from dmf_sim.core.compiled import jit

__all__ = ['ON_GRID_REL', 'GRID_SNAP', 'GRID_STEP_MAX', 'GRID_STEP_GROWTH', 'GROW', 'SHRINK',
           'HARD_EXTRA_ITER', 'BOUND_TOL', 'STEP_MIN_MARGIN', 'RETRY_ARC', 'RETRY_HALF', 'JUMP',
           'on_grid', 'next_grid', 'grid_step', 'moved_too_far', 'tangent_turn',
           'turned_too_far', 'next_step', 'after_failure', 'on_bound']

ON_GRID_REL = 1e-7
"""A speed within this fraction of max(1, |s|) of a grid value lies on the grid."""
GRID_SNAP = 1e-7
"""A speed within this many grid spacings of a grid value counts as on it for the next one."""
GRID_STEP_MAX = 1.5
"""A grid step may be at most this many ``step_max`` long ..."""
GRID_STEP_GROWTH = 2.0
"""... and at most this many times the current arc step."""
GROW = 1.5
"""Arc-step factor after an easy corrector (at most ``easy_iter`` iterations)."""
SHRINK = 0.6
"""Arc-step factor after a hard corrector (more than ``easy_iter`` + :data:`HARD_EXTRA_ITER`)."""
HARD_EXTRA_ITER = 3
"""Iterations beyond ``easy_iter`` that make a corrector hard."""
BOUND_TOL = 1e-9
"""A point within this [speed unit] of a bound of the range lies on it."""
STEP_MIN_MARGIN = 1.01
"""An arc step above ``step_min`` x this can still be halved."""

# what the loop does after a step it did not accept (:func:`after_failure`)
RETRY_ARC = 0      # a grid step failed: retry the same stretch with arc-length steps
RETRY_HALF = 1     # an arc-length step failed: retry with half the step
JUMP = 2           # the step cannot be made smaller: jump over a (near) branch point


def on_grid(s, grid):
    """Whether the parameter s lies on the grid of spacing ``grid`` (within
    :data:`ON_GRID_REL` x max(1, |s|) of a grid value)."""
    k = round(s / grid)
    return abs(s - k * grid) < ON_GRID_REL * max(1.0, abs(s))


def next_grid(s, sign, grid):
    """The next grid value beyond s in the direction ``sign`` (a value within
    :data:`GRID_SNAP` grid spacings of a grid value counts as on it)."""
    k = s / grid
    if sign > 0:
        nxt = math.floor(k + GRID_SNAP) + 1
    else:
        nxt = math.ceil(k - GRID_SNAP) - 1
    return nxt * grid


def grid_step(s, ts, h, lo, hi, grid, s_scale, step_max, min_ts):
    """Whether the step from speed s (scaled tangent component ``ts`` = dS/da, arc step h)
    lands on the next grid speed, and where: (grid mode, target speed, arc length h_grid to it).
    Grid mode needs |ts| >= ``min_ts`` (away from turning points) and 0 < h_grid <=
    min(:data:`GRID_STEP_MAX` x step_max, :data:`GRID_STEP_GROWTH` x h); the target is the next
    grid speed along the tangent, clipped to [lo, hi]. (False, nan, nan) when |ts| < min_ts."""
    if not abs(ts) >= min_ts:
        return False, math.nan, math.nan
    target = next_grid(s, 1.0 if ts > 0 else -1.0, grid)
    target = min(max(target, lo), hi)
    h_grid = (target - s) / s_scale / ts
    return 0.0 < h_grid <= min(GRID_STEP_MAX * step_max, GRID_STEP_GROWTH * h), target, h_grid


def moved_too_far(moved, step_len, max_correction, step_min):
    """Whether the corrector moved farther than ``max_correction`` x max(step, step_min) from
    the prediction (``moved``: that distance): converged maybe onto another branch."""
    return moved > max_correction * max(step_len, step_min)


def tangent_turn(dot):
    """The angle [rad] between two unit tangents with the scalar product ``dot``."""
    return math.acos(min(max(dot, -1.0), 1.0))


def turned_too_far(turn, grid_mode, h, max_turn, step_min):
    """Whether a step whose tangent turned by ``turn`` [rad] is refused: more than
    ``max_turn``, unless an arc-length step is already at ``step_min`` (a grid step is always
    refused)."""
    return turn > max_turn and (grid_mode or h > step_min * STEP_MIN_MARGIN)


def next_step(h, iterations, easy_iter, step_min, step_max):
    """The arc step after an accepted step of ``iterations`` corrector iterations: x
    :data:`GROW` (at most step_max) after an easy one, x :data:`SHRINK` (at least step_min) after
    a hard one, else h."""
    if iterations <= easy_iter:
        return min(h * GROW, step_max)
    if iterations > easy_iter + HARD_EXTRA_ITER:
        return max(h * SHRINK, step_min)
    return h


def after_failure(h, h_grid, grid_mode, step_min):
    """What to do after a step not accepted: (action, new arc step). A grid step is retried
    with arc-length steps (:data:`RETRY_ARC`, h at most half the grid step), an arc-length step
    with half the step (:data:`RETRY_HALF`) while it is above step_min, else :data:`JUMP`
    (h unchanged)."""
    if grid_mode:
        return RETRY_ARC, max(min(h, 0.5 * h_grid), step_min)
    if h > step_min * STEP_MIN_MARGIN:
        return RETRY_HALF, max(h * 0.5, step_min)
    return JUMP, h


def on_bound(s, lo, hi):
    """Whether speed s lies on a bound of the range [lo, hi] (within :data:`BOUND_TOL`)."""
    return s >= hi - BOUND_TOL or s <= lo + BOUND_TOL


on_grid = jit(on_grid)
next_grid = jit(next_grid)
grid_step = jit(grid_step)
moved_too_far = jit(moved_too_far)
tangent_turn = jit(tangent_turn)
turned_too_far = jit(turned_too_far)
next_step = jit(next_step)
after_failure = jit(after_failure)
on_bound = jit(on_bound)
