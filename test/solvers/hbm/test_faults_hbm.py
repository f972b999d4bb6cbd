"""Steady states with faults (dmf_sim.solvers.hbm.faulted): the harmonic balance, Newmark, the
steady-state search and the monitor's prediction take one fault description. Physics: an
every-cycle misfire agrees with Newmark, a weak cylinder tends to the healthy engine, cylinders
that fire alike keep the symmetry, a DMF stiffness fault moves the DMF mode as its share of
the strain energy says. Symmetry: every place that merges a state with its 120 deg shifted copy
does so only while the cylinders fire alike. The CLI's --faults."""
from __future__ import annotations

import json
import time
from types import SimpleNamespace

import numpy as np
import pytest

from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.monitor.prediction import OperatingPoint, predict_states, solve_prediction
from dmf_sim.physics.engine.excitation import engine_torque_orders
from dmf_sim.physics.faults import FaultSet, parse_faults
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.modal import modes
from dmf_sim.physics.model import read_driveline
from dmf_sim.physics.orders import CYCLE_RAD, OrderSummary, half_orders, resample_on_angle
from dmf_sim.solvers.hbm import CondensedHBM, HBMOptions, SweepOptions, sweep
from dmf_sim.solvers.hbm.faulted import apply_faults, is_symmetric, steady_faults
from dmf_sim.solvers.hbm.results import Branch, SweepResult
from dmf_sim.solvers.hbm.search import N_SHIFTS
from dmf_sim.solvers.hbm.sweep import SpeedSweep
from dmf_sim.solvers.hbm.unknowns import shift
from dmf_sim.solvers.newmark import SimulationOptions, simulate
from dmf_sim.solvers.steady import BasinOptions, SteadyState, _Matcher, find_steady_states

MISFIRE_1 = '{kind: misfire, cylinders: [1], mode: every_cycle}'
ORDERS = {'0.5': 1, '1': 2, '1.5': 3, '3': 6}      # engine order -> half-order index n
FAST = SweepOptions(step_rpm=10.0, search=None)


@pytest.fixture(scope='module')
def line():
    return read_driveline('truck_dmf')


@pytest.fixture(scope='module')
def loads(line, engine_d13):
    return DrivelineExcitation(line.reduce(), engine_d13)


def faults_of(spec, line):
    return FaultSet(parse_faults(spec, line=line))


def factors_of(spec, line):
    return faults_of(spec, line).combustion_factors(len(line.cylinders))


# ------------------------------------------------------------------------------------------------
# the faulted condensed problem: its linear parts
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize('spec', [MISFIRE_1, '{kind: weak_cylinder, cylinder: 4, factor: 0.6}',
                                  '[{kind: misfire, cylinders: [2, 6], mode: every_cycle}]'])
def test_faulted_linear_parts_equal_direct_solves(loads, line, spec):
    """The two-component modal sums (A^m on every cylinder, A^f - A^m weighted by s_k) give the
    wind-up response of the faulted generalized loads (DrivelineExcitation.dof_harmonics with the
    factors, solved directly on the whole chain), compiled and in numpy alike."""
    s = factors_of(spec, line)
    hb = CondensedHBM(loads, 1.0, factors=s)
    ref = CondensedHBM(loads, 1.0, HBMOptions(compiled=False), factors=s)
    assert not hb.symmetric and hb._engine_kernel_args() is None     # the Python path
    for speed in (900.0, 1234.5, 1777.0):
        assert np.abs(hb.dof_loads(speed) - loads.dof_harmonics(speed, 1.0, s)).max() < 1e-9
        lp, lr = hb.linear_parts(speed), ref.linear_parts(speed)
        h, wlin, _, _ = hb.linear_parts_direct(speed)
        assert np.abs(lp.h - h).max() <= 1e-9 * np.abs(h).max()
        assert np.abs(lp.wlin - wlin).max() <= 1e-9 * np.abs(wlin).max()
        for name in ('h', 'wlin', 'dh_ds', 'dwlin_ds'):
            a, b = getattr(lp, name), getattr(lr, name)
            assert np.abs(a - b).max() <= 1e-12 * np.abs(b).max(), name
        assert np.array_equal(hb._linear_parts_one(speed).wlin, lp.wlin)
        assert np.array_equal(hb.linear_response([speed])[0], lp.wlin)


