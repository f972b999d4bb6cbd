"""Branch switching of the harmonic balance speed sweep: 1.5th-order and other coexisting branches.

Branch switching to the 1.5th-order (sub-harmonic) solutions. The excitation is almost
120 deg periodic (orders 3, 6, 9 dominate the DMF), so the 3rd-order solution can lose
stability by a period doubling of its 120 deg period: over the 720 deg base period a Floquet
multiplier leaves the unit circle through +1 with an eigen-solution of half-orders n = 3 mod 6.
The flexible crank lets the cylinders excite n = 3 directly a little, so the bifurcation is
imperfect: either the branch traced from low speed itself turns into the 1.5th-order solution
(a smooth hump of order_1_5, no loss of stability), or the 3rd-order branch loses stability
and the 1.5th-order branch is separate. Seeds for Newton at one speed, each followed in both
directions when it converges to a solution not yet on a branch:

1. unstable stretch of a branch, sub-harmonic eigen-solution: the most unstable point plus
   +-a times the eigen-solution's n = 3, 9, 15, 21 wind-up harmonics;
2. 1.5th-order hump on a branch: its peak with the n = 3 mod 6 harmonics reversed (the
   120 deg-shifted twin) or set back to the directly forced (linear) values (the 3rd-order
   solution beside it);
3. if 1 and 2 find nothing: n = 3 seeds every ``scan_step_rpm`` where the main branch reaches
   near the knee (a branch not connected to it), and optionally Newmark from the perturbed
   unstable solution (``newmark_seed``).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from dmf_sim.core.errors import ConvergenceError
from dmf_sim.solvers.hbm.faulted import fingerprints
from dmf_sim.solvers.hbm.point import HBMPoint
from dmf_sim.solvers.hbm.results import Branch, SweepEvent, on_grid, runs
from dmf_sim.solvers.hbm.unknowns import SUB_HARMONICS, sub_part, to_complex, to_real

__all__ = ['BranchSwitching']


class BranchSwitching:
    """Seeding and following of further branches: a collaborator of
    :class:`dmf_sim.solvers.hbm.sweep.SpeedSweep`, given what it uses.

    Args:
        hbm: the :class:`~dmf_sim.solvers.hbm.condensed.CondensedHBM` (the problem).
        options: the sweep's ``SweepOptions`` (the switching's settings).
        cont: the sweep's ``ContinuationOptions`` (its scales and step, to tell a closed branch).
        floquet: the sweep's ``FloquetAnalyzer`` (the sub-harmonic eigen-solution of a point).
        branches: the sweep's list of :class:`~dmf_sim.solvers.hbm.results.Branch`; every new
            branch is appended to it, with the next id.
        events: the sweep's list of ``SweepEvent``; a branch switch is appended to it.
        trace: ``trace(x0, s0, direction, branch, kind, bar, stop=None)`` follows a branch by
            continuation from a solution and returns its finished points.
        record_events: ``record_events(branch)`` records a traced branch's folds and stability
            changes.

    Neither settings nor solvers are changed; ``branches`` and ``events`` grow.
    """

    def __init__(self, hbm, options, cont, floquet, branches: list, events: list,
                 trace: Callable[..., list], record_events: Callable[[Branch], None]) -> None:
        self.hbm = hbm
        self.options = options
        self.cont = cont
        self.floquet = floquet
        self.branches = branches
        self.events = events
        self._trace = trace
        self._events = record_events

    # ---- is a solution already on a branch? -----------------------------------------------------
    def _fingerprints(self, x: np.ndarray) -> np.ndarray:
        """:func:`dmf_sim.solvers.hbm.faulted.fingerprints` of the problem: the harmonic
        amplitudes with alike cylinders (a 120 deg shifted twin is the same state), else x."""
        return fingerprints(x, self.hbm.H, self.hbm.symmetric)

    def _distance_to_branch(self, x: np.ndarray, s: float, b: Branch) -> float:
        """Smallest max |f - f_b(s)| [rad] of the fingerprints f (:meth:`_fingerprints`: the
        harmonic amplitudes |w_n|, or with unlike cylinders the harmonics themselves) over the
        stretches of branch b that bracket speed s (linear interpolation between its points)."""
        S = b.column('speed_rpm')
        a0 = self._fingerprints(x)
        if len(S) == 1:
            return (float(np.abs(a0 - self._fingerprints(b.points[0].x)).max())
                    if abs(S[0] - s) < 1e-9 else np.inf)
        a, c = S[:-1], S[1:]
        idx = np.flatnonzero((np.minimum(a, c) - 1e-9 <= s) & (s <= np.maximum(a, c) + 1e-9))
        if len(idx) == 0:
            return np.inf
        X = self._fingerprints(np.array([b.points[i].x for i in idx]))
        Y = self._fingerprints(np.array([b.points[i + 1].x for i in idx]))
        den = c[idx] - a[idx]
        safe = np.where(np.abs(den) < 1e-12, 1.0, den)
        f = np.where(np.abs(den) < 1e-12, 0.0, (s - a[idx]) / safe)
        return float(np.abs(a0[None, :] - (X + f[:, None] * (Y - X))).max(axis=1).min())

    def _known(self, q: HBMPoint, tol: float) -> bool:
        return any(self._distance_to_branch(q.x, q.speed_rpm, b) < tol for b in self.branches)

    def _novelty_tol(self, q: HBMPoint) -> float:
        return max(0.1 * max(q.subharmonic_amplitude(), q.order_3), 5e-4)

    def _try(self, s: float, x0: np.ndarray) -> HBMPoint | None:
        try:
            q = self.hbm.solve(s, x0)
        except ConvergenceError:
            return None
        return None if self._known(q, self._novelty_tol(q)) else q

    # ---- seeds ----------------------------------------------------------------------------------
    def _sub_part(self, c: np.ndarray) -> np.ndarray:
        return sub_part(c, self.hbm.H)

    def _eigen_seeds(self, p: HBMPoint) -> tuple[HBMPoint | None, str]:
        mc = self.floquet.classify(p.windup_orders, p.speed_rpm)
        if mc.kind != 'subharmonic':
            return None, ''
        d = self._sub_part(mc.coefficients)
        d /= max(np.abs(d).max(), 1e-300)
        scale = max(p.order_3, 1e-3)
        for a in (0.5, 1.0, 2.0, 4.0):
            for sign in (1.0, -1.0):
                q = self._try(p.speed_rpm, p.x + sign * a * scale * d)
                if q is not None:
                    return q, (f'branch switching at {p.speed_rpm:.1f} rpm: Newton from the '
                               f'unstable solution + its sub-harmonic Floquet eigen-solution '
                               f'(multiplier {mc.multiplier.real:+.3f})')
        if self.options.newmark_seed:
            q = self._newmark_seed(p, d)
            if q is not None:
                return q, (f'branch switching at {p.speed_rpm:.1f} rpm: Newmark from the '
                           f'perturbed unstable solution, then Newton')
        return None, ''

    def _hump_seeds(self, p: HBMPoint) -> tuple[HBMPoint | None, str]:
        sub = self._sub_part(p.windup_orders)
        forced = self._sub_part(self.hbm.linear_parts(p.speed_rpm).wlin)
        for how, x0 in (('n = 3 mod 6 harmonics reversed (120 deg shifted twin)', p.x - 2.0 * sub),
                        ('n = 3 mod 6 harmonics set to the forced response', p.x - sub + forced)):
            q = self._try(p.speed_rpm, x0)
            if q is not None:
                return q, (f'branch switching at {p.speed_rpm:.1f} rpm '
                           f'from the 1.5th-order hump: {how}')
        return None, ''

    def _newmark_seed(self, p: HBMPoint, direction: np.ndarray) -> HBMPoint | None:
        """Time integration from the perturbed (unstable) solution, then Newton from the
        attractor."""
        H = self.hbm.H
        _, _, u, _ = self.hbm.linear_parts_direct(p.speed_rpm)
        c = to_complex(direction, H)
        e = self.hbm.model.e
        # DOF perturbation: the chain's response shape to a DMF torque of each sub-harmonic
        dq = np.real(sum(c[n] / (e @ u[n]) * u[n] for n in SUB_HARMONICS if n <= H and c[n] != 0))
        dq *= 0.5 * max(p.order_3, 1e-3) / max(np.abs(e @ dq), 1e-12)
        res = self.hbm.newmark_from(p, perturb=dq, max_cycles=300)
        if res.windup_orders is None:
            return None
        return self._try(p.speed_rpm, to_real(res.windup_orders[:H + 1], H))

    # ---- following a new branch -----------------------------------------------------------------
    def _follow(self, seed: HBMPoint, origin: str, bar) -> Branch:
        bid = len(self.branches)
        x_start, s_start = seed.x.copy(), seed.speed_rpm
        others = list(self.branches)
        xs, ss = self.cont.x_scale, self.cont.s_scale
        y_start = np.concatenate([x_start / xs, [s_start / ss]])
        away = [False]

        def back_at_start(cp) -> bool:
            """Closed loop (an isolated branch): far from the start, then back within a step."""
            d = float(np.linalg.norm(np.concatenate([cp.x / xs, [cp.s / ss]]) - y_start))
            away[0] = away[0] or d > 3.0 * self.cont.step_max
            return away[0] and d < 0.75 * self.cont.step_max

        closed = [False]

        def stop(cp, cps):
            if len(cps) < 3:
                return False
            tol = max(0.02 * np.abs(cp.x[1:]).max(), 1e-4)
            if any(self._distance_to_branch(cp.x, cp.s, b) < tol for b in others):
                return True       # arrived on a known branch (a turning or bifurcation point)
            if back_at_start(cp):
                closed[0] = True
                return True
            return False

        up = self._trace(seed.x, s_start, +1.0, bid, 'subharmonic', bar, stop)
        if closed[0]:
            # an isolated closed branch: one direction went all the way round; start the list at
            # its lowest speed so stretches are contiguous
            loop = up[:-1]
            k = int(np.argmin([q.speed_rpm for q in loop]))
            pts = loop[k:] + loop[:k + 1]
            origin += ' (closed branch)'
        else:
            down = self._trace(seed.x, s_start, -1.0, bid, 'subharmonic', bar, stop)
            for q in down:  # reversed list: the arc parameter runs the other way
                q.tangent_speed = -q.tangent_speed
            pts = down[::-1] + up[1:]
        kind = 'subharmonic' if self._humps(pts) else 'harmonic'
        for q in pts:
            q.kind = kind
        b = Branch(bid, kind, pts, origin)
        self.branches.append(b)
        self.events.append(SweepEvent('branch_switch', bid, s_start, origin))
        self._events(b)
        return b

    def _humps(self, pts: list[HBMPoint]) -> list[list[HBMPoint]]:
        """Stretches where the 1.5th order clearly exceeds its directly forced (linear) level."""
        o = self.options
        return runs(pts, lambda q: q.order_1_5 > max(o.ratio_1_5 * q.forced_order_1_5,
                                                      o.min_subharmonic))

    def _switch_branches(self, bar) -> None:
        o = self.options
        queue = [self.branches[0]]
        main_humps = None                  # branch 0's, asked again at the end
        while queue and len(self.branches) <= o.max_branches:
            b = queue.pop(0)
            seeds = []
            for run in runs(b.points, lambda q: q.stable is False):
                seeds.append(('eigen', max(run, key=lambda q: q.max_multiplier)))
            humps = self._humps(b.points)
            if b is self.branches[0]:
                main_humps = humps
            for run in humps:
                peak = max(run, key=lambda q: q.order_1_5 / max(q.forced_order_1_5, 1e-12))
                seeds.append(('hump', peak))
                if len(run) >= 4:
                    seeds += [('hump', run[len(run) // 4]), ('hump', run[(3 * len(run)) // 4])]
            for kind, p in seeds:
                if len(self.branches) > o.max_branches:
                    break
                q, how = (self._eigen_seeds(p) if kind == 'eigen' else self._hump_seeds(p))
                if q is not None and not self._known(q, self._novelty_tol(q)):
                    queue.append(self._follow(q, how, bar))
        if main_humps is None:
            main_humps = self._humps(self.branches[0].points)
        if o.isola_scan and len(self.branches) == 1 and not main_humps:
            self._scan(bar)

    def _scan(self, bar) -> None:
        """Seed n = 3 perturbations where the main branch comes near the knee (isolated
        branches)."""
        o = self.options
        theta = self.hbm.spring.theta
        H = self.hbm.H
        last = -np.inf
        for p in list(self.branches[0].points):
            if len(self.branches) > o.max_branches:
                break
            sm = p.summary
            ptp = sm.max_deviation - sm.min_deviation
            if sm.mean + sm.max_deviation < theta - o.scan_margin * ptp:
                continue
            if p.speed_rpm - last < o.scan_step_rpm - 1e-6 or not on_grid(p.speed_rpm, o.step_rpm):
                continue
            last = p.speed_rpm
            scale = max(p.order_3, 1e-3)
            found = None
            for phase in (0.0, 0.5 * np.pi, np.pi, 1.5 * np.pi):
                c = np.zeros(H + 1, dtype=complex)
                c[3] = 2.0 * scale * np.exp(1j * phase)
                q = self._try(p.speed_rpm, p.x + to_real(c, H))
                if q is not None and q.subharmonic_amplitude() > max(
                        o.ratio_1_5 * p.subharmonic_amplitude(), o.min_subharmonic):
                    found = q
                    break
            if found is not None:
                self._follow(found, f'n = 3 seed at {p.speed_rpm:.0f} rpm (search for a branch '
                                    'not connected to the main one)', bar)

