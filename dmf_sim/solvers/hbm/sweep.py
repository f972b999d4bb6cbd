"""Harmonic balance speed sweeps: continuation over engine speed, stability, events
(paper Fig. 13/15)."""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass

import numpy as np

from dmf_sim.core.errors import ConfigError, ConvergenceError, TimeLimitError
from dmf_sim.core.kernel_cache import warm_up
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.orders import synthesize
from dmf_sim.solvers.hbm.branches import BranchSwitching
from dmf_sim.solvers.hbm.condensed import CondensedHBM
from dmf_sim.solvers.hbm.faulted import apply_faults, steady_faults
from dmf_sim.solvers.hbm.point import HBMOptions, HBMPoint
from dmf_sim.solvers.hbm.results import Branch, SweepEvent, SweepResult
from dmf_sim.solvers.hbm.search import SearchOptions, StateSearch
from dmf_sim.solvers.hbm.unknowns import to_complex
from dmf_sim.solvers.hbm.warm import SWEEP
from dmf_sim.solvers.stability import by_modulus

__all__ = ['TIME_LIMIT_RANGE_S', 'check_time_limit', 'SweepOptions', 'SpeedSweep', 'sweep']

TIME_LIMIT_RANGE_S = (1e-3, 86400.0)   # allowed SweepOptions.time_limit_s [s]


def check_time_limit(value, field_name: str = 'time_limit_s') -> float | None:
    """A sweep time limit [s] in TIME_LIMIT_RANGE_S, or None; else a one-line ConfigError."""
    if value is None:
        return None
    lo, hi = TIME_LIMIT_RANGE_S
    if (isinstance(value, bool) or not isinstance(value, (int, float))
            or not (math.isfinite(value) and lo <= value <= hi)):
        raise ConfigError(f'{field_name}: must be a number in [{lo:g}, {hi:g}] s, got {value!r}')
    return float(value)


@dataclass(frozen=True)
class SweepOptions:
    """What a sweep does besides following the main branch.

    Attributes:
        step_rpm: output grid (continuation lands on multiples of it where the branch runs along
            speed).
        stability: compute Floquet multipliers of every point.
        branch_switching: at a sub-harmonic loss of stability or a 1.5th-order hump, seed and
            follow the other 1.5th-order / 3rd-order branches (see SpeedSweep).
        isola_scan: if no bifurcation leads to one, also try n = 3 seeds where the main branch
            reaches within ``scan_margin`` x its peak-to-peak of the knee (a branch not connected
            to the main one), every ``scan_step_rpm``.
        newmark_seed: when Newton seeding fails, integrate in time from the perturbed unstable
            solution and start Newton from the attractor reached (slower).
        min_subharmonic: smallest 1.5th-order wind-up amplitude [rad] that counts as a
            1.5th-order response (besides exceeding ``ratio_1_5`` x the directly forced, linear
            1.5th-order wind-up at that speed).
        ratio_1_5: see min_subharmonic.
        max_branches: stop switching after this many extra branches.
        search: the full steady-state search after the branch switching (deflated Newton
            seeds, Newmark shots, non-periodic speeds, re-seeding; dmf_sim.solvers.hbm.search), or
            None for continuation and branch switching only (the ``--fast`` sweep).
        time_limit_s: wall-clock limit [s] of the whole sweep, or None. Reaching it raises
            :class:`dmf_sim.core.errors.TimeLimitError` naming the phase and the speed reached (a
            design study records that design as failed with this reason and goes on). Checked at
            every continuation point and before every search step, so the overrun is at most one
            point's or one Newmark shot's time.
    """

    step_rpm: float = 10.0
    stability: bool = True
    branch_switching: bool = True
    isola_scan: bool = True
    scan_step_rpm: float = 100.0
    scan_margin: float = 0.25
    newmark_seed: bool = False
    min_subharmonic: float = 2e-4
    ratio_1_5: float = 3.0
    max_branches: int = 6
    search: SearchOptions | None = SearchOptions()
    time_limit_s: float | None = None


