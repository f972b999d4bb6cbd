"""A three-stage drive spring with a coast stage, given only in YAML, through every solver:
Newmark (kernel = reference path, energy balance), harmonic balance vs Newmark,
Floquet multipliers vs a brute-force monodromy from finite differences of Newmark, modes per
stage, non-linear normal modes, the speed sweep CLI and the live simulation."""
from __future__ import annotations

import json

import numpy as np
import pytest
import yaml
from support.fake_engine import FakeEngine

from dmf_sim.cli import main as cli_main
from dmf_sim.core.paths import config_file
from dmf_sim.core.units import CYCLE_RAD, RPM_TO_RAD_S
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_driveline
from dmf_sim.solvers.hbm import CondensedHBM
from dmf_sim.solvers.newmark import NewmarkIntegrator, SimulationOptions, StepRecord, simulate
from dmf_sim.solvers.stability import FlexibleModes, FloquetAnalyzer

STAGES = [{'angle_rad': 0.10, 'stiffness_factor': 1.0},
          {'angle_rad': 0.14, 'stiffness_factor': 2.5},
          {'angle_rad': 0.18, 'stiffness_factor': 5.0}]
COAST = [{'angle_rad': 0.02, 'stiffness_factor': 1.5}]
# mean 1080 Nm, strong 3rd order: at 850 rpm the wind-up visits every stage (-0.05 .. 0.19 rad)
ENGINE = FakeEngine({0: 180.0, 3: 60 + 20j, 6: 3500 - 300j, 12: 200.0})
SPEED = 850.0


@pytest.fixture(scope='module')
def yaml_path(tmp_path_factory):
    d = yaml.safe_load(config_file('truck_dmf').read_text())
    d['name'] = 'truck_dmf_3stage'
    d['dmf'] = {'element': d['dmf']['element'], 'stiffness': 10890, 'stages': STAGES,
                'coast_stages': COAST}
    path = tmp_path_factory.mktemp('multistage') / 'truck_dmf_3stage.yaml'
    path.write_text(yaml.safe_dump(d, sort_keys=False))
    return path


@pytest.fixture(scope='module')
def loads(yaml_path):
    return DrivelineExcitation(read_driveline(yaml_path).reduce(), ENGINE)


def test_yaml_spring_has_every_stage(loads):
    sp = loads.model.spring
    assert sp.knees.tolist() == [-0.02, 0.10, 0.14, 0.18]
    assert [sp.stiffness(w) / sp.k for w in (-0.1, 0.0, 0.12, 0.16, 0.3)] == pytest.approx(
        [2.5, 1.0, 2.0, 3.5, 6.0])


def test_newmark_kernel_equals_reference_across_all_stages(loads):
    out = []
    for use_numba in (True, False):
        integ = NewmarkIntegrator(loads, dt=1e-4, use_numba=use_numba)
        integ.reset(SPEED, 1.0)
        rec = StepRecord.allocate(3000, loads.model.n_dof)
        integ.advance(3000, rec, 1)
        out.append((rec.q.copy(), rec.windup.copy(), integ.knee_crossings, integ.split_steps))
    # same split decisions; the states differ only by round-off (Thomas vs dense solve) that
    # the lightly damped modes carry along: ~1e-13 at first, ~1e-9 rad after 3000 steps
    assert out[0][2:] == out[1][2:]
    np.testing.assert_allclose(out[0][0][:500], out[1][0][:500], atol=1e-11)
    np.testing.assert_allclose(out[0][0], out[1][0], atol=1e-8)
    assert out[0][2] > 10 and out[0][3] > 0
    stages = set(loads.model.spring.stage(out[0][1]).tolist())
    assert stages == {-1, 0, 1, 2, 3}


def test_newmark_energy_balance_multistage(loads):
    r = simulate(loads, SPEED, 1.0, options=SimulationOptions(dt=5e-5, eval_cycles=2))
    m, sp = loads.model, loads.model.spring
    P = r.integrator.generalized_load(r.psi)
    dt = np.diff(r.t)

    def trap(y):
        return float(np.sum(0.5 * (y[1:] + y[:-1]) * dt))
    E_in = trap(np.einsum('ij,ij->i', P, r.v))
    E_d = trap(np.einsum('ij,jk,ik->i', r.v, m.C, r.v))

    def stored(i):
        q, v = r.q[i], r.v[i]
        return 0.5 * v @ m.J @ v + 0.5 * q @ m.K @ q + float(sp.extra_energy(r.windup[i]))
    assert E_in == pytest.approx(E_d + stored(-1) - stored(0), rel=5e-3)
    assert set(sp.stage(r.windup).tolist()) == {-1, 0, 1, 2, 3}


@pytest.fixture(scope='module')
def steady(loads):
    hb = CondensedHBM(loads, 1.0)
    return hb, hb.solve(SPEED), simulate(loads, SPEED, 1.0, options=SimulationOptions(dt=5e-5))


