"""Harmonic balance and Floquet stability of the DMF with arc-spring friction and end stops
(doc/theory.md §2 eq. 8a-8b, §7, §8): the AFT with the law against its numpy reference and
finite differences, HBM against Newmark where the DMF slips and where it sticks, convergence in
the number of harmonics, the energy balance of one cycle, and the multipliers of a state Newmark
reaches."""
from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

import dmf_sim as dmf
from dmf_sim.core.paths import config_dir
from dmf_sim.core.units import CYCLE_RAD, RPM_TO_RAD_S
from dmf_sim.physics.model import ReducedModel, driveline_from_dict
from dmf_sim.solvers.hbm.condensed import CondensedHBM
from dmf_sim.solvers.hbm.point import HBMOptions
from dmf_sim.solvers.newmark import NewmarkIntegrator
from dmf_sim.solvers.stability import FloquetAnalyzer

ENGINE = 'engine_d13'
SLIP_SPEEDS = (1000.0, 1500.0)
"""Full load, truck_dmf_friction: |w_dot| exceeds omega_reg over ~99 % of the cycle."""
REL_MAIN = 0.02
"""HBM vs Newmark, orders 1.5 and 3 (the forced ones): relative to their own amplitude."""
ABS_SMALL = 0.01
"""HBM vs Newmark, orders 0.5 and 1 (~1 % of the 3rd order, made by the friction's square-wave
torque, whose harmonics fall off as 1/n): absolute, relative to the 3rd-order amplitude."""


def _loads(name='truck_dmf_friction', **friction):
    d = yaml.safe_load((config_dir() / f'{name}.yaml').read_text())
    d = copy.deepcopy(d)
    d['dmf'].setdefault('friction', {}).update(friction)
    return dmf.DrivelineExcitation(ReducedModel(driveline_from_dict(d)), dmf.read_engine(ENGINE))


def _newmark(hb, point, **kw):
    opts = dict(dt=5e-5, steady_tol=1e-7, max_cycles=200)
    opts.update(kw)
    return hb.newmark_from(point, **opts).windup_orders


def test_aft_with_friction_and_stops_equals_reference():
    """The compiled AFT of g + T_f + T_s (friction slipping and a drive-stop contact in the
    cycle) equals its numpy reference; its Jacobian and omega derivative equal central
    differences of the reference."""
    loads = _loads()
    hb = CondensedHBM(loads, 1.0, HBMOptions(n_harmonics=8))
    ref = CondensedHBM(loads, 1.0, HBMOptions(n_harmonics=8, compiled=False))
    s = 1200.0
    lp = hb.linear_parts(s)
    x = hb.linear_solution(s)
    x[0] = 0.44                                   # the drive stop at 0.45 rad is reached
    x[1:] += 2e-3 * np.random.default_rng(3).standard_normal(len(x) - 1)
    assert (hb.windup_samples(x) > hb.spring.stops.drive_angle_rad).any()
    G, dG = hb.nonlinear_harmonics(x, True, speed_rpm=s)
    Gr, dGr = ref.nonlinear_harmonics(x, True, speed_rpm=s)
    np.testing.assert_allclose(G, Gr, rtol=0, atol=1e-9 * np.abs(Gr).max())
    np.testing.assert_allclose(dG, dGr, rtol=0, atol=1e-9 * np.abs(dGr).max())
    eps = 1e-8
    fd = np.empty_like(dGr)
    for k in range(len(x)):
        d = np.zeros_like(x)
        d[k] = eps
        fd[:, k] = (ref.nonlinear_harmonics(x + d, speed_rpm=s)
                    - ref.nonlinear_harmonics(x - d, speed_rpm=s)) / (2 * eps)
    np.testing.assert_allclose(dG, fd, rtol=0, atol=1e-4 * np.abs(dG).max())
    r, J, rs = hb.residual_and_jacobians(x, s)
    np.testing.assert_allclose(rs, ref.residual_speed_derivative(x, lp), rtol=0,
                               atol=1e-9 * np.abs(rs).max())
    _, _, Gs = ref._nonlinear_reference(x, False, s)
    ds = 0.01
    fd_s = (ref.nonlinear_harmonics(x, speed_rpm=s + ds)
            - ref.nonlinear_harmonics(x, speed_rpm=s - ds)) / (2 * ds)
    np.testing.assert_allclose(Gs * RPM_TO_RAD_S, fd_s, rtol=0, atol=1e-6 * np.abs(fd_s).max())


