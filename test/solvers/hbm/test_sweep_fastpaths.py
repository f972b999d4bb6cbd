"""The sweep's cheaper per-point paths give what the general
code gives: the stable-state mask of many speeds, the linear parts of one off-grid speed and of
many speeds, the scalar order summary, the spring's condensed static solve, a linear stretch's
points made in one batch and where it starts, and the sharp resonances' modal contributions (a
grid's linear parts and a traced branch's points in one batch against the general code:
test_kernel_parity.py; the multipliers' eigenvalue call: test_eigenvalues)."""
from __future__ import annotations

import numpy as np
import pytest

from dmf_sim.physics.engine import read_engine
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_model
from dmf_sim.physics.orders import fig13_rows, summarize_orders, synthesize
from dmf_sim.physics.spring import PiecewiseLinearSpring
from dmf_sim.solvers.hbm import CondensedHBM, SweepOptions
from dmf_sim.solvers.hbm.point import HBMOptions, HBMPoint
from dmf_sim.solvers.hbm.results import Branch
from dmf_sim.solvers.hbm.sweep import SpeedSweep
from dmf_sim.solvers.hbm.unknowns import to_real


@pytest.fixture(scope='module')
def loads():
    eng = read_engine('engine_d13', load_set='A')
    eng.warm_up()
    return DrivelineExcitation(read_model('truck_dmf', alpha=3.0), eng)


def _point(s, stable):
    x = np.array([s * 1e-4, 1e-3, 0.0])
    return HBMPoint(s, x, np.array([x[0], 1e-3]), None, 0.0, 0, stable=stable)


def _by_states_at(sw, speeds):
    return [any(st for _, st in sw.states_at(float(s))) for s in speeds]


