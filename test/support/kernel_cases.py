"""The parity cases of the kernel registry (dmf_sim/solvers/kernel_registry.py): for each case
name an entry of the registry gives, a builder that runs the compiled path and its reference on
small problems and returns their outputs side by side (:class:`Pair`).

test/solvers/test_kernel_parity.py runs every case and compares each pair to the tolerance the
registry entries naming the case state (:func:`assert_parity`). A builder also asserts that its
problem exercises what the kernel is for (a knee crossed, every spring stage visited, the speed
moved): a parity on a linear point would prove little.

The builders live here, not in the registry, because they build test problems (a made-up engine,
an edited spring) the package must not import; the registry holds only the case's name and its
tolerance.
"""
from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
import yaml

from support.fake_engine import FakeEngine

PAPER_SPEED = 1200.0     # rpm: the paper case crosses the knee here
STAGED_SPEED = 850.0     # rpm: the staged spring's wind-up visits every stage (test_multistage)
STAGED_D13_SPEED = 1000.0  # rpm: the staged spring driven by the default engine


@dataclass(frozen=True)
class Pair:
    """One output of the compiled path and the same output of its reference."""

    label: str
    kernel: Any
    reference: Any


@dataclass(frozen=True)
class Unordered:
    """Values whose order is not part of the result (eigenvalues, multipliers): compared as
    sets, each value within the tolerance of one of the others, both ways."""

    values: np.ndarray
    floor: float = 0.0
    """The tolerance's scale is at least this (1 for eigenvalues: the zero matrix)."""


def assert_parity(got: Any, want: Any, rel_tol: float, label: str = '') -> None:
    """``got`` (compiled) equals ``want`` (reference): arrays and floats to ``rel_tol`` times the
    largest magnitude of the reference value (bitwise where ``rel_tol`` is 0), integers, flags
    and strings exactly, None as None; tuples, lists and dicts item by item."""
    if isinstance(want, Unordered):
        a, b = np.asarray(got.values), np.asarray(want.values)
        assert a.shape == b.shape, label
        if a.size:
            bound = rel_tol * max(np.abs(b).max(), want.floor)
            assert np.abs(b[:, None] - a[None, :]).min(axis=1).max() <= bound, label
            assert np.abs(a[:, None] - b[None, :]).min(axis=1).max() <= bound, label
    elif want is None or isinstance(want, (bool, int, str, np.bool_, np.integer)):
        assert got == want, (label, got, want)
    elif dataclasses.is_dataclass(want):
        assert got == want, (label, got, want)
    elif isinstance(want, (tuple, list)):
        assert isinstance(got, (tuple, list)) and len(got) == len(want), label
        for k, (g, w) in enumerate(zip(got, want)):
            assert_parity(g, w, rel_tol, f'{label}[{k}]')
    elif isinstance(want, dict):
        assert set(got) == set(want), label
        for k in want:
            assert_parity(got[k], want[k], rel_tol, f'{label}.{k}')
    else:
        a, b = np.asarray(got), np.asarray(want)
        assert a.shape == b.shape and a.dtype == b.dtype, (label, a.shape, b.shape)
        if rel_tol == 0.0 or not b.size:
            assert np.array_equal(a, b), label
        else:
            assert np.abs(a - b).max() <= rel_tol * np.abs(b).max(), label


