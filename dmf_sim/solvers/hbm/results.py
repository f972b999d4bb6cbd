"""Results of harmonic balance speed sweeps: branches of steady states, events, the sweep
result."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dmf_sim.core.errors import ConvergenceError
from dmf_sim.solvers.hbm.condensed import CondensedHBM
from dmf_sim.solvers.hbm.faulted import fingerprints
from dmf_sim.solvers.hbm.point import HBMPoint

__all__ = ['Branch', 'SweepEvent', 'NonPeriodicBand', 'SweepResult', 'runs', 'on_grid',
           'UNREACHED',
           'instability_text']


@dataclass
class Branch:
    """A solution branch over speed.

    Attributes:
        id: 0 for the branch traced from the lowest speed, then further ones in the order found.
        kind: 'main' (traced from a speed-range end: the forced response, which can itself carry a
            1.5th-order hump where the bifurcation is imperfect), 'subharmonic' (found by branch
            switching, with a 1.5th-order resonance) or 'harmonic' (found by branch switching,
            without one).
        points: HBMPoints in continuation order (speed may go back and forth at turning points).
        origin: how the branch was found.
        multiplicity: how many 120 deg shifted copies of each state exist (2 for a 1.5th-order
            state: one physical state, reported once); 1 when the cylinders do not fire alike
            (faults: a shifted copy is no solution).
    """

    id: int
    kind: str
    points: list[HBMPoint]
    origin: str = ''
    multiplicity: int = 1

    def column(self, name: str) -> np.ndarray:
        """One quantity of every point: a summary field, 'speed_rpm', 'stable' or
        'max_multiplier'."""
        if name in ('speed_rpm', 'stable', 'max_multiplier'):
            return np.array([getattr(p, name) for p in self.points], dtype=float)
        return np.array([getattr(p.summary, name) for p in self.points], dtype=float)

    @property
    def speed_range(self) -> tuple[float, float]:
        s = self.column('speed_rpm')
        return float(s.min()), float(s.max())


@dataclass
class SweepEvent:
    """Something that happens along a branch: 'fold' (turning point: coexisting solutions beyond),
    'stability_loss' / 'stability_gain' (a Floquet multiplier crosses the unit circle; ``detail``
    says which kind), 'branch_switch' (a new branch seeded there)."""

    kind: str
    branch: int
    speed_rpm: float
    detail: str = ''

    def as_dict(self) -> dict:
        return {'kind': self.kind, 'branch': self.branch, 'speed_rpm': float(self.speed_rpm),
                'detail': self.detail}


UNREACHED = 'none'
"""The ``instability`` of speeds no periodic solution reached at all (the time integration
started from static equilibrium)."""


def instability_text(kind: str) -> str:
    """How the periodic state was lost, in words (what the sweep's messages say)."""
    if kind == UNREACHED:
        return 'no periodic solution reached this speed'
    return f'the periodic solution lost stability by a {kind} bifurcation'


@dataclass
class NonPeriodicBand:
    """Neighbouring speeds [rpm] where no periodic state is stable: what time integration shows
    there (``results``: dmf_sim.solvers.nonperiodic.NonPeriodicResult per speed), ``label``
    (quasi-periodic, chaotic, long transient, periodic of k cycles) and how the periodic solution
    lost stability (``instability``: torus, flip, fold, subharmonic, or :data:`UNREACHED`;
    :func:`instability_text` says it in words)."""

    speed_min_rpm: float
    speed_max_rpm: float
    label: str
    instability: str
    results: list = field(default_factory=list)
    half_width_rpm: float = 0.0       # half the spacing of the speeds checked (for shading)

    def rows(self, theta: float) -> list[dict]:
        out = []
        for r in self.results:
            d = r.as_dict()
            d.update(branch=-1, kind='non_periodic', stable=False, mean_minus_theta=r.mean - theta,
                     instability=self.instability)
            out.append(d)
        return out

    def as_dict(self) -> dict:
        return {'speed_min_rpm': float(self.speed_min_rpm),
                'speed_max_rpm': float(self.speed_max_rpm),
                'label': self.label, 'instability': self.instability,
                'envelope': [r.as_dict() for r in self.results]}


@dataclass
class SweepResult:
    """All branches of one sweep (one alpha, one load set, one load fraction)."""

    branches: list[Branch]
    events: list[SweepEvent]
    speed_range: tuple[float, float]
    load: float
    alpha: float
    theta: float
    label: str = ''
    seconds: float = 0.0
    n_harmonics: int = 24
    ratio_1_5: float = 3.0
    min_1_5: float = 2e-4
    hbm: 'CondensedHBM | None' = field(default=None, repr=False)
    floquet: object = field(default=None, repr=False)
    non_periodic: list[NonPeriodicBand] = field(default_factory=list)
    uncovered: list[float] = field(default_factory=list)
    search: bool = False
    not_computed: list[dict] = field(default_factory=list)
    sharp_resonances: list[dict] = field(default_factory=list)
    faults: object = None          # the FaultSet of the sweep (None: healthy)

    def rows(self) -> list[dict]:
        """One dict per computed point: speed_rpm, branch, kind, stable, order_3, order_1_5,
        max_deviation, min_deviation, mean_minus_theta (wind-up, rad), mean, max_multiplier,
        multiplicity (a faulted sweep also order_0_5 and order_1: the half orders the cylinders
        that differ excite); then one per non-periodic speed (kind 'non_periodic', branch -1:
        the envelope and averaged orders of a long time integration, and its label)."""
        out = []
        for b in self.branches:
            for p in b.points:
                d = p.as_dict()
                d['branch'], d['kind'], d['multiplicity'] = b.id, b.kind, b.multiplicity
                if self.faults:
                    c = p.windup_orders
                    d['order_0_5'], d['order_1'] = float(abs(c[1])), float(abs(c[2]))
                out.append(d)
        for band in self.non_periodic:
            out.extend(band.rows(self.theta))
        return out

    def stable_states_at(self, speed_rpm: float) -> int:
        """Number of distinct stable states at ``speed_rpm`` (stretches of branches bracketing
        it whose both ends are stable, or computed points at that speed that are stable; 120 deg
        twins counted once, as one branch)."""
        n, counted = 0, set()
        for b in self.branches:
            for p, q in zip(b.points[:-1], b.points[1:]):
                if not min(p.speed_rpm, q.speed_rpm) <= speed_rpm <= max(p.speed_rpm, q.speed_rpm):
                    continue
                end = next((e for e in (p, q) if abs(e.speed_rpm - speed_rpm) < 1e-9), None)
                if end is not None:
                    if end.stable and id(end) not in counted:
                        counted.add(id(end))
                        n += 1
                elif p.stable and q.stable:
                    n += 1
        return n

    @property
    def n_points(self) -> int:
        return sum(len(b.points) for b in self.branches)

    def main(self) -> Branch:
        return self.branches[0]

    def subharmonic_branches(self) -> list[Branch]:
        return [b for b in self.branches if b.kind == 'subharmonic']

    def solutions_at(self, speed_rpm: float) -> list[HBMPoint]:
        """Every state on the branches at exactly ``speed_rpm`` (several where states coexist):
        for each stretch of a branch that brackets the speed, Newton at that speed from the
        interpolated branch; duplicates and, when the cylinders fire alike, 120 deg shifted
        twins (same order amplitudes) are reported once (with unlike cylinders states of equal
        amplitudes but other phases are other states: :func:`faulted.fingerprints`); with
        stability when the sweep had it."""
        s = float(speed_rpm)
        out: list[HBMPoint] = []
        symmetric = getattr(self.hbm, 'symmetric', True)
        for b in self.branches:
            for p, q in zip(b.points[:-1], b.points[1:]):
                a, c = p.speed_rpm, q.speed_rpm
                if not (min(a, c) <= s <= max(a, c)):
                    continue
                if abs(a - s) < 1e-9 or abs(c - s) < 1e-9:
                    sol = p if abs(a - s) < 1e-9 else q
                else:
                    f = (s - a) / (c - a)
                    try:
                        sol = self.hbm.solve(s, p.x + f * (q.x - p.x))
                    except ConvergenceError:
                        continue
                    sol.branch, sol.kind = b.id, b.kind
                    sol.forced_order_1_5 = float(abs(self.hbm.linear_parts(s).wlin[3]))
                    if self.floquet is not None:
                        fr = self.floquet.analyze(sol.windup_orders, s)
                        sol.stable, sol.multipliers, sol.max_multiplier = (
                            fr.stable, fr.multipliers, fr.max_abs)
                H = (len(sol.x) - 1) // 2
                tol = 1e-6 + 1e-4 * np.abs(sol.x).max()
                f = fingerprints(sol.x, H, symmetric)
                if all(np.abs(f - fingerprints(o.x, H, symmetric)).max() > tol for o in out):
                    out.append(sol)
        return out

    def subharmonic_summary(self) -> list[dict]:
        """Where the 1.5th order is a resonance, not just the directly forced response: per branch,
        each speed stretch where order_1_5 > ratio_1_5 x the linear forced level (and > min_1_5),
        with its peak amplitude and whether it is stable there."""
        out = []
        for b in self.branches:
            humps = runs(b.points, lambda q: q.order_1_5 > max(self.ratio_1_5 * q.forced_order_1_5,
                                                              self.min_1_5))
            for run in humps:
                s = np.array([q.speed_rpm for q in run])
                k = int(np.argmax([q.order_1_5 for q in run]))
                st = [q.speed_rpm for q in run if q.stable]
                out.append({'branch': b.id, 'branch_kind': b.kind,
                            'speed_min_rpm': float(s.min()), 'speed_max_rpm': float(s.max()),
                            'peak_order_1_5_rad': float(run[k].order_1_5),
                            'peak_speed_rpm': float(s[k]),
                            'order_3_at_peak_rad': float(run[k].order_3),
                            'peak_stable': None if run[k].stable is None else bool(run[k].stable),
                            'stable_speed_min_rpm': float(min(st)) if st else None,
                            'stable_speed_max_rpm': float(max(st)) if st else None,
                            'origin': b.origin})
        return out

    def as_dict(self) -> dict:
        faulted = {'faults': self.faults.text()} if self.faults else {}
        return {'label': self.label, **faulted, 'alpha': self.alpha, 'theta_rad': self.theta,
                'load': self.load,
                'speed_range_rpm': list(self.speed_range), 'n_harmonics': self.n_harmonics,
                'seconds': self.seconds, 'n_points': self.n_points,
                'branches': [{'id': b.id, 'kind': b.kind, 'origin': b.origin,
                              'n_points': len(b.points),
                              'speed_range_rpm': list(b.speed_range),
                              'multiplicity': b.multiplicity}
                             for b in self.branches],
                'subharmonic': self.subharmonic_summary(), 'search': self.search,
                'non_periodic': [b.as_dict() for b in self.non_periodic],
                'uncovered_rpm': list(self.uncovered),
                'not_computed': list(self.not_computed),
                'sharp_resonances': list(self.sharp_resonances),
                'events': [e.as_dict() for e in self.events], 'points': self.rows()}


def runs(items, pred) -> list[list]:
    """Maximal consecutive runs of items satisfying pred."""
    runs, cur = [], []
    for q in items:
        if pred(q):
            cur.append(q)
        elif cur:
            runs.append(cur)
            cur = []
    if cur:
        runs.append(cur)
    return runs


def on_grid(s: float, grid: float) -> bool:
    k = round(s / grid)
    return abs(s - k * grid) < 1e-6