def test_stable_at_is_states_at_on_made_up_branches(loads):
    """Folds, repeated speeds, unknown stability (None), a one-point branch: the mask of many
    speeds at once is what ``states_at`` says speed by speed."""
    sw = SpeedSweep(CondensedHBM(loads, 1.0))
    fold = [(600.0, True), (610.0, True), (620.0, False), (615.0, False), (612.5, True),
            (620.0, True), (630.0, None), (640.0, True), (640.0, False), (650.0, False)]
    sw.branches[:] = [Branch(0, 'main', [_point(s, st) for s, st in fold]),
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


def test_linear_parts_of_a_grid_outside_the_engine_data_are_left_to_python(loads):
    """A grid with a speed outside the engine's data, or a problem without the compiled engine
    query, gets no compiled batch (None: the numpy batch instead), and the Python path raises as
    usual there (the batch's parity with numpy: test_kernel_parity.py)."""
    from dmf_sim.core.errors import OperatingRangeError
    hb = CondensedHBM(loads, 1.0)
    top = hb._speed_range()[1]
    assert hb._linear_parts_compiled([1000.0, top]) is not None
    ref = CondensedHBM(loads, 1.0)
    ref._kernel_engine = ()                 # no compiled engine query: the numpy batch
    assert ref._linear_parts_compiled([1000.0, top]) is None
    assert hb._linear_parts_compiled([1000.0, top + 50.0]) is None
    with pytest.raises(OperatingRangeError):
        hb.linear_parts(top + 50.0)


@pytest.mark.parametrize('cache_size', [512, 4])
def test_linear_parts_of_many_speeds_are_the_calls_one_by_one(loads, cache_size, monkeypatch):
    """CondensedHBM.linear_parts_of (a branch's points: the speeds not cached computed in one
    batch) gives bitwise what linear_parts gives speed by speed, and leaves the cache in the same
    state (the same speeds in the same order), also where the batch itself evicts speeds that
    were cached when it started (a cache of 4)."""
    from dmf_sim.solvers.hbm import condensed
    monkeypatch.setattr(condensed, 'LINEAR_PARTS_CACHE', cache_size)
    one, many = CondensedHBM(loads, 1.0), CondensedHBM(loads, 1.0)
    for hb in (one, many):
        hb.prepare([900.0, 910.0, 920.0])
    speeds = [905.5, 910.0, 1234.25, 905.5, 900.0, 987.125, 920.0, 1500.75]
    a = [one.linear_parts(s) for s in speeds]
    b = many.linear_parts_of(speeds)
    for p, q in zip(a, b):
        assert p.speed_rpm == q.speed_rpm
        for f in ('h', 'wlin', 'dh_ds', 'dwlin_ds'):
            assert np.array_equal(getattr(p, f), getattr(q, f))
    assert list(one._cache) == list(many._cache)


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


def test_points_of_a_linear_stretch_made_in_one_batch_equal_one_by_one(loads):
    """``make_points`` (a sweep's linear stretch) gives bitwise what ``make_point`` gives for
    each solution: harmonics, unknowns, the Fig. 13 summary and the static wind-up."""
    hb = CondensedHBM(loads, 1.0)
    speeds = np.arange(620.0, 700.0, 10.0)
    W = hb.linear_response(speeds)
    series = hb.time_series_batch(W, 1024)
    made = hb.make_points(speeds, W, series, W[:, 0].real)
    assert len(made) == len(speeds)
    for k, p in enumerate(made):
        q = hb.make_point(float(speeds[k]), to_real(W[k], hb.H), 0.0, 0, samples=series[k],
                          wlin0=float(W[k, 0].real))
        assert p.speed_rpm == q.speed_rpm and p.residual == 0.0 and p.iterations == 0
        assert np.array_equal(p.x, q.x) and np.array_equal(p.windup_orders, q.windup_orders)
        assert p.summary == q.summary
    made[0].x[0] += 1.0                     # one point's unknowns are not another's
    assert made[1].x[0] == to_real(W[1], hb.H)[0]


def test_the_linear_stretch_starts_only_below_the_knees(loads):
    """The fast-forward starts only where the point's wind-up stays in the primary region: on
    the AFT samples (no torque beyond a knee) and on the finer samples of the stability
    analysis; its points are stable, with the exact tangent at the last one."""
    sw = SpeedSweep(CondensedHBM(loads, 1.0), SweepOptions(step_rpm=10.0, search=None))
    sw.range = (600.0, 2000.0)
    sw.hbm.prepare(np.arange(600.0, 2001.0, 10.0))
    from dmf_sim.solvers.continuation import ContinuationPoint
    for s in (700.0, 1300.0):               # below the knee, and crossing it
        x = sw.hbm.solve(s).x
        cp = ContinuationPoint(x, s, np.r_[np.zeros(len(x)), 1.0], 0, 0.0, True)
        own = sw._linear_stretch(cp, 1.0)
        crosses = bool(np.any(sw.hbm.nonlinear_harmonics(x)))
        assert crosses == (s == 1300.0)
        assert (len(own) > 0) == (s == 700.0)
        for q in own:
            assert q.point.stable is True and np.isclose(np.linalg.norm(q.tangent), 1.0)
            assert not np.any(sw.hbm.nonlinear_harmonics(q.x))


def test_sharp_resonance_contribution_is_the_dof_load_formula(loads):
    """The peak contribution of a lightly damped mode, |(P_n . B_k) ell_k / Re d_k| with the DOF
    load harmonics P_n, computed from the engine coefficients and the modal loads instead."""
    hb = CondensedHBM(loads, 1.0)
    marks = hb.sharp_resonances((600.0, 2000.0))
    assert marks
    for m in marks:
        k = int(np.flatnonzero(np.isclose(hb._d.imag, 2 * np.pi * m['frequency_hz'], rtol=1e-12)
                               & (hb._d.imag > 0))[0])
        P = hb.dof_loads(m['speed_rpm'])
        n = m['half_order']
        ref = abs((P[n] @ hb._B[:, k]) * hb._ell[k] / -hb._d[k].real)
        assert m['contribution_rad'] == pytest.approx(ref, rel=1e-12)


def test_aft_tables_made_once_and_copied_per_problem(loads):
    """The AFT matrices are made once per (H, M), read-only, and each problem works on its own
    copies: the formulas w_j = E x, G = F g (F = diag(weights) E^T), cos / sin tables of
    m phi_j."""
    from dmf_sim.solvers.hbm.condensed import aft_tables
    a, b = CondensedHBM(loads, 1.0), CondensedHBM(loads, 1.0)
    H, M = a.H, a.M
    phi, E, weights, F, cos_m, sin_m = aft_tables(H, M)
    assert aft_tables(H, M)[1] is E and not E.flags.writeable
    assert np.allclose(phi, 2 * np.pi * np.arange(M) / M, rtol=0, atol=1e-15)
    n = np.arange(1, H + 1)
    assert np.allclose(E[:, 1:H + 1], np.cos(np.outer(phi, n)), rtol=0, atol=1e-15)
    assert np.allclose(E[:, H + 1:], -np.sin(np.outer(phi, n)), rtol=0, atol=1e-15)
    assert np.allclose(F, weights[:, None] * E.T, rtol=0, atol=1e-18)
    assert np.allclose(F @ E, np.eye(2 * H + 1), rtol=0, atol=1e-12)      # exact on H harmonics
    assert np.allclose(sin_m[:, 1], np.sin(phi), rtol=0, atol=1e-15)
    assert cos_m.shape == (M, 2 * H + 1)
    assert np.array_equal(a.E, E) and a.E is not b.E and a.E.flags.writeable
    a.E[0, 0] = 7.0
    assert b.E[0, 0] == 1.0 and E[0, 0] == 1.0


def _modal_sums_complex(omega, dOm, d, ml, a, unit, dunit, h, dh):
    """The modal sums in complex arithmetic, one (speed, harmonic) at a time over the modes: what
    ``linear_kernels.modal_sums`` computes with the harmonics innermost and the complex
    operations written out."""
    for q in range(omega.shape[0]):
        for n in range(ml.shape[0]):
            Om = omega[q] * ((n + 1) / 2.0)
            su = sdu = sh = sdh = 0j
            for k in range(d.shape[0]):
                p = 1.0 / (1j * Om - d[k])
                p2 = -1j * (p * p)
                su += p * ml[n, k]
                sdu += p2 * ml[n, k]
                sh += p * a[k]
                sdh += p2 * a[k]
            unit[q, n], dunit[q, n] = su, sdu * dOm[n]
            h[q, n], dh[q, n] = sh, sdh * dOm[n]


@pytest.mark.slow
def test_modal_sums_written_out_equal_complex_arithmetic_to_rounding():
    """The linear parts' modal sums, harmonics innermost with the complex operations written out
    (SIMD), give the same sums as numba's complex arithmetic to rounding: random poles (one at
    zero, resonant ones where Im d = Om_n), receptance and residue vectors. Usually bit for bit;
    not always (a fresh checkout's compile of the complex reference differed by up to 1.2e-16 of
    the largest value on 40 % of the entries), so within 4 ulps of the largest magnitude."""
    from dmf_sim.core.compiled import jit
    from dmf_sim.solvers.hbm.linear_kernels import modal_sums
    reference = jit(_modal_sums_complex)
    rng = np.random.default_rng(21)
    for trial in range(12):
        K, H, m = (int(v) for v in rng.integers(1, 30, 3))
        omega = rng.random(K) * 300.0
        dOm = rng.random(H)
        d = -rng.random(m) * 50.0 + 1j * (rng.random(m) - 0.5) * 3000.0
        if trial % 3 == 0:
            d[0] = 0.0
        if trial % 3 == 1:
            d[-1] = -1e-3 + 1j * omega[0] * 0.5     # Im d on the first harmonic's frequency
        ml = rng.standard_normal((H, m)) + 1j * rng.standard_normal((H, m))
        a = rng.standard_normal(m) + 1j * rng.standard_normal(m)
        got = [np.empty((K, H), dtype=complex) for _ in range(4)]
        ref = [np.empty((K, H), dtype=complex) for _ in range(4)]
        modal_sums(omega, dOm, d, ml, a, *got)
        reference(omega, dOm, d, ml, a, *ref)
        for g, r in zip(got, ref):
            scale = float(np.abs(r).max())
            assert np.abs(g - r).max() <= 4 * np.finfo(float).eps * scale