class Problems:
    """The small problems the cases run on, each built once (by the first case needing it)."""

    @cached_property
    def engine_d13(self):
        from dmf_sim.physics.engine import read_engine
        engine = read_engine('engine_d13', load_set='A')
        engine.warm_up()
        return engine

    @cached_property
    def paper(self):
        """The paper's two-step spring (alpha = 3) at a speed across its knee."""
        from dmf_sim.physics.loads import DrivelineExcitation
        from dmf_sim.physics.model import read_model
        model = read_model('truck_dmf', alpha=3.0)
        return DrivelineExcitation(model, self.engine_d13), PAPER_SPEED

    @cached_property
    def staged_model(self):
        """A spring with three drive stages and a coast stage."""
        from dmf_sim.core.paths import config_file
        from dmf_sim.physics.model import driveline_from_dict
        d = yaml.safe_load(config_file('truck_dmf').read_text())
        d['dmf'] = {'element': d['dmf']['element'], 'stiffness': 10890,
                    'stages': [{'angle_rad': 0.10, 'stiffness_factor': 1.0},
                               {'angle_rad': 0.14, 'stiffness_factor': 2.5},
                               {'angle_rad': 0.18, 'stiffness_factor': 5.0}],
                    'coast_stages': [{'angle_rad': 0.02, 'stiffness_factor': 1.5}]}
        return driveline_from_dict(d).reduce()

    @cached_property
    def staged(self):
        """The staged spring under a made-up engine whose wind-up visits every stage."""
        from dmf_sim.physics.loads import DrivelineExcitation
        engine = FakeEngine({0: 180.0, 3: 60 + 20j, 6: 3500 - 300j, 12: 200.0})
        return DrivelineExcitation(self.staged_model, engine), STAGED_SPEED

    @cached_property
    def staged_d13(self):
        """The staged spring driven by the default engine (a compiled engine table, as the grid
        runs need)."""
        from dmf_sim.physics.loads import DrivelineExcitation
        return DrivelineExcitation(self.staged_model, self.engine_d13), STAGED_D13_SPEED

    def both(self, name: str):
        """(loads, speed, compiled problem, reference problem) of the case ``name``."""
        from dmf_sim.solvers.hbm import CondensedHBM, HBMOptions
        loads, speed = getattr(self, name)
        return (loads, speed, CondensedHBM(loads, 1.0),
                CondensedHBM(loads, 1.0, HBMOptions(compiled=False)))


SPRINGS = ('paper', 'staged')
"""The two springs most cases run on."""

Builder = Callable[[Problems], Iterator[Pair]]
CASES: dict[str, Builder] = {}
"""The case builders by name (the names the registry entries give)."""

def case(name: str) -> Callable[[Builder], Builder]:
    """Register the decorated builder as the case ``name``."""
    def register(fn: Builder) -> Builder:
        CASES[name] = fn
        return fn
    return register


def trial_points(hb, speed, n=6, seed=3):
    """Wind-up harmonics around the linear response, large enough that part of every cycle lies
    beyond a knee (some on the coast side for the staged spring)."""
    x0 = hb.linear_solution(speed)
    rng = np.random.default_rng(seed)
    return [x0 + 0.5 * np.abs(x0).max() * rng.standard_normal(len(x0)) for _ in range(n)]


@case('aft')
def aft(p: Problems) -> Iterator[Pair]:
    """The AFT harmonics of the spring torque with their Jacobian, and the residual with its
    Jacobian, at wind-ups beyond the knees."""
    for name in SPRINGS:
        loads, speed, hb, ref = p.both(name)
        lp = hb.linear_parts(speed)
        sp = loads.model.spring
        w = np.concatenate([hb.windup_samples(x) for x in trial_points(hb, speed)])
        assert np.count_nonzero(sp.stage(w)) > 0          # the points do exercise the stages
        if name == 'staged':
            assert set(np.unique(sp.stage(w))) == set(sp.stages())   # every region, coast too
        for k, x in enumerate(trial_points(hb, speed)):
            yield Pair(f'{name} G, dG {k}', hb.nonlinear_harmonics(x, jacobian=True),
                       ref.nonlinear_harmonics(x, jacobian=True))
            yield Pair(f'{name} r, J {k}', hb.residual_and_jacobian(x, lp),
                       ref.residual_and_jacobian(x, lp))


