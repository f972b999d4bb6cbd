"""The compiled hot paths of a sweep point against their readable numpy reference:
AFT residual and Jacobian, Newton, deflated Newton, the continuation corrector on a grid speed and
the Floquet multipliers, on the paper's two-step spring and on a spring with three drive stages
and a coast stage; and a whole sweep both ways (same branches, events and stable states)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml
from support.fake_engine import FakeEngine

from dmf_sim.core.paths import config_file
from dmf_sim.physics.engine import read_engine
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import driveline_from_dict, read_model
from dmf_sim.solvers import continuation
from dmf_sim.solvers.hbm import CondensedHBM, HBMOptions, SweepOptions, sweep
from dmf_sim.solvers.hbm.deflation import DeflatedNewton
from dmf_sim.solvers.stability import FloquetAnalyzer

REL_TOL = 1e-10          # compiled vs reference, relative to the largest entry
PAPER_SPEED = 1200.0     # rpm: the paper case crosses the knee here
STAGED_SPEED = 850.0     # rpm: the staged spring's wind-up visits every stage (test_multistage)


@pytest.fixture(scope='module')
def paper():
    eng = read_engine('engine_d13', load_set='A')
    eng.warm_up()
    return DrivelineExcitation(read_model('truck_dmf', alpha=3.0), eng), PAPER_SPEED


@pytest.fixture(scope='module')
def staged():
    d = yaml.safe_load(config_file('truck_dmf').read_text())
    d['dmf'] = {'element': d['dmf']['element'], 'stiffness': 10890,
                'stages': [{'angle_rad': 0.10, 'stiffness_factor': 1.0},
                           {'angle_rad': 0.14, 'stiffness_factor': 2.5},
                           {'angle_rad': 0.18, 'stiffness_factor': 5.0}],
                'coast_stages': [{'angle_rad': 0.02, 'stiffness_factor': 1.5}]}
    engine = FakeEngine({0: 180.0, 3: 60 + 20j, 6: 3500 - 300j, 12: 200.0})
    return DrivelineExcitation(driveline_from_dict(d).reduce(), engine), STAGED_SPEED


CASES = ['paper', 'staged']


@pytest.fixture(scope='module')
def staged_d13(staged):
    """The staged spring driven by the default engine (a compiled engine table, as the grid
    runs need)."""
    loads, _ = staged
    eng = read_engine('engine_d13', load_set='A')
    eng.warm_up()
    return DrivelineExcitation(loads.model, eng), 1000.0


def both(loads):
    return (CondensedHBM(loads, 1.0), CondensedHBM(loads, 1.0, HBMOptions(compiled=False)))


def close(a, b):
    return np.abs(np.asarray(a) - np.asarray(b)).max() <= REL_TOL * np.abs(b).max()


def trial_points(hb, speed, n=6, seed=3):
    """Wind-up harmonics around the linear response, large enough that part of every cycle lies
    beyond a knee (some on the coast side for the staged spring)."""
    x0 = hb.linear_solution(speed)
    rng = np.random.default_rng(seed)
    return [x0 + 0.5 * np.abs(x0).max() * rng.standard_normal(len(x0)) for _ in range(n)]


@pytest.mark.parametrize('case', CASES)
def test_aft_residual_and_jacobian_equal_reference(case, request):
    loads, speed = request.getfixturevalue(case)
    hb, ref = both(loads)
    lp = hb.linear_parts(speed)
    sp = loads.model.spring
    beyond = 0
    for x in trial_points(hb, speed):
        w = hb.windup_samples(x)
        beyond += int(np.count_nonzero(sp.stage(w)))
        G, dG = hb.nonlinear_harmonics(x, jacobian=True)
        Gr, dGr = ref.nonlinear_harmonics(x, jacobian=True)
        assert close(G, Gr) and close(dG, dGr)
        r, J = hb.residual_and_jacobian(x, lp)
        rr, Jr = ref.residual_and_jacobian(x, lp)
        assert close(r, rr) and close(J, Jr)
    assert beyond > 0                     # the trial points do exercise the stages
    if case == 'staged':
        w = np.concatenate([hb.windup_samples(x) for x in trial_points(hb, speed)])
        assert set(np.unique(sp.stage(w))) == set(sp.stages())   # every region, coast too


@pytest.mark.parametrize('case', CASES)
def test_linear_parts_equal_reference(case, request):
    """h_n, wlin_n and their speed derivatives: compiled modal sums vs numpy, one speed and a
    prepared batch."""
    loads, speed = request.getfixturevalue(case)
    hb, ref = both(loads)
    hb.prepare([speed - 10.0, speed, speed + 10.0])
    for s in (speed, speed + 3.7):
        a, b = hb.linear_parts(s), ref.linear_parts(s)
        for name in ('h', 'wlin', 'dh_ds', 'dwlin_ds'):
            assert close(getattr(a, name), getattr(b, name)), name


@pytest.mark.parametrize('case', CASES)
def test_continuation_jacobians_equal_reference(case, request):
    """What the continuation asks off the grid, (r, dr/dx, dr/ds) in one compiled call, and the
    real layouts of wlin and dwlin the kernels read, against the numpy reference."""
    loads, speed = request.getfixturevalue(case)
    hb, ref = both(loads)
    s = speed + 3.7
    a, b = hb.linear_parts(s), ref.linear_parts(s)
    assert close(a.lin[0], b.lin[0]) and close(a.dlin[0], b.dlin[0])
    for x in trial_points(hb, speed):
        got, want = hb.residual_and_jacobians(x, s), ref.residual_and_jacobians(x, s)
        for g, w in zip(got, want):
            assert close(g, w)


@pytest.mark.parametrize('case', CASES)
def test_continuation_tangent_equals_reference(case, request):
    """The continuation's unit tangent at a point (CondensedSteps.tangent, one compiled call with
    the kernels' LU) against continuation._tangent (numpy, LAPACK): the same vector, oriented
    along the previous one; a singular bordered system raises LinAlgError both ways, and the
    reference problem leaves the tangent to the reference."""
    loads, speed = request.getfixturevalue(case)
    hb, ref = both(loads)
    s, xs, ss = speed + 3.7, 0.01, 10.0
    rng = np.random.default_rng(5)
    for x in trial_points(hb, speed):
        _, Jx, rs = hb.residual_and_jacobians(x, s)
        prev = rng.standard_normal(len(x) + 1)
        prev /= np.linalg.norm(prev)
        got = continuation.tangent_of(Jx, rs, prev, xs, ss, hb.compiled_steps())
        want = continuation._tangent(Jx, rs, prev, xs, ss)
        assert close(got, want)
        assert abs(np.linalg.norm(got) - 1.0) <= 1e-12 and got @ prev > 0
        assert np.abs(Jx @ got[:-1] * xs + rs * got[-1] * ss).max() <= 1e-10 * np.abs(Jx).max()
        flipped = continuation.tangent_of(Jx, rs, -prev, xs, ss, hb.compiled_steps())
        assert close(flipped, -want)
    assert ref.steps.tangent(Jx, rs, prev, xs, ss) is None
    zero = np.zeros_like(Jx)
    for tangent in (lambda: hb.steps.tangent(zero, rs * 0.0, prev, xs, ss),
                    lambda: continuation._tangent(zero, rs * 0.0, prev, xs, ss)):
        with pytest.raises(np.linalg.LinAlgError):
            tangent()


def test_warm_up_compiles_the_tangent(paper):
    """warm_up loads the tangent kernel too: a sweep adds no signature to it."""
    from dmf_sim.solvers.hbm import continuation_kernels
    from dmf_sim.solvers.hbm.warm import warm_up
    warm_up()
    before = len(continuation_kernels.tangent.signatures)
    assert before >= 1
    loads, _ = paper
    sweep(loads, 1.0, (1150.0, 1250.0), options=SweepOptions(step_rpm=10.0, search=None))
    assert len(continuation_kernels.tangent.signatures) == before


def test_primary_only_is_the_linear_problem(paper):
    loads, _ = paper
    hb, _ = both(loads)
    lp = hb.linear_parts(700.0)                     # far below the knee
    x = hb.linear_solution(700.0)
    r, J = hb.residual_and_jacobian(x, lp)
    assert np.abs(r).max() == 0.0 and np.array_equal(J, np.eye(len(x)))
    G, dG = hb.nonlinear_harmonics(x, jacobian=True)
    assert dG is None and not G.any()


@pytest.mark.parametrize('case', CASES)
def test_newton_equals_reference(case, request):
    loads, speed = request.getfixturevalue(case)
    hb, ref = both(loads)
    p, q = hb.solve(speed), ref.solve(speed)
    assert p.iterations == q.iterations and p.iterations > 0
    assert close(p.x, q.x) and p.residual <= hb.options.tol


def test_newton_failure_is_the_reference_failure(paper):
    """At 1000 rpm Newton from the linear response stalls (the sweep approaches this speed by
    continuation instead): the compiled solver gives up the same way."""
    loads, _ = paper
    msgs = []
    for hb in both(loads):
        with pytest.raises(Exception) as exc:
            hb.solve(1000.0)
        msgs.append(str(exc.value))
    assert msgs[0] == msgs[1] and 'stalled' in msgs[0]


@pytest.mark.parametrize('case', CASES)
def test_deflated_newton_equals_reference(case, request):
    loads, speed = request.getfixturevalue(case)
    hb, ref = both(loads)
    lp = hb.linear_parts(speed)
    known = np.array([hb.solve(speed).x])
    for x0 in trial_points(hb, speed, n=4, seed=7):
        a = DeflatedNewton(hb).solve(lp, x0, known)
        b = DeflatedNewton(ref).solve(lp, x0, known)
        assert (a is None) == (b is None)
        if a is not None:
            assert a[1] == b[1] and close(a[0], b[0])


@pytest.mark.parametrize('case', CASES)
def test_deflated_seeds_in_one_call_are_the_seeds_one_by_one(case, request):
    """DeflatedNewton.solve_first (a search pass's seeds in one kernel call) stops at the first
    seed from ``start`` on that solve() brings to a solution, with bitwise its result; the
    reference path agrees; None where no seed converges."""
    loads, speed = request.getfixturevalue(case)
    hb, ref = both(loads)
    lp = hb.linear_parts(speed)
    sol = hb.solve(speed).x
    seeds = np.array(trial_points(hb, speed, n=6, seed=7))
    found = [check_seeds(hb, ref, lp, seeds, known)     # without and with the solution deflated
             for known in (np.empty((0, len(sol))), sol[None])]
    seeds[3] = sol                                # a seed on a deflated solution: converged as is
    with np.errstate(over='ignore', invalid='ignore'):  # the reference's M(x) there is inf
        found.append(check_seeds(hb, ref, lp, seeds, sol[None]))
    assert found[0] > 0 and found[2] > 0


def check_seeds(hb, ref, lp, seeds, known):
    one = [DeflatedNewton(hb).solve(lp, x0, known) for x0 in seeds]
    hits = [i for i, sol in enumerate(one) if sol is not None]
    for start in range(len(seeds) + 1):
        got = DeflatedNewton(hb).solve_first(lp, seeds, known, start)
        later = [i for i in hits if i >= start]
        if not later:
            assert got is None and DeflatedNewton(ref).solve_first(lp, seeds, known, start) is None
            continue
        i = later[0]
        assert got[0] == i and np.array_equal(got[1], one[i][0])
        assert (got[2], got[3]) == (one[i][1], one[i][2])
        r = DeflatedNewton(ref).solve_first(lp, seeds, known, start)
        assert r[0] == i and r[2] == got[2] and close(r[1], got[1])
    return len(hits)


@pytest.mark.parametrize('case', CASES)
def test_grid_corrector_equals_reference(case, request):
    """continuation.correct on a grid speed: one compiled call (CondensedSteps.corrector_at) vs the
    reference iteration over residual_and_jacobians."""
    loads, speed = request.getfixturevalue(case)
    hb, ref = both(loads)
    xs, ss = 0.01, 10.0
    x = hb.solve(speed).x
    y_pred = np.concatenate([x * 1.05 / xs, [(speed + 10.0) / ss]])   # next grid speed
    normal = np.zeros(len(y_pred))
    normal[-1] = 1.0
    a = continuation.correct(hb, y_pred, normal, xs, ss, 1e-10, 12, steps=hb.compiled_steps())
    b = continuation.correct(ref, y_pred, normal, xs, ss, 1e-10, 12, steps=ref.compiled_steps())
    assert a[1] == b[1] and a[1] > 0
    assert close(a[0], b[0])
    r, Jx, rs = a[3]
    assert np.abs(r).max() <= 1e-10 and np.abs(b[3][0]).max() <= 1e-10   # rounding noise
    assert close(Jx, b[3][1]) and close(rs, b[3][2])                      # dr/dx, dr/ds


@pytest.mark.parametrize('case', CASES)
def test_grid_step_in_one_call_is_corrector_then_tangent(case, request):
    """A continuation step on a grid speed in one compiled call (CondensedSteps.step_at, through
    continuation.correct_step) gives bitwise the corrector's point and the tangent there that the
    two calls give, and the reference problem's two Python calls agree with it."""
    loads, speed = request.getfixturevalue(case)
    hb, ref = both(loads)
    xs, ss = 0.01, 10.0
    x = hb.solve(speed).x
    y_pred = np.concatenate([x * 1.05 / xs, [(speed + 10.0) / ss]])
    normal = np.zeros(len(y_pred))
    normal[-1] = 1.0
    prev = np.zeros(len(y_pred))
    prev[-1], prev[0] = 0.8, 0.6
    steps = hb.compiled_steps()
    y, it, res, t = continuation.correct_step(hb, y_pred, normal, prev, xs, ss, 1e-10, 12,
                                              steps=steps)
    a = continuation.correct(hb, y_pred, normal, xs, ss, 1e-10, 12, steps=steps)
    ta = continuation.tangent_of(a[3][1], a[3][2], prev, xs, ss, steps)
    assert np.array_equal(y, a[0]) and (it, res) == (a[1], a[2]) and np.array_equal(t, ta)
    assert ref.steps.step_at(y_pred, prev, xs, ss, 1e-10, 12) is None
    yr, itr, _, tr = continuation.correct_step(ref, y_pred, normal, prev, xs, ss, 1e-10, 12,
                                               steps=ref.compiled_steps())
    assert itr == it and close(yr, y) and close(tr, t)
    with pytest.raises(continuation.CorrectorFailed):
        hb.steps.step_at(np.concatenate([x * 40.0 / xs, [speed / ss]]), prev, xs, ss, 1e-10, 2)


def _branch(hb, x0, s0, bounds, options, grid_run, fast_forward=None):
    """continue_branch on hb with ``grid_run`` as its grid runs (None: every step taken by the
    Python loop); (points, why the branch ended)."""
    ended = []
    steps = dataclasses.replace(hb.compiled_steps(), grid_run=grid_run)
    pts = continuation.continue_branch(
        hb, continuation.BranchStart(x0, s0, bounds, 1.0), options,
        continuation.BranchHooks(fast_forward=fast_forward,
                                 on_end=lambda why, p: ended.append(why), steps=steps))
    return pts, ended[0]


GRID_RUN_OPTIONS = {
    'default': {},
    'retries': {'max_turn': 0.05, 'step_max': 0.6},     # rejected grid steps: the loop retries
    'few steps': {'max_steps': 25},                      # the run stops at the step budget
}


@pytest.mark.parametrize('case', ['paper', 'staged_d13'])
@pytest.mark.parametrize('variant', list(GRID_RUN_OPTIONS))
def test_grid_runs_are_the_loops_grid_steps(case, variant, request):
    """continue_branch with the problem's compiled grid runs (CondensedSteps.grid_run) gives
    bitwise the points of the Python loop taking every step itself: x, speed, tangent,
    iterations, residual, on-grid flag, and the same end; across the knee (grid steps, a turning
    region's arc-length steps), with rejected grid steps retried by the loop and with a step
    budget the run stops at."""
    loads, speed = request.getfixturevalue(case)
    hb = CondensedHBM(loads, 1.0)
    o = continuation.ContinuationOptions(**{'grid': 10.0, 's_scale': 10.0,
                                            **GRID_RUN_OPTIONS[variant]})
    lo, hi = speed - 350.0, speed + 250.0           # from below the knee (a linear start)
    x0 = hb.solve(lo).x
    made = []

    def run(*args):
        out = hb.steps.grid_run(*args)
        made.append(len(out.s))
        return out

    a, why_a = _branch(hb, x0, lo, (lo, hi), o, run)
    b, why_b = _branch(hb, x0, lo, (lo, hi), o, None)
    assert sum(made) >= 5 and why_a == why_b and len(a) == len(b) > 3
    assert (why_a == "max_steps") == (variant == "few steps")
    for p, q in zip(a, b):
        assert p.s == q.s and np.array_equal(p.x, q.x) and np.array_equal(p.tangent, q.tangent)
        assert (p.iterations, p.residual, p.on_grid) == (q.iterations, q.residual, q.on_grid)


def test_grid_run_on_a_range_given_the_wrong_way_round_is_the_loop(paper):
    """Bounds given as (hi, lo): the loop's first grid step lands on a bound and the branch
    ends there; the grid run takes that step as the loop does (a run of one row)."""
    loads, _ = paper
    hb = CondensedHBM(loads, 1.0)
    o = continuation.ContinuationOptions(grid=10.0, s_scale=10.0)
    x0 = hb.solve(845.0).x
    made = []

    def run(*args):
        out = hb.steps.grid_run(*args)
        made.append(len(out.s))
        return out

    a, why_a = _branch(hb, x0, 845.0, (900.0, 850.0), o, run)
    b, why_b = _branch(hb, x0, 845.0, (900.0, 850.0), o, None)
    assert made == [1] and why_a == why_b == 'bound' and len(a) == len(b) == 2
    assert a[1].s == b[1].s == 850.0 and np.array_equal(a[1].x, b[1].x)


def test_grid_run_stops_where_the_fast_forward_may_apply(paper):
    """With a fast-forward, a grid run returns at every on-grid point whose AFT samples reach no
    knee and the loop asks the fast-forward there, as it does without runs; the run's own grid
    steps ask it nothing (at their points the harmonics are not zero: it would return no
    points), and the points are the loop's own."""
    loads, _ = paper
    hb = CondensedHBM(loads, 1.0)
    o = continuation.ContinuationOptions(grid=10.0, s_scale=10.0)
    lo, hi = 850.0, 1400.0
    x0 = hb.solve(lo).x
    asked = {True: [], False: []}

    def ff(grid_run):
        def fast_forward(cp, sign):
            asked[grid_run].append((cp.s, not hb.nonlinear_harmonics(cp.x).any()))
            return []
        return fast_forward

    a, _ = _branch(hb, x0, lo, (lo, hi), o, hb.steps.grid_run, ff(True))
    b, _ = _branch(hb, x0, lo, (lo, hi), o, None, ff(False))
    assert len(a) == len(b) and all(np.array_equal(p.x, q.x) for p, q in zip(a, b))
    linear = [[s for s, lin in asked[k] if lin] for k in (True, False)]
    assert linear[0] and linear[0] == linear[1]              # asked at every linear point
    assert len(asked[True]) < len(asked[False]) - 10         # the runs' steps ask nothing


def test_grid_corrector_failure_raises_corrector_failed(paper):
    loads, _ = paper
    hb, _ = both(loads)
    x = hb.solve(PAPER_SPEED).x
    y_pred = np.concatenate([x * 40.0 / 0.01, [PAPER_SPEED / 10.0]])   # hopeless predictor
    normal = np.zeros(len(y_pred))
    normal[-1] = 1.0
    with pytest.raises(continuation.CorrectorFailed):
        continuation.correct(hb, y_pred, normal, 0.01, 10.0, 1e-10, 2,
                             steps=hb.compiled_steps())


def test_compiled_engine_query_is_the_engine(paper):
    """linear_kernels.engine_at on Engine.speed_table: bitwise Engine.coefficients (speeds across
    the load set's shift and limit, grid nodes and the top end), zero-padded beyond n_max; outside
    the data it says so."""
    from dmf_sim.solvers.hbm import linear_kernels
    loads, _ = paper
    eng = loads.engine
    table = eng.speed_table(1.0)
    lo, hi = eng.speed_range_rpm
    for s in np.concatenate([np.linspace(lo, hi, 97), [1000.0, 1000.0 + 1e-9, 1234.567]]):
        out = np.empty(eng.n_max + 4, dtype=complex)
        assert linear_kernels.engine_at(float(s), table, out) == linear_kernels.ENGINE_OK
        assert np.array_equal(out[:eng.n_max + 1], eng.coefficients(float(s), 1.0))
        assert not out[eng.n_max + 1:].any()
    for s in (lo - 1.0, hi + 1.0, float('nan')):
        assert (linear_kernels.engine_at(s, table, np.empty(3, dtype=complex))
                == linear_kernels.ENGINE_OUTSIDE)


def test_off_grid_jacobians_in_one_call_are_the_python_path(paper):
    """(r, dr/dx, dr/ds) at a speed not prepared: the linear parts and the engine query inside
    the kernel give bitwise what the Python linear parts and the AFT kernel give."""
    from dmf_sim.solvers.hbm import kernels
    loads, speed = paper
    hb = CondensedHBM(loads, 1.0)
    top = hb._speed_range()[1]
    for s in (speed + 3.7, speed - 41.3, top - 0.01):
        for x in trial_points(hb, speed, n=3):
            got = hb.residual_and_jacobians(x, s)
            lp = CondensedHBM(loads, 1.0)._linear_parts_one(s)
            want = kernels.residual_jacobians_py(x, lp.lin, lp.dlin, hb._aft_mats,
                                                 hb._spring_arrays)
            for g, w in zip(got, want):
                assert np.array_equal(g, w)
        assert s not in hb._cache          # computed in the kernel, not through the cache


def _arc_step(hb, speed, h=0.6):
    """A pseudo-arc-length predictor from the solution at ``speed`` along its tangent."""
    xs, ss = 0.01, 10.0
    x = hb.solve(speed).x
    r, Jx, rs = hb.residual_and_jacobians(x, speed)
    prev = np.zeros(len(x) + 1)
    prev[-1] = 1.0
    t = continuation._tangent(Jx, rs, prev, xs, ss)
    y = np.concatenate([x / xs, [speed / ss]])
    return y + h * t, t, xs, ss


def test_arc_length_corrector_equals_reference(paper):
    """continuation.correct with the tangent as normal: one compiled call
    (CondensedSteps.corrector_arc, every iterate's linear parts in the kernel) vs the reference
    iteration over the numpy residual and Jacobians."""
    loads, speed = paper
    hb, ref = both(loads)
    y_pred, t, xs, ss = _arc_step(hb, speed)
    assert hb.steps.corrector_arc(y_pred, t, xs, ss, 1e-10, 12) is not None
    assert ref.steps.corrector_arc(y_pred, t, xs, ss, 1e-10, 12) is None
    a = continuation.correct(hb, y_pred, t, xs, ss, 1e-10, 12, steps=hb.compiled_steps())
    b = continuation.correct(ref, y_pred, t, xs, ss, 1e-10, 12, steps=ref.compiled_steps())
    assert a[1] == b[1] and a[1] > 0
    assert close(a[0], b[0])
    assert a[0][-1] != y_pred[-1]                      # the speed moved: an arc-length step
    assert np.abs(a[3][0]).max() <= 1e-10
    assert close(a[3][1], b[3][1]) and close(a[3][2], b[3][2])


def test_arc_length_corrector_on_a_lazy_engine(paper):
    """An engine whose gas grid is not computed yet: the compiled corrector computes the nodes
    it needs (through the engine) and gives the same result as on the warmed engine; a
    predictor beyond the engine data ends the branch (LeftRange), as in Python."""
    loads, speed = paper
    lazy = DrivelineExcitation(loads.model, read_engine('engine_d13', load_set='A'))
    assert not lazy.engine._gas.done.all()
    warm, cold = CondensedHBM(loads, 1.0), CondensedHBM(lazy, 1.0)
    y_pred, t, xs, ss = _arc_step(warm, speed)
    a = continuation.correct(warm, y_pred, t, xs, ss, 1e-10, 12, steps=warm.compiled_steps())
    b = continuation.correct(cold, y_pred, t, xs, ss, 1e-10, 12, steps=cold.compiled_steps())
    assert a[1] == b[1] and np.array_equal(a[0], b[0])
    top = loads.engine.speed_range_rpm[1]
    y_out = y_pred.copy()
    y_out[-1] = (top + 5.0) / ss
    with pytest.raises(continuation.LeftRange):
        continuation.correct(warm, y_out, t, xs, ss, 1e-10, 12,
                             steps=warm.compiled_steps())


@pytest.mark.parametrize('case', CASES)
def test_floquet_multipliers_equal_reference(case, request):
    loads, speed = request.getfixturevalue(case)
    hb, _ = both(loads)
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
        assert a.n_crossings == b.n_crossings and a.stable == b.stable
        assert [st for st, _ in a.segments] == [st for st, _ in b.segments]
        assert close([t for _, t in a.segments], [t for _, t in b.segments])
        # each reference multiplier has a compiled one within the tolerance
        gap = np.abs(a.multipliers[None, :] - b.multipliers[:, None]).min(axis=1)
        assert gap.max() <= REL_TOL * np.abs(b.multipliers).max()
        assert a.max_abs == pytest.approx(b.max_abs, rel=REL_TOL)
    assert crossings > 0


def test_sweep_compiled_equals_reference(paper):
    """A sweep across the paper case's knee region, full search: the same branches, events and
    stable states, the same points to rounding."""
    loads, _ = paper
    out = []
    for compiled in (True, False):
        res = sweep(loads, 1.0, (950.0, 1150.0), hbm_options=HBMOptions(compiled=compiled),
                    options=SweepOptions(step_rpm=10.0))
        out.append(res)
    a, b = out
    assert [(br.kind, len(br.points)) for br in a.branches] == [(br.kind, len(br.points))
                                                              for br in b.branches]
    assert [(e.kind, e.branch, round(e.speed_rpm, 6)) for e in a.events] == [
        (e.kind, e.branch, round(e.speed_rpm, 6)) for e in b.events]
    for ba, bb in zip(a.branches, b.branches):
        assert [p.stable for p in ba.points] == [p.stable for p in bb.points]
        for p, q in zip(ba.points, bb.points):
            assert p.speed_rpm == pytest.approx(q.speed_rpm, abs=1e-9)
            assert np.abs(p.x - q.x).max() <= 1e-9 * np.abs(q.x).max()
    assert len(a.non_periodic) == len(b.non_periodic) and a.uncovered == b.uncovered


def test_warm_up_compiles_what_a_sweep_calls(paper):
    """warm_up (run by a design-study worker when it starts) leaves no compilation for
    the first sweep: the sweep adds no new signature to any kernel."""
    from dmf_sim.solvers.hbm.warm import kernels, warm_up
    warm_up()
    fs = kernels()            # the sweep group of the kernel registry
    before = [len(f.signatures) for f in fs]
    assert all(n >= 1 for n in before)
    loads, _ = paper
    sweep(loads, 1.0, (1150.0, 1250.0), options=SweepOptions(step_rpm=10.0, search=None))
    assert [len(f.signatures) for f in fs] == before


def test_constant_speed_shot_is_one_kernel_call(paper, monkeypatch):
    """A transient Newmark run at constant speed (the long shots of the search and of the
    non-periodic classification) is one kernel call, with the same result as the run chunked
    every 10 ms (a target equal to the speed keeps the chunks)."""
    from dmf_sim.solvers import newmark
    loads, speed = paper
    calls = []
    advance = newmark.NewmarkIntegrator.advance

    def counting(self, *args, **kwargs):
        calls.append(args[0])
        return advance(self, *args, **kwargs)

    monkeypatch.setattr(newmark.NewmarkIntegrator, 'advance', counting)
    every_2nd = newmark.SimulationOptions(record_stride=2)
    one = newmark.simulate(loads, speed, 1.0, t_end=0.2, options=every_2nd)
    n_one = len(calls)
    calls.clear()
    chunked = newmark.simulate(loads, speed, 1.0, t_end=0.2, target_speed_rpm=speed,
                               options=every_2nd)
    assert n_one == 1 and len(calls) >= 20
    assert len(one.windup) == len(chunked.windup) == 1000
    assert np.abs(one.windup - chunked.windup).max() <= 1e-9 * np.ptp(chunked.windup)
    assert np.abs(one.psi - chunked.psi).max() <= 1e-9 * chunked.psi[-1]


WARM_THEN_SWEEP = '''
import json
import numpy as np
from dmf_sim.physics.engine import read_engine
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_model
from dmf_sim.solvers import stability
from dmf_sim.solvers.hbm import CondensedHBM, SweepOptions, sweep
from dmf_sim.solvers.hbm.warm import kernels, warm_up
warm_up()
fs = kernels()
before = [len(f.signatures) for f in fs]
loads = DrivelineExcitation(read_model('truck_dmf', alpha=3.0),
                            read_engine('engine_d13', load_set='A'))
sweep(loads, 1.0, (1150.0, 1250.0), options=SweepOptions(step_rpm=10.0, search=None))
CondensedHBM(loads, 1.0).linear_parts(1001.5)
stability.eigenvalues(np.eye(3) + 0.5)        # the multipliers of one point analyzed alone
print(json.dumps([before, [len(f.signatures) for f in fs]]))
'''


@pytest.mark.slow
def test_warm_up_compiles_what_a_fresh_worker_calls():
    """In a fresh process (a design-study worker), warm_up leaves no signature for the first
    sweep to add: a prepared batch of speeds and a single speed reach the modal sums with
    different array layouts, and both are loaded by warm_up; so is the eigenvalue call of one
    point analyzed alone (from Python, not from a kernel)."""
    import json
    import os
    import subprocess
    import sys
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    out = subprocess.run([sys.executable, '-c', WARM_THEN_SWEEP], capture_output=True,
                         text=True, env=env, timeout=120, check=True).stdout
    before, after = json.loads(out.strip().splitlines()[-1])
    assert all(n >= 1 for n in before) and after == before
