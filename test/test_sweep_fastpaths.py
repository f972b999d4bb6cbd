"""The sweep's cheaper per-point paths (issue 22, third step) give what the general code gives:
the stable-state mask of many speeds, the linear parts of one off-grid speed, the scalar order
summary and the spring's condensed static solve."""
from __future__ import annotations

import numpy as np
import pytest

from dmf_sim.physics.engine import load_engine
from dmf_sim.physics.loads import DrivelineLoads
from dmf_sim.physics.model import load_model
from dmf_sim.physics.orders import fig13_rows, summarize_orders, synthesize
from dmf_sim.physics.spring import PiecewiseLinearSpring
from dmf_sim.solvers.hbm import CondensedHBM, SweepOptions
from dmf_sim.solvers.hbm.point import HBMOptions, HBMPoint
from dmf_sim.solvers.hbm.results import Branch
from dmf_sim.solvers.hbm.sweep import SpeedSweep


@pytest.fixture(scope='module')
def loads():
    eng = load_engine('engine_d13', load_set='A')
    eng.warm()
    return DrivelineLoads(load_model('truck_dmf', alpha=3.0), eng)


def _point(s, stable):
    x = np.array([s * 1e-4, 1e-3, 0.0])
    return HBMPoint(s, x, np.array([x[0], 1e-3]), None, 0.0, 0, stable=stable)


def _by_states_at(sw, speeds):
    return [any(st for _, st in sw.states_at(float(s))) for s in speeds]


def test_stable_at_is_states_at_on_made_up_branches():
    """Folds, repeated speeds, unknown stability (None), a one-point branch: the mask of many
    speeds at once is what ``states_at`` says speed by speed."""
    sw = SpeedSweep.__new__(SpeedSweep)
    fold = [(600.0, True), (610.0, True), (620.0, False), (615.0, False), (612.5, True),
            (620.0, True), (630.0, None), (640.0, True), (640.0, False), (650.0, False)]
    sw.branches = [Branch(0, 'main', [_point(s, st) for s, st in fold]),
                   Branch(1, 'main', [_point(635.0, True)]),
                   Branch(2, 'main', [_point(645.0, None), _point(655.0, True)])]
    speeds = np.concatenate([np.arange(595.0, 661.0, 0.5), [612.5 + 1e-10, 635.0, 640.0]])
    assert sw.stable_at(speeds).tolist() == _by_states_at(sw, speeds)
    assert sw.stable_at(speeds).any() and not sw.stable_at(speeds).all()


def test_stable_at_is_states_at_after_a_sweep(loads):
    sw = SpeedSweep(CondensedHBM(loads, 1.0), SweepOptions(step_rpm=10.0, search=None))
    sw.run((900.0, 1150.0))
    speeds = np.arange(895.0, 1155.0, 2.5)
    mask = sw.stable_at(speeds)
    assert mask.tolist() == _by_states_at(sw, speeds)
    assert mask.any() and not mask.all()      # the knee region's unstable stretch is seen


def test_linear_parts_of_one_speed_equal_the_batch(loads):
    """The one-speed path (arc-length corrector speeds) gives bitwise the batch's values, at the
    top of the engine's range too (backward difference there)."""
    hb = CondensedHBM(loads, 1.0)
    top = hb._speed_range()[1]
    for s in (1234.567, top - 0.01):
        one = hb._linear_parts_one(s)
        hb2 = CondensedHBM(loads, 1.0)
        batch = hb2._linear_parts_many([s, s - 3.0, s - 7.0, s - 9.0, s - 11.0, s - 13.0,
                                        s - 17.0, s - 19.0])[0]     # a vectorized batch
        for name in ('h', 'wlin', 'dh_ds', 'dwlin_ds'):
            assert np.array_equal(getattr(one, name), getattr(batch, name)), name
        assert np.array_equal(one.lin[0], batch.lin[0])
        assert np.array_equal(one.dlin[0], batch.dlin[0])
        ref = CondensedHBM(loads, 1.0, HBMOptions(compiled=False))._linear_parts_many([s])[0]
        assert np.allclose(one.wlin, ref.wlin, rtol=1e-12, atol=0.0)


def test_scalar_summary_equals_the_rows():
    rng = np.random.default_rng(5)
    c = rng.standard_normal(25) * 1e-2 + 1j * rng.standard_normal(25) * 1e-2
    c[0] = 0.2
    w = synthesize(c, 1024)
    s = summarize_orders(c, w, 0.24, 0.18)
    r = fig13_rows(c[None], w[None])
    assert s.order_3 == r['order_3'][0] and s.order_1_5 == r['order_1_5'][0]
    assert s.max_deviation == r['max_deviation'][0] and s.min_deviation == r['min_deviation'][0]
    assert s.mean == r['mean'][0] and s.mean_minus_theta == pytest.approx(0.2 - 0.24, abs=1e-15)
    short = summarize_orders(c[:3], w, 0.24)           # no 1.5th or 3rd order kept
    assert short.order_3 == 0.0 and short.order_1_5 == 0.0


def test_solve_condensed_equals_the_array_form():
    sp = PiecewiseLinearSpring.two_step(10890.0, 0.24, 3.0, theta_coast=0.05, alpha_coast=1.0)
    h = 2e-5
    for w_lin in np.linspace(-0.4, 0.6, 41):
        r = int(np.searchsorted(sp.knees + h * sp._g_at_knees, w_lin, side='left'))
        ref = float((w_lin - h * sp.offsets[r]) / (1.0 + h * sp.slopes[r]))
        w = sp.solve_condensed(float(w_lin), h)
        assert w == ref
        assert w + h * float(sp.extra_torque(np.array([w]))[0]) == pytest.approx(w_lin,
                                                                                 abs=1e-12)