@case('linear parts')
def linear_parts(p: Problems) -> Iterator[Pair]:
    """h_n, wlin_n and their speed derivatives: the compiled modal sums vs numpy, at one speed
    and in a prepared batch."""
    for name in SPRINGS:
        loads, speed, hb, ref = p.both(name)
        hb.prepare([speed - 10.0, speed, speed + 10.0])
        for s in (speed, speed + 3.7):
            a, b = hb.linear_parts(s), ref.linear_parts(s)
            for field in ('h', 'wlin', 'dh_ds', 'dwlin_ds'):
                yield Pair(f'{name} {field} at {s}', getattr(a, field), getattr(b, field))


@case('linear parts of a grid')
def linear_parts_grid(p: Problems) -> Iterator[Pair]:
    """A sweep's grid in one kernel call with the engine query compiled (the engine's speed
    table) vs the numpy batch, at the top of the range too."""
    from dmf_sim.solvers.hbm import CondensedHBM
    loads, _ = p.paper
    hb = CondensedHBM(loads, 1.0)
    lo, top = hb._speed_range()
    speeds = [lo, 610.0, 1234.567, 1500.0, 1700.25, 1800.0, 1900.0, 1950.0, top - 0.01, top]
    fast = hb._linear_parts_compiled(speeds)
    assert fast is not None and len(fast) == len(speeds)
    for a, b in zip(fast, CondensedHBM(loads, 1.0)._linear_parts_many(speeds)):
        for field in ('speed_rpm', 'omega', 'h', 'wlin', 'dh_ds', 'dwlin_ds'):
            yield Pair(f'{field} at {b.speed_rpm}', getattr(a, field), getattr(b, field))
        yield Pair(f'lin, dlin at {b.speed_rpm}', (a.lin[0], a.dlin[0]), (b.lin[0], b.dlin[0]))


@case('continuation jacobians')
def continuation_jacobians(p: Problems) -> Iterator[Pair]:
    """What the continuation asks off the grid, (r, dr/dx, dr/ds) in one compiled call, and the
    real layouts of wlin and dwlin the kernels read."""
    for name in SPRINGS:
        loads, speed, hb, ref = p.both(name)
        s = speed + 3.7
        a, b = hb.linear_parts(s), ref.linear_parts(s)
        yield Pair(f'{name} lin, dlin', (a.lin[0], a.dlin[0]), (b.lin[0], b.dlin[0]))
        for k, x in enumerate(trial_points(hb, speed)):
            yield Pair(f'{name} r, dr/dx, dr/ds {k}', tuple(hb.residual_and_jacobians(x, s)),
                       tuple(ref.residual_and_jacobians(x, s)))


@case('off-grid jacobians')
def off_grid_jacobians(p: Problems) -> Iterator[Pair]:
    """(r, dr/dx, dr/ds) at a speed not prepared, with the linear parts and the engine query
    inside the kernel, vs the Python linear parts and the AFT kernel."""
    from dmf_sim.solvers.hbm import CondensedHBM, kernels
    loads, speed = p.paper
    hb = CondensedHBM(loads, 1.0)
    top = hb._speed_range()[1]
    for s in (speed + 3.7, speed - 41.3, top - 0.01):
        for k, x in enumerate(trial_points(hb, speed, n=3)):
            got = hb.residual_and_jacobians(x, s)
            lp = CondensedHBM(loads, 1.0)._linear_parts_one(s)
            want = kernels.residual_jacobians_py(x, lp.lin, lp.dlin, hb._aft_mats,
                                                 hb._spring_arrays)
            yield Pair(f'{s} {k}', tuple(got), tuple(want))
        assert s not in hb._cache          # computed in the kernel, not through the cache


@case('newton')
def newton(p: Problems) -> Iterator[Pair]:
    for name in SPRINGS:
        loads, speed, hb, ref = p.both(name)
        a, b = hb.solve(speed), ref.solve(speed)
        assert a.iterations > 0 and a.residual <= hb.options.tol
        yield Pair(f'{name} iterations, x', (a.iterations, a.x), (b.iterations, b.x))