class _Progress:
    """tqdm over covered speed (or nothing)."""

    def __init__(self, enabled, total: float, desc: str):
        self.bar = None
        if enabled:
            from tqdm import tqdm
            self.bar = tqdm(total=round(total), desc=desc, unit='rpm', leave=False)
        self.done = 0.0

    def advance(self, ds: float) -> None:
        if self.bar is not None:
            self.done += abs(ds)
            step = int(self.done) - self.bar.n
            if step > 0:
                self.bar.update(min(step, self.bar.total - self.bar.n))

    def note(self, text: str) -> None:
        if self.bar is not None:
            self.bar.set_postfix_str(text)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


class SpeedSweep:
    """Continuation over engine speed with stability and branch switching (used by :func:`sweep`).

    Follows the branch from the lowest speed (pseudo-arc-length continuation through turning
    points, fast-forwarding linear stretches), covers speeds no branch reached, computes the
    Floquet stability of every point and records events; the branch switching to 1.5th-order
    and other coexisting branches is its collaborator :attr:`switching` (a
    :class:`dmf_sim.solvers.hbm.branches.BranchSwitching`), the full search for every stable
    state :attr:`state_search` (a :class:`dmf_sim.solvers.hbm.search.StateSearch`); both are
    given the sweep's settings, its result lists and the sweep's own steps they call.

    Args:
        hbm: CondensedHBM (driveline, engine, load fraction).
        options: SweepOptions; continuation: ContinuationOptions (grid set from step_rpm).
    """

    def __init__(self, hbm: CondensedHBM, options: SweepOptions | None = None, continuation=None):
        from dmf_sim.solvers.continuation import ContinuationOptions
        from dmf_sim.solvers.stability import FloquetAnalyzer
        self.hbm = hbm
        self.options = options or SweepOptions()
        base = continuation or ContinuationOptions()
        self.cont = dataclasses.replace(base, grid=self.options.step_rpm,
                                        s_scale=self.options.step_rpm, tol=hbm.options.tol)
        self.floquet = FloquetAnalyzer(hbm.model, modes=hbm.modes, compiled=hbm.compiled)
        self.search = self.options.search
        self.events: list[SweepEvent] = []
        self.branches: list[Branch] = []
        self.non_periodic: list = []
        self.uncovered: list[float] = []
        self.not_computed: list[dict] = []
        self.range = (0.0, 0.0)
        self._deadline = math.inf          # perf_counter() value of the time limit
        self._phase = 'continuation'
        self.switching = BranchSwitching(hbm, self.options, self.cont, self.floquet,
                                         self.branches, self.events, self._trace, self._events)
        self.state_search = StateSearch(
            hbm, self.options, self.floquet, self.switching, non_periodic=self.non_periodic,
            uncovered=self.uncovered, not_computed=self.not_computed,
            output_grid=self.output_grid, uncovered_speeds=self._uncovered,
            check_time=self.check_time, set_phase=self._set_phase)

    # ---- the collaborators' public steps --------------------------------------------------------
    def states_at(self, s: float) -> list[tuple[np.ndarray, bool | None]]:
        """:meth:`StateSearch.states_at <dmf_sim.solvers.hbm.search.StateSearch.states_at>`."""
        return self.state_search.states_at(s)

    def stable_at(self, speeds) -> np.ndarray:
        """:meth:`StateSearch.stable_at <dmf_sim.solvers.hbm.search.StateSearch.stable_at>`."""
        return self.state_search.stable_at(speeds)

    def multiplicity(self, p: HBMPoint) -> int:
        """:meth:`StateSearch.multiplicity
        <dmf_sim.solvers.hbm.search.StateSearch.multiplicity>`."""
        return self.state_search.multiplicity(p)

    def nonperiodic_speeds(self) -> list[float]:
        """:meth:`StateSearch.nonperiodic_speeds
        <dmf_sim.solvers.hbm.search.StateSearch.nonperiodic_speeds>`."""
        return self.state_search.nonperiodic_speeds()

    def full_search(self, bar) -> None:
        """The full search over the sweep's range (:meth:`StateSearch.full_search
        <dmf_sim.solvers.hbm.search.StateSearch.full_search>`)."""
        self.state_search.full_search(bar, self.range)

    def _set_phase(self, text: str) -> None:
        self._phase = text

    # ---- time limit -----------------------------------------------------------------------------
    def check_time(self, speed_rpm: float) -> None:
        """Raise TimeLimitError once the sweep's wall-clock limit has passed."""
        if time.perf_counter() > self._deadline:
            raise TimeLimitError(f'sweep time limit {self.options.time_limit_s:g} s reached '
                                 f'during {self._phase} at {speed_rpm:.0f} rpm')

    # ---- the points of a traced branch --------------------------------------------------------
    def _points(self, cps: list, branch: int, kind: str) -> list[HBMPoint]:
        """HBMPoints of continuation points the corrector solved, made after their branch is
        traced, all at once (nothing during the trace needs them): the wind-up samples in one
        FFT, the summaries in one pass (:meth:`CondensedHBM.make_points`), the Floquet
        multipliers in one compiled call (:meth:`FloquetAnalyzer.analyze_many`)."""
        if not cps:
            return []
        hb = self.hbm
        X = np.array([cp.x for cp in cps], dtype=float)
        speeds = [cp.s for cp in cps]
        C = to_complex(X, hb.H)
        W = synthesize(C, self.floquet.n_fine)
        lps = hb.linear_parts_of(speeds)
        pts = hb.make_points(speeds, C, W, [float(lp.wlin[0].real) for lp in lps], X=X)
        for p, cp, lp in zip(pts, cps, lps):
            p.residual, p.iterations = float(cp.residual), int(cp.iterations)
            p.branch, p.kind, p.tangent_speed = branch, kind, float(cp.tangent[-1])
            p.forced_order_1_5 = float(abs(lp.wlin[3])) if hb.H >= 3 else 0.0
        if self.options.stability:
            mus, tops, stable = self.floquet.analyze_many(C, speeds, W)
            for p, mu, top, st in zip(pts, mus, tops, stable):
                p.stable, p.multipliers, p.max_multiplier = st, mu, top
        return pts

    def _trace(self, x0, s0, direction, branch, kind, bar, stop=None) -> list[HBMPoint]:
        from dmf_sim.solvers.continuation import BranchHooks, BranchStart, continue_branch
        pts: list[HBMPoint | None] = []
        solved: list = []              # (index in pts, continuation point): made at the end
        last = [s0]

        def on_point(cp):
            pre = cp.point
            if pre is not None:
                pre.branch, pre.kind = branch, kind
                pts.append(pre)
            else:
                solved.append((len(pts), cp))
                pts.append(None)
            bar.advance(cp.s - last[0])
            last[0] = cp.s
            self.check_time(cp.s)

        def on_end(reason, cp):
            if reason == 'left_range':
                self.events.append(SweepEvent('left_speed_range', branch, cp.s,
                                              'the continuation needed engine speeds outside the '
                                              'engine data: the branch ends here'))
            elif reason == 'closed':
                self.events.append(SweepEvent('closed_loop', branch, cp.s,
                                              'the branch came back onto its own earlier part '
                                              '(a closed loop): it ends here'))

        hooks = BranchHooks(stop=stop, on_point=on_point, fast_forward=self._linear_stretch,
                            on_end=on_end, steps=self.hbm.compiled_steps())
        continue_branch(self.hbm, BranchStart(x0, s0, self.range, direction), self.cont, hooks)
        made = self._points([cp for _, cp in solved], branch, kind)
        for (i, _), p in zip(solved, made):
            pts[i] = p
        return pts

    def _in_primary(self, w: np.ndarray) -> np.ndarray:
        """Rows of w (K, N) that stay strictly inside the primary region, short of the end
        stops (the spring's linear_bounds), over the whole cycle."""
        lo, hi = self.hbm.spring.linear_bounds()
        return (w.max(axis=1) < hi) & (w.min(axis=1) > lo)

    def _linear_stretch(self, cp, sign: float) -> list:
        """Grid points ahead of ``cp`` where the wind-up never reaches a knee or an end stop:
        there g = 0 and no stop pushes, the HBM solution is the linear response wlin (exact, no
        iteration) and the stability follows from the primary-stiffness eigenvalues. Checked in
        batches of growing size."""
        from dmf_sim.solvers.continuation import ContinuationPoint, tangent_of
        hb, o = self.hbm, self.options
        # the point must stay below the knees: no torque beyond one on the AFT samples (one
        # kernel call; this ends the check at a point on the non-linear part of a branch), and
        # none on the finer samples the stability analysis reads
        if hb.nonlinear_harmonics(cp.x, speed_rpm=cp.s).any():
            return []
        if not self._in_primary(hb.time_series(cp.x, self.floquet.n_fine)[None])[0]:
            return []
        lo, hi = self.range
        out: list = []
        s0, batch = cp.s, 4
        xs, ss = self.cont.x_scale, self.cont.s_scale
        while True:
            speeds = s0 + sign * o.step_rpm * np.arange(1, batch + 1)
            speeds = speeds[(speeds >= lo - 1e-9) & (speeds <= hi + 1e-9)]
            speeds = np.round(speeds / o.step_rpm) * o.step_rpm
            if len(speeds) == 0:
                break
            W = hb.linear_response(speeds)
            series = hb.time_series_batch(W, self.floquet.n_fine)
            ok = self._in_primary(series)
            k = len(ok) if ok.all() else int(np.argmin(ok))
            if k == 0:
                break
            mu = top = None
            if o.stability:        # each row sorted by decreasing modulus
                mu, top = by_modulus(self.floquet.linear_multipliers(speeds[:k]))
                top = top.tolist()
            made = hb.make_points(speeds[:k], W[:k], series[:k], W[:k, 0].real)
            forced = np.abs(W[:k, 3]).tolist() if hb.H >= 3 else [0.0] * k
            for j, p in enumerate(made):
                p.forced_order_1_5 = forced[j]
                if mu is not None:
                    p.multipliers, p.max_multiplier = mu[j], top[j]
                    p.stable = top[j] < 1.0 + self.floquet.tol
                q = ContinuationPoint(p.x, p.speed_rpm, None, 0, 0.0, True, point=p)
                out.append(q)
            if k < len(ok) or len(speeds) < batch:
                break
            s0 = speeds[-1]
            batch = min(2 * batch, 32)
        # tangents: secant directions in scaled coordinates, the last one exact
        if out:
            Y = np.empty((len(out) + 1, len(cp.x) + 1))
            Y[0, :-1], Y[0, -1] = cp.x / xs, cp.s / ss
            Y[1:, :-1] = np.array([q.x for q in out]) / xs
            Y[1:, -1] = np.array([q.s for q in out]) / ss
            D = np.diff(Y, axis=0)
            D /= np.sqrt(np.einsum('ij,ij->i', D, D))[:, None]
            for q, d in zip(out, D):
                q.tangent = d
                q.point.tangent_speed = float(d[-1])
            last = out[-1]
            r, Jx, rs = hb.residual_and_jacobians(last.x, last.s)
            last.tangent = tangent_of(Jx, rs, last.tangent, xs, ss, hb.compiled_steps())
            last.point.tangent_speed = float(last.tangent[-1])
        return out

    # ---- the sweep ------------------------------------------------------------------------------
    def run(self, speed_range: tuple[float, float], progress=False,
            start_x: np.ndarray | None = None, desc: str = 'HBM sweep') -> SweepResult:
        if progress:      # compiled first if needed (with a notice): the bar's rate without it
            warm_up((SWEEP,), prefix='dmf_sim')
        t0 = time.perf_counter()
        lo, hi = float(speed_range[0]), float(speed_range[1])
        if not hi > lo:
            raise ConfigError(f'speed range [{lo}, {hi}] rpm: need TO > FROM')
        limit = check_time_limit(self.options.time_limit_s)
        if limit is not None:
            self._deadline = t0 + limit
        self.range = (lo, hi)
        step = self.options.step_rpm
        self.hbm.prepare(np.arange(np.ceil(lo / step - 1e-9), np.floor(hi / step + 1e-9) + 1)
                         * step)                    # the grid's linear parts, all at once
        bar = _Progress(progress, hi - lo, desc)
        try:
            origin = f'continuation from {lo:g} rpm'
            try:
                x0 = self.hbm.solve(lo, start_x).x
            except ConvergenceError:
                x0, origin = self._approach(lo)   # None: the re-seeding below starts elsewhere
            if x0 is not None:
                pts = self._trace(x0, lo, +1.0, 0, 'main', bar)
                self.branches[:] = [Branch(0, 'main', pts, origin)]
                self._events(self.branches[0])
            self._cover(bar)
            if not self.branches:
                raise ConvergenceError('no periodic solution converged anywhere in '
                                       f'{lo:g}-{hi:g} rpm')
            if self.options.stability and self.options.branch_switching:
                bar.note('branch switching')
                self._phase = 'branch switching'
                self.switching._switch_branches(bar)
            if self.options.stability and self.search is not None:
                self.full_search(bar)
                for b in self.branches:
                    if b.kind == 'subharmonic':
                        b.multiplicity = self.multiplicity(max(b.points,
                                                               key=lambda q: q.order_1_5))
            else:
                self.uncovered[:] = [float(s) for s in self._uncovered()]
                self._not_searched()
        finally:
            bar.close()
        # a sweep that ran over its limit between two checks (a compiled stretch) says so too
        self._phase = 'the sweep'
        self.check_time(hi)
        sp = self.hbm.spring
        return SweepResult(self.branches, self.events, (lo, hi), self.hbm.load, sp.alpha, sp.theta,
                           seconds=time.perf_counter() - t0, n_harmonics=self.hbm.H,
                           ratio_1_5=self.options.ratio_1_5, min_1_5=self.options.min_subharmonic,
                           hbm=self.hbm, floquet=self.floquet if self.options.stability else None,
                           non_periodic=self.non_periodic, uncovered=self.uncovered,
                           not_computed=self.not_computed,
                           sharp_resonances=self.hbm.sharp_resonances((lo, hi)),
                           search=self.search is not None and self.options.stability)

    def _approach(self, lo: float) -> tuple[np.ndarray | None, str]:
        """Newton from the linear response did not converge at ``lo`` (inside a 1.5th-order
        resonance it may not): reach ``lo`` by continuation from the lowest speed of the engine
        data, where the response is far from the knee."""
        rng = getattr(self.hbm.loads.engine, 'speed_range_rpm', None)
        if rng is None or float(rng[0]) >= lo:
            return None, ''
        start = float(rng[0])
        try:
            x = self.hbm.solve(start).x
        except ConvergenceError:
            return None, ''
        from dmf_sim.solvers.continuation import BranchHooks, BranchStart, continue_branch
        pts = continue_branch(self.hbm, BranchStart(x, start, (start, lo), 1.0), self.cont,
                              BranchHooks(steps=self.hbm.compiled_steps()))
        if abs(pts[-1].s - lo) > 1e-6:
            return None, ''
        return pts[-1].x, (f'continuation from {lo:g} rpm (its start solution continued from '
                           f'{start:g} rpm: Newton from the linear response did not converge at '
                           f'{lo:g} rpm)')

    def output_grid(self) -> np.ndarray:
        """The requested speeds [rpm]: multiples of ``step_rpm`` in the range, and its ends."""
        lo, hi = self.range
        step = self.options.step_rpm
        grid = np.arange(np.ceil(lo / step - 1e-9), np.floor(hi / step + 1e-9) + 1) * step
        grid = grid[(grid > lo + 1e-6) & (grid < hi - 1e-6)]
        return np.concatenate(([lo], grid, [hi]))

    def _not_searched(self) -> None:
        """Without the full search (or without stability) no speed gets a non-periodic envelope:
        say so for every grid speed it concerns."""
        if not self.options.stability:
            self.not_computed.append({'speed_rpm': None, 'reason': 'stability not computed '
                                      '(no Floquet analysis): whether a periodic state is stable, '
                                      'and the non-periodic envelope, are not computed'})
            return
        grid = self.output_grid()
        for s, stable in zip(grid, self.stable_at(grid).tolist()):
            if not stable:
                self.not_computed.append({'speed_rpm': float(s), 'reason': (
                    'no stable periodic state found; the non-periodic envelope was not computed '
                    '(the full search is off: --fast / search=None)')})

    def _uncovered(self) -> np.ndarray:
        """Grid speeds that no branch passes through (e.g. beyond a turning point where the branch
        from the lowest speed went back down)."""
        grid = self.output_grid()
        covered = np.zeros(len(grid), dtype=bool)
        for b in self.branches:
            S = b.column('speed_rpm')
            if len(S) == 1:
                covered |= np.abs(grid - S[0]) < 1e-6
                continue
            lo_seg = np.minimum(S[:-1], S[1:])[:, None] - 1e-6     # every segment of the branch
            hi_seg = np.maximum(S[:-1], S[1:])[:, None] + 1e-6
            covered |= ((grid >= lo_seg) & (grid <= hi_seg)).any(axis=0)
        return grid[~covered]

    def _cover(self, bar) -> None:
        """Start further branches at speeds not reached yet (highest first), both directions."""
        for _ in range(3):
            todo = self._uncovered()
            if len(todo) == 0:
                return
            s0 = float(todo[-1])
            try:
                first = self.hbm.solve(s0)
            except ConvergenceError:
                return
            bid = len(self.branches)
            down = self._trace(first.x, s0, -1.0, bid, 'main', bar)
            up = (self._trace(first.x, s0, +1.0, bid, 'main', bar) if s0 < self.range[1] - 1e-9
                  else down[:1])
            for q in down:
                q.tangent_speed = -q.tangent_speed
            b = Branch(bid, 'main', down[::-1] + up[1:],
                       f'continuation from {s0:g} rpm (speeds the branches before did not reach)')
            self.branches.append(b)
            self._events(b)

    # ---- events along a branch ------------------------------------------------------------------
    def _events(self, b: Branch) -> None:
        pts = b.points
        for a, c in zip(pts[:-1], pts[1:]):
            if a.tangent_speed * c.tangent_speed < 0:
                self.events.append(SweepEvent('fold', b.id, 0.5 * (a.speed_rpm + c.speed_rpm),
                                              'turning point: solutions coexist on one side'))
            if a.stable is not None and c.stable is not None and a.stable != c.stable:
                unstable = c if a.stable else a
                self.events.append(SweepEvent('stability_loss' if a.stable else 'stability_gain',
                                              b.id, 0.5 * (a.speed_rpm + c.speed_rpm),
                                              self._instability_kind(unstable)))

    def _instability_kind(self, p: HBMPoint) -> str:
        mc = self.floquet.classify(p.windup_orders, p.speed_rpm)
        return (f'{mc.kind}: multiplier {mc.multiplier.real:+.3f}{mc.multiplier.imag:+.3f}j, '
                f'dominant half-order n={mc.dominant_n}, '
                f'n=3 mod 6 share {mc.sub_harmonic_share:.2f}')