def test_an_elastic_spring_reads_no_speed():
    """Without friction and stops the AFT is the elastic one: the speed changes nothing."""
    hb = CondensedHBM(_loads('truck_dmf'), 1.0, HBMOptions(n_harmonics=8))
    x = hb.linear_solution(1200.0)
    x[0] = 0.3
    assert np.array_equal(hb.nonlinear_harmonics(x), hb.nonlinear_harmonics(x, speed_rpm=900.0))
    with pytest.raises(ValueError, match='speed_rpm'):
        CondensedHBM(_loads(), 1.0).nonlinear_harmonics(x)


@pytest.mark.parametrize('speed', SLIP_SPEEDS)
def test_hbm_agrees_with_newmark_where_the_dmf_slips(speed):
    hb = CondensedHBM(_loads(), 1.0)
    p = hb.solve(speed)
    c = _newmark(hb, p)
    main = abs(c[6])
    for n in (3, 6):                              # orders 1.5 and 3
        assert abs(abs(p.windup_orders[n]) - abs(c[n])) <= REL_MAIN * abs(c[n]), n
    for n in (1, 2):                              # orders 0.5 and 1
        assert abs(abs(p.windup_orders[n]) - abs(c[n])) <= ABS_SMALL * main, n
    assert abs(p.windup_orders[0].real - c[0].real) <= 1e-3 * abs(c[0])


def test_the_harmonics_converge_as_h_grows():
    loads = _loads()
    c6 = [abs(CondensedHBM(loads, 1.0, HBMOptions(n_harmonics=H)).solve(1000.0)
              .windup_orders[6]) for H in (12, 24, 48)]
    assert abs(c6[1] - c6[2]) < abs(c6[0] - c6[2])
    assert abs(c6[1] - c6[2]) <= 1e-3 * c6[2]