@case('deflated newton')
def deflated_newton(p: Problems) -> Iterator[Pair]:
    """Deflated Newton from points around the linear response, one solution deflated: the same
    outcome, iterations and point."""
    from dmf_sim.solvers.hbm.deflation import DeflatedNewton
    for name in SPRINGS:
        loads, speed, hb, ref = p.both(name)
        lp = hb.linear_parts(speed)
        known = np.array([hb.solve(speed).x])
        for k, x0 in enumerate(trial_points(hb, speed, n=4, seed=7)):
            a = DeflatedNewton(hb).solve(lp, x0, known)
            b = DeflatedNewton(ref).solve(lp, x0, known)
            yield Pair(f'{name} seed {k}', a and (a[0], a[1]), b and (b[0], b[1]))


@case('deflated seeds')
def deflated_seeds(p: Problems) -> Iterator[Pair]:
    """DeflatedNewton.solve_first (a search pass's seeds in one kernel call) vs solve() seed by
    seed: the first seed from ``start`` on that solve() brings to a solution, with its result;
    None where none does. Without and with the solution deflated, and with a seed on a deflated
    solution (converged as is)."""
    from dmf_sim.solvers.hbm.deflation import DeflatedNewton
    for name in SPRINGS:
        loads, speed, hb, _ = p.both(name)
        lp = hb.linear_parts(speed)
        sol = hb.solve(speed).x
        seeds = np.array(trial_points(hb, speed, n=6, seed=7))
        on_solution = seeds.copy()
        on_solution[3] = sol
        runs = {'none deflated': (seeds, np.empty((0, len(sol)))),
                'one deflated': (seeds, sol[None]), 'a seed on it': (on_solution, sol[None])}
        for label, (xs, known) in runs.items():
            one = [DeflatedNewton(hb).solve(lp, x0, known) for x0 in xs]
            hits = [i for i, s in enumerate(one) if s is not None]
            if label != 'one deflated':
                assert hits                          # some seed converges
            for start in range(len(xs) + 1):
                later = [i for i in hits if i >= start]
                want = (later[0], *one[later[0]]) if later else None
                got = DeflatedNewton(hb).solve_first(lp, xs, known, start)
                yield Pair(f'{name} {label} from {start}', got and tuple(got), want)


def _grid_predictor(hb, speed, xs=0.01, ss=10.0):
    """A predictor at the next grid speed from the solution at ``speed``, and the normal e_S."""
    x = hb.solve(speed).x
    y_pred = np.concatenate([x * 1.05 / xs, [(speed + 10.0) / ss]])
    normal = np.zeros(len(y_pred))
    normal[-1] = 1.0
    return y_pred, normal, xs, ss


@case('grid corrector')
def grid_corrector(p: Problems) -> Iterator[Pair]:
    """continuation.correct on a grid speed: one compiled call (CondensedSteps.corrector_at) vs
    the reference iteration over residual_and_jacobians."""
    from dmf_sim.solvers import continuation
    for name in SPRINGS:
        loads, speed, hb, ref = p.both(name)
        y_pred, normal, xs, ss = _grid_predictor(hb, speed)
        a = continuation.correct(hb, y_pred, normal, xs, ss, 1e-10, 12, steps=hb.compiled_steps())
        b = continuation.correct(ref, y_pred, normal, xs, ss, 1e-10, 12,
                                 steps=ref.compiled_steps())
        assert a[1] > 0
        assert np.abs(a[3][0]).max() <= 1e-10 and np.abs(b[3][0]).max() <= 1e-10  # rounding noise
        yield Pair(f'{name} y, iterations, dr/dx, dr/ds', (a[0], a[1], a[3][1], a[3][2]),
                   (b[0], b[1], b[3][1], b[3][2]))


