"""The full steady-state search of a speed sweep: every stable 720 deg periodic state,
and what time integration shows where there is none.

After continuation and branch switching (dmf_sim.solvers.hbm.sweep, .branches):

1. at the speeds of a coarse grid (``SearchOptions.seed_step_rpm``) where the wind-up comes
   within reach of a knee or no stable state is known: deflated Newton
   (dmf_sim.solvers.hbm.deflation) from seeds in the 1.5th-order harmonic (n = 3, a few
   amplitudes and phases) and the 3rd order (n = 6 scaled), every known state at that speed (and,
   when the cylinders fire alike, its 120 deg shifts) deflated; every new solution is followed
   by continuation in both
   directions (isolated branches and folds included);
2. grid speeds no branch reached are re-seeded from the linear solution and, failing that,
   listed as uncovered;
3. where still no stable state is known (seed grid): a short Newmark shot from the unstable
   solution, perturbed; if it settles, Newton polishes the state it reached (a new branch);
4. every speed of the *requested output grid* (``SweepOptions.step_rpm``, or
   ``SearchOptions.nonperiodic_speeds``) that still has no stable periodic state gets a long
   time integration (dmf_sim.solvers.nonperiodic) from the unstable periodic state (or, where
   no branch reached, from the static equilibrium): its envelope, averaged orders and label
   (quasi-periodic, chaotic, long transient or a k x 720 deg periodic state). A speed where
   that cannot be done gets an explicit reason instead (``not_computed``).

Twins: when the cylinders fire alike, the 120 deg shifts of a state
(dmf_sim.solvers.hbm.unknowns.shift) are one physical state; its multiplicity is the number of
distinct shifted solutions Newton confirms. With faults that make the cylinders differ
(dmf_sim.solvers.hbm.faulted) a shifted state is no solution: only the known states themselves
are deflated, and every state counts once.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from dmf_sim.core.errors import ConvergenceError, OperatingRangeError
from dmf_sim.solvers.hbm.branches import BranchSwitching
from dmf_sim.solvers.hbm.deflation import DeflatedNewton, DeflationOptions
from dmf_sim.solvers.hbm.point import HBMPoint
from dmf_sim.solvers.hbm.results import (
    UNREACHED,
    Branch,
    NonPeriodicBand,
    SweepEvent,
    instability_text,
)
from dmf_sim.solvers.hbm.unknowns import all_shifts, amplitudes, shift, to_complex, to_real
from dmf_sim.solvers.newmark import SimulationOptions, simulate
from dmf_sim.solvers.nonperiodic import NonPeriodicOptions, analyze

__all__ = ['N_SHIFTS', 'SearchOptions', 'StateSearch']

N_SHIFTS = 6        # a 720 deg cycle holds six 120 deg firing intervals


@dataclass(frozen=True)
class SearchOptions:
    """Settings of the full search.

    Attributes:
        seed_step_rpm: grid on which seeds are tried [rpm].
        reach: seed where a known state's wind-up comes within ``reach`` x its peak-to-peak of
            a knee (or where no stable state is known).
        amplitudes: n = 3 seed amplitudes, in units of the larger of the 3rd-order amplitude and
            the distance of the wind-up range to the knee.
        phases: n = 3 seed phases [rad].
        scale_3rd: factors applied to the n = 6 harmonic for 3rd-order seeds.
        newmark_shots: try time integration where no stable state is found.
        shot_cycles: engine cycles of a Newmark shot.
        nonperiodic: label speeds without a stable periodic state by a long Newmark run.
        nonperiodic_speeds: the speeds [rpm] checked for that (None: every speed of the sweep's
            output grid, ``SweepOptions.step_rpm``).
        max_new_branches: stop seeding after this many new branches.
    """

    seed_step_rpm: float = 20.0
    reach: float = 1.0
    amplitudes: tuple[float, ...] = (0.5, 2.0)
    phases: tuple[float, ...] = (0.0, 0.5 * np.pi)
    scale_3rd: tuple[float, ...] = (0.5, 2.0)
    newmark_shots: bool = True
    shot_cycles: int = 60
    nonperiodic: bool = True
    nonperiodic_options: NonPeriodicOptions = NonPeriodicOptions()
    nonperiodic_speeds: tuple[float, ...] | None = None
    deflation: DeflationOptions = DeflationOptions(max_iter=25)
    max_new_branches: int = 16


def _stretches(S: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(start, end, lowest, highest) speed of every stretch between successive points of speeds
    S, the bounds widened by the speed tolerance (1e-9 rpm) of :func:`_interp_states`."""
    a, c = S[:-1], S[1:]
    return a, c, np.minimum(a, c) - 1e-9, np.maximum(a, c) + 1e-9


