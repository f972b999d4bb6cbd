"""Hypervolume of minimized objectives: the volume dominated by a set of points and bounded by a
reference point (the usual quality measure of a Pareto front: larger is better).

Two objectives: the area under the staircase of the front. More: the slicing of the
"hypervolume by slicing objectives" algorithm (L. While, P. Hingston, L. Barone, S. Huband, "A
faster algorithm for calculating hypervolume", IEEE Trans. Evol. Comput. 10(1), 2006): the
points sorted by the last objective, each slab between two successive values is the
(m-1)-objective hypervolume of the points below it times the slab's thickness; the points are
first reduced to their non-dominated set (exact, and small for the fronts compared here)."""
from __future__ import annotations

import numpy as np

from dmf_sim.design.pareto import pareto_mask

__all__ = ['hypervolume', 'hypervolume_history']


def _points(points, n_obj: int) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    return p.reshape(-1, n_obj) if p.size else np.zeros((0, n_obj))


def hypervolume(points, ref) -> float:
    """Volume dominated by ``points`` ((n, m) objective values, all minimized) inside the box
    below ``ref`` (m values). Points not strictly below the reference in every objective, or
    undefined, add nothing."""
    r = np.asarray(ref, dtype=float)
    if not np.all(np.isfinite(r)):
        return 0.0
    p = _points(points, len(r))
    ok = np.all(np.isfinite(p), axis=1) & np.all(p < r, axis=1)
    p = p[ok]
    if not len(p):
        return 0.0
    return float(_volume(p[pareto_mask(*p.T)] if len(r) > 2 else p, r))


def _volume(p: np.ndarray, r: np.ndarray) -> float:
    """Hypervolume of points all strictly below ``r`` (module docstring)."""
    if len(r) == 2:
        area, best_b = 0.0, r[1]
        for i in np.lexsort((p[:, 1], p[:, 0])):       # ascending f1; sweep the staircase
            if p[i, 1] < best_b:
                area += (r[0] - p[i, 0]) * (best_b - p[i, 1])
                best_b = p[i, 1]
        return area
    order = np.argsort(p[:, -1], kind='stable')
    p = p[order]
    z = np.append(p[:, -1], r[-1])
    total = 0.0
    for i in range(len(p)):
        depth = z[i + 1] - z[i]
        if depth > 0:
            below = p[:i + 1, :-1]
            if len(r) > 3:
                below = below[pareto_mask(*below.T)]
            total += depth * _volume(below, r[:-1])
    return total


def hypervolume_history(points, valid, ref) -> np.ndarray:
    """Hypervolume of the valid (feasible) points among the first i points, i = 1..n (in
    evaluation order): the convergence curve. ``points``: (n, m) objective values. A point
    dominated (weakly) by one kept before, or undefined, leaves the hypervolume as it was."""
    r = np.asarray(ref, dtype=float)
    p = _points(points, len(r))
    v = np.asarray(valid, dtype=bool)
    out = np.zeros(len(p))
    front = np.zeros((0, len(r)))
    last = 0.0
    for i in range(len(p)):
        if v[i] and np.isfinite(p[i]).all() and not np.any(np.all(front <= p[i], axis=1)):
            front = np.vstack([front, p[i]])
            front = front[pareto_mask(*front.T)]
            last = hypervolume(front, r)
        out[i] = last
    return out