def test_hbm_and_newmark_agree_within_one_percent(steady):
    hb, p, r = steady
    assert r.steady
    s, n = p.summary, r.summary
    scale = s.order_3
    for key in ('order_3', 'max_deviation', 'min_deviation'):
        assert getattr(s, key) == pytest.approx(getattr(n, key), rel=1e-2), key
    assert abs(s.order_1_5 - n.order_1_5) < 1e-2 * scale
    assert s.mean == pytest.approx(n.mean, rel=1e-3)


@pytest.mark.slow
def test_floquet_matches_finite_difference_monodromy_of_newmark(loads, steady):
    """Brute force: the one-period map of the Newmark integrator from the periodic state,
    differentiated by central differences in the flexible (J-orthonormal modal) coordinates, at
    two step sizes. The moduli of all multipliers agree within 1e-3 at each step size.
    Newmark's error in log(multiplier) is O(dt^2) from its period error, so the Richardson
    extrapolation of the two is compared with the Floquet multipliers: within 1e-3 for all but
    the two nearly undamped kHz pairs (|mu| > 0.9999), whose phase error at these steps
    (~0.1 rad at dt = 2.4 us) is larger than their distance to other multipliers."""
    hb, p, _ = steady
    m = loads.model
    fr = FloquetAnalyzer(m).analyze(p.windup_orders, SPEED)
    assert fr.n_crossings > 10
    fm = FlexibleModes(m)
    q0, v0 = hb.dof_state(p, 0.0)
    T = CYCLE_RAD / (SPEED * RPM_TO_RAD_S)
    n, nf = m.n_dof, fm.nf
    PJ = fm.Phi.T @ m.J
    nearest = []
    for N in (30000, 60000):
        integ = NewmarkIntegrator(loads, dt=T / N)

        def flow(q, v):
            integ.reset(SPEED, 1.0, psi=0.0)
            integ.q[:], integ.v[:] = q, v
            integ.a[:] = integ.acceleration(integ.q, integ.v)
            integ.advance(N)
            return integ.q.copy(), integ.v.copy()
        M = np.empty((2 * nf, 2 * nf))
        for k in range(2 * nf):
            eps = 1e-6 if k < nf else 1e-4
            dq = fm.Phi[:, k] * eps if k < nf else np.zeros(n)
            dv = fm.Phi[:, k - nf] * eps if k >= nf else np.zeros(n)
            qp, vp = flow(q0 + dq, v0 + dv)
            qm, vm = flow(q0 - dq, v0 - dv)
            M[:nf, k] = PJ @ (qp - qm) / (2 * eps)
            M[nf:, k] = PJ @ (vp - vm) / (2 * eps)
        mu = np.linalg.eigvals(M)
        assert np.abs(np.sort(np.abs(fr.multipliers)) - np.sort(np.abs(mu))).max() < 1e-3
        nearest.append(mu[np.abs(fr.multipliers[:, None] - mu[None, :]).argmin(axis=1)])
    ref = fr.multipliers
    d1, d2 = (np.log(mu / ref) for mu in nearest)      # log-error: phase and modulus, O(dt^2)
    extrapolated = ref * np.exp(d2 + (d2 - d1) / 3.0)
    damped = np.abs(ref) < 0.9999
    assert damped.sum() == 2 * nf - 4
    assert np.abs(extrapolated - ref)[damped].max() < 1e-3


def test_modes_per_stage_cli(yaml_path, capsys):
    assert cli_main(['modes', '--config', str(yaml_path), '--json']) == 0
    data = json.loads(capsys.readouterr().out)
    regions = data['regions']
    names = ['coast', 'primary', 'secondary', 'drive stage 2', 'drive stage 3']
    assert set(names) <= set(regions)
    f2 = [regions[name][2] for name in ('primary', 'secondary', 'drive stage 2',
                                                            'drive stage 3')]
    assert f2 == sorted(f2) and f2[0] == pytest.approx(17.9, abs=0.1)


def test_sweep_cli_runs_on_multistage(yaml_path, tmp_path, capsys):
    assert cli_main(['sweep', '--config', str(yaml_path), '--speeds', '900', '1000', '25',
                     '--no-progress', '--json', '--harmonics', '12']) == 0
    data = json.loads(capsys.readouterr().out)
    pts = data['sweeps'][0]['points']
    assert len(pts) >= 5 and all(np.isfinite(p['order_3']) for p in pts)


def test_nnm_branches_multistage(yaml_path):
    from dmf_sim.solvers.nnm import NNMOptions, nnm_branches
    m = read_driveline(yaml_path).reduce()
    res = nnm_branches(m, xi_max=4.0, options=NNMOptions(n_harmonics=8, step_max=0.3))
    prim = res.branches['primary']
    f = prim.frequency_at(np.array([1.0, 3.0]))
    assert f[0] == pytest.approx(17.9, abs=0.2)          # linear limit at xi = 1
    assert f[1] > f[0]                                    # the primary branch stiffens