def _interp_states(b: Branch, s: float, stretches: tuple | None = None
                   ) -> list[tuple[np.ndarray, bool | None]]:
    """(x, stable) of branch b at speed s: linear interpolation on every stretch bracketing s;
    stable only if both ends of the stretch are (at a computed point: that point's stability).
    ``stretches``: :func:`_stretches` of b's speeds, if at hand (asking at many speeds)."""
    pts = b.points
    if len(pts) == 1:
        return [(pts[0].x, pts[0].stable)] if abs(pts[0].speed_rpm - s) < 1e-9 else []
    a, c, lo, hi = stretches if stretches is not None else _stretches(b.column('speed_rpm'))
    idx = np.flatnonzero((lo <= s) & (s <= hi))
    out = []
    for i in idx.tolist():
        p, q = pts[i], pts[i + 1]
        f = 0.0 if abs(c[i] - a[i]) < 1e-12 else (s - a[i]) / (c[i] - a[i])
        st = None if p.stable is None or q.stable is None else bool(p.stable and q.stable)
        for end in (p, q):
            if abs(end.speed_rpm - s) < 1e-9:
                st = None if end.stable is None else bool(end.stable)
        out.append((p.x + f * (q.x - p.x), st))
    return out


def _stable_mask(b: Branch, speeds: np.ndarray, stretches: tuple | None = None) -> np.ndarray:
    """(K,) bool: does branch b have a stable state at each of ``speeds``, by the rules of
    :func:`_interp_states` (a stretch bracketing s is stable if both ends are; at a computed
    point, that point's stability), for many speeds at once without interpolating x."""
    pts = b.points
    S = np.asarray(speeds, dtype=float)
    # stability of every point: 1 stable, 0 unstable, -1 not computed
    st = np.array([-1 if p.stable is None else int(bool(p.stable)) for p in pts])
    if len(pts) == 1:
        return (np.abs(pts[0].speed_rpm - S) < 1e-9) & (st[0] == 1)
    a, c, lo, hi = stretches if stretches is not None else _stretches(b.column('speed_rpm'))
    sa, sc = st[:-1, None], st[1:, None]
    inside = (lo[:, None] <= S) & (S <= hi[:, None])                  # (stretch, speed)
    value = np.where((sa < 0) | (sc < 0), -1, sa & sc) * np.ones_like(inside, dtype=int)
    value = np.where(np.abs(a[:, None] - S) < 1e-9, sa, value)         # at a point: its own
    value = np.where(np.abs(c[:, None] - S) < 1e-9, sc, value)
    return (inside & (value == 1)).any(axis=0)


def _seed_label(label: tuple) -> str:
    """What a deflated Newton seed is, in words (for the branch's origin)."""
    if label[0] == 'n = 3':
        _, a, ref, ph = label
        return f'n = 3 seed {a:g} x {ref * 1e3:.1f} mrad, phase {np.degrees(ph):.0f} deg'
    return f'3rd-order seed x {label[1]:g}'


