"""Non-dominated designs (Pareto front) of two minimized objectives, and a compromise choice."""
from __future__ import annotations

import numpy as np

__all__ = ['pareto_mask', 'compromise']


def pareto_mask(f1, f2) -> np.ndarray:
    """True for the points no other point dominates (<= in both objectives, < in one).

    A point with an undefined (NaN) objective is never on the front: e.g. a design without any
    stable state has no worst amplitude. Identical points are all non-dominated.
    O(n log n): sort by (f1, f2), keep the running minimum of f2."""
    a = np.asarray(f1, dtype=float)
    b = np.asarray(f2, dtype=float)
    valid = ~(np.isnan(a) | np.isnan(b))
    order = [i for i in np.lexsort((b, a)) if valid[i]]
    mask = np.zeros(len(a), dtype=bool)
    best_b, best_a = np.inf, np.nan
    for i in order:
        if b[i] < best_b:
            mask[i] = True
            best_b, best_a = b[i], a[i]
        elif b[i] == best_b and a[i] == best_a:
            mask[i] = True
    return mask


def compromise(f1, f2, mask) -> int:
    """Index of the front design nearest the ideal point: smallest sum of both objectives, each
    scaled to 0..1 over the points where both are defined (the 'best' design of the plots)."""
    valid = np.isfinite(np.asarray(f1, dtype=float)) & np.isfinite(np.asarray(f2, dtype=float))
    cols = []
    for f in (f1, f2):
        f = np.asarray(f, dtype=float)
        fin = f[valid]
        span = (fin.max() - fin.min()) if len(fin) else 1.0
        cols.append((f - (fin.min() if len(fin) else 0.0)) / (span if span > 0 else 1.0))
    score = np.where(mask, cols[0] + cols[1], np.inf)
    return int(np.argmin(np.where(np.isnan(score), np.inf, score)))
