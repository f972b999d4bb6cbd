"""Arc-spring friction and end stops of the DMF spring (doc/theory.md eq. 8a-8c): the law, the
Newmark kernel and its reference twin, energy balance, hysteresis, step refinement, friction
zero = the elastic spring bit for bit, end-stop contacts in a tip-in, what run / the node's
health / durability report, bad input and the harmonic balance's refusal."""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest
import yaml

import dmf_sim as dmf
from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.paths import config_dir
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.physics.loads import ConstantTorque, DrivelineExcitation
from dmf_sim.physics.model import driveline_from_dict
from dmf_sim.physics.spring import ArcFriction, EndStops
from dmf_sim.solvers.newmark import NewmarkIntegrator, SimulationOptions, StepRecord, simulate

ENGINE = 'engine_d13'


def _doc(name='truck_dmf_friction') -> dict:
    return yaml.safe_load((config_dir() / f'{name}.yaml').read_text())


def _line(friction=None, end_stops=None, alpha=None, base='truck_dmf'):
    """truck_dmf with the given dmf.friction / dmf.end_stops mappings (None: absent)."""
    d = copy.deepcopy(_doc(base))
    if alpha is not None:
        d['dmf']['alpha'] = alpha
    for key, value in (('friction', friction), ('end_stops', end_stops)):
        if value is not None:
            d['dmf'][key] = value
    return driveline_from_dict(d)