def test_one_cycle_balances_excitation_work_with_viscous_and_friction_heat():
    """Over one cycle of the HBM state the work of the engine's loads equals the viscous heat
    plus the friction heat (the time integral of T_f w_dot, eq. 8a), and that friction heat is
    Newmark's (its own trapezoidal count, started on the HBM state)."""
    loads = _loads()
    hb = CondensedHBM(loads, 1.0)
    s = 1000.0
    p = hb.solve(s)
    m = hb.model
    omega = s * RPM_TO_RAD_S
    T = CYCLE_RAD / omega
    qn = hb.dof_harmonics(p)[1:]
    Om = np.arange(1, hb.H + 1) * omega / 2.0
    vn = 1j * Om[:, None] * qn
    P = hb.dof_loads(s)[1:]
    work_in = 0.5 * T * np.sum(np.real(np.conj(vn) * P))
    viscous = 0.5 * T * np.real(np.einsum('ni,ij,nj->', np.conj(vn), m.C, vn))
    heat = {}
    for N in (hb.M, 4096):           # the AFT's own samples, and a fine grid
        w = hb.time_series(p.x, N)
        wd = np.fft.irfft(np.concatenate([[0], 1j * Om * p.windup_orders[1:] * N / 2,
                                          np.zeros(N // 2 - hb.H)]), N)
        # the whole non-linear torque's work: g's vanishes over a cycle up to the sampling
        heat[N] = T * np.mean((hb.spring.extra_torque(w) + hb.spring.law_torque(w, wd, omega))
                              * wd)
    friction = heat[4096]
    assert friction > 0.05 * work_in                  # a share worth checking
    # exact on the AFT's samples (the balanced harmonics are the samples' own); on the fine
    # grid within the aliasing of the friction's square wave onto H harmonics
    assert work_in == pytest.approx(viscous + heat[hb.M], rel=1e-8)
    assert work_in == pytest.approx(viscous + friction, rel=1e-3)
    integ = NewmarkIntegrator(loads, dt=2.5e-5)
    integ.reset(s, 1.0)
    integ.q[:], integ.v[:] = hb.dof_state(p, 0.0)
    steps = int(round(T / 2.5e-5))
    integ.advance(10 * steps)                        # settle the start's small transient
    heat0 = integ.friction_heat_j
    integ.advance(4 * steps)
    assert (integ.friction_heat_j - heat0) / 4 == pytest.approx(friction, rel=0.01)


def test_floquet_multipliers_with_friction_are_inside_and_converge():
    """A state Newmark reaches (it settles on the HBM solution) has every multiplier inside the
    unit circle; the step-by-step monodromy converges as the cycle's steps double, and its
    compiled and numpy forms agree."""
    loads = _loads()
    hb = CondensedHBM(loads, 1.0)
    s = 1000.0
    p = hb.solve(s)
    c = _newmark(hb, p)
    assert abs(abs(c[6]) - abs(p.windup_orders[6])) <= REL_MAIN * abs(c[6])
    res = {N: FloquetAnalyzer(hb.model, n_fine=N, modes=hb.modes).analyze(p.windup_orders, s)
           for N in (1024, 2048, 8192)}
    assert res[1024].stable and np.abs(res[1024].multipliers).max() < 1.0
    spread = [np.abs(np.sort(np.abs(res[N].multipliers)) - np.sort(np.abs(res[8192].multipliers)))
              .max() for N in (1024, 2048)]
    assert spread[1] < 0.25 * spread[0] and spread[0] <= 1e-3   # converges as the steps double
    assert abs(res[1024].max_abs - res[8192].max_abs) <= 1e-6      # the one stability reads
    ref = FloquetAnalyzer(hb.model, modes=hb.modes, compiled=False).analyze(p.windup_orders, s)
    np.testing.assert_allclose(np.sort(np.abs(ref.multipliers)),
                               np.sort(np.abs(res[1024].multipliers)), rtol=0, atol=1e-10)



@pytest.mark.parametrize('speed', SLIP_SPEEDS)
def test_the_monodromy_leaves_out_only_negligible_steps(speed):
    """The far tails of the regularized friction (tanh' tiny but not zero), which the monodromy
    skips below NEGLIGIBLE_STEPS in all: the multipliers move (steps were left out) by far less
    than the stability tolerance, compiled and numpy alike."""
    from dmf_sim.solvers.stability import NEGLIGIBLE_STEPS
    hb = CondensedHBM(_loads(), 1.0)
    c = hb.solve(speed).windup_orders
    mu = {}
    for compiled in (True, False):
        for neg in (NEGLIGIBLE_STEPS, 0.0):
            fa = FloquetAnalyzer(hb.model, modes=hb.modes, compiled=compiled, negligible=neg)
            mu[compiled, neg] = np.sort_complex(np.asarray(fa.analyze(c, speed).multipliers,
                                                           dtype=complex))
    for compiled in (True, False):
        moved = np.abs(mu[compiled, NEGLIGIBLE_STEPS] - mu[compiled, 0.0]).max()
        assert 0.0 < moved <= 1e-3 * fa.tol
    np.testing.assert_allclose(np.sort(np.abs(mu[True, NEGLIGIBLE_STEPS])),
                               np.sort(np.abs(mu[False, NEGLIGIBLE_STEPS])), rtol=0, atol=1e-10)

@pytest.mark.slow
@pytest.mark.parametrize('reg, tol', [(0.05, 0.01), (0.2, 0.01)])
def test_where_the_dmf_sticks_hbm_is_newmarks_regularized_creep(reg, tol):
    """T0 = 6000 Nm at 1000 rpm: |w_dot| < omega_reg over ~70 % of the cycle (stick). HBM (a
    homotopy in omega_reg from the linear guess) and Newmark agree on the regularized law; the
    3rd-order wind-up is the creep of the viscous-like stick, ~proportional to omega_reg."""
    hb = CondensedHBM(_loads(torque_nm=6000.0, regularization_rad_s=reg), 1.0,
                      HBMOptions(n_harmonics=48))
    p = hb.solve(1000.0)
    c = _newmark(hb, p, max_cycles=400)
    assert abs(abs(p.windup_orders[6]) - abs(c[6])) <= tol * abs(c[6])
    assert abs(c[6]) < 0.05 * 1.5e-2             # far below the slipping DMF's 3rd order


@pytest.mark.slow
def test_the_linear_fast_forward_ends_at_an_end_stop():
    """The sweep's fast-forward takes the linear response at grid speeds where the wind-up stays
    inside the primary region, and that region ended at the knees only. With end stops and no
    friction (truck_dmf_friction's stops, the coast one moved to 7 mrad, load 0), ``steady`` at
    600 rpm reported the linear state as stable: 1 mrad beyond the coast stop (min -8.0 mrad),
    ~1 kNm of contact torque left out, its residual with the stop law 8.5e-3 rad. Every state
    reported now solves eq. 15 with the whole law (to Newton's tolerance)."""
    from dmf_sim.solvers.steady import BasinOptions, find_steady_states
    d = yaml.safe_load((config_dir() / 'truck_dmf_friction.yaml').read_text())
    del d['dmf']['friction']
    d['dmf']['end_stops']['coast_angle_rad'] = 0.007
    loads = dmf.DrivelineExcitation(ReducedModel(driveline_from_dict(d)), dmf.read_engine(ENGINE))
    res = find_steady_states(loads, 600.0, 0.0, basin=BasinOptions(samples=0))
    hb = CondensedHBM(loads, 0.0)
    lp = hb.linear_parts(600.0)
    assert res.states
    for st in res.states:
        assert np.abs(hb.residual(st.point.x, lp)).max() < 1e-9
    assert hb.spring.linear_bounds() == (-0.007, 0.24)