def sweep(loads: DrivelineExcitation, load: float,
          speed_range: tuple[float, float] = (600.0, 2000.0), *,
          hbm_options: HBMOptions | None = None, options: SweepOptions | None = None,
          continuation=None, progress=False, label: str = '', faults=None) -> SweepResult:
    """Steady-state wind-up over engine speed by condensed HBM + pseudo-arc-length continuation.

    Follows the branch from the lowest speed (turning points included), computes the Floquet
    stability of every point, and switches to 1.5th-order branches where the 3rd-order solution
    loses stability to a sub-harmonic (or, failing that, seeds n = 3 perturbations near the knee).

    Args:
        loads: DrivelineExcitation (driveline with DMF + engine); load: load fraction -1..1.
        speed_range: (from, to) [rpm].
        hbm_options, options, continuation: HBMOptions, SweepOptions, ContinuationOptions.
        progress: show a tqdm bar.
        label: free text stored in the result (e.g. 'alpha=3 Load A').
        faults: a :class:`~dmf_sim.physics.faults.FaultSet` of persistent faults (every-cycle
            misfires, weak cylinders, DMF faults; :mod:`dmf_sim.solvers.hbm.faulted`), None:
            healthy. A fault without a steady state (a single or random misfire, a time
            window, a sensor fault) is refused with one line.
    """
    faults = steady_faults(faults)
    loads, factors = apply_faults(loads, faults)
    hb = CondensedHBM(loads, load, hbm_options, factors)
    res = SpeedSweep(hb, options, continuation).run(speed_range, progress=progress,
                                                    desc=label or 'HBM sweep')
    res.label = label
    res.faults = faults
    return res
