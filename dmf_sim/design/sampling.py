"""Design samples: a full grid, uniform random samples, or a Latin hypercube (scipy.stats.qmc).

Every method returns an (n_designs, n_variables) array of values in the variables' ranges, in a
fixed order for a given study (random and Latin-hypercube samples are seeded), so the design
numbers of a study are the same in every run: that is what lets an interrupted study resume.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

__all__ = ['METHODS', 'VariableRange', 'grid', 'uniform_random', 'latin_hypercube']

METHODS = ('grid', 'random', 'lhs')


@dataclass(frozen=True)
class VariableRange:
    """A design variable's range: ``values`` (grid levels) or ``low``..``high`` (SI units)."""

    name: str
    low: float
    high: float
    values: tuple[float, ...] = ()

    def levels(self, n: int) -> np.ndarray:
        """Grid levels: the given values, or ``n`` points from low to high inclusive."""
        if self.values:
            return np.asarray(self.values, dtype=float)
        return np.linspace(self.low, self.high, n)


def grid(ranges: list[VariableRange], points: list[int]) -> np.ndarray:
    """Full factorial grid; the last variable varies fastest."""
    levels = [r.levels(n) for r, n in zip(ranges, points)]
    return np.array(list(itertools.product(*levels)), dtype=float).reshape(-1, len(ranges))


def uniform_random(ranges: list[VariableRange], n: int, seed: int) -> np.ndarray:
    """``n`` independent uniform samples in the box."""
    u = np.random.default_rng(seed).random((n, len(ranges)))
    return _scale(u, ranges)


def latin_hypercube(ranges: list[VariableRange], n: int, seed: int) -> np.ndarray:
    """``n`` Latin-hypercube samples (one per stratum and variable), scipy.stats.qmc."""
    from scipy.stats import qmc
    u = qmc.LatinHypercube(d=len(ranges), seed=np.random.default_rng(seed)).random(n)
    return _scale(u, ranges)


def _scale(u: np.ndarray, ranges: list[VariableRange]) -> np.ndarray:
    lo = np.array([r.low for r in ranges])
    hi = np.array([r.high for r in ranges])
    return lo + u * (hi - lo)
