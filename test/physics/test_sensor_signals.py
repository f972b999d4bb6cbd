"""Sensor signals from the motion (dmf_sim.physics.sensor_signals): tooth-edge times against
known motions (constant speed: exact to the timer; a sinusoid: the Hermite crossing's error and
its order), the gap, tooth indices and pitch errors, bus quantization/period/delay, sensor
faults, chunk invariance (bit for bit), and the kernel's tracking."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.optimize import brentq

from dmf_sim.physics.model import read_model
from dmf_sim.physics.sensor_signals import (
    FLAG_FIRST_AFTER_GAP,
    FLAG_SPURIOUS,
    SensorSynthesizer,
    hermite_crossing,
)
from dmf_sim.physics.sensors import parse_sensors

MODEL = read_model('truck_dmf')
CRANK = 'PRIMARY FLYWHEEL'          # R = 1, its DOF's angle is the element's (T = 1)


def synth(wheels=(), signals=()) -> SensorSynthesizer:
    s = parse_sensors({'tooth_wheels': list(wheels), 'bus_signals': list(signals)},
                      MODEL.names)
    return SensorSynthesizer(s, MODEL)


def wheel(**kw):
    w = {'name': 'crank', 'element': CRANK, 'teeth': 60, 'gap': 2, 'timer_resolution_s': 1e-9}
    w.update(kw)
    return w


def motion(sy: SensorSynthesizer, t: np.ndarray, theta, theta_dot, omega=0.0):
    """Track rows: reference rotation psi = omega t; the vibratory angle theta(t) - omega t on
    the crank DOF (other tracked DOFs: the same angle through their ratio is not needed)."""
    k = len(sy.dofs)
    rows = np.zeros((len(t), 3 + 2 * k))
    rows[:, 0] = t
    rows[:, 1] = omega * t
    rows[:, 2] = omega
    col = list(sy.dofs).index(int(MODEL.dof_of_element[MODEL.names.index(CRANK)]))
    rows[:, 3 + col] = theta(t) - omega * t
    rows[:, 3 + k + col] = theta_dot(t) - omega
    return rows


def run(sy, rows, chunks=None, faults=None):
    """Edges (time_ns, tooth, flags) per wheel and bus (ns, rpm) per signal over all rows,
    processed in chunks of the given lengths (default: one)."""
    sy.start(rows[0])
    if faults is not None:
        sy.set_faults(faults)
    rest = rows[1:]
    sizes = chunks or [len(rest)]
    out_e = {n: [] for n in sy.wheel_names}
    out_b = {n: [] for n in sy.signal_names}
    at = 0
    while at < len(rest):
        n = sizes[len(out_e[sy.wheel_names[0]] if sy.wheel_names else out_b[sy.signal_names[0]])
                  % len(sizes)]
        ch = sy.process(rest[at:at + n])
        at += n
        for w, name in enumerate(sy.wheel_names):
            out_e[name].append(ch.edge_rows(w))
        for b, name in enumerate(sy.signal_names):
            out_b[name].append(np.stack(ch.bus_of(b), axis=1) if ch.bus_counts[b]
                               else np.zeros((0, 2)))
    return ({k: np.concatenate(v) for k, v in out_e.items()},
            {k: np.concatenate(v) for k, v in out_b.items()})


# ---- tooth edges ------------------------------------------------------------------------------

def test_constant_speed_edges_are_exact_to_the_timer_and_the_gap_is_marked():
    res = 1e-7
    sy = synth([wheel(timer_resolution_s=res, offset_deg=3.0)])
    om = 1300 * 2 * math.pi / 60
    dt = 1e-4
    t = np.arange(0, 20001) * dt
    edges, _ = run(sy, motion(sy, t, lambda x: om * x, lambda x: np.full_like(x, om)))
    e = edges['crank']
    teeth = 58
    # every level crossed once, in order: tooth j of revolution r at (3 deg + 6 deg j + 2 pi r)
    g0 = 0                                           # 3 deg > 0: tooth 0 is the first level
    g = g0 + np.arange(len(e))
    levels = 2 * math.pi * (g // teeth) + np.radians(3.0 + 6.0 * (g % teeth))
    assert len(e) == np.sum(levels < om * t[-1]) and np.array_equal(e[:, 1], g % teeth)
    exact = levels / om
    ticks = np.floor(exact / res)
    expected_ns = np.round(ticks * res * 1e9).astype(np.int64)
    near = np.abs(exact / res - np.round(exact / res)) < 1e-6       # on a tick boundary
    assert np.array_equal(e[~near, 0], expected_ns[~near])
    assert np.all(np.abs(e[near, 0] - expected_ns[near]) <= res * 1e9)
    # flags: bit 0 on tooth 0 only; the gap spans three pitches
    assert np.array_equal(e[:, 2] == FLAG_FIRST_AFTER_GAP, e[:, 1] == 0)
    gaps = np.diff(e[:, 0])[e[1:, 1] == 0] / 1e9
    assert gaps == pytest.approx(3 * math.radians(6.0) / om, abs=2 * res)


def test_given_pitch_errors_move_each_edge_by_error_over_speed():
    errors = [0.0] * 58
    errors[5], errors[17], errors[40] = 0.5, -0.25, 2.9       # deg, within half a pitch
    sy = synth([wheel(pitch_errors_deg=errors)])
    om = 900 * 2 * math.pi / 60
    t = np.arange(0, 5001) * 1e-4
    e = run(sy, motion(sy, t, lambda x: om * x, lambda x: np.full_like(x, om)))[0]['crank']
    # at t = 0 the angle is on tooth 0's edge (error 0): the first edge is tooth 1's
    nominal = (2 * math.pi * (np.arange(1, len(e) + 1) // 58) + np.radians(6.0 * e[:, 1])) / om
    shift = e[:, 0] / 1e9 - nominal
    for j, err in enumerate(errors):
        assert shift[e[:, 1] == j] == pytest.approx(math.radians(err) / om, abs=1.5e-9)


def sinusoid(A=0.05, f=100.0, om=125.0):
    W = 2 * math.pi * f
    return (lambda x: om * x + A * np.sin(W * x), lambda x: om + A * W * np.cos(W * x),
            A * W ** 4, om - A * W)


def hermite_errors(dt: float, t_end: float = 0.2):
    """Max |edge time - analytic crossing| [s] under a sinusoidal angle, timer 1 ns."""
    theta, theta_dot, d4, v_min = sinusoid()
    sy = synth([wheel(gap=0, teeth=60)])
    t = np.arange(0, round(t_end / dt) + 1) * dt
    e = run(sy, motion(sy, t, theta, theta_dot))[0]['crank']
    levels = 2 * math.pi * (np.arange(1, len(e) + 1) // 60) + np.radians(6.0 * e[:, 1])
    exact = np.array([brentq(lambda x, L=L: theta(np.array(x)) - L, 0, t_end + 1e-3,
                             xtol=1e-15) for L in levels])
    return np.max(np.abs(e[:, 0] / 1e9 - exact)), d4, v_min


def test_hermite_edges_match_the_analytic_crossings_with_fourth_order():
    """The cubic Hermite interpolant's error is <= h^4/384 max|theta''''| (a textbook bound),
    so the crossing time's is that over the slowest speed, plus the 1-ns timer; halving dt
    divides it by 16 (order 4)."""
    errs = []
    for dt in (2e-3, 1e-3, 5e-4):
        err, d4, v_min = hermite_errors(dt)
        bound = dt ** 4 / 384 * d4 / v_min + 1e-9
        assert err <= bound, (dt, err, bound)
        errs.append(err)
    orders = [math.log2(errs[i] / errs[i + 1]) for i in range(2)]
    assert all(3.6 < o < 4.4 for o in orders), (errs, orders)


def test_hermite_crossing_solves_the_cubic_to_round_off():
    rng = np.random.default_rng(3)
    for _ in range(200):
        d1 = rng.uniform(0.1, 2.0)
        hv0, hv1 = d1 * rng.uniform(0.5, 1.5, 2)
        level = rng.uniform(0, d1)
        tau = hermite_crossing(d1, hv0, hv1, level)
        c2, c3 = 3 * d1 - 2 * hv0 - hv1, -2 * d1 + hv0 + hv1
        assert 0 <= tau <= 1
        assert abs(((c3 * tau + c2) * tau + hv0) * tau - level) < 1e-14


def test_backward_rotation_gives_the_teeth_in_reverse():
    sy = synth([wheel(gap=0, teeth=10)])
    om = -50.0
    t = np.arange(0, 2001) * 1e-4
    e = run(sy, motion(sy, t, lambda x: 0.3 + om * x, lambda x: np.full_like(x, om)))[0]['crank']
    # from 0.3 rad down: levels 0.0 (tooth 0), then -36 deg = tooth 9 of the previous turn ...
    assert list(e[:4, 1]) == [0, 9, 8, 7]
    assert e[0, 0] == pytest.approx(0.3 / 50 * 1e9, abs=1)


def test_jitter_is_gaussian_of_its_sigma_and_captures_never_go_back():
    sy = synth([wheel(timer_jitter_s=2e-7, seed=5)])
    om = 1200 * 2 * math.pi / 60
    t = np.arange(0, 50001) * 1e-4
    e = run(sy, motion(sy, t, lambda x: om * x, lambda x: np.full_like(x, om)))[0]['crank']
    g = np.arange(1, len(e) + 1)                     # tooth 0's edge is at the start
    levels = 2 * math.pi * (g // 58) + np.radians(6.0 * e[:, 1])
    dev = e[:, 0] / 1e9 - levels / om
    assert abs(dev.mean()) < 2e-8 and dev.std() == pytest.approx(2e-7, rel=0.05)
    assert np.all(np.diff(e[:, 0]) >= 0)


# ---- bus signals ---------------------------------------------------------------------------

def test_bus_value_period_delay_and_quantization_are_exact():
    sig = {'name': 'engine_speed', 'element': CRANK, 'period_s': 0.01, 'resolution_rpm': 0.125,
           'delay_s': 0.0025}
    sy = synth(signals=[sig])
    theta, theta_dot, _, _ = sinusoid(A=0.01, f=7.0, om=130.0)
    dt = 1e-4
    t = np.arange(0, 5001) * dt
    bus = run(sy, motion(sy, t, theta, theta_dot))[1]['engine_speed']
    k = np.arange(2, 2 + len(bus))                  # the first value one period after t = 0.01
    assert np.array_equal(bus[:, 0].astype(np.int64), np.round((k * 0.01 + 0.0025) * 1e9))
    mean = (theta(k * 0.01) - theta((k - 1) * 0.01)) / 0.01 * 60 / (2 * math.pi)
    assert np.array_equal(bus[:, 1], np.floor(mean / 0.125 + 0.5) * 0.125)
    # delivered once its time has come: the last one by the end of the run
    assert bus[-1, 0] <= t[-1] * 1e9 < bus[-1, 0] + 0.01e9


def test_bus_noise_is_its_sigma():
    sig = {'name': 's', 'element': CRANK, 'period_s': 0.001, 'resolution_rpm': 0.001,
           'noise_rpm': 2.0, 'seed': 9}
    sy = synth(signals=[sig])
    om = 100.0
    t = np.arange(0, 40001) * 1e-4
    v = run(sy, motion(sy, t, lambda x: om * x, lambda x: np.full_like(x, om)))[1]['s'][:, 1]
    assert v.std() == pytest.approx(2.0, rel=0.05)
    assert v.mean() == pytest.approx(om * 60 / (2 * math.pi), abs=0.1)


# ---- faults ------------------------------------------------------------------------------------

def F(**kw):
    kw.setdefault('start_s', None)
    kw.setdefault('end_s', None)
    kw.setdefault('seed', 0)
    for k in ('probability', 'tooth', 'rate_per_s', 'sigma_rpm'):
        kw.setdefault(k, None)
    return SimpleNamespace(**kw)


def constant(sy, rpm=1200.0, seconds=2.0, dt=1e-4):
    om = rpm * 2 * math.pi / 60
    t = np.arange(0, round(seconds / dt) + 1) * dt
    return motion(sy, t, lambda x: om * x, lambda x: np.full_like(x, om))


def test_missing_edges_by_probability_and_by_tooth_within_their_window():
    sy = synth([wheel()])
    rows = constant(sy)
    clean = run(sy, rows)[0]['crank']
    drop = run(sy, rows, faults=[F(kind='sensor_edges', sensor='crank', mode='missing',
                                   probability=0.2, start_s=0.5, end_s=1.5, seed=4)])[0]['crank']
    inside = (clean[:, 0] >= 0.5e9) & (clean[:, 0] < 1.5e9)
    kept = np.isin(clean[:, 0], drop[:, 0])
    assert kept[~inside].all()
    assert 1 - kept[inside].mean() == pytest.approx(0.2, abs=0.04)
    assert np.isin(drop[:, 0], clean[:, 0]).all()            # nothing else changes
    tooth = run(sy, rows, faults=[F(kind='sensor_edges', sensor='crank', mode='missing',
                                    tooth=17, start_s=0.5)])[0]['crank']
    gone = clean[~np.isin(clean[:, 0], tooth[:, 0])]
    assert set(gone[:, 1]) == {17} and (gone[:, 0] >= 0.5e9).all()
    assert len(gone) == np.sum((clean[:, 1] == 17) & (clean[:, 0] >= 0.5e9))


def test_extra_edges_come_at_their_rate_flagged_with_the_tooth_before():
    sy = synth([wheel()])
    rows = constant(sy, seconds=4.0)
    clean = run(sy, rows)[0]['crank']
    e = run(sy, rows, faults=[F(kind='sensor_edges', sensor='crank', mode='extra',
                                rate_per_s=50.0, start_s=1.0, end_s=3.0, seed=2)])[0]['crank']
    spur = e[e[:, 2] & FLAG_SPURIOUS > 0]
    assert len(spur) == pytest.approx(100, abs=30)            # Poisson: 100 +- 10
    assert (spur[:, 0] >= 1e9).all() and (spur[:, 0] < 3e9).all()
    assert np.array_equal(e[e[:, 2] & FLAG_SPURIOUS == 0], clean)
    assert np.all(np.diff(e[:, 0]) >= 0)
    before = np.searchsorted(clean[:, 0], spur[:, 0], side='right') - 1
    assert np.array_equal(spur[:, 1], clean[before, 1])


def test_stuck_and_noisy_bus_signals():
    sig = {'name': 's', 'element': CRANK, 'period_s': 0.01, 'resolution_rpm': 0.125}
    sy = synth(signals=[sig])
    theta, theta_dot, _, _ = sinusoid(A=0.02, f=3.0, om=120.0)
    t = np.arange(0, 20001) * 1e-4
    rows = motion(sy, t, theta, theta_dot)
    clean = run(sy, rows)[1]['s']
    stuck = run(sy, rows, faults=[F(kind='bus_signal', signal='s', mode='stuck', start_s=0.5,
                                    end_s=1.0)])[1]['s']
    sent = clean[:, 0] / 1e9                                  # no delay: sent = delivered
    inside = (sent >= 0.5) & (sent < 1.0)
    assert np.array_equal(stuck[~inside], clean[~inside])
    held = clean[np.flatnonzero(inside)[0] - 1, 1]
    assert (stuck[inside, 1] == held).all() and len(set(clean[inside, 1])) > 5
    noisy = run(sy, rows, faults=[F(kind='bus_signal', signal='s', mode='noisy',
                                    sigma_rpm=5.0, seed=3)])[1]['s']
    assert (noisy[:, 1] - clean[:, 1]).std() == pytest.approx(5.0, rel=0.15)


# ---- streaming ----------------------------------------------------------------------------

def test_any_chunking_gives_the_same_signals_bit_for_bit():
    sy = synth([wheel(timer_jitter_s=2e-7, seed=1, pitch_error_sigma_deg=0.05),
                wheel(name='out', element='OUTPUT SHAFT', teeth=20, gap=0)],
               [{'name': 'a', 'wheel': 'crank', 'period_s': 0.02, 'resolution_rpm': 0.125,
                 'delay_s': 0.013, 'noise_rpm': 0.5, 'seed': 3},
                {'name': 'b', 'element': 'OUTPUT SHAFT', 'period_s': 1e-4,
                 'resolution_rpm': 0.5}])
    theta, theta_dot, _, _ = sinusoid(A=0.03, f=40.0, om=140.0)
    t = np.arange(0, 4001) * 3e-4                  # steps of 3e-4 s: three bus values in each
    rows = motion(sy, t, theta, theta_dot)
    faults = [F(kind='sensor_edges', sensor='crank', mode='extra', rate_per_s=30.0, seed=7,
                start_s=0.2, end_s=0.9),
              F(kind='sensor_edges', sensor='out', mode='missing', probability=0.3, seed=8),
              F(kind='bus_signal', signal='a', mode='noisy', sigma_rpm=3.0, start_s=0.3),
              F(kind='bus_signal', signal='b', mode='stuck', start_s=0.5, end_s=0.7)]
    one = run(sy, rows, faults=faults)
    rng = np.random.default_rng(0)
    for sizes in ([1], [7, 1, 30], list(rng.integers(1, 400, 20)), [3000]):
        other = run(sy, rows, chunks=sizes, faults=faults)
        for a, b in zip(one, other):
            for name in a:
                assert a[name].tobytes() == b[name].tobytes(), (sizes, name)
    assert len(one[0]['crank']) > 1000 and len(one[1]['b']) > 1000


def test_outputs_grow_when_a_chunk_has_many_edges():
    sy = synth([wheel(teeth=3600, gap=0)])
    e = run(sy, constant(sy, rpm=2000.0, seconds=0.5))[0]['crank']
    assert len(e) == pytest.approx(2000 / 60 * 3600 * 0.5, abs=2)


# ---- the kernel's tracking ------------------------------------------------------------------

def test_tracking_writes_every_step_and_changes_no_state():
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.solvers.newmark import NewmarkIntegrator

    excitation = DrivelineExcitation(MODEL, read_engine('engine_d13'))
    a, b = NewmarkIntegrator(excitation), NewmarkIntegrator(excitation)
    for it in (a, b):
        it.reset(1100.0, 0.8)
    dofs = np.array([3, 8, 9])
    b.set_tracked(dofs)
    track = np.zeros((500, b.track_columns()))
    ra = a.advance(500, None, 1)
    rb = b.advance(500, None, 1, track=track)
    assert ra == rb and np.array_equal(a.q, b.q) and np.array_equal(a.v, b.v)
    assert np.array_equal(track[-1, 3:6], b.q[dofs]) and np.array_equal(track[-1, 6:], b.v[dofs])
    assert np.allclose(np.diff(track[:, 0]), 1e-4) and track[-1, 0] == b.t
    assert track[-1, 1] == b.psi and track[-1, 2] == b.omega
    with pytest.raises(ValueError):
        b.advance(10, None, 1, track=np.zeros((5, b.track_columns())))