def _run(loads, speed, load, nsteps, dt=1e-4, use_numba=True, stride=1, initial=None):
    integ = NewmarkIntegrator(loads, dt=dt, use_numba=use_numba)
    integ.reset(speed, load)
    if initial is not None:
        integ.q[:], integ.v[:] = initial
        integ.a[:] = integ.acceleration(integ.q, integ.v)
    rec = StepRecord.allocate(nsteps // stride, loads.model.n_dof)
    integ.advance(nsteps, rec, stride)
    return integ, rec


# ---- the law ----------------------------------------------------------------------------------
def test_forced_sliding_cycle_loop_area_is_four_friction_torques_times_amplitude():
    """A prescribed sinusoidal wind-up w = A sin(2 pi f t): the loop area of T_f over w, the
    friction's work per cycle, tends to Coulomb's 4 T_f A as the regularization goes to zero
    (the loss is the time spent at |w_dot| < ~omega_reg: relative O(omega_reg / (A 2 pi f)))."""
    A, f, omega = 0.01, 60.0, 1200 * RPM_TO_RAD_S
    t = np.linspace(0.0, 1.0 / f, 200001)
    w, wd = A * np.sin(2 * np.pi * f * t), A * 2 * np.pi * f * np.cos(2 * np.pi * f * t)
    errors = []
    for reg in (0.5, 0.05, 0.005):
        law = ArcFriction(40.0, 3e-3, reg)
        tf = law.torque(wd, omega)
        area = float(np.sum(0.5 * (tf[1:] + tf[:-1]) * np.diff(w)))
        coulomb = 4.0 * float(law.amplitude(omega)) * A
        assert 0.0 < area < coulomb
        errors.append(1.0 - area / coulomb)
    assert errors[2] < 2e-3 and errors[0] > 5 * errors[1] > 25 * errors[2]   # ~ omega_reg


def test_end_stop_law_pushes_never_pulls():
    st = EndStops(0.3, 0.2, 1e6, 500.0)
    assert st.torque(0.29, 5.0) == 0.0 and st.torque(-0.19, -5.0) == 0.0
    assert st.torque(0.31, 0.0) == pytest.approx(1e4)
    assert st.torque(-0.21, 0.0) == pytest.approx(-1e4)
    assert st.torque(0.301, -10.0) == 0.0          # separating fast: no tension (clipped)


# ---- the time integration ----------------------------------------------------------------------
def test_friction_zero_reproduces_the_elastic_spring_bit_for_bit():
    """Zero friction given in the file is no friction: the spring equals the paper's and the
    kernel and its reference give the same bits as without the fields."""
    plain = _line()
    zero = _line(friction={'torque_nm': 0.0, 'speed_coefficient': 0.0})
    assert zero.spring == plain.spring and zero.spring.friction is None
    engine = dmf.read_engine(ENGINE)
    for use_numba, n in ((True, 3000), (False, 300)):
        runs = [_run(DrivelineExcitation(line.reduce(), engine), 900.0, 1.0, n,
                     use_numba=use_numba) for line in (plain, zero)]
        (i1, r1), (i2, r2) = runs
        assert np.array_equal(r1.q, r2.q) and np.array_equal(r1.windup, r2.windup)
        assert i1.friction_heat_j == i2.friction_heat_j == 0.0
    assert i1.knee_crossings > 0


def test_kernel_equals_reference_with_friction_and_stops():
    """The compiled step and its readable twin (brentq on the spring's own law) through a ramp
    with knee crossings, sticking and sliding, and end-stop contacts."""
    line = _line(friction={'torque_nm': 60.0, 'speed_coefficient': 4e-3,
                           'regularization_rad_s': 0.05},
                 end_stops={'drive_angle_rad': 0.25, 'coast_angle_rad': 0.25,
                            'stiffness': 1e6, 'damping': 300.0})
    loads = DrivelineExcitation(line.reduce(), dmf.read_engine(ENGINE))
    out = []
    for use_numba in (True, False):
        integ = NewmarkIntegrator(loads, dt=1e-4, use_numba=use_numba)
        integ.reset(850, 1.0)
        integ.set_target(950, 2000.0)
        rec = StepRecord.allocate(2500, loads.model.n_dof)
        integ.advance(2500, rec, 1)
        out.append((rec.q.copy(), integ))
    (q1, a), (q2, b) = out
    np.testing.assert_allclose(q1, q2, atol=1e-9)
    assert a.knee_crossings == b.knee_crossings > 0 and a.split_steps == b.split_steps
    assert a.stop_contacts == b.stop_contacts and sum(a.stop_contacts) > 0
    assert a.friction_heat_j == pytest.approx(b.friction_heat_j, rel=1e-7)
    assert a.peak_stop_torque_nm == pytest.approx(b.peak_stop_torque_nm, rel=1e-6)
    assert a.peak_stop_torque_nm > 100.0


def test_energy_balance_with_friction_free_decay():
    """No excitation (a zero-torque engine) at 1200 rpm, the DMF wound up 0.1 rad and released:
    the energy lost over the decay equals the viscous work plus the friction heat the kernel
    booked, and that heat equals the work of T_f(w_dot, Omega) over the recorded motion (both
    trapezoidal, the average-acceleration rule's own energy identity: to round-off). The
    friction, 40 + 3e-3 Omega^2 = 87 Nm, takes ~45 % of the energy."""
    line = driveline_from_dict(_doc())
    model = line.reduce()
    loads = DrivelineExcitation(model, ConstantTorque(0.0, len(line.cylinders)))
    # the static deflection under a steady engine torque, scaled to a 0.1 rad wind-up
    unit = DrivelineExcitation(model, ConstantTorque(1.0, len(line.cylinders))).static_state(
        0.0, 1.0)
    q0 = unit.q * (0.1 / unit.windup)
    integ, rec = _run(loads, 1200.0, 0.0, 6000, initial=(q0, np.zeros(model.n_dof)))
    q, v, w = rec.q, rec.v, rec.windup
    sp, J, K, C = model.spring, model.J, model.K, model.C

    def stored(qq, vv):
        ww = float(model.e @ qq)
        return 0.5 * vv @ J @ vv + 0.5 * qq @ K @ qq + float(sp.extra_energy(ww))

    vv = np.vstack([np.zeros(model.n_dof), v])
    qq = np.vstack([q0, q])
    ww = qq @ model.e
    dq = np.diff(qq, axis=0)
    viscous = float(np.sum(np.einsum('ij,jk,ik->i', dq, C, 0.5 * (vv[1:] + vv[:-1]))))
    tf = sp.friction.torque(vv @ model.e, 1200.0 * RPM_TO_RAD_S)
    heat_motion = float(np.sum(0.5 * (tf[1:] + tf[:-1]) * np.diff(ww)))
    lost = stored(q0, np.zeros(model.n_dof)) - stored(q[-1], v[-1])
    assert integ.friction_heat_j == pytest.approx(heat_motion, rel=1e-9)
    assert lost == pytest.approx(viscous + integ.friction_heat_j, rel=1e-8)
    assert integ.friction_heat_j > 0.3 * lost > 0.0
    assert abs(w[-1]) < 0.02 and integ.knee_crossings == 0


def test_heat_of_forced_sliding_is_coulomb_torque_times_travel():
    """Forced steady motion at 1200 rpm, load 0.5 (the 3rd order slides the springs): the heat
    the kernel books over 0.2 s equals the Coulomb law's (T0 + c Omega^2) x the wind-up's total
    travel sum |dw| (the hysteresis loops' area) to the regularization's share."""
    line = driveline_from_dict(_doc())
    loads = DrivelineExcitation(line.reduce(), dmf.read_engine(ENGINE))
    integ, _ = _run(loads, 1200.0, 0.5, 3000)
    h0 = integ.friction_heat_j
    rec = StepRecord.allocate(2000, loads.model.n_dof)
    w0 = integ.windup
    integ.advance(2000, rec, 1)
    travel = float(np.sum(np.abs(np.diff(np.concatenate(([w0], rec.windup))))))
    amp = float(line.spring.friction.amplitude(1200.0 * RPM_TO_RAD_S))
    assert travel > 0.05                                         # it does slide
    assert integ.friction_heat_j - h0 == pytest.approx(amp * travel, rel=0.02)


def test_step_refinement_converges_with_friction():
    """A transient with friction (released 0.05 rad off the static wind-up at 1200 rpm, load
    0.5, sticking and sliding): halving the step shrinks the wind-up's difference ~4x (second
    order: the regularized law is smooth), to < 1 % of the motion's range at dt = 5e-5 s
    (measured 0.4 %: the stick-slip transitions are fast, omega_reg = 0.05 rad/s)."""
    line = driveline_from_dict(_doc())
    loads = DrivelineExcitation(line.reduce(), dmf.read_engine(ENGINE))
    st = loads.static_state(1200.0, 0.5)
    q0 = st.q + loads.model.e / float(loads.model.e @ loads.model.e) * 0.05
    runs = []
    for dt, stride in ((1e-4, 1), (5e-5, 2), (2.5e-5, 4)):
        r = simulate(loads, 1200.0, 0.5, t_end=0.15, initial=(q0, np.zeros(len(q0))),
                     options=SimulationOptions(dt=dt, record_stride=stride))
        runs.append(r.windup)
    e1 = np.max(np.abs(runs[0] - runs[1]))
    e2 = np.max(np.abs(runs[1] - runs[2]))
    assert e2 < e1 / 3.0, (e1, e2)
    assert e2 < 1e-2 * np.ptp(runs[2])


def test_tip_in_with_a_soft_spring_hits_the_end_stop():
    """A soft linear spring (alpha 0) and a one-step tip-in 0 -> 1 at 1200 rpm: the overshoot
    (~1.8x the static 0.26 rad) reaches the drive stop at 0.35 rad, the tip-out's undershoot the
    coast stop at -0.10 rad. Contacts begin where the wind-up passes the stop angle, the kernel's
    count equals the entries of the every-step wind-up, and the peak contact torque is the law's
    largest over the motion."""
    from dmf_sim.live.simulation import LiveSimulation
    stops = {'drive_angle_rad': 0.35, 'coast_angle_rad': 0.10, 'stiffness': 2e6,
             'damping': 400.0}
    line = _line(end_stops=stops, alpha=0.0)
    sim = LiveSimulation(line, dmf.read_engine(ENGINE), speed_rpm=1200.0, load=0.0,
                         load_ramp_per_s=1e4, stride=1)
    ws = []
    for setpoint in (1.0, 0.0):
        sim.set_load_setpoint(setpoint)
        for _ in range(40):
            ws.append(sim.advance(250).windup.copy())
    w = np.concatenate(ws)
    side = (w > 0.35).astype(int) - (w < -0.10)
    entries = np.flatnonzero((side[1:] != 0) & (side[1:] != side[:-1])) + 1
    d = sim.peaks.as_dict()
    assert d['stop_contacts'] == len(entries) >= 2
    assert w.max() > 0.35 and w.min() < -0.10
    assert np.all(np.abs(np.abs(w[entries - 1]) - np.where(side[entries] > 0, 0.35, 0.10))
                  < 0.01)                            # entered within one step of the stop
    assert w.max() - 0.35 < 0.02                     # the stiff stop holds the travel
    # the peak impact: k_s times the deepest penetration (damping adds, separating subtracts)
    depth = max(w.max() - 0.35, -0.10 - w.min())
    assert d['peak_stop_torque_nm'] == pytest.approx(2e6 * depth, rel=0.35)
    assert d['peak_stop_torque_nm'] > 1000.0


def test_run_summary_health_and_durability_report_friction_and_stops(tmp_path, capsys):
    doc = _doc()
    doc['dmf']['alpha'] = 0.0
    doc['dmf']['end_stops'].update(drive_angle_rad=0.35, coast_angle_rad=0.10)
    cfg = tmp_path / 'soft.yaml'
    cfg.write_text(yaml.safe_dump(doc))
    bag = tmp_path / 'bag'
    assert cli_main(['run', 'step:1200:0:1:0.0001:1:0.5', '--config', str(cfg), '--out',
                     str(bag), '--json', '--no-progress', '--no-sensors']) == 0
    d = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert d['stop_contacts'] >= 2 and d['peak_stop_torque_nm'] > 1000.0
    assert d['friction_heat_j'] > 0.0 and d['travel_margin_rad'] < 0.0
    assert cli_main(['durability', str(bag), '--out', str(tmp_path / 'dur')]) == 0
    capsys.readouterr()
    rep = json.loads((tmp_path / 'dur' / 'durability.json').read_text())
    p = rep['dissipated_power']
    assert p['friction_energy_j'] == pytest.approx(d['friction_heat_j'], rel=0.02)
    assert p['energy_j'] == pytest.approx(p['viscous_energy_j'] + p['friction_energy_j']
                                          + p['stop_energy_j'])
    assert p['stop_energy_j'] > 0.0 and 'contact damping' in p['note']
    assert rep['end_stops']['contacts'] >= 2
    assert rep['end_stops']['peak_impact_torque_nm'] > 500.0
    # the node's health (ROS-free core)
    from dmf_sim.live.health import SimulationHealth
    from dmf_sim.live.simulation import LiveSimulation
    sim = LiveSimulation(driveline_from_dict(doc), dmf.read_engine(ENGINE), speed_rpm=1200.0,
                         load=0.0, load_ramp_per_s=1e4)
    sim.set_load_setpoint(1.0)
    for _ in range(10):
        sim.advance(500)
    values = SimulationHealth(sim).report('x').values
    assert int(values['stop_contacts']) >= 1 and float(values['peak_stop_torque_nm']) > 1000
    assert float(values['friction_heat_j']) > 0.0


def _stop_tip_in(tmp_path, dt, **stops):
    """`dmf-sim run` of a tip-in onto a drive stop at 0.25 rad (the shipped friction DMF's stop
    moved in: ~30 contacts), the stop's other fields as given; its JSON summary."""
    doc = _doc()
    doc['dmf']['end_stops'].update(drive_angle_rad=0.25, **stops)
    cfg = tmp_path / f'stop_{dt:g}.yaml'
    cfg.write_text(yaml.safe_dump(doc))
    code = cli_main(['run', 'step:1200:0:1:0.1', '--config', str(cfg), '--dt', str(dt),
                     '--no-write', '--json', '--no-progress', '--no-sensors'])
    return code, cfg


@pytest.mark.parametrize('stops, needle', [
    ({'damping': 5e5}, 'dmf.end_stops.damping 500000 Nms/rad: the Newmark step dt = 0.0001 s'),
    ({'stiffness': 1e10}, 'dmf.end_stops.stiffness 1e+10 Nm/rad: the Newmark step dt = 0.0001 s'),
])
def test_a_contact_the_step_cannot_resolve_is_refused(tmp_path, capsys, stops, needle):
    """A contact of 5e5 Nms/rad at dt = 1e-4 s (within the field's bound) ran to a wind-up of
    1e251 rad and printed it with exit 0; 1e10 Nm/rad gave an impact set by the step. Refused
    before anything runs, in one line naming the field, the step and the largest value."""
    code, _ = _stop_tip_in(tmp_path, 1e-4, **stops)
    err = capsys.readouterr().err
    assert code == 2 and err.count('\n') == 1 and needle in err and 'up to' in err


def test_contacts_at_the_resolvable_limits_converge_under_step_refinement(tmp_path, capsys):
    """At the stiffness limit (9e6 Nm/rad: ~20 steps a contact period at dt = 1e-4 s) with the
    shipped damping, halving the step changes the peak wind-up by < 0.5 % and the peak impact
    torque by < 1 %. At the damping limit (1.9e4 Nms/rad: c dt / J_eff ~ 2) the run stays
    physical and the wind-up converges; the impact's damping part c w_dot at first contact does
    not (doc/configuration.md says how far it is resolved)."""
    from dmf_sim.solvers.newmark import STOP_DAMPING_STEP, stop_resolution_error
    for stops, impact_rel in (({'stiffness': 9.0e6}, 0.01), ({'damping': 1.9e4}, None)):
        out = {}
        for dt in (1e-4, 5e-5):
            code, cfg = _stop_tip_in(tmp_path, dt, **stops)
            assert code == 0
            out[dt] = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
        model = dmf.read_model(str(cfg))
        assert stop_resolution_error(model, 1e-4) is None
        a, b = out[1e-4], out[5e-5]
        assert 0.25 < a['peak_windup_rad'][1] < 0.26
        assert a['peak_windup_rad'][1] == pytest.approx(b['peak_windup_rad'][1], rel=0.005)
        # grazing contacts come and go with the step: the count agrees within 15 %
        assert abs(a['stop_contacts'] - b['stop_contacts']) <= 0.15 * b['stop_contacts']
        assert a['stop_contacts'] >= 20
        if impact_rel is not None:
            assert a['peak_stop_torque_nm'] == pytest.approx(b['peak_stop_torque_nm'],
                                                             rel=impact_rel)
    e = model.e
    assert 1.9e4 * 1e-4 * float(np.sum(e * e / np.diag(model.J))) <= STOP_DAMPING_STEP


# ---- bad input and the harmonic balance --------------------------------------------------------
@pytest.mark.parametrize('friction, stops, needle', [
    ({'torque_nm': -5.0}, None, "dmf.friction: field 'torque_nm' must be in [0, 10000] Nm"),
    ({'speed_coefficient': 1.0}, None, "field 'speed_coefficient' must be in [0, 0.1]"),
    ({'torque_nm': 5.0, 'regularization_rad_s': 0}, None,
     "field 'regularization_rad_s' must be in [0.0001, 10] rad/s"),
    ({'torque_nm': 5.0, 'regularization_rad_s': 1e-300}, None,
     "field 'regularization_rad_s' must be in [0.0001, 10] rad/s"),
    ({'torque': 5.0}, None, "dmf.friction: unknown key 'torque'"),
    (None, {'drive_angle_rad': 0.2, 'coast_angle_rad': 0.2, 'stiffness': 1e6},
     "dmf.end_stops: field 'drive_angle_rad' must be beyond the last drive stage angle 0.24"),
    (None, {'drive_angle_rad': 0.5, 'coast_angle_rad': 0.2, 'stiffness': 0},
     "dmf.end_stops: field 'stiffness' must be in (0, 1e+10] Nm/rad"),
    (None, {'drive_angle_rad': 0.5, 'stiffness': 1e6}, "missing key 'coast_angle_rad'"),
])
def test_bad_friction_and_stop_fields_are_one_line(friction, stops, needle):
    with pytest.raises(ConfigError) as err:
        _line(friction=friction, end_stops=stops)
    assert needle in str(err.value) and '\n' not in str(err.value)


def test_the_harmonic_balance_takes_friction_and_stops(capsys):
    """steady and sweep run on the spring with friction and end stops (the harmonic balance
    balances g + T_f + T_s, doc/theory.md §7); friction lowers the 3rd-order wind-up at the
    knee resonance against the elastic spring's."""
    assert cli_main(['steady', '--config', 'truck_dmf_friction', '--speed', '1000',
                     '--load', '1', '--samples', '20', '--no-progress']) == 0
    out = capsys.readouterr()
    assert 'Traceback' not in out.err
    assert 'basin: 20 runs' in out.out and '0 did not settle' in out.out
    eng = dmf.read_engine(ENGINE)
    rough = dmf.sweep(dmf.DrivelineExcitation(dmf.read_model('truck_dmf_friction'), eng), 1.0,
                      (1100.0, 1300.0))
    plain = dmf.sweep(dmf.DrivelineExcitation(dmf.read_model('truck_dmf'), eng), 1.0,
                      (1100.0, 1300.0))
    top = [max(p.order_3 for b in r.branches for p in b.points) for r in (rough, plain)]
    assert top[0] < top[1]
    assert all(p.stable is not None for b in rough.branches for p in b.points)


def test_the_monitor_predicts_with_friction():
    """The node's monitor submits its harmonic-balance job for a spring with friction too, and
    no reason to be off stands in its status values."""
    from dmf_sim.monitor.worker import LiveMonitor, MonitorSettings
    calls = []

    def solver(*args, **kw):
        calls.append(args)
        raise AssertionError('not run: only the submission is checked')

    line = dmf.read_driveline('truck_dmf_friction')
    mon = LiveMonitor(line, dmf.read_engine(ENGINE), MonitorSettings(worker='thread'),
                      solver=solver)
    try:
        mon.wait_ready(60.0)
        assert mon.counters['prediction_off'] == ''
        mon.set_setpoint(1200.0, 1.0)
        assert mon._job is not None                  # submitted to the worker
    finally:
        mon.close()


def test_runup_overlays_the_harmonic_balance_with_friction(tmp_path, capsys):
    bag = tmp_path / 'ru'
    assert cli_main(['run', 'ramp:1000:1200:200', '--config', 'truck_dmf_friction', '--out',
                     str(bag), '--no-progress', '--no-sensors']) == 0
    capsys.readouterr()
    assert cli_main(['runup', str(bag), '--out', str(tmp_path / 'r')]) == 0
    capsys.readouterr()
    warnings = json.loads((tmp_path / 'r' / 'runup.json').read_text())['warnings']
    assert warnings and not any('HBM' in w for rows in warnings for w in rows)


def test_published_torques_carry_the_friction_and_stop_torque():
    """The node's element torques (effort) with friction and a stop contact equal the model's
    transmitted torques with the DMF's non-linear torque g + T_f + T_s (eq. 8a-8b), and differ
    from the elastic spring's by exactly that torque at the DMF."""
    from dmf_sim.live.simulation import LiveSimulation
    line = _line(friction={'torque_nm': 80.0, 'speed_coefficient': 3e-3},
                 end_stops={'drive_angle_rad': 0.25, 'coast_angle_rad': 0.2,
                            'stiffness': 1e6, 'damping': 300.0})
    sim = LiveSimulation(line, dmf.read_engine(ENGINE), speed_rpm=1200.0, load=1.0)
    sim.advance(2000)
    it, op = sim.integ, sim._torques
    m = it.model
    q = np.vstack([it.q, it.q + m.e * (0.02 / float(m.e @ m.e))])    # the second in contact
    v, a = np.vstack([it.v, it.v]), np.vstack([it.a, it.a])
    w, psi = q @ m.e, np.repeat(it.psi, 2)
    omega = np.full(2, it.omega)
    law = m.spring.law_torque(w, v @ m.e, omega)
    assert abs(law[0]) > 10.0 and law[1] > 1e3                  # friction; friction + contact
    loads = it.element_loads(psi, it.omega_dot)
    ref = m.transmitted_torques(q, v, a, loads, m.spring.extra_torque(w) + law)
    with_law = op.outputs_of(q, v, a, w, psi, it.omega_dot, omega_rad_s=omega)[2].copy()
    elastic = op.outputs_of(q, v, a, w, psi, it.omega_dot)[2].copy()
    np.testing.assert_allclose(with_law, ref, rtol=1e-9, atol=1e-6)
    np.testing.assert_allclose(with_law - elastic, np.multiply.outer(law, op.c), atol=1e-6)


def test_the_theta_shorthand_stays_before_the_next_stage_and_the_stop():
    """theta moved past the drive end stop (or the next drive stage) is refused naming theta and
    what it passes; before, the message blamed the file's dmf.end_stops.drive_angle_rad."""
    from dmf_sim.core.errors import ConfigError
    from dmf_sim.physics.spring import PiecewiseLinearSpring, Stage
    line = dmf.read_driveline('truck_dmf_friction')
    assert line.with_dmf(theta=0.44).spring.theta == 0.44
    with pytest.raises(ConfigError, match=r'^theta 0\.45 rad \(--theta 0\.45\) moves the '
                                          r'first drive knee to or past the drive end stop at '
                                          r'0\.45 rad'):
        line.with_dmf(theta=0.45)
    two = PiecewiseLinearSpring(10890.0, (Stage(0.2, 1.0), Stage(0.3, 2.0)))
    with pytest.raises(ConfigError, match=r'past the next drive stage at 0\.3 rad '
                                          r'\(dmf\.stages\[1\]\.angle_rad\)'):
        two.with_first_stage(theta=0.35)
