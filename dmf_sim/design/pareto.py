"""Non-dominated designs (Pareto front) of minimized objectives, and a compromise choice."""
from __future__ import annotations

import numpy as np

__all__ = ['pareto_mask', 'compromise']


def _matrix(objectives) -> np.ndarray:
    """The objective columns as an (n_points, n_objectives) float array."""
    cols = [np.asarray(f, dtype=float) for f in objectives]
    return np.stack(cols, axis=1) if cols else np.zeros((0, 0))


def pareto_mask(*objectives) -> np.ndarray:
    """True for the points no other point dominates (<= in every objective, < in one); the
    arguments are the objective columns (two or more, equally long).

    A point with an undefined (NaN) objective is never on the front: e.g. a design without any
    stable state has no worst amplitude. Identical points are all non-dominated.
    Two objectives: O(n log n) (sort by (f1, f2), keep the running minimum of f2); more:
    O(n^2) pairwise comparisons, vectorized over the points."""
    f = _matrix(objectives)
    n = len(f)
    valid = ~np.isnan(f).any(axis=1) if n else np.zeros(0, dtype=bool)
    mask = np.zeros(n, dtype=bool)
    if f.shape[1] == 2:
        a, b = f[:, 0], f[:, 1]
        best_b, best_a = np.inf, np.nan
        for i in (i for i in np.lexsort((b, a)) if valid[i]):
            if b[i] < best_b:
                mask[i] = True
                best_b, best_a = b[i], a[i]
            elif b[i] == best_b and a[i] == best_a:
                mask[i] = True
        return mask
    idx = np.flatnonzero(valid)
    g = f[idx]
    for k, i in enumerate(idx):
        le = np.all(g <= g[k], axis=1)
        lt = np.any(g < g[k], axis=1)
        mask[i] = not np.any(le & lt)
    return mask


def compromise(objectives, mask) -> int:
    """Index of the front design nearest the ideal point: smallest sum of the objectives (the
    columns in ``objectives``), each scaled to 0..1 over the points where all are defined (the
    'best' design of the plots)."""
    f = _matrix(objectives)
    valid = np.isfinite(f).all(axis=1)
    score = np.zeros(len(f))
    for col in f.T:
        fin = col[valid]
        span = (fin.max() - fin.min()) if len(fin) else 1.0
        score = score + (col - (fin.min() if len(fin) else 0.0)) / (span if span > 0 else 1.0)
    score = np.where(mask, score, np.inf)
    return int(np.argmin(np.where(np.isnan(score), np.inf, score)))
