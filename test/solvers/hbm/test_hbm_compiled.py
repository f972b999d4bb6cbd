"""The compiled paths of a sweep beyond their parity with the reference (the parity of each
kernel: test/solvers/test_kernel_parity.py): the tangent's properties and its singular system,
the reference problem's Python paths, failures raised the same way, grid runs at their edges
(a range given the wrong way round, a fast-forward), the engine query, a lazy engine, a whole
sweep both ways (same branches, events and stable states) and what warm_up loads."""
from __future__ import annotations

import numpy as np
import pytest
from support.kernel_cases import SPRINGS, Problems, arc_step, branch, trial_points

from dmf_sim.physics.engine import read_engine
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.solvers import continuation
from dmf_sim.solvers.hbm import CondensedHBM, HBMOptions, SweepOptions, sweep
from dmf_sim.solvers.hbm.deflation import DeflatedNewton
from dmf_sim.solvers.kernel_registry import REL_TOL

PAPER_SPEED = 1200.0     # rpm: the paper case crosses the knee here


@pytest.fixture(scope='module')
def problems():
    return Problems()


@pytest.fixture(scope='module')
def paper(problems):
    return problems.paper


def both(loads):
    return (CondensedHBM(loads, 1.0), CondensedHBM(loads, 1.0, HBMOptions(compiled=False)))


def close(a, b):
    return np.abs(np.asarray(a) - np.asarray(b)).max() <= REL_TOL * np.abs(b).max()


@pytest.mark.parametrize('case', SPRINGS)
def test_continuation_tangent_is_the_unit_tangent(case, problems):
    """The compiled tangent (CondensedSteps.tangent) has unit length, points along the previous
    one and solves the bordered system; a singular system raises LinAlgError both ways, and the
    reference problem leaves the tangent to the numpy path."""
    loads, speed, hb, ref = problems.both(case)
    s, xs, ss = speed + 3.7, 0.01, 10.0
    rng = np.random.default_rng(5)
    for x in trial_points(hb, speed):
        _, Jx, rs = hb.residual_and_jacobians(x, s)
        prev = rng.standard_normal(len(x) + 1)
        prev /= np.linalg.norm(prev)
        got = continuation.tangent_of(Jx, rs, prev, xs, ss, hb.compiled_steps())
        assert abs(np.linalg.norm(got) - 1.0) <= 1e-12 and got @ prev > 0
        assert np.abs(Jx @ got[:-1] * xs + rs * got[-1] * ss).max() <= 1e-10 * np.abs(Jx).max()
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


@pytest.mark.parametrize('case', SPRINGS)
def test_reference_problems_seeds_are_its_seeds_one_by_one(case, problems):
    """On the reference problem DeflatedNewton.solve_first (the Python loop) stops at the first
    seed from ``start`` on that its solve() brings to a solution, as the kernel does, and finds
    what the compiled problem finds to the parity tolerance."""
    loads, speed, hb, ref = problems.both(case)
    lp = hb.linear_parts(speed)
    sol = hb.solve(speed).x
    seeds = np.array(trial_points(hb, speed, n=6, seed=7))
    seeds[3] = sol                                # a seed on a deflated solution: converged as is
    found = 0
    with np.errstate(over='ignore', invalid='ignore'):  # the reference's M(x) there is inf
        for start in range(len(seeds) + 1):
            r = DeflatedNewton(ref).solve_first(lp, seeds, sol[None], start)
            got = DeflatedNewton(hb).solve_first(lp, seeds, sol[None], start)
            assert (r is None) == (got is None)
            if r is not None:
                found += 1
                one = DeflatedNewton(ref).solve(lp, seeds[r[0]], sol[None])
                assert r[0] >= start and np.array_equal(r[1], one[0]) and r[2:] == one[1:]
                assert r[0] == got[0] and r[2] == got[2] and close(r[1], got[1])
    assert found > 0


@pytest.mark.parametrize('case', SPRINGS)
def test_grid_step_on_the_reference_problem_and_a_failed_one(case, problems):
    """The reference problem has no one-call grid step (the two Python calls instead, which give
    the compiled step's point and tangent to the parity tolerance); a hopeless predictor raises
    CorrectorFailed from the compiled step."""
    loads, speed, hb, ref = problems.both(case)
    xs, ss = 0.01, 10.0
    x = hb.solve(speed).x
    y_pred = np.concatenate([x * 1.05 / xs, [(speed + 10.0) / ss]])
    normal = np.zeros(len(y_pred))
    normal[-1] = 1.0
    prev = np.zeros(len(y_pred))
    prev[-1], prev[0] = 0.8, 0.6
    assert ref.steps.step_at(y_pred, prev, xs, ss, 1e-10, 12) is None
    y, it, _, t = continuation.correct_step(hb, y_pred, normal, prev, xs, ss, 1e-10, 12,
                                            steps=hb.compiled_steps())
    yr, itr, _, tr = continuation.correct_step(ref, y_pred, normal, prev, xs, ss, 1e-10, 12,
                                               steps=ref.compiled_steps())
    assert itr == it and close(yr, y) and close(tr, t)
    with pytest.raises(continuation.CorrectorFailed):
        hb.steps.step_at(np.concatenate([x * 40.0 / xs, [speed / ss]]), prev, xs, ss, 1e-10, 2)


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

    a, why_a = branch(hb, x0, 845.0, (900.0, 850.0), o, run)
    b, why_b = branch(hb, x0, 845.0, (900.0, 850.0), o, None)
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

    a, _ = branch(hb, x0, lo, (lo, hi), o, hb.steps.grid_run, ff(True))
    b, _ = branch(hb, x0, lo, (lo, hi), o, None, ff(False))
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


def test_arc_length_corrector_on_a_lazy_engine(paper):
    """An engine whose gas grid is not computed yet: the compiled corrector computes the nodes
    it needs (through the engine) and gives the same result as on the warmed engine; a
    predictor beyond the engine data ends the branch (LeftRange), as in Python."""
    loads, speed = paper
    lazy = DrivelineExcitation(loads.model, read_engine('engine_d13', load_set='A'))
    assert not lazy.engine._gas.done.all()
    warm, cold = CondensedHBM(loads, 1.0), CondensedHBM(lazy, 1.0)
    y_pred, t, xs, ss = arc_step(warm, speed)
    a = continuation.correct(warm, y_pred, t, xs, ss, 1e-10, 12, steps=warm.compiled_steps())
    b = continuation.correct(cold, y_pred, t, xs, ss, 1e-10, 12, steps=cold.compiled_steps())
    assert a[1] == b[1] and np.array_equal(a[0], b[0])
    top = loads.engine.speed_range_rpm[1]
    y_out = y_pred.copy()
    y_out[-1] = (top + 5.0) / ss
    with pytest.raises(continuation.LeftRange):
        continuation.correct(warm, y_out, t, xs, ss, 1e-10, 12,
                             steps=warm.compiled_steps())


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