@case('grid step')
def grid_step(p: Problems) -> Iterator[Pair]:
    """A continuation step on a grid speed in one compiled call (CondensedSteps.step_at, through
    continuation.correct_step) vs the corrector's point and the tangent there in two calls."""
    from dmf_sim.solvers import continuation
    for name in SPRINGS:
        loads, speed, hb, _ = p.both(name)
        y_pred, normal, xs, ss = _grid_predictor(hb, speed)
        prev = np.zeros(len(y_pred))
        prev[-1], prev[0] = 0.8, 0.6
        steps = hb.compiled_steps()
        y, it, res, t = continuation.correct_step(hb, y_pred, normal, prev, xs, ss, 1e-10, 12,
                                                  steps=steps)
        a = continuation.correct(hb, y_pred, normal, xs, ss, 1e-10, 12, steps=steps)
        ta = continuation.tangent_of(a[3][1], a[3][2], prev, xs, ss, steps)
        yield Pair(f'{name} y, iterations, residual, tangent', (y, it, res, t),
                   (a[0], a[1], a[2], ta))


@case('tangent')
def tangent(p: Problems) -> Iterator[Pair]:
    """The continuation's unit tangent at a point (one compiled call with the kernels' LU) vs
    continuation._tangent (numpy, LAPACK), oriented along the previous one and against it."""
    from dmf_sim.solvers import continuation
    for name in SPRINGS:
        loads, speed, hb, _ = p.both(name)
        s, xs, ss = speed + 3.7, 0.01, 10.0
        rng = np.random.default_rng(5)
        for k, x in enumerate(trial_points(hb, speed)):
            _, Jx, rs = hb.residual_and_jacobians(x, s)
            prev = rng.standard_normal(len(x) + 1)
            prev /= np.linalg.norm(prev)
            for sign in (1.0, -1.0):
                yield Pair(f'{name} {k} {sign:+}',
                           continuation.tangent_of(Jx, rs, sign * prev, xs, ss,
                                                   hb.compiled_steps()),
                           continuation._tangent(Jx, rs, sign * prev, xs, ss))


def arc_step(hb, speed, h=0.6):
    """A pseudo-arc-length predictor from the solution at ``speed`` along its tangent."""
    from dmf_sim.solvers import continuation
    xs, ss = 0.01, 10.0
    x = hb.solve(speed).x
    r, Jx, rs = hb.residual_and_jacobians(x, speed)
    prev = np.zeros(len(x) + 1)
    prev[-1] = 1.0
    t = continuation._tangent(Jx, rs, prev, xs, ss)
    y = np.concatenate([x / xs, [speed / ss]])
    return y + h * t, t, xs, ss


@case('arc-length corrector')
def arc_corrector(p: Problems) -> Iterator[Pair]:
    """continuation.correct with the tangent as normal: one compiled call
    (CondensedSteps.corrector_arc, every iterate's linear parts in the kernel) vs the reference
    iteration over the numpy residual and Jacobians."""
    from dmf_sim.solvers import continuation
    loads, speed, hb, ref = p.both('paper')
    y_pred, t, xs, ss = arc_step(hb, speed)
    assert hb.steps.corrector_arc(y_pred, t, xs, ss, 1e-10, 12) is not None
    a = continuation.correct(hb, y_pred, t, xs, ss, 1e-10, 12, steps=hb.compiled_steps())
    b = continuation.correct(ref, y_pred, t, xs, ss, 1e-10, 12, steps=ref.compiled_steps())
    assert a[1] > 0 and a[0][-1] != y_pred[-1]        # the speed moved: an arc-length step
    assert np.abs(a[3][0]).max() <= 1e-10
    yield Pair('y, iterations, dr/dx, dr/ds', (a[0], a[1], a[3][1], a[3][2]),
               (b[0], b[1], b[3][1], b[3][2]))


GRID_RUN_OPTIONS = {
    'default': {},
    'retries': {'max_turn': 0.05, 'step_max': 0.6},     # rejected grid steps: the loop retries
    'few steps': {'max_steps': 25},                      # the run stops at the step budget
}
"""The continuation options the grid runs are checked under."""


