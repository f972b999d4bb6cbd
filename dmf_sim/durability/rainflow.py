"""Rainflow counting of a signal that arrives in batches (ASTM E1049-85), with ``fatpack``.

The four-point rainflow pass (``fatpack.find_rainflow_cycles``) extracts a closed cycle as soon
as the reversals around it are known and leaves a residue; running it on (residue + the next
reversals) continues exactly where it stopped. So a record of any length is counted batch by
batch with memory bounded by the residue (a handful of reversals for a bounded signal), never
the whole record. At the end the residue counts as half cycles (0.5 each, consecutive residue
points), as ASTM E1049-85 counts what stays open. ASTM's three-point method (5.4.4) treats the
record's start a little differently (a range holding the first point is a half cycle at once),
so a few half cycles of the residue pair up differently: the number of cycles is the same and
the damage agrees to ~0.1 % on a random walk (tests: batch-size invariance, closed-form cases,
the three-point method written out).

Reversals (turning points) are found here, exactly (no level classes): the first and last
samples of the record are reversals, repeated values are one point.
"""
from __future__ import annotations

import numpy as np

from dmf_sim.core.optional import require

fatpack = require('fatpack')

__all__ = ['StreamingRainflow', 'count_cycles']


class StreamingRainflow:
    """Feed batches with :meth:`add`; each call returns the cycles it closed as arrays
    (ranges, means, counts) -- full cycles here; :meth:`finish` returns the residue's half
    cycles."""

    def __init__(self) -> None:
        self._residue = np.zeros(0)
        self._pend: float | None = None     # last sample, not yet known to be a reversal
        self._dir = 0                        # direction into the pending sample (0: start)
        self.reversals = 0

    def _reversals(self, y: np.ndarray) -> np.ndarray:
        y = np.asarray(y, dtype=float)
        if self._pend is not None:
            y = np.concatenate(([self._pend], y))
        if len(y) == 0:
            return y
        keep = np.concatenate(([True], np.diff(y) != 0))
        y = y[keep]
        if len(y) == 1:
            self._pend = float(y[0])
            return np.zeros(0)
        d = np.sign(np.diff(y))
        into = np.concatenate(([self._dir], d[:-1]))     # direction into points 0..len-2
        rev = y[:-1][into != d]
        self._pend, self._dir = float(y[-1]), int(d[-1])
        return rev

    @staticmethod
    def _cycles(pairs: np.ndarray, count: float):
        if len(pairs) == 0:
            return np.zeros(0), np.zeros(0), np.zeros(0)
        pairs = np.asarray(pairs, dtype=float).reshape(-1, 2)
        return (np.abs(pairs[:, 1] - pairs[:, 0]), pairs.mean(axis=1),
                np.full(len(pairs), count))

    def add(self, y: np.ndarray):
        """Count a batch; returns (ranges, means, counts) of the cycles closed by it."""
        rev = self._reversals(y)
        self.reversals += len(rev)
        if len(rev) == 0:
            return self._cycles(np.zeros((0, 2)), 1.0)
        cycles, residue = fatpack.find_rainflow_cycles(np.concatenate((self._residue, rev)))
        self._residue = np.asarray(residue, dtype=float)
        return self._cycles(cycles, 1.0)

    def finish(self):
        """The end of the record: the last sample is a reversal; the residue's consecutive
        points are half cycles. Returns (ranges, means, counts)."""
        ranges, means, counts = self.add(np.zeros(0))
        tail = self._residue
        if self._pend is not None:
            tail = np.concatenate((tail, [self._pend]))
            self.reversals += 1
            self._pend = None
        self._residue = np.zeros(0)
        if len(tail) < 2:
            return ranges, means, counts
        half = np.stack((tail[:-1], tail[1:]), axis=1)
        r, m, c = self._cycles(half, 0.5)
        return (np.concatenate((ranges, r)), np.concatenate((means, m)),
                np.concatenate((counts, c)))


def count_cycles(y: np.ndarray, batch: int | None = None):
    """Rainflow cycles of a whole signal (optionally fed in batches of ``batch`` samples):
    (ranges, means, counts)."""
    rf = StreamingRainflow()
    out = []
    y = np.asarray(y, dtype=float)
    step = len(y) if not batch else int(batch)
    for i in range(0, len(y), max(step, 1)):
        out.append(rf.add(y[i:i + step]))
    out.append(rf.finish())
    return tuple(np.concatenate([o[k] for o in out]) for k in range(3))