def test_faulted_speed_derivative_matches_finite_differences(loads, line):
    """dr/ds of the faulted problem (both components' engine coefficients differenced) against
    central differences inside an engine grid cell, where the data are smooth."""
    hb = CondensedHBM(loads, 1.0, factors=factors_of(MISFIRE_1, line))
    speed = 1023.7
    x = hb.solve(speed).x
    assert np.any(hb.nonlinear_harmonics(x))            # beyond the knee: non-trivial
    _, _, rs = hb.residual_and_jacobians(x, speed)
    ds = 1e-3
    fd = (hb.residual_and_jacobians(x, speed + ds)[0]
          - hb.residual_and_jacobians(x, speed - ds)[0]) / (2 * ds)
    assert np.abs(fd - rs).max() <= 1e-4 * np.abs(rs).max()


# ------------------------------------------------------------------------------------------------
# (a) an every-cycle misfire: harmonic balance against Newmark
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize('speed', [900.0, 1000.0, 1200.0, 1600.0])
def test_misfire_every_cycle_hbm_matches_newmark(loads, line, speed):
    """Cylinder 1 misfires every cycle at full load: the 0.5, 1, 1.5 and 3rd orders and the mean
    of the wind-up, and the 0.5, 1, 1.5 and 3rd orders of the crank speed (primary flywheel), of
    the harmonic balance (a sweep around the speed, its state there, the driveline recovered
    from it) and of Newmark run to a steady state from the static equilibrium with the same
    factors agree within 1 % (doc/theory.md §6; measured below 0.2 %), and the state Newmark
    settles on is a stable one."""
    faults = faults_of(MISFIRE_1, line)
    res = sweep(loads, 1.0, (speed - 30.0, speed + 30.0), faults=faults)
    assert res.faults == faults and not res.hbm.symmetric
    nm = simulate(loads, speed, 1.0, factors=faults.combustion_factors(6),
                  options=SimulationOptions(steady_tol=1e-5, max_cycles=1000))
    assert nm.steady, nm.message
    c = nm.windup_orders
    sols = res.solutions_at(speed)
    hb = min(sols, key=lambda q: np.abs(np.abs(q.windup_orders[:7]) - np.abs(c[:7])).sum())
    assert hb.stable
    for order, n in ORDERS.items():
        assert abs(abs(c[n]) - abs(hb.windup_orders[n])) < 0.01 * abs(hb.windup_orders[n]), order
    assert abs(c[0].real - hb.summary.mean) < 0.01 * abs(hb.summary.mean)
    # the crank speed (the primary flywheel's, where the crank tooth wheel sits) too
    m = loads.model
    pf = m.names.index('PRIMARY FLYWHEEL')
    n = np.arange(res.hbm.H + 1)
    v_hbm = 1j * n * (speed * RPM_TO_RAD_S / 2) * res.hbm.element_harmonics(hb)[:, pf]
    start = np.ceil(nm.psi[0] / CYCLE_RAD) * CYCLE_RAD
    cycles = int((nm.psi[-1] - start) // CYCLE_RAD)
    v_nm = half_orders(resample_on_angle(nm.psi, nm.v @ m.T[pf], start, cycles, 512), 6, cycles)
    for order, k in ORDERS.items():
        assert abs(abs(v_nm[k]) - abs(v_hbm[k])) < 0.01 * abs(v_hbm[k]), f'speed {order}'
    # the misfire is what drives it: its 0.5 order dwarfs the healthy engine's
    healthy = CondensedHBM(loads, 1.0).solve(speed)
    assert abs(hb.windup_orders[1]) > 10 * abs(healthy.windup_orders[1])


# ------------------------------------------------------------------------------------------------
# (b) a weak cylinder tends to the healthy engine; factor 1 is the healthy path, bitwise
# ------------------------------------------------------------------------------------------------

def _same_sweep(a, b) -> bool:
    pa = [p for br in a.branches for p in br.points]
    pb = [p for br in b.branches for p in br.points]
    return (len(pa) == len(pb) and all(
        p.speed_rpm == q.speed_rpm and np.array_equal(p.x, q.x) and p.stable == q.stable
        and np.array_equal(p.multipliers, q.multipliers) for p, q in zip(pa, pb)))


def test_weak_cylinder_tends_to_the_healthy_sweep(loads, line):
    """Continuity: a cylinder weakened by eps changes the sweep's states by O(eps) (the
    faulted problem, its own code path, lands on the healthy sweep); all factors exactly 1 is
    the healthy problem: the same sweep bit for bit, and Newmark's run too."""
    healthy = sweep(loads, 1.0, (900.0, 1300.0), options=FAST)
    ref = np.array([p.x for p in healthy.main().points])
    scale = np.abs(ref).max()
    errors = []
    for eps in (1e-2, 1e-4):
        weak = faults_of(f'{{kind: weak_cylinder, cylinder: 3, factor: {1 - eps}}}', line)
        res = sweep(loads, 1.0, (900.0, 1300.0), options=FAST, faults=weak)
        S = res.main().column('speed_rpm')
        assert res.hbm.factors is not None and not res.hbm.symmetric
        X = np.array([p.x for p in res.main().points])
        # on the healthy sweep's speeds (grid speeds both reach)
        common = [s for s in healthy.main().column('speed_rpm') if np.any(np.abs(S - s) < 1e-9)]
        assert len(common) > 30
        err = max(np.abs(X[np.argmin(np.abs(S - s))] - ref[np.argmin(
            np.abs(healthy.main().column('speed_rpm') - s))]).max() for s in common)
        errors.append(err / scale)
    # measured 2.4e-2 and 2.6e-4 (the DMF amplifies the 0.5 order the weak cylinder adds):
    # O(eps), and linear in eps
    assert errors[0] < 5e-2 and errors[1] < 5e-4
    assert 0.005 < errors[1] / errors[0] < 0.02
    ones = CondensedHBM(loads, 1.0, factors=np.ones(6))
    assert ones.factors is None and ones.symmetric
    assert ones._engine_kernel_args() is not None          # the compiled healthy path
    same = sweep(loads, 1.0, (900.0, 1300.0), options=FAST, faults=FaultSet(()))
    assert _same_sweep(same, healthy)
    a = simulate(loads, 1200.0, 1.0, factors=np.ones(6))
    b = simulate(loads, 1200.0, 1.0)
    assert np.array_equal(a.windup, b.windup) and np.array_equal(a.windup_orders, b.windup_orders)


# ------------------------------------------------------------------------------------------------
# (c) cylinders that fire alike keep the symmetry
# ------------------------------------------------------------------------------------------------

class _Scaled:
    """An engine whose coefficients are A^m + s (A^f - A^m) of another one: what every cylinder
    fires with when all factors are s."""

    def __init__(self, engine, s):
        self.engine, self.s = engine, s
        self.n_cylinders, self.n_max = engine.n_cylinders, engine.n_max
        self.firing_phases_deg = engine.firing_phases_deg
        self.speed_range_rpm = engine.speed_range_rpm

    def coefficients(self, speed_rpm, load):
        f = self.engine.coefficients(speed_rpm, load)
        m = self.engine.motored_coefficients(speed_rpm, load)
        return m + self.s * (f - m)


def test_cylinders_alike_keep_the_symmetry(loads, line, engine_d13):
    """All six cylinders at factor 0.5: the engine's 0.5-order torque on the crank vanishes (as
    the healthy engine's), the problem is symmetric, and its states are those of a healthy
    engine firing with the scaled coefficients (the same physics, another path)."""
    s = np.full(6, 0.5)
    hb = CondensedHBM(loads, 1.0, factors=s)
    assert hb.factors is not None and hb.symmetric and is_symmetric(s)
    scaled = _Scaled(engine_d13, 0.5)
    B = engine_torque_orders(scaled, 1200.0, 1.0)
    assert abs(B[1]) < 1e-12 * abs(B[6]) and abs(B[2]) < 1e-12 * abs(B[6])
    twin = CondensedHBM(DrivelineExcitation(loads.model, scaled), 1.0)
    misfire = CondensedHBM(loads, 1.0, factors=factors_of(MISFIRE_1, line))
    for speed in (900.0, 1200.0):
        p, q = hb.solve(speed), twin.solve(speed)
        assert np.abs(p.x - q.x).max() <= 1e-9 * np.abs(q.x).max()
        # the 0.5 order stays at the flexible crank's level, far below a misfire's
        assert abs(p.windup_orders[1]) < 0.05 * abs(p.windup_orders[6])
        assert abs(p.windup_orders[1]) < 0.01 * abs(misfire.solve(speed).windup_orders[1])


# ------------------------------------------------------------------------------------------------
# (d) DMF faults: through the model
# ------------------------------------------------------------------------------------------------

def test_dmf_stiffness_fault_moves_the_dmf_mode_as_sqrt_k(line):
    """A worn primary stiffness (stage 1 x s): each natural frequency scales as s^(eta/2),
    eta the mode's share of strain energy in the DMF spring (f ~ sqrt(k) for a mode that is all
    DMF); the second natural frequency (the DMF mode, 7.8 Hz) has eta = 0.57, the crank modes
    almost none."""
    m0 = line.reduce()
    r0 = modes(m0)
    om2 = np.where(r0.omega > 0, r0.omega, 1.0) ** 2     # (the rigid mode: no strain)
    eta = m0.spring.k * (m0.e @ r0.dof_shapes) ** 2 / om2
    assert 0.5 < eta[1] < 0.65 and eta[4:].max() < 0.01
    for s, tol in ((0.98, 1e-4), (0.9, 2e-3)):
        fault = faults_of(f'{{kind: dmf_stiffness, stage: 1, factor: {s}}}', line)
        r = modes(fault.apply_to_driveline(line).reduce())
        pred = r0.frequencies_hz[1:] * s ** (eta[1:] / 2)
        assert np.abs(r.frequencies_hz[1:] / pred - 1).max() < tol
        assert r.frequencies_hz[1] < r0.frequencies_hz[1] * s ** 0.25     # it did move


def test_dmf_fault_enters_through_the_model(loads, line, engine_d13):
    """A sweep with a DMF fault is the sweep of the faulted driveline (the one spring object),
    bit for bit; a broken stage changes nothing below its knee's reach and no combustion
    factor is made of it."""
    faults = faults_of('[{kind: dmf_stiffness, stage: 1, factor: 0.7}, '
                       '{kind: dmf_damping, factor: 2.0}]', line)
    faulted_loads, factors = apply_faults(loads, faults)
    assert factors is None and faulted_loads.model.spring.k == pytest.approx(0.7 * 10890)
    by_hand = DrivelineExcitation(faults.apply_to_driveline(line).reduce(), engine_d13)
    a = sweep(loads, 1.0, (1000.0, 1200.0), options=FAST, faults=faults)
    b = sweep(by_hand, 1.0, (1000.0, 1200.0), options=FAST)
    assert _same_sweep(a, b) and a.hbm.symmetric


# ------------------------------------------------------------------------------------------------
# what has a steady state
# ------------------------------------------------------------------------------------------------

@pytest.mark.parametrize('spec, says', [
    ('{kind: misfire, cylinders: [2], mode: single}', "mode 'single' is an event"),
    ('{kind: misfire, cylinders: [2], mode: random, probability: 0.1}', "mode 'random'"),
    ('{kind: misfire, cylinders: [2], mode: every_cycle, start_s: 1.0}', "field 'start_s'"),
    ('{kind: weak_cylinder, cylinder: 2, factor: 0.5, end_s: 3.0}', "field 'end_s'"),
    ('{kind: bus_signal, signal: engine_speed, mode: stuck}', 'sensor fault'),
])
def test_faults_without_a_steady_state_are_refused(loads, line, spec, says):
    faults = FaultSet(parse_faults(spec))         # (sensor names not checked: no line)
    with pytest.raises(ConfigError, match=says) as info:
        sweep(loads, 1.0, (1000.0, 1100.0), options=FAST, faults=faults)
    assert '\n' not in str(info.value) and 'faults[0]' in str(info.value)
    with pytest.raises(ConfigError, match=says):
        steady_faults(faults)


def test_a_table_engine_refuses_combustion_faults_in_one_line(line, tmp_path):
    from dmf_sim.physics.engine import read_engine
    table = read_engine('engine_table_example.csv')
    loads = DrivelineExcitation(line.reduce(), table)
    with pytest.raises(ConfigError, match='does not fire'):
        sweep(loads, 1.0, (1000.0, 1100.0), options=FAST, faults=faults_of(MISFIRE_1, line))
    dmf = faults_of('{kind: dmf_damping, factor: 0.5}', line)
    assert sweep(loads, 1.0, (1000.0, 1100.0), options=FAST, faults=dmf).n_points > 0


# ------------------------------------------------------------------------------------------------
# symmetry: twins only while the cylinders fire alike
# ------------------------------------------------------------------------------------------------

def _sweep(hbm, branches=()):
    """A sweep on a given problem holding ``branches``, not run: its branch switching and its
    search keep the state bookkeeping."""
    sw = SpeedSweep(hbm)
    sw.branches[:] = branches
    return sw


def _point_branch(hb, x, speed):
    p = hb.make_point(speed, x)
    return Branch(0, 'main', [p])


def _subharmonic_state(hb, speed):
    """A state with a marked 1.5th order (its 120 deg shift differs from it)."""
    x = hb.solve(speed).x.copy()
    x[3] += 0.02                          # Re w_3: a 1.5th-order part (x need not solve here)
    return x


@pytest.mark.parametrize('factors, merged', [(None, True), (np.full(6, 0.5), True),
                                             ('misfire', False)])
def test_known_state_fingerprint_merges_shifted_copies_only_when_alike(loads, line, factors,
                                                                      merged):
    """branches._known / _distance_to_branch: a state 120 deg shifted from a branch point has
    the same harmonic amplitudes; it is the known state when the cylinders fire alike, another
    state when one misfires."""
    f = factors_of(MISFIRE_1, line) if isinstance(factors, str) else factors
    hb = CondensedHBM(loads, 1.0, factors=f)
    x = _subharmonic_state(hb, 1100.0)
    search = _sweep(hb, [_point_branch(hb, x, 1100.0)]).switching
    twin = hb.make_point(1100.0, shift(x, 1, hb.H))
    assert np.abs(twin.x - x).max() > 0.01                  # really another vector
    assert search._known(twin, 1e-6) is merged
    assert search._known(hb.make_point(1100.0, x), 1e-6)    # itself: always known


@pytest.mark.parametrize('faulty', [False, True])
def test_deflation_and_multiplicity_use_shifts_only_when_alike(loads, line, faulty):
    """search._deflation_set deflates the 120 deg shifts of known states (solutions too) only
    for alike cylinders; multiplicity (Newton from every shift) counts twins only then: with a
    misfire every state counts once, whatever Newton reaches from a shifted start."""
    hb = CondensedHBM(loads, 1.0, factors=factors_of(MISFIRE_1, line) if faulty else None)
    x = _subharmonic_state(hb, 1100.0)
    search = _sweep(hb).state_search
    rows = search._deflation_set([x])
    assert len(rows) == (1 if faulty else N_SHIFTS)
    assert np.array_equal(rows[0], x)
    if faulty:
        p = hb.solve(1100.0)
        assert search.multiplicity(p) == 1


def _result(hbm, xs, speed=1000.0):
    pts = [SimpleNamespace(speed_rpm=speed, x=x, stable=True) for x in xs]
    return SweepResult([Branch(i, 'main', [p, p]) for i, p in enumerate(pts)], [],
                       (speed - 10, speed + 10), 1.0, 3.0, 0.24, hbm=hbm)


@pytest.mark.parametrize('symmetric', [True, False])
def test_solutions_at_keeps_shifted_states_apart_when_cylinders_differ(symmetric):
    """SweepResult.solutions_at reports a state and its 120 deg shifted copy once for alike
    cylinders, twice when they differ (two states)."""
    H = 24
    x = np.zeros(2 * H + 1)
    x[0], x[3], x[6], x[H + 6] = 0.2, 0.03, 0.01, 0.004
    res = _result(SimpleNamespace(symmetric=symmetric), [x, shift(x, 1, H)])
    assert len(res.solutions_at(1000.0)) == (1 if symmetric else 2)


@pytest.mark.parametrize('symmetric', [True, False])
def test_basin_runs_match_a_state_by_its_phases_when_cylinders_differ(symmetric):
    """steady._Matcher: a Newmark run on the 120 deg shifted copy of a state matches that state
    for alike cylinders (one state), and none when they differ (it is another state, added by
    Newton then)."""
    H = 24
    x = np.zeros(2 * H + 1)
    x[0], x[3], x[6], x[H + 6] = 0.2, 0.03, 0.01, 0.004
    c = np.zeros(H + 1, dtype=complex)
    c[0], c[3], c[6] = 0.2, 0.03, 0.01 + 0.004j
    point = SimpleNamespace(windup_orders=c, stable=True)
    st = SteadyState(point)
    run = c * np.exp(-1j * np.arange(H + 1) * np.pi / 3)          # shifted by 120 deg
    m = _Matcher([st], 0.03, symmetric)
    assert (m.match(run) is st) is symmetric
    assert m.match(c) is st


def _summary(order_1_5):
    return OrderSummary(order_3=0.01, order_1_5=order_1_5, max_deviation=0.02,
                        min_deviation=-0.02, mean=0.2, mean_minus_theta=-0.04,
                        static_windup=0.19, theta=0.24)


def test_prediction_keeps_equal_looking_states_apart_under_a_misfire(loads, line):
    """monitor.prediction: two stable states with equal Fig. 13 quantities are one (a state and
    its shifted copy) for the healthy engine, two under a misfire; the solver is asked with
    the faults, and the faults are part of the cache key."""
    seen = []

    def solver(loads_, speed, load, **kw):
        seen.append(kw)
        p = SimpleNamespace(summary=_summary(0.012), stable=True, kind='main', branch=0,
                            max_multiplier=0.9)
        return [p, SimpleNamespace(**vars(p))]

    sp = loads.model.spring
    healthy = OperatingPoint.rounded(1200.0, 1.0, 'A', sp, 5.0, 0.01)
    faulted = OperatingPoint.rounded(1200.0, 1.0, 'A', sp, 5.0, 0.01,
                                     faults_of(MISFIRE_1, line))
    assert healthy != faulted and healthy.faults is None
    assert len(solve_prediction(solver, loads, healthy).states) == 1
    assert len(solve_prediction(solver, loads, faulted).states) == 2
    assert seen == [{}, {'faults': faulted.faults}]
    # a DMF fault alone leaves the cylinders alike: twins are merged as before
    dmf = OperatingPoint.rounded(1200.0, 1.0, 'A', sp, 5.0, 0.01,
                                 faults_of('{kind: dmf_damping, factor: 2}', line))
    assert len(solve_prediction(solver, loads, dmf).states) == 1


def test_fast_forward_of_a_linear_stretch_holds_with_a_misfire(loads, line):
    """The sweep skips Newton where the wind-up stays below the knee (g = 0: the linear
    response is the solution, whatever the excitation): at half load with a misfire the
    stretch's points are the faulted linear response, equal to Newton's solutions."""
    faults = faults_of(MISFIRE_1, line)
    res = sweep(loads, 0.3, (1300.0, 1700.0), options=FAST, faults=faults)
    hb = res.hbm
    skipped = [p for p in res.main().points if p.iterations == 0 and p.residual == 0.0]
    assert len(skipped) > 10
    healthy = CondensedHBM(loads, 0.3)
    for p in skipped[::5]:
        q = hb.solve(p.speed_rpm)
        assert np.abs(p.x - q.x).max() <= 1e-12 * np.abs(q.x).max() + 1e-15
        # the misfire's own response, not the healthy engine's
        assert abs(p.windup_orders[1]) > 10 * abs(healthy.solve(p.speed_rpm).windup_orders[1])


# ------------------------------------------------------------------------------------------------
# steady states, the monitor's prediction, the CLI
# ------------------------------------------------------------------------------------------------

def test_steady_states_with_a_misfire(loads, line):
    """find_steady_states with an every-cycle misfire: one stable state at 1200 rpm, its orders
    those of the faulted problem, every basin run (Newmark with the same factors) lands on it."""
    faults = faults_of(MISFIRE_1, line)
    res = find_steady_states(loads, 1200.0, 1.0, window_rpm=20.0, faults=faults,
                             basin=BasinOptions(samples=3, max_cycles=150))
    assert res.faults == faults and len(res.stable) == 1
    st = res.stable[0]
    assert st.hits == 3 and st.kind == 'forced' and st.multiplicity == 1
    d = res.as_dict()
    assert d['faults'] == faults.text() and float(d['states'][0]['orders_rad']['0.5']) > 0.1
    ref = CondensedHBM(loads, 1.0, factors=faults.combustion_factors(6)).solve(1200.0)
    assert np.abs(st.point.x - ref.x).max() <= 1e-8


def test_predict_states_with_a_misfire_is_the_faulted_state(loads, line):
    faults = faults_of(MISFIRE_1, line)
    pts = predict_states(loads, 1200.0, 1.0, faults=faults)
    ref = CondensedHBM(loads, 1.0, factors=faults.combustion_factors(6)).solve(1200.0)
    assert len(pts) == 1 and np.abs(pts[0].x - ref.x).max() <= 1e-8
    healthy = predict_states(loads, 1200.0, 1.0)
    assert abs(pts[0].summary.mean - healthy[0].summary.mean) > 0.02     # one cylinder less


def test_live_monitor_predicts_with_the_faults_acting(loads, line):
    """LiveMonitor.set_faults: the next prediction is made with the persistent part of the
    faults acting (windows dropped, single misfires and sensor faults left out), cached per
    fault set; back to healthy is a cache hit."""
    from dmf_sim.monitor.worker import LiveMonitor, MonitorSettings
    calls = []

    def solver(loads_, speed, load, **kw):
        calls.append(kw.get('faults'))
        return [SimpleNamespace(summary=_summary(0.001), stable=True)]

    mon = LiveMonitor(line, loads.engine, MonitorSettings(worker='thread'), solver=solver)
    try:
        mon.wait_ready(60.0)

        def published():
            for _ in range(6000):
                up = mon.poll()
                if up.prediction is not None:
                    return up.prediction
                time.sleep(0.01)
            raise AssertionError('no prediction')

        mon.set_setpoint(1200.0, 1.0)
        assert published().point.faults is None
        acting = FaultSet(parse_faults(
            '[{kind: misfire, cylinders: [3], mode: every_cycle, start_s: 2.0}, '
            '{kind: misfire, cylinders: [5], mode: single, at_s: 3.0}]', line=line))
        mon.set_faults(acting)
        pred = published()
        held = pred.point.faults
        assert [f.cylinders for f in held] == [(3,)] and held.faults[0].start_s is None
        assert calls == [None, held]
        mon.set_faults(None)
        assert published().point.faults is None and len(calls) == 2      # from the cache
    finally:
        mon.close()


def test_cli_sweep_and_steady_take_faults(tmp_path, capsys, line):
    assert cli_main(['sweep', '--speeds', '1150', '1250', '10', '--fast', '--no-progress',
                     '--faults', MISFIRE_1, '--json']) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['faults'] == faults_of(MISFIRE_1, line).text()
    rows = data['sweeps'][0]['points']
    assert all(r['order_0_5'] > 0.05 for r in rows)
    schedule = tmp_path / 'weak.yaml'
    schedule.write_text('faults:\n  - {kind: weak_cylinder, cylinder: 2, factor: 0.5}\n')
    assert cli_main(['steady', '--speed', '1200', '--samples', '0', '--no-progress',
                     '--faults', str(schedule)]) == 0
    out = capsys.readouterr().out
    assert 'weak_cylinder' in out and '0.5th' in out
    for bad, says in (('{kind: misfire, cylinders: [1], mode: single}', 'is an event'),
                      ('{kind: misfire, cylinders: [7], mode: every_cycle}', 'cylinders'),
                      (str(tmp_path / 'none.yaml'), 'not found')):
        for cmd in (['sweep', '--speeds', '1150', '1250', '10'], ['steady', '--speed', '1200']):
            assert cli_main(cmd + ['--faults', bad, '--no-progress']) == 2
            err = capsys.readouterr().err.strip()
            assert says in err and len(err.splitlines()) == 1, err


def test_the_node_core_predicts_with_the_faults_it_applies():
    """The live runtime hands the monitor the faults acting after each tick: an every-cycle
    misfire set by its parameter becomes the prediction's fault set (its held part), clearing
    it brings the healthy point back."""
    from dmf_sim.live.parameters import PARAMETERS
    from dmf_sim.live.runtime import LiveRuntime, read_line
    from dmf_sim.live.streams import STREAMS, resolved_topics

    class Quiet:
        def __getattr__(self, name):
            return lambda *a, **k: None

    values = {name: spec.default for name, spec in PARAMETERS.items()}
    values.update(alpha=2.5, theta=0.24, monitor=True, monitor_worker='thread', pacing='fast',
                  initial_speed_rpm=1200.0, initial_load=1.0)
    topics = resolved_topics('')
    rt = LiveRuntime(values, read_line(values['driveline']), Quiet(), Quiet(),
                     topics={topics[k]: s.msgtype for k, s in STREAMS.items()},
                     node_name='/driveline_node')
    try:
        rt.loop.start()

        def run_for(seconds):
            end = rt.sim.t + seconds
            while rt.sim.t < end:
                with rt.lock:
                    rt.loop.tick(rt.loop.clock())

        run_for(0.02)
        assert rt.monitor.faults is None and rt.monitor._want.faults is None
        rt.apply({'fault_misfire': '{cylinders: [2], mode: every_cycle}'})
        run_for(0.05)
        held = rt.monitor._want.faults
        assert [(f.kind, f.cylinders, f.mode) for f in held] == [('misfire', (2,), 'every_cycle')]
        rt.apply({'fault_misfire': ''})
        run_for(0.05)
        assert rt.monitor.faults is None and rt.monitor._want.faults is None
    finally:
        rt.close()