def branch(hb, x0, s0, bounds, options, grid_run, fast_forward=None):
    """continue_branch on hb with ``grid_run`` as its grid runs (None: every step taken by the
    Python loop); (points, why the branch ended)."""
    from dmf_sim.solvers import continuation
    ended = []
    steps = dataclasses.replace(hb.compiled_steps(), grid_run=grid_run)
    pts = continuation.continue_branch(
        hb, continuation.BranchStart(x0, s0, bounds, 1.0), options,
        continuation.BranchHooks(fast_forward=fast_forward,
                                 on_end=lambda why, p: ended.append(why), steps=steps))
    return pts, ended[0]


@case('grid runs')
def grid_runs(p: Problems) -> Iterator[Pair]:
    """continue_branch with the problem's compiled grid runs (CondensedSteps.grid_run, which
    calls the compiled step control) vs the Python loop taking every step itself: x, speed,
    tangent, iterations, residual, on-grid flag, and the same end; across the knee (grid steps,
    a turning region's arc-length steps), with rejected grid steps retried by the loop and with
    a step budget the run stops at."""
    from dmf_sim.solvers import continuation
    from dmf_sim.solvers.hbm import CondensedHBM
    for name in ('paper', 'staged_d13'):
        loads, speed = getattr(p, name)
        for variant, opts in GRID_RUN_OPTIONS.items():
            hb = CondensedHBM(loads, 1.0)
            o = continuation.ContinuationOptions(**{'grid': 10.0, 's_scale': 10.0, **opts})
            lo, hi = speed - 350.0, speed + 250.0           # from below the knee (a linear start)
            x0 = hb.solve(lo).x
            made = []

            def run(*args):
                out = hb.steps.grid_run(*args)
                made.append(len(out.s))
                return out

            a, why_a = branch(hb, x0, lo, (lo, hi), o, run)
            b, why_b = branch(hb, x0, lo, (lo, hi), o, None)
            assert sum(made) >= 5 and len(b) > 3
            assert (why_b == 'max_steps') == (variant == 'few steps')
            label = f'{name} {variant}'
            yield Pair(f'{label} end, points', (why_a, len(a)), (why_b, len(b)))
            for k, (u, v) in enumerate(zip(a, b)):
                yield Pair(f'{label} point {k}',
                           (u.s, u.x, u.tangent, u.iterations, u.residual, u.on_grid),
                           (v.s, v.x, v.tangent, v.iterations, v.residual, v.on_grid))


@case('floquet')
def floquet(p: Problems) -> Iterator[Pair]:
    """The Floquet multipliers, crossings and segments of solutions around the knee."""
    from dmf_sim.solvers.stability import FloquetAnalyzer
    for name in SPRINGS:
        loads, speed, hb, _ = p.both(name)
        fa = FloquetAnalyzer(loads.model, modes=hb.modes)
        fr = FloquetAnalyzer(loads.model, modes=hb.modes, compiled=False)
        crossings = 0
        for s in (speed - 50.0, speed, speed + 50.0):
            try:
                c = hb.solve(s).windup_orders
            except Exception:
                continue
            a, b = fa.analyze(c, s), fr.analyze(c, s)
            crossings += a.n_crossings

            def fields(r):
                return (r.n_crossings, r.stable, [st for st, _ in r.segments],
                        np.array([t for _, t in r.segments]), Unordered(r.multipliers),
                        r.max_abs)
            yield Pair(f'{name} at {s}', fields(a), fields(b))
        assert crossings > 0


@case('traced points')
def traced_points(p: Problems) -> Iterator[Pair]:
    """``SpeedSweep._points`` (the points of a traced branch, made after the trace: one FFT, one
    summary pass, one compiled Floquet call for all) vs making each point and analyzing it
    alone, for points below the knees (closed-form multipliers) and across them, and with
    friction and end stops (the batch of step-by-step monodromies)."""
    paper, _ = p.paper
    for loads, speeds in ((paper, (700.0, 1250.0, 1300.0, 1333.3, 1500.0)),
                          (_friction(p), (800.0, FRICTION_SPEED, 1500.0))):
        yield from _traced_points(loads, speeds)


