"""Engine braking: the engine file's brake curve, the compression-release brake of the pressure
model (calibration, energy, orders), negative loads through every solver, the coast side of the
DMF, and the bad inputs (one line each, nothing written)."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import yaml

import dmf_sim as dmf
from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError, OperatingRangeError
from dmf_sim.core.paths import config_dir
from dmf_sim.core.units import CYCLE_RAD
from dmf_sim.physics.engine import engine_from_mapping, engine_torque_orders, load_error
from dmf_sim.physics.orders import half_orders

BRAKE_SPEEDS = [400, 600, 800, 1000, 1200, 1400, 1600, 1800, 2000, 2200]   # engine_d13.yaml
BRAKE_TORQUES = [-400, -440, -560, -720, -900, -1080, -1230, -1340, -1410, -1440]


@pytest.fixture(scope='module')
def engine():
    return dmf.read_engine('engine_d13')


def _doc() -> dict:
    return yaml.safe_load((config_dir() / 'engine_d13.yaml').read_text())


def _engine(doc):
    return engine_from_mapping(doc, config_dir() / 'engine_x.yaml')


def _one_line(exc, *needles):
    msg = str(exc)
    assert '\n' not in msg, msg
    for n in needles:
        assert n in msg, msg


# ---- the engine file ---------------------------------------------------------------------------
def test_shipped_engine_brakes_on_its_curve(engine):
    assert engine.load_range == (-1.0, 1.0) and engine.has_brake
    for s, t in zip(BRAKE_SPEEDS, BRAKE_TORQUES):
        assert engine.brake_torque(s) == t
    # the 2500 Nm rating is the same engine (base: engine_d13): the same brake
    rating = dmf.read_engine('engine_d13_2500nm')
    assert rating.load_range == (-1.0, 1.0) and rating.brake_torque(2000) == -1410.0
    # a coefficient table knows no brake: 0..1, and a negative load says why, naming the field
    table = dmf.read_engine('engine_table_example.csv')
    assert table.load_range == (0.0, 1.0) and not table.has_brake
    with pytest.raises(OperatingRangeError) as exc:
        table.coefficients(1000.0, -0.5)
    _one_line(exc.value, 'load -0.5 outside [0, 1]', 'no brake curve')
    assert load_error(table, -0.5, '--load').startswith('--load -0.5 outside [0, 1]')
    assert load_error(engine, -1.0) is None and load_error(engine, -1.01) is not None


def test_a_base_file_can_drop_the_brake(tmp_path):
    path = tmp_path / 'no_brake.yaml'
    path.write_text('base: engine_d13\nname: no_brake\nbrake_curve: null\n')
    eng = dmf.read_engine(str(path))
    assert eng.load_range == (0.0, 1.0) and eng.brake_torque(1500) == 0.0
    with pytest.raises(OperatingRangeError, match='no_brake'):
        eng.coefficients(1500.0, -1.0)


@pytest.mark.parametrize('change, needles', [
    (lambda d: d['brake_curve']['torque_nm'].__setitem__(3, 120.0),
     ["field 'brake_curve.torque_nm[3]' must be in [-1e+06, 0] Nm, got 120"]),
    (lambda d: d.pop('compression_release_brake'),
     ["field 'compression_release_brake' missing (required with brake_curve"]),
    (lambda d: d['brake_curve'].__setitem__('torque_nm', [-20000.0] * 10),
     ["field 'brake_curve.torque_nm' at 400 rpm: -20000 Nm needs the exhaust manifold at",
      'this compression-release brake gives -356 Nm', '10 bar']),
    (lambda d: d['brake_curve'].__setitem__('torque_nm', [-100.0] * 10),
     ['-100 Nm needs the exhaust manifold at 0.', '(manifold at ambient pressure)']),
    (lambda d: d['compression_release_brake'].__setitem__('release_deg', 10.0),
     ["field 'compression_release_brake.release_deg' must be in [-90, 0] deg, got 10"]),
])
def test_bad_brake_curves_are_one_line(change, needles):
    d = _doc()
    change(d)
    with pytest.raises(ConfigError) as exc:
        _engine(d)
    _one_line(exc.value, *needles)


def test_a_positive_brake_curve_writes_nothing(tmp_path, capsys):
    d = _doc()
    d['brake_curve']['torque_nm'][0] = 50.0
    path = tmp_path / 'bad_brake.yaml'
    path.write_text(yaml.safe_dump(d))
    out = tmp_path / 'out'
    assert cli_main(['loads', '--engine', str(path), '--load', '-1', '--out', str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count('\n') == 0 and 'Traceback' not in err
    assert "field 'brake_curve.torque_nm[0]' must be in [-1e+06, 0] Nm, got 50" in err
    assert not out.exists()


@pytest.mark.parametrize('argv', [
    ['sweep', '--speeds', '1000', '1100', '50', '--fast'],
    ['steady', '--speed', '1200'],
    ['loads'],
])
def test_commands_refuse_braking_without_a_brake_curve(argv, tmp_path, capsys):
    out = tmp_path / 'out'
    extra = [] if argv[0] == 'steady' else ['--out', str(out)]      # steady writes no files
    assert cli_main(argv + ['--engine', 'engine_table_example.csv', '--load', '-0.5',
                            *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count('\n') == 0 and 'Traceback' not in err
    assert '--load -0.5 outside [0, 1]' in err and 'no brake curve' in err
    assert not out.exists()
    assert cli_main(argv + ['--load', '-1.5']) == 2
    assert '--load -1.5: allowed range -1..1' in capsys.readouterr().err


# ---- the brake in the pressure model -----------------------------------------------------------
def test_mean_torque_is_the_brake_curve(engine):
    """Load -1 is the curve at every speed (grid nodes, between them, off the curve's points),
    load b < 0 is |b| of it; the mean is exact to 1e-6 relative: the manifold pressure is solved
    for it (the mean is affine in it) and part braking is linear."""
    for s in (400.0, 650.0, 1000.0, 1234.5, 1777.0, 2200.0):
        curve = float(np.interp(s, BRAKE_SPEEDS, BRAKE_TORQUES))
        for b in (-1.0, -0.3, -0.05):
            assert engine.mean_torque(s, b) == pytest.approx(-b * curve, rel=1e-6)
    # load set B sees the curve at its effective speed, as it sees the full-load curve
    eng_b = engine.with_load_set('B')
    assert eng_b.mean_torque(900.0, -1.0) == pytest.approx(eng_b.brake_torque(900.0), rel=1e-6)
    assert eng_b.brake_torque(900.0) == pytest.approx(np.interp(950.0, BRAKE_SPEEDS,
                                                                BRAKE_TORQUES))


def test_part_braking_is_linear_from_zero_load(engine):
    """Between load 0 and the full brake every A_n moves linearly (no jump at 0)."""
    for s in (800.0, 1500.0, 2100.0):
        a0, a1 = engine.coefficients(s, 0.0), engine.coefficients(s, -1.0)
        for b in (0.25, 0.6):
            assert np.allclose(engine.coefficients(s, -b), (1 - b) * a0 + b * a1,
                               rtol=0, atol=1e-9 * np.abs(a1).max())
        assert np.allclose(engine.coefficients(s, -1e-9), a0, atol=1e-5)


def test_brake_cycle_work_is_the_mean_torque_times_4pi(engine):
    """The energy one cylinder absorbs per cycle, the closed integral of p dV taken on the
    volume (not on the crank lever the torque uses), equals its mean gas torque x 4 pi, which is
    the brake curve / 6; the compression work is not returned: the expansion stroke gives back
    less than a tenth of what the compression stroke took (the gas left after the release
    re-expands below the crankcase pressure)."""
    model = engine.model
    geo = model.cfg.geometry
    p_cc = model.cfg.gas_exchange.crankcase_pa
    for s in (1000.0, 1800.0):
        cyc = model.brake_cycle(s)
        theta = np.radians(cyc.psi_deg)
        order = np.argsort(theta)
        th, p = theta[order], cyc.pressure_pa[order] - p_cc
        th, p = np.append(th, th[0] + CYCLE_RAD), np.append(p, p[0])
        x = geo.kinematics(th)[0]
        dv = np.diff(geo.piston_area_m2 * x)
        work = float(np.sum(0.5 * (p[1:] + p[:-1]) * dv))          # [J] per cycle
        mean = float(cyc.gas_torque_nm.mean())
        assert work == pytest.approx(mean * 4 * math.pi, rel=2e-3)
        assert mean * 6 == pytest.approx(np.interp(s, BRAKE_SPEEDS, BRAKE_TORQUES), rel=1e-6)
        comp = (th >= np.radians(180.0)) & (th < CYCLE_RAD)        # compression stroke
        expa = (th >= 0.0) & (th < np.radians(180.0))              # expansion stroke
        w_comp = -float(np.sum((0.5 * (p[1:] + p[:-1]) * dv)[comp[:-1]]))
        w_exp = float(np.sum((0.5 * (p[1:] + p[:-1]) * dv)[expa[:-1]]))
        assert w_comp > 0 and abs(w_exp) < 0.1 * w_comp


def test_brake_manifold_and_cylinder_pressures_are_plausible(engine):
    """The calibrated exhaust manifold pressure rises with the brake curve from about ambient
    to ~3.4 bar (exhaust pressure governors hold a few bar); the peak cylinder pressure at the
    release, 21-65 bar, brackets the ~34 bar of a classic compression-release brake [JB]."""
    model = engine.model
    p = [model.brake_cycle(s).brake_manifold_pa for s in BRAKE_SPEEDS]
    peak = [model.brake_cycle(s).peak_pressure_pa for s in BRAKE_SPEEDS]
    assert np.all(np.diff(p) > 0)
    assert 1.0e5 < p[0] < 1.2e5 and 3.2e5 < p[-1] < 3.5e5
    assert 20e5 < peak[0] < 23e5 and 63e5 < peak[-1] < 67e5
    assert 33e5 < model.brake_cycle(1000.0).peak_pressure_pa < 36e5


def test_brake_orders_against_full_load(engine):
    """The brake's 3rd order (whole engine on a rigid crank): its gas part is one compression
    pulse per cylinder and cycle with no expansion pulse after it, narrower than a 3rd-order
    period, so its 3rd harmonic is 0.85-0.96 of the (negative) mean; full load's gas 3rd order
    is 2.9-6.6x larger (the firing pulse). The brake's gas 3rd order lies nearly opposite the
    oscillating-mass inertia part (150-170 deg apart), so in sum they cancel to a minimum near
    1200 rpm, and below 1800 rpm the braking engine's 3rd order is at most a sixth of full
    load's."""
    model = engine.model
    beta = np.radians(engine.firing_phases_deg)
    whole = np.exp(-0.5j * 6 * beta).sum()
    totals = {}
    for s in (800.0, 1000.0, 1200.0, 1400.0, 1600.0, 2000.0):
        gas_b = half_orders(model.brake_cycle(s).gas_torque_nm, 24)[6] * whole
        gas_f = half_orders(model.cycle(s, 1.0).gas_torque_nm, 24)[6] * whole
        inertia = model.inertia_coefficients(s)[6] * whole
        mean = abs(engine.brake_torque(s))
        assert 0.8 * mean < abs(gas_b) < mean, s
        assert 2.5 < abs(gas_f) / abs(gas_b) < 7.0, s
        apart = abs(np.degrees(np.angle(gas_b / inertia)))
        assert 150.0 < apart < 170.0, s
        b3 = abs(engine_torque_orders(engine, s, -1.0)[6])
        f3 = abs(engine_torque_orders(engine, s, 1.0)[6])
        assert b3 == pytest.approx(abs(gas_b + inertia), rel=1e-6)
        totals[s] = b3
        if s < 1800.0:
            assert b3 < f3 / 6.0, s
    assert min(totals, key=totals.get) == 1200.0


# ---- negative loads through the solvers --------------------------------------------------------
@pytest.fixture(scope='module')
def coast_loads(engine):
    return dmf.DrivelineExcitation(dmf.read_model('truck_dmf_coast'), engine)


def test_newmark_and_harmonic_balance_agree_under_braking(coast_loads):
    """Full brake at 2000 rpm on the driveline with a coast stage: the static wind-up is in the
    coast stage, and Newmark's steady state agrees with the harmonic balance within 1 % (the
    tolerance of the HBM-vs-Newmark tests at full load, test_hbm.py)."""
    speed = 2000.0
    st = coast_loads.static_state(speed, -1.0)
    assert st.windup < -0.10 and st.region == 'coast'
    res = dmf.sweep(coast_loads, load=-1.0, speed_range=(speed - 50.0, speed + 50.0))
    nm = dmf.simulate(coast_loads, speed, -1.0, options=dmf.SimulationOptions(dt=1e-4))
    assert nm.steady, nm.message
    c = nm.windup_orders
    hb = min(res.solutions_at(speed), key=lambda q: abs(q.order_3 - abs(c[6])))
    assert hb.stable
    assert abs(abs(c[6]) - hb.order_3) < 0.01 * hb.order_3
    assert abs(c[0].real - hb.summary.mean) < 0.01 * abs(hb.summary.mean)
    assert hb.summary.mean == pytest.approx(st.windup, abs=2e-4)


def test_the_coast_stage_acts_under_full_braking(coast_loads):
    """truck_dmf_coast (coast knee 0.10 rad): the mean wind-up under the full brake is negative
    at every speed and beyond the coast knee exactly where the brake torque on the DMF exceeds
    k theta_c = 1089 Nm (above ~1410 rpm); in the paper's DMF (no coast stage) the spring stays
    linear there."""
    spring = coast_loads.model.spring
    knee_torque = spring.k * spring.coast[0].angle_rad
    res = dmf.sweep(coast_loads, load=-1.0, speed_range=(1000.0, 2200.0))
    crossed = []
    for s in np.arange(1000.0, 2201.0, 100.0):
        states = res.solutions_at(float(s))
        assert states and all(q.summary.mean < 0 for q in states)
        beyond = abs(coast_loads.engine.brake_torque(s)) > knee_torque
        for q in states:
            assert (q.summary.mean < -spring.coast[0].angle_rad) == beyond, s
        crossed.append(beyond)
    assert not crossed[0] and crossed[-1]                   # the knee is crossed in the sweep
    paper = dmf.DrivelineExcitation(dmf.read_model('truck_dmf'), coast_loads.engine)
    assert paper.static_state(2200.0, -1.0).region == 'primary'


def test_live_core_takes_braking_setpoints(engine):
    from dmf_sim.live.simulation import LiveSimulation
    line = dmf.read_driveline('truck_dmf')
    sim = LiveSimulation(line, engine, speed_rpm=1500.0, load=-0.5, load_ramp_per_s=100.0)
    assert sim.set_load_setpoint(-1.0) is None
    sim.advance(2000)
    assert sim.load == -1.0 and sim.windup < 0
    reason = sim.set_load_setpoint(-1.5)
    assert reason.startswith('load setpoint -1.5 outside [-1, 1]')
    tab = dmf.read_engine('engine_table_example.csv')
    limits = tab.speed_range_rpm
    table = LiveSimulation(line, tab, speed_rpm=1500.0, load=0.5, speed_limits_rpm=limits)
    assert 'no brake curve' in table.set_load_setpoint(-0.2)
    with pytest.raises(ConfigError, match='initial_load -0.2 outside'):
        LiveSimulation(line, tab, speed_rpm=1500.0, load=-0.2, speed_limits_rpm=limits)


def test_study_conditions_take_braking_loads(tmp_path):
    from dmf_sim.design.study import study_from_dict
    d = yaml.safe_load((config_dir() / 'study_example.yaml').read_text())
    d['conditions']['loads'] = [-1.0, 1.0]
    study = study_from_dict(copy.deepcopy(d), 'study.yaml')
    assert sorted({c.load for c in study.conditions}) == [-1.0, 1.0]
    d['engine'] = 'engine_table_example.csv'
    with pytest.raises(ConfigError) as exc:
        study_from_dict(d, 'study.yaml')
    _one_line(exc.value, 'study.yaml: conditions.loads[0] -1 outside [0, 1]', 'no brake curve')