def test_live_simulation_multistage(yaml_path):
    from dmf_sim.live.simulation import LiveSimulation
    line = read_driveline(yaml_path)
    sim = LiveSimulation(line, ENGINE, speed_rpm=SPEED, load=1.0)
    s = sim.advance(3000)
    assert len(s) == 300 and np.all(np.isfinite(s.effort))
    assert set(line.spring.stage(s.windup).tolist()) >= {-1, 0, 1, 2}
    # the torque read-out equals the model's transmitted torques, in a state beyond a knee
    it = sim.integ
    q, v, a = it.q[None], it.v[None], it.a[None]
    w, psi = np.array([it.windup]), np.array([it.psi])
    fast = sim._torques(q, v, a, w, psi, it.omega_dot)
    ref = it.model.transmitted_torques(q, v, a, it.element_loads(psi, it.omega_dot))
    np.testing.assert_allclose(fast, ref, rtol=1e-9, atol=1e-6)
    q2 = q + it.model.e * (0.3 / float(it.model.e @ it.model.e))      # push into drive stage 3
    w2 = q2 @ it.model.e
    assert it.model.spring.stage(w2[0]) == 3
    np.testing.assert_allclose(sim._torques(q2, v, a, w2, psi, it.omega_dot),
                               it.model.transmitted_torques(q2, v, a,
                                                            it.element_loads(psi, it.omega_dot)),
                               rtol=1e-9, atol=1e-6)
    # the compiled read-out over M's non-zeros (the samples above) equals the dense product, in
    # every stage and with a d'Alembert load, to round-off
    op = sim._torques
    assert not op.needs_loads          # the compiled path (the d'Alembert part alone)
    qs, vs, as_ = (np.vstack([x, x2, x]) for x, x2 in ((q, q2), (v, v), (a, a)))
    ws = qs @ it.model.e
    psis = np.repeat(psi, 3)
    for omega_dot in (0.0, 35.0):
        fast = op.outputs_of(qs, vs, as_, ws, psis, omega_dot)
        dense = op.outputs(np.hstack([qs, vs, as_]), ws, psis, omega_dot)
        for f, d in zip(fast, dense):
            np.testing.assert_allclose(f, d, rtol=1e-12, atol=1e-9 * np.abs(d).max())
        np.testing.assert_allclose(fast[2], it.model.transmitted_torques(
            qs, vs, as_, it.element_loads(psis, omega_dot)), rtol=1e-9, atol=1e-6)


def test_steady_cli_multistage(yaml_path, capsys):
    """`dmf-sim steady` on the YAML-only spring (default engine, 1400 rpm: the mean wind-up sits
    in drive stage 2): every random start Newmark settles from lands on a listed state."""
    assert cli_main(['steady', '--config', str(yaml_path), '--speed', '1400', '--samples', '4',
                     '--harmonics', '12', '--no-progress', '--json']) == 0
    data = json.loads(capsys.readouterr().out)
    states = data['states']
    assert states and any(s['stable'] for s in states)
    spring = read_driveline(yaml_path).spring
    assert all(spring.stage(s['mean']) == 2 for s in states)
    assert data['basin_sampling']['unsettled'] == 0
    assert sum(s['basin']['hits'] for s in states) == 4


@pytest.mark.slow
@pytest.mark.ros
def test_live_node_runs_the_multistage_yaml(yaml_path, tmp_path):
    """The ROS node with `driveline:=<the YAML>` (default engine, speed and load): its published
    wind-up oscillates about the static wind-up of the multi-stage spring, and its start-up log
    names the YAML's driveline."""
    from std_msgs.msg import Float64
    from support.dds_peer import START_TIMEOUT, NodeProcess, Peer, new_domain

    from dmf_sim.live.parameters import PARAMETERS
    from dmf_sim.physics.engine import read_engine

    speed, load = (PARAMETERS[n].default for n in ('initial_speed_rpm', 'initial_load'))
    loads = DrivelineExcitation(read_driveline(yaml_path).reduce(),
                           read_engine(PARAMETERS['engine'].default))
    static = loads.static_state(speed, load).windup
    assert loads.model.spring.stage(static) >= 1           # beyond the first drive knee
    domain = new_domain()
    node = NodeProcess(['--ros-args', '-p', f'driveline:={yaml_path}', '-p', 'monitor:=false'],
                       tmp_path, domain)
    peer = Peer(domain)
    try:
        peer.subscribe('/driveline/dmf_windup', Float64, keep=True)
        assert peer.spin_until(lambda: len(peer.series['/driveline/dmf_windup']) > 1500,
                               START_TIMEOUT), node.output()
        w = np.array([v for _t, v in peer.series['/driveline/dmf_windup'][-1000:]])
        assert np.all(np.isfinite(w)) and w.mean() == pytest.approx(static, abs=0.01)
    finally:
        peer.close()
        assert node.stop() == 0, node.output()
    assert 'truck_dmf_3stage' in node.output() and '0.18 rad: +5k' in node.output()