def _traced_points(loads, speeds) -> Iterator[Pair]:
    """The pairs of :func:`traced_points` at ``speeds`` [rpm] of one driveline."""
    from dmf_sim.solvers.continuation import ContinuationPoint
    from dmf_sim.solvers.hbm import CondensedHBM, SweepOptions
    from dmf_sim.solvers.hbm.sweep import SpeedSweep
    sw = SpeedSweep(CondensedHBM(loads, 1.0), SweepOptions(step_rpm=10.0, search=None))
    hb, fl = sw.hbm, sw.floquet
    cps = []
    for k, s in enumerate(speeds):
        x = hb.solve(s).x
        t = np.r_[np.zeros(len(x)), 0.5 + 0.1 * k]
        cps.append(ContinuationPoint(x, s, t, k + 1, 1e-12 * k, True))
    made = sw._points(cps, 3, 'subharmonic')
    assert len(made) == len(cps) and sw._points([], 0, 'main') == []
    crossing = 0
    for cp, a in zip(cps, made):
        lp = hb.linear_parts(cp.s)
        q = hb.make_point(cp.s, cp.x, cp.residual, cp.iterations, wlin0=float(lp.wlin[0].real))
        fr = fl.analyze(q.windup_orders, cp.s)
        crossing += fr.n_crossings > 0
        yield Pair(f'point at {cp.s}',
                   (a.speed_rpm, a.residual, a.iterations, a.x, a.windup_orders, a.summary,
                    a.branch, a.kind, a.tangent_speed, a.forced_order_1_5, a.stable,
                    a.max_multiplier, a.multipliers),
                   (q.speed_rpm, q.residual, q.iterations, q.x, q.windup_orders, q.summary,
                    3, 'subharmonic', cp.tangent[-1], abs(lp.wlin[3]), fr.stable, fr.max_abs,
                    fr.multipliers))
    assert 0 < crossing < len(cps)


def eigen_matrices() -> list[np.ndarray]:
    """Random and hard matrices for the eigenvalue call: sizes 1 to 64, badly scaled,
    triangular, zero, a repeated eigenvalue, the roots of unity, known complex pairs."""
    rng = np.random.default_rng(2026)
    out = [rng.standard_normal((n, n)) for n in (1, 2, 3, 4, 5, 7, 16, 32, 33, 64)]
    D = np.diag(10.0 ** rng.integers(-6, 7, 12))        # badly scaled: balancing's work
    out.append(D @ rng.standard_normal((12, 12)) @ np.linalg.inv(D))
    out.append(np.triu(rng.standard_normal((9, 9))))     # triangular: the diagonal
    out.append(np.zeros((5, 5)))
    out.append(3.0 * np.eye(4))                          # one eigenvalue, repeated
    out.append(np.roll(np.eye(6), 1, axis=1))            # cyclic shift: the 6th roots of unity
    # known complex pairs under an orthogonal similarity
    B = np.zeros((8, 8))
    for k, (s, w) in enumerate(((-0.1, 2.0), (0.3, 0.5), (-2.0, 7.0), (1e-3, 1e3))):
        B[2 * k:2 * k + 2, 2 * k:2 * k + 2] = [[s, w], [-w, s]]
    Q, _ = np.linalg.qr(rng.standard_normal((8, 8)))
    out.append(Q @ B @ Q.T)
    return out


