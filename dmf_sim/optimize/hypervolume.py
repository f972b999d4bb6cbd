"""Hypervolume of two minimized objectives: the area dominated by a set of points and bounded by
a reference point (the usual quality measure of a Pareto front: larger is better)."""
from __future__ import annotations

import math

import numpy as np

__all__ = ['hypervolume', 'hypervolume_history']


def hypervolume(f1, f2, ref: tuple[float, float]) -> float:
    """Area dominated by the points (f1, f2) inside the box below ``ref`` (both minimized).
    Points not strictly below the reference in both objectives, or undefined, add nothing."""
    a = np.asarray(f1, dtype=float)
    b = np.asarray(f2, dtype=float)
    r1, r2 = ref
    if not (math.isfinite(r1) and math.isfinite(r2)):
        return 0.0
    ok = np.isfinite(a) & np.isfinite(b) & (a < r1) & (b < r2)
    a, b = a[ok], b[ok]
    area, best_b = 0.0, r2
    for i in np.lexsort((b, a)):           # ascending f1; sweep the staircase
        if b[i] < best_b:
            area += (r1 - a[i]) * (best_b - b[i])
            best_b = b[i]
    return float(area)


def hypervolume_history(f1, f2, valid, ref: tuple[float, float]) -> np.ndarray:
    """Hypervolume of the valid (feasible) points among the first i points, i = 1..n (in
    evaluation order): the convergence curve."""
    a = np.asarray(f1, dtype=float)
    b = np.asarray(f2, dtype=float)
    v = np.asarray(valid, dtype=bool)
    out = np.zeros(len(a))
    keep = []
    last = 0.0
    for i in range(len(a)):
        if v[i]:
            keep.append(i)
            last = hypervolume(a[keep], b[keep], ref)
        out[i] = last
    return out