class StateSearch:
    """The full search: a collaborator of :class:`dmf_sim.solvers.hbm.sweep.SpeedSweep`, given
    what it uses.

    Args:
        hbm: the :class:`~dmf_sim.solvers.hbm.condensed.CondensedHBM` (the problem).
        options: the sweep's ``SweepOptions``: its ``search`` (``SearchOptions``, never None when
            the search runs) and its output grid step.
        floquet: the sweep's ``FloquetAnalyzer`` (how a periodic state lost stability).
        switching: the sweep's :class:`~dmf_sim.solvers.hbm.branches.BranchSwitching`: its
            ``branches`` and ``events`` are the sweep's; a new state is followed both ways as a
            new branch by it (``_follow``), and it tells whether a state is on a known branch
            (``_known``, ``_novelty_tol``).
        non_periodic, uncovered, not_computed: the sweep's result lists the search fills (bands
            without a stable periodic state, grid speeds no branch reached, speeds that could
            not be computed and why).
        output_grid: ``output_grid()`` gives the requested speeds [rpm].
        uncovered_speeds: ``uncovered_speeds()`` gives the grid speeds no branch reached.
        check_time: ``check_time(speed_rpm)`` raises ``TimeLimitError`` once the sweep's time
            limit has passed, naming the step ``set_phase(text)`` last said the search is in.
    """

    def __init__(self, hbm, options, floquet, switching: BranchSwitching, *, non_periodic: list,
                 uncovered: list, not_computed: list, output_grid: Callable[[], np.ndarray],
                 uncovered_speeds: Callable[[], np.ndarray],
                 check_time: Callable[[float], None], set_phase: Callable[[str], None]) -> None:
        self.hbm = hbm
        self.options = options
        self.search = options.search
        self.floquet = floquet
        self.branches = switching.branches
        self.events = switching.events
        self._follow = switching._follow
        self._known = switching._known
        self._novelty_tol = switching._novelty_tol
        self.non_periodic = non_periodic
        self.uncovered = uncovered
        self.not_computed = not_computed
        self.output_grid = output_grid
        self._uncovered = uncovered_speeds
        self.check_time = check_time
        self._set_phase = set_phase
        self._branch_stretches: dict[int, tuple] = {}

    # ---- known states at one speed --------------------------------------------------------------
    def states_at(self, s: float) -> list[tuple[np.ndarray, bool | None]]:
        """(x, stable) of every branch at speed s (interpolated between computed points)."""
        return [st for b in self.branches for st in _interp_states(b, s, self._stretches_of(b))]

    def stable_at(self, speeds) -> np.ndarray:
        """(K,) bool: is any state at each of ``speeds`` stable (``any(st for _, st in
        states_at(s))`` for many speeds at once)?"""
        S = np.asarray(speeds, dtype=float).reshape(-1)
        out = np.zeros(len(S), dtype=bool)
        for b in self.branches:
            out |= _stable_mask(b, S, self._stretches_of(b) if len(b.points) > 1 else None)
        return out

    def _stretches_of(self, b: Branch) -> tuple:
        """:func:`_stretches` of b's speeds, kept while b has the same points (branches only
        grow: a sweep asks for the states at every grid speed, several times)."""
        cache = self._branch_stretches
        hit = cache.get(id(b))
        if hit is None or hit[0] is not b.points or hit[1] != len(b.points):
            hit = cache[id(b)] = (b.points, len(b.points), _stretches(b.column('speed_rpm')))
        return hit[2]

    def _deflation_set(self, known: list[np.ndarray]) -> np.ndarray:
        """The states deflated for the known ones: with alike cylinders each with its 120 deg
        shifts (solutions too), otherwise each alone (a shifted copy is no solution, and the
        state another phase away may be a new one)."""
        shifts = N_SHIFTS if self.hbm.symmetric else 1
        return all_shifts(np.array(known), shifts, self.hbm.H)

    def _windup_range(self, x: np.ndarray) -> tuple[float, float]:
        """(lowest, highest) wind-up [rad] of x over one cycle (256 samples): what the knee tests
        below read (one synthesis per state and pass)."""
        w = self.hbm.time_series(x, 256)
        return float(w.min()), float(w.max())

    def _windup_ranges(self, xs: list[np.ndarray]) -> list[tuple[float, float]]:
        """:meth:`_windup_range` of several states, synthesized in one call."""
        W = self.hbm.time_series_batch(to_complex(np.array(xs, dtype=float), self.hbm.H), 256)
        return list(zip(W.min(axis=1).tolist(), W.max(axis=1).tolist()))

    def _reaches_knee(self, x: np.ndarray, span: tuple[float, float] | None = None) -> bool:
        """Does the wind-up of x come within ``reach`` x its peak-to-peak of a knee or an end
        stop (the spring's linear_bounds)? (``span``: its :meth:`_windup_range`, if at hand.)"""
        w_min, w_max = self._windup_range(x) if span is None else span
        lo, hi = self.hbm.spring.linear_bounds()
        reach = self.search.reach * max(w_max - w_min, 1e-6)
        return w_max > hi - reach or w_min < lo + reach

    def _knee_gap(self, x: np.ndarray, span: tuple[float, float] | None = None) -> float:
        """Distance [rad] from the wind-up range of x to the nearest knee (0 if it crosses one;
        ``span``: that range, if at hand)."""
        knees = self.hbm.spring.knees
        if len(knees) == 0:
            return np.inf
        w_min, w_max = self._windup_range(x) if span is None else span
        gaps = np.where(knees > w_max, knees - w_max,
                        np.where(knees < w_min, w_min - knees, 0.0))
        return float(gaps.min())

    # ---- seeds ----------------------------------------------------------------------------------
    def _seeds(self, x: np.ndarray, knee_gap: float | None = None
               ) -> tuple[np.ndarray, list[tuple]]:
        """Deflated Newton seeds around the state x (``knee_gap``: its :meth:`_knee_gap`, if at
        hand): the seeds as rows, and what each is (:func:`_seed_label` says it in words)."""
        H = self.hbm.H
        c = to_complex(x, H)
        gap = self._knee_gap(x) if knee_gap is None else knee_gap
        ref = max(abs(c[6]) if H >= 6 else 0.0, gap, 1e-3)
        o = self.search
        labels = [('n = 3', a, ref, ph) for a in o.amplitudes for ph in o.phases]
        D = np.zeros((len(labels), H + 1), dtype=complex)
        D[:, 3] = (np.array([lb[1] for lb in labels]) * ref
                   * np.exp(1j * np.array([lb[3] for lb in labels])))
        if H >= 6:
            scale = np.zeros((len(o.scale_3rd), H + 1), dtype=complex)
            scale[:, 6] = (np.array(o.scale_3rd, dtype=float) - 1.0) * c[6]
            D = np.concatenate([D, scale])
            labels += [('3rd order', f) for f in o.scale_3rd]
        return x + to_real(D, H), labels

    def _deflated_pass(self, s: float, bar) -> int:
        """Deflated Newton from every seed at speed s; new solutions are followed. Returns the
        number of new branches."""
        states = self.states_at(s)
        if not states:
            return 0
        spans = self._windup_ranges([x for x, _ in states])    # every test below reads them
        if all(st for _, st in states) and not any(self._reaches_knee(x, span) for (x, _), span
                                                   in zip(states, spans)):
            return 0
        lp = self.hbm.linear_parts(s)
        solver = DeflatedNewton(self.hbm, self.search.deflation)
        known = [x for x, _ in states]
        gaps = [self._knee_gap(x, span) for x, span in zip(known, spans)]
        nearest = min(range(len(known)), key=gaps.__getitem__)  # the state nearest a knee
        deflate = self._deflation_set(known)     # grows with each solution found, not per seed
        seeds, labels = self._seeds(known[nearest], gaps[nearest])
        new, start = 0, 0
        while True:           # the seeds in turn, until one converges: then on from the next
            sol = solver.solve_first(lp, seeds, deflate, start)
            if sol is None:
                return new
            i, x, it, res = sol
            start = i + 1
            q = self.hbm.make_point(s, x, res, it)
            known.append(q.x)
            deflate = np.concatenate([deflate, self._deflation_set([q.x])])
            if self._known(q, self._novelty_tol(q)):
                continue
            self._follow(q, f'deflated Newton at {s:.0f} rpm from a {_seed_label(labels[i])}',
                         bar)
            new += 1
            if self._new_branches >= self.search.max_new_branches:
                return new

    # ---- Newmark where no stable state is known -------------------------------------------------
    def _shot(self, s: float, x: np.ndarray, bar) -> bool:
        """A Newmark shot from the (unstable) state x perturbed; True if it led to a new branch."""
        hb = self.hbm
        p = hb.make_point(s, x)
        q, v = hb.dof_state(p, 0.0)
        u = hb.model.e / float(hb.model.e @ hb.model.e)
        q = q + 0.05 * max(p.order_3, 1e-3) * u
        try:
            res = simulate(hb.loads, s, hb.load, initial=(q, v), factors=hb.factors,
                           options=SimulationOptions(max_cycles=self.search.shot_cycles))
        except OperatingRangeError:
            return False
        if not res.steady or res.windup_orders is None:
            return False
        c = np.zeros(hb.H + 1, dtype=complex)
        k = min(len(res.windup_orders), hb.H + 1)
        c[:k] = res.windup_orders[:k]
        try:
            found = hb.solve(s, to_real(c, hb.H))
        except ConvergenceError:
            return False
        if self._known(found, self._novelty_tol(found)):
            return False
        self._follow(found, f'Newmark shot at {s:.0f} rpm from the perturbed unstable state, '
                            'then Newton', bar)
        return True

    def _nonperiodic(self, s: float, x: np.ndarray | None):
        """Long time integration at speed s from the state x perturbed (None: from the static
        equilibrium); (result, how the periodic solution lost stability)."""
        hb = self.hbm
        if x is None:
            res = analyze(hb.loads, s, hb.load, options=self.search.nonperiodic_options,
                          factors=hb.factors)
            return res, UNREACHED
        p = hb.make_point(s, x)
        q, v = hb.dof_state(p, 0.0)
        u = hb.model.e / float(hb.model.e @ hb.model.e)
        res = analyze(hb.loads, s, hb.load, initial=(q + 1e-4 * u, v),
                      options=self.search.nonperiodic_options, factors=hb.factors)
        mc = self.floquet.classify(p.windup_orders, s)
        return res, mc.kind

    # ---- the search -----------------------------------------------------------------------------
    @property
    def _new_branches(self) -> int:
        return sum(1 for b in self.branches if b.origin.startswith(('deflated', 'Newmark shot')))

    def _seed_grid(self, speed_range: tuple[float, float]) -> np.ndarray:
        lo, hi = speed_range
        step = self.search.seed_step_rpm
        grid = np.arange(np.ceil(lo / step - 1e-9), np.floor(hi / step + 1e-9) + 1) * step
        return grid[(grid >= lo - 1e-9) & (grid <= hi + 1e-9)]

    def full_search(self, bar, speed_range: tuple[float, float]) -> None:
        """Steps 1-4 of the module docstring over ``speed_range`` (lo, hi) [rpm]; results go to
        ``branches``, ``events``, ``non_periodic``, ``not_computed`` and ``uncovered``."""
        grid = self._seed_grid(speed_range)
        bar.note('deflated Newton search')
        self._set_phase('the deflated Newton search')
        for s in grid:
            if self._new_branches >= self.search.max_new_branches:
                break
            self.check_time(s)
            self._deflated_pass(float(s), bar)
        self._set_phase('re-seeding uncovered speeds')
        self._reseed_uncovered(bar)
        bar.note('stable states check')
        self._set_phase('the stable-states check (Newmark shots)')
        stable = self.stable_at(grid)     # a shot only adds branches: stable stays stable
        for s, known_stable in zip(grid, stable.tolist()):
            self.check_time(s)
            if known_stable:
                continue
            states = self.states_at(float(s))
            if states and not any(st for _, st in states) and self.search.newmark_shots:
                x = max(states, key=lambda t: np.abs(t[0]).max())[0]
                self._shot(float(s), x, bar)
        speeds = self.nonperiodic_speeds()
        if self.search.nonperiodic:
            bar.note('non-periodic speeds')
            self._set_phase('the non-periodic classification')
            self._label_nonperiodic(speeds)
        else:
            self.not_computed.extend(
                {'speed_rpm': s, 'reason': 'no stable periodic state; the time integration '
                                           'was switched off (SearchOptions.nonperiodic)'}
                for s, st in zip(speeds, self.stable_at(speeds).tolist()) if not st)

    def nonperiodic_speeds(self) -> list[float]:
        """The speeds checked for a stable periodic state: the output grid (or the chosen
        ``SearchOptions.nonperiodic_speeds``)."""
        chosen = self.search.nonperiodic_speeds
        if chosen is not None:
            return [float(s) for s in chosen]
        return [float(s) for s in self.output_grid()]

    def _label_nonperiodic(self, speeds: list[float]) -> None:
        """A long time integration at every speed of ``speeds`` without a stable periodic state
        (step 4 of the module docstring); neighbouring speeds of one label form a band."""
        step = self.options.step_rpm
        stable = self.stable_at(speeds)   # the time integrations add no branches
        for s, known_stable in zip(speeds, stable.tolist()):
            self.check_time(s)
            if known_stable:
                continue
            states = self.states_at(s)
            if any(st for _, st in states):
                continue
            x = min(states, key=lambda t: np.abs(t[0][1:]).max())[0] if states else None
            try:
                res, kind = self._nonperiodic(s, x)
            except OperatingRangeError as exc:
                self.not_computed.append({'speed_rpm': s, 'reason': 'no stable periodic state; '
                                          f'time integration impossible: {exc}'})
                continue
            band = next((b for b in self.non_periodic
                         if abs(res.speed_rpm - b.speed_max_rpm) <= step + 1e-6
                         and b.label == res.label and b.instability == kind), None)
            if band is None:
                band = NonPeriodicBand(res.speed_rpm, res.speed_rpm, res.label, kind, [],
                                       0.5 * step)
                self.non_periodic.append(band)
                self.events.append(SweepEvent('non_periodic', -1, res.speed_rpm,
                                              'no stable periodic state; time integration: '
                                              f'{res.describe()} ({instability_text(kind)})'))
            band.speed_max_rpm = res.speed_rpm
            band.results.append(res)

    def _reseed_uncovered(self, bar) -> None:
        for s in list(self._uncovered()):
            self.check_time(s)
            if any(abs(s - t) < 1e-9 for t in self._uncovered()):
                try:
                    first = self.hbm.solve(float(s))
                except (ConvergenceError, OperatingRangeError):
                    continue
                if not self._known(first, self._novelty_tol(first)):
                    self._follow(first, f'continuation from {s:g} rpm '
                                        '(re-seeded: no branch reached it)', bar)
        self.uncovered[:] = [float(s) for s in self._uncovered()]

    # ---- twins ----------------------------------------------------------------------------------
    def multiplicity(self, p: HBMPoint) -> int:
        """Number of distinct 120 deg shifts of the state p that are solutions (Newton from each
        shift; 1 for a 120 deg periodic 3rd-order state, 2 for a 1.5th-order state). 1 when the
        cylinders do not fire alike: then a solution Newton reaches from a shift is another
        state, found and reported on its own."""
        hb = self.hbm
        if not hb.symmetric:
            return 1
        found = [p.x]
        tol = 1e-6 + 1e-4 * np.abs(p.x).max()
        for k in range(1, N_SHIFTS):
            try:
                q = hb.solve(p.speed_rpm, shift(p.x, k, hb.H))
            except ConvergenceError:
                continue
            if np.abs(amplitudes(q.x, hb.H) - amplitudes(p.x, hb.H)).max() > 10 * tol:
                continue                              # converged to another state
            if all(np.abs(q.x - f).max() > tol for f in found):
                found.append(q.x)
        return len(found)