def eigenvalues_of(X: np.ndarray, max_iter: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(real parts, imaginary parts) by the compiled call, which leaves ``X`` as it was."""
    from dmf_sim.solvers.francis_qr import MAX_ITER
    from dmf_sim.solvers.lapack_kernel import eigenvalues_into
    keep = X.copy()
    wr, wi = np.empty(len(X)), np.empty(len(X))
    assert eigenvalues_into(X, wr, wi, MAX_ITER if max_iter is None else max_iter) == 0
    assert np.array_equal(X, keep)                      # X is not touched
    return wr, wi


@case('eigenvalues')
def eigenvalues(p: Problems) -> Iterator[Pair]:
    """The compiled eigenvalue call (balancing, Hessenberg, double-shift QR) vs numpy's eigvals
    on random and hard matrices: the same set of eigenvalues, as many real ones."""
    for k, X in enumerate(eigen_matrices()):
        wr, wi = eigenvalues_of(X)
        ref = np.linalg.eigvals(X)
        yield Pair(f'matrix {k}', Unordered(wr + 1j * wi),
                   Unordered(ref.astype(complex), floor=1.0))
        yield Pair(f'matrix {k} real ones', int((wi == 0).sum()), int((ref.imag == 0).sum()))


@case('newmark step')
def newmark_step(p: Problems) -> Iterator[Pair]:
    """4000 Newmark steps at 850 rpm through the knee: the compiled advance vs the reference
    (phase, loads and the friction law step by step in numpy)."""
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_model
    from dmf_sim.solvers.newmark import NewmarkIntegrator, StepRecord
    engine = FakeEngine({0: 400.0, 3: 150 + 50j, 6: 700 - 300j, 12: 250 + 100j})
    loads = DrivelineExcitation(read_model('truck_dmf', alpha=3.0), engine)
    out = []
    for use_numba in (True, False):
        integ = NewmarkIntegrator(loads, dt=1e-4, use_numba=use_numba)
        integ.reset(850, 1.0)
        rec = StepRecord.allocate(4000, loads.model.n_dof)
        integ.advance(4000, rec, 1)
        out.append((rec.q.copy(), rec.windup.copy(), integ.knee_crossings))
    assert out[1][2] > 0
    yield Pair('q, windup, knee crossings', out[0], out[1])


FRICTION_SPEED = 1200.0   # rpm: the example friction DMF slips over most of the cycle here


def _friction(p: Problems):
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_model
    return DrivelineExcitation(read_model('truck_dmf_friction'), p.engine_d13)


@case('aft with friction')
def aft_with_friction(p: Problems) -> Iterator[Pair]:
    """The AFT of g + T_f + T_s with its Jacobian and speed derivative, the friction slipping
    and the drive stop reached in the cycle."""
    from dmf_sim.solvers.hbm import CondensedHBM, HBMOptions
    loads, s = _friction(p), FRICTION_SPEED
    hb = CondensedHBM(loads, 1.0, HBMOptions(n_harmonics=8))
    ref = CondensedHBM(loads, 1.0, HBMOptions(n_harmonics=8, compiled=False))
    lp = hb.linear_parts(s)
    rng = np.random.default_rng(3)
    for k in range(4):
        x = hb.linear_solution(s)
        x[0] = 0.44                                # the drive stop at 0.45 rad is reached
        x[1:] += 2e-3 * rng.standard_normal(len(x) - 1)
        assert (hb.windup_samples(x) > hb.spring.stops.drive_angle_rad).any()
        yield Pair(f'G, dG {k}', hb.nonlinear_harmonics(x, True, speed_rpm=s),
                   ref.nonlinear_harmonics(x, True, speed_rpm=s))
        yield Pair(f'dr/ds {k}', hb.residual_and_jacobians(x, s)[2],
                   ref.residual_speed_derivative(x, lp))


@case('floquet with friction')
def floquet_with_friction(p: Problems) -> Iterator[Pair]:
    """The Floquet multipliers of solutions with friction: the compiled splitting of the
    monodromy against its numpy twin."""
    from dmf_sim.solvers.hbm import CondensedHBM
    from dmf_sim.solvers.stability import FloquetAnalyzer
    loads = _friction(p)
    hb = CondensedHBM(loads, 1.0)
    fa = FloquetAnalyzer(loads.model, modes=hb.modes)
    fr = FloquetAnalyzer(loads.model, modes=hb.modes, compiled=False)
    for s in (1000.0, FRICTION_SPEED):
        c = hb.solve(s).windup_orders
        a, b = fa.analyze(c, s), fr.analyze(c, s)
        yield Pair(f'at {s}', (a.stable, Unordered(a.multipliers), a.max_abs),
                   (b.stable, Unordered(b.multipliers), b.max_abs))
