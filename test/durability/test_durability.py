"""Durability: rainflow and Palmgren-Miner damage against closed forms (a pure sine, a
two-level block), batch-size invariance, time per spring stage and dissipated power against
closed forms, and ``dmf-sim durability`` on a run bag (batches, report, one-line errors)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dmf_sim.cli import main as cli_main
from dmf_sim.core.paths import config_file
from dmf_sim.durability.accumulate import DurabilityAccumulator
from dmf_sim.durability.rainflow import count_cycles
from dmf_sim.durability.settings import SNCurve, read_settings
from dmf_sim.physics.orders import CYCLE_RAD
from dmf_sim.physics.spring import PiecewiseLinearSpring
from dmf_sim.transient.profiles import read_profile
from dmf_sim.transient.run import run_profile

SN = SNCurve(exponent=5.0, reference_range_nm=1000.0, reference_cycles=1e6, placeholder=False)
PTS = 64                    # samples per period of the test signals


def cosine(amplitude: float, periods: int, mean: float = 0.0) -> np.ndarray:
    """``periods`` whole periods starting and ending at a peak."""
    t = np.arange(periods * PTS + 1) / PTS
    return mean + amplitude * np.cos(2 * np.pi * t)


def test_pure_sine_counts_and_damage_closed_form():
    """A cosine of amplitude A over n periods: n cycles of range 2 A (rainflow, ASTM E1049),
    damage n / N(2A) = n (2A / S_ref)^b / N_ref, whatever the batch size."""
    a, n = 700.0, 200
    y = cosine(a, n, mean=1500.0)
    exact = n * (2 * a / SN.reference_range_nm) ** SN.exponent / SN.reference_cycles
    for batch in (None, 1, 37, 1000):
        r, m, c = count_cycles(y, batch)
        assert c.sum() == pytest.approx(n)
        assert np.allclose(r, 2 * a) and np.allclose(m, 1500.0)
        assert SN.damage(r, c) == pytest.approx(exact, rel=1e-12)


def test_two_level_block_damage_closed_form():
    """n1 cycles at A1 then n2 at A2: Miner's sum n1/N(2 A1) + n2/N(2 A2); the junction
    between the blocks changes it by at most one cycle of the larger range."""
    a1, n1, a2, n2 = 900.0, 50, 300.0, 2000
    y = np.concatenate([cosine(a1, n1)[:-1], cosine(a2, n2)])
    r, m, c = count_cycles(y, batch=777)
    exact = (n1 / SN.cycles_to_failure(2 * a1) + n2 / SN.cycles_to_failure(2 * a2))
    one = 1 / SN.cycles_to_failure(2 * a1)
    assert abs(SN.damage(r, c) - exact) <= one
    assert c[np.isclose(r, 2 * a1)].sum() == pytest.approx(n1, abs=1)
    assert c[np.isclose(r, 2 * a2)].sum() == pytest.approx(n2, abs=1)


@pytest.mark.slow
def test_batches_do_not_change_the_count():
    y = np.random.default_rng(7).normal(size=30_000).cumsum()
    ref = sorted(zip(*count_cycles(y)))
    for batch in (1, 13, 4096):
        got = sorted(zip(*count_cycles(y, batch)))
        assert np.allclose(np.array(got), np.array(ref))
    # ASTM E1049-85 5.4.4 (three-point method, written out here on the whole record): the same
    # number of cycles and the same damage to 0.1 % (the two treat the record's start and
    # residue a little differently: a few half cycles of the residue pair up differently)
    astm = np.array(astm_three_point(y))
    mine = np.array(ref)
    assert mine[:, 2].sum() == astm[:, 2].sum()
    assert SN.damage(mine[:, 0], mine[:, 2]) == pytest.approx(SN.damage(astm[:, 0], astm[:, 2]),
                                                               rel=1e-3)


def astm_three_point(y):
    """ASTM E1049-85 rainflow, section 5.4.4, as printed (reference for the tests)."""
    y = np.asarray(y, float)
    y = y[np.concatenate(([True], np.diff(y) != 0))]
    d = np.sign(np.diff(y))
    rev = [y[0], *y[1:-1][d[1:] != d[:-1]], y[-1]]
    out, pts = [], []
    for x in rev:
        pts.append(x)
        while len(pts) >= 3:
            X, Y = abs(pts[-1] - pts[-2]), abs(pts[-2] - pts[-3])
            if X < Y:
                break
            if len(pts) == 3:
                out.append((Y, (pts[0] + pts[1]) / 2, 0.5))
                pts.pop(0)
            else:
                out.append((Y, (pts[-2] + pts[-3]) / 2, 1.0))
                last = pts.pop()
                pts.pop()
                pts.pop()
                pts.append(last)
    out += [(abs(b - a), (a + b) / 2, 0.5) for a, b in zip(pts[:-1], pts[1:])]
    return out


def test_sn_curve_and_endurance():
    sn = SNCurve(3.0, 100.0, 1e5, endurance_range_nm=50.0)
    assert sn.cycles_to_failure(200.0) == pytest.approx(1e5 / 8)
    assert math.isinf(float(sn.cycles_to_failure(40.0)))
    assert sn.damage([200.0, 40.0], [0.5, 10]) == pytest.approx(0.5 * 8 / 1e5)


def test_stage_time_and_dissipated_power_closed_form():
    """w = w0 + A sin(W t) across the knee theta: the time above it is acos((theta-w0)/A)/pi
    of the record; the viscous power c (dw/dt)^2 averages c A^2 W^2 / 2 per engine cycle."""
    spring = PiecewiseLinearSpring.two_step(10890.0, 0.24, 3.0)
    settings = read_settings()
    c, amp, w0 = 49.5, 0.05, 0.22
    speed = 1200.0
    om = speed * np.pi / 30
    W = 3 * om                                       # 3rd engine order
    fs = 20_000.0
    t = np.arange(int(4.0 * fs)) / fs
    w = w0 + amp * np.sin(W * t)
    wdot = amp * W * np.cos(W * t)
    psi = om * t
    acc = DurabilityAccumulator(spring, c, settings)
    for a in range(0, len(t), 5000):
        sl = slice(a, a + 5000)
        acc.add((t[sl] * 1e9).astype(np.int64), w[sl], wdot[sl], np.full(len(t[sl]), speed),
                psi[sl])
    res = acc.finish()
    frac = res.stages['secondary'].time_s / res.duration_s
    assert frac == pytest.approx(math.acos((0.24 - w0) / amp) / math.pi, abs=2e-3)
    assert res.power_mean_w == pytest.approx(c * amp ** 2 * W ** 2 / 2, rel=1e-3)
    assert np.allclose(res.power_w, c * amp ** 2 * W ** 2 / 2, rtol=1e-3)
    assert res.power_t_s[-1] <= t[-1] and len(res.power_t_s) >= 3
    # the spring torque's extremes, and its cycles: 3 per engine cycle (3rd order)
    assert res.torque_max_nm == pytest.approx(float(spring.torque(w0 + amp)), rel=1e-6)
    engine_cycles = psi[-1] / CYCLE_RAD
    assert res.cycles == pytest.approx(6 * engine_cycles, abs=1.0)
    assert res.largest[0][1] == pytest.approx(res.torque_max_nm)


def test_end_stop_damping_heat_closed_form():
    """w = w0 + A sin(W t) pressing past the drive stop a: the contact's damping dissipates
    c_s (dw/dt)^2 while the stop pushes, per period c_s A^2 W ((pi - 2 a0) - sin 2 a0) / 2 with
    a0 = asin((a - w0) / A) (the contact damping small enough that the stop never lets go
    before the wind-up leaves it); it joins the dissipated power and is reported apart, and a
    stop without damping dissipates nothing."""
    from dmf_sim.physics.spring import EndStops
    base = PiecewiseLinearSpring.two_step(10890.0, 0.24, 3.0)
    c, c_s, amp, w0, a = 49.5, 2.0, 0.05, 0.22, 0.25
    speed = 1200.0
    om = speed * np.pi / 30
    W = 3 * om
    fs = 50_000.0
    t = np.arange(int(2.0 * fs)) / fs
    w = w0 + amp * np.sin(W * t)
    wdot = amp * W * np.cos(W * t)
    a0 = math.asin((a - w0) / amp)
    per_period = c_s * amp ** 2 * W * ((math.pi - 2 * a0) - math.sin(2 * a0)) / 2
    for damping, expected in ((c_s, per_period * t[-1] * W / (2 * math.pi)), (0.0, 0.0)):
        spring = PiecewiseLinearSpring(base.k, base.drive, base.coast,
                                       stops=EndStops(a, 0.25, 1e6, damping))
        acc = DurabilityAccumulator(spring, c, read_settings())
        acc.add((t * 1e9).astype(np.int64), w, wdot, np.full(len(t), speed), om * t)
        d = acc.finish().as_dict()
        p = d['dissipated_power']
        assert d['end_stops']['contacts'] >= 10
        # 1 %: ~245 samples per contact, and c_s (dw/dt)^2 jumps from 0 to near its largest
        # value where the contact begins and ends (half a sample's weight each)
        assert p['stop_energy_j'] == pytest.approx(expected, rel=1e-2, abs=1e-12)
        assert p['viscous_energy_j'] == pytest.approx(c * amp ** 2 * W ** 2 / 2 * t[-1],
                                                      rel=2e-3)
        assert p['energy_j'] == pytest.approx(p['viscous_energy_j'] + p['stop_energy_j'])


@pytest.mark.slow
def test_damping_power_has_a_point_per_engine_cycle():
    """The report's power panel said 'per engine cycle' but drew one point per second (14 points
    for 152 cycles). Every whole engine cycle is now a point, at c A^2 W^2 / 2 for a pure 3rd
    order; the cycle the record starts inside and the one it ends inside are left out."""
    from support.figure_checks import points_under_legends, texts_off_canvas

    from dmf_sim.durability.read import DurabilityRun
    from dmf_sim.durability.report import report_figure
    spring = PiecewiseLinearSpring.two_step(10890.0, 0.24, 3.0)
    c, amp, speed, fs = 49.5, 0.03, 1300.0, 5000.0
    om = speed * np.pi / 30
    t = np.arange(int(14.0 * fs)) / fs
    psi = 0.3 * CYCLE_RAD + om * t                   # starts inside a cycle
    w, wdot = 0.1 + amp * np.sin(3 * om * t), amp * 3 * om * np.cos(3 * om * t)
    acc = DurabilityAccumulator(spring, c, read_settings())
    for a in range(0, len(t), 7000):
        sl = slice(a, a + 7000)
        acc.add((t[sl] * 1e9).astype(np.int64), w[sl], wdot[sl], np.full(len(t[sl]), speed),
                psi[sl])
    res = acc.finish()
    whole = int(psi[-1] // CYCLE_RAD) - 1
    assert whole > 140 and len(res.cycle_power_w) == whole == len(res.cycle_t_s)
    assert np.allclose(res.cycle_power_w, c * (amp * 3 * om) ** 2 / 2, rtol=2e-3)
    assert np.allclose(res.cycle_speed_rpm, speed)
    assert np.allclose(np.diff(res.cycle_t_s), CYCLE_RAD / om, atol=1.5 / fs)
    assert res.as_dict()['dissipated_power']['engine_cycles'] == whole
    fig = report_figure(DurabilityRun(res, 'synthetic', 1, [], {}, 0.0, 0.0, 1))
    ax = next(a for a in fig.axes if 'damping power' in a.get_title())
    dots = [line for line in ax.get_lines() if line.get_marker() == '.']
    assert len(dots) == 1 and len(dots[0].get_xdata()) == whole
    assert f'each engine cycle ({whole})' in ax.get_title()
    assert texts_off_canvas(fig) == [] and points_under_legends(fig) == []


@pytest.fixture(scope='module')
def road_bag(tmp_path_factory):
    """The first 8 s of the road cycle (launch, shifts) as a run bag."""
    from dmf_sim.transient.profiles import make_profile
    full = read_profile('truck_road_cycle')
    keep = full.t_s <= 8.0
    rows = [(t, s, x) for t, s, x in zip(full.t_s[keep], full.speed_rpm[keep], full.load[keep])]
    rows.append((8.0, *[float(v) for v in full.at(8.0)]))
    prof = make_profile(rows[:-1] if rows[-2][0] == 8.0 else rows, name='road_8s')
    out = tmp_path_factory.mktemp('dur') / 'road'
    run_profile(prof, out)
    return out


@pytest.mark.slow
def test_durability_command_on_a_run_bag(road_bag, tmp_path, capsys):
    out = tmp_path / 'rep'
    assert cli_main(['durability', str(road_bag), '--out', str(out)]) == 0
    text = capsys.readouterr().out
    assert 'placeholder S-N curve' in text and (out / 'durability.png').stat().st_size > 10_000
    d = json.loads((out / 'durability.json').read_text())
    assert d['sn_curve_is_placeholder'] is True
    assert d['duration_s'] == pytest.approx(8.0, abs=0.01) and d['samples'] == 8000
    assert d['damage'] > 0 and d['damage_per_hour'] == pytest.approx(d['damage'] / (8 / 3600),
                                                                     rel=1e-3)
    assert sum(b['damage'] for b in d['speed_bands']) + d['damage_residue'] == \
        pytest.approx(d['damage'])
    assert sum(s['time_s'] for s in d['stages'].values()) == pytest.approx(d['duration_s'])
    assert 'the spring has no arc-spring friction' in d['dissipated_power']['note']
    assert d['dissipated_power']['friction_energy_j'] == 0.0 and d['end_stops'] is None
    assert d['largest_torques'][0]['torque_nm'] == pytest.approx(
        max(abs(d['torque_nm']['min']), abs(d['torque_nm']['max'])))
    assert d['batches'] >= 2                      # read in batches, not whole
    # the curve from the options is the user's: no longer a placeholder
    assert cli_main(['durability', str(road_bag), '--json', '--exponent', '6']) == 0
    d6 = json.loads(capsys.readouterr().out)
    assert d6['sn_curve_is_placeholder'] is False and d6['sn_curve']['exponent'] == 6.0


@pytest.mark.parametrize('yaml_text, words', [
    ('sn_curve: {exponent: -1}\n', ["field 'sn_curve.exponent' must be in [0.5, 50]"]),
    ('sn_curve: {reference_cycles: many}\n', ["field 'sn_curve.reference_cycles' must be a "
                                              'number']),
    ('bins: {torque_nm: 0}\n', ["field 'bins.torque_nm' must be in"]),
    ('colour: red\n', ["unknown key 'colour'"]),
])
def test_bad_durability_settings_one_line(road_bag, tmp_path, capsys, yaml_text, words):
    cfg = tmp_path / 'd.yaml'
    cfg.write_text(yaml_text)
    assert cli_main(['durability', str(road_bag), '--json', '--settings', str(cfg)]) == 2
    err = capsys.readouterr().err.strip()
    assert '\n' not in err and 'Traceback' not in err
    for w in words:
        assert w in err


def test_durability_of_a_bag_without_the_topics(tmp_path, capsys):
    from dmf_sim.bags.writer import BagRecorder
    with BagRecorder(tmp_path / 'other', {'/x': 'std_msgs/msg/Float64'}) as rec:
        rec.write('/x', 1, b'\x00\x01\x00\x00' + bytes(8))
    assert cli_main(['durability', str(tmp_path / 'other'), '--json']) == 2
    err = capsys.readouterr().err
    assert 'durability needs the joint states' in err and err.count('\n') == 1


def _diverging(n: int = 4000, fs: float = 1000.0, speed: float = 1200.0):
    """A record whose wind-up grows without bound from 2 s on, as a diverged run writes it:
    time [ns], w, dw/dt, speed, crank angle."""
    t = np.arange(n) / fs
    om = speed * np.pi / 30
    grow = np.exp(np.clip(t - 2.0, 0.0, None) * 300.0)            # 1e260 at 4 s
    w = 0.1 + 0.03 * np.sin(3 * om * t) * grow
    wdot = np.gradient(w, t)
    return (t * 1e9).astype(np.int64), w, wdot, np.full(n, speed), om * t


@pytest.mark.parametrize('spoil, words', [
    (None, 'Nm is beyond 1e+06 Nm'),
    ('nan', 'DMF wind-up nan rad is not finite'),
    ('speed', 'engine speed 1e+05 rpm is beyond 10000 rpm'),
])
def test_a_diverged_record_is_refused_where_it_leaves_physics(spoil, words):
    """A diverged run (wind-up 1e251 rad) used to overflow every figure with numpy warnings and
    crash the report: it is refused at its first sample beyond the physical bounds, naming it."""
    import warnings

    from dmf_sim.core.errors import BagError
    t, w, wdot, speed, psi = _diverging()
    if spoil == 'nan':
        w = np.where(t >= 3e9, np.nan, 0.1)
        wdot = np.zeros_like(w)
    elif spoil == 'speed':
        w, wdot = np.full_like(w, 0.1), np.zeros_like(w)
        speed = np.where(t >= 3e9, 1e5, speed)
    spring = PiecewiseLinearSpring.two_step(10890.0, 0.24, 2.5)
    acc = DurabilityAccumulator(spring, 49.5, read_settings())
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        with pytest.raises(BagError, match='the record is not physical from t = ') as err:
            for a in range(0, len(t), 1000):
                sl = slice(a, a + 1000)
                acc.add(t[sl], w[sl], wdot[sl], speed[sl], psi[sl])
    msg = str(err.value)
    assert words in msg and '\n' not in msg, msg
    first = float(msg.split('from t = ')[1].split(' s')[0])
    assert 2.0 <= first <= 3.0 + 1e-9


def test_report_of_torques_near_the_bound_merges_matrix_bins():
    """Torque swings of ~1 MNm (inside the torque bound) would ask for a rainflow-matrix panel of
    20000 x 20000 cells (3 GB); the panel merges bins instead and says so."""
    from dmf_sim.durability.read import DurabilityRun
    from dmf_sim.durability.report import MATRIX_PANEL_BINS, report_figure
    spring = PiecewiseLinearSpring.two_step(10890.0, 0.24, 2.5)
    n, fs, speed = 4000, 1000.0, 1200.0
    t = np.arange(n) / fs
    om = speed * np.pi / 30
    amp = np.where(t < 2.0, 0.01, 20.0)                    # 0.75 MNm swings after 2 s
    w = amp * np.sin(3 * om * t)
    wdot = amp * 3 * om * np.cos(3 * om * t)
    acc = DurabilityAccumulator(spring, 0.0, read_settings())
    acc.add((t * 1e9).astype(np.int64), w, wdot, np.full(n, speed), om * t)
    res = acc.finish()
    fig = report_figure(DurabilityRun(res, 'synthetic', 1, [], {}, 0.0, 0.0, 1))
    ax = next(a for a in fig.axes if a.get_title().startswith('rainflow matrix'))
    shape = ax.get_images()[0].get_array().shape
    assert max(shape) <= MATRIX_PANEL_BINS and 'bins merged to' in ax.get_title()
    # the counts are kept: the merged panel holds every cycle
    assert float(np.nansum(10 ** ax.get_images()[0].get_array())) == pytest.approx(res.cycles)


def test_durability_of_a_diverged_bag_is_one_line(tmp_path, capsys):
    """`dmf-sim durability` of a diverged run's bag: one line, exit 2, nothing written."""
    from support.cdr import Float64, joint_state, serialize_message

    from dmf_sim.bags.writer import BagRecorder
    from dmf_sim.physics.model import read_driveline
    names = read_driveline('truck_dmf').names
    s = names.index('SECONDARY FLYWHEEL')
    t, w, wdot, speed, psi = _diverging()
    topics = {'/driveline/joint_states': 'sensor_msgs/msg/JointState',
              '/engine/speed': 'std_msgs/msg/Float64',
              '/engine/crank_angle': 'std_msgs/msg/Float64'}
    with BagRecorder(tmp_path / 'div', topics) as rec:
        for i in range(len(t)):
            pos, vel = np.zeros(len(names)), np.zeros(len(names))
            pos[s - 1], vel[s - 1] = w[i], wdot[i]
            stamp = 1_700_000_000_000_000_000 + int(t[i])
            rec.write('/driveline/joint_states', stamp,
                      serialize_message(joint_state(stamp, names, pos, vel)))
            rec.write('/engine/speed', stamp, serialize_message(Float64(data=float(speed[i]))))
            rec.write('/engine/crank_angle', stamp, serialize_message(Float64(data=float(psi[i]))))
    for extra in (['--json'], ['--out', str(tmp_path / 'rep')]):
        assert cli_main(['durability', str(tmp_path / 'div'), *extra]) == 2
        out = capsys.readouterr()
        assert out.out == '' and out.err.count('\n') == 1, out.err
        assert 'not physical from t = ' in out.err and 'Traceback' not in out.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ['div']


@pytest.mark.slow
def test_a_bag_whose_driveline_file_is_gone_takes_config(tmp_path, capsys):
    """A bag names its driveline file; once that file is gone the message says "pass --config",
    which durability (like runup and detect) did not have ("unrecognized arguments"). Every
    command that reads a bag's model takes it now, with analyze's meaning."""
    import shutil

    from dmf_sim.cli import build_parser
    cfg = tmp_path / 'x' / 'cfg.yaml'
    cfg.parent.mkdir()
    shutil.copy(config_file('truck_dmf'), cfg)
    bag = tmp_path / 'bag'
    assert cli_main(['run', 'step:1200:0:1:0.1:0.5:0.5', '--config', str(cfg), '--out',
                     str(bag), '--no-progress']) == 0
    shutil.rmtree(cfg.parent)
    capsys.readouterr()
    assert cli_main(['durability', str(bag), '--json']) == 2
    err = capsys.readouterr().err
    assert 'cannot be loaded' in err and 'pass --config' in err and err.count('\n') == 1
    assert cli_main(['durability', str(bag), '--json', '--config', 'truck_dmf']) == 0
    d = json.loads(capsys.readouterr().out)
    assert d['samples'] > 0 and d['model']['driveline'] == 'truck_dmf'
    assert cli_main(['durability', str(bag), '--json', '--config', 'no_such_driveline']) == 2
    err = capsys.readouterr().err
    assert "--config 'no_such_driveline' cannot be loaded" in err and 'pass --config' not in err
    parser = build_parser()
    for command in ('analyze', 'durability', 'runup', 'detect', 'identify'):
        args = parser.parse_args([command, str(bag), '--config', 'truck_dmf'])
        assert args.config == 'truck_dmf', command


def test_the_spring_stored_in_the_bag_keeps_its_friction_and_end_stops(tmp_path, capsys):
    """``--config`` names another driveline YAML while the spring stored in the bag still
    applies (the page says so): its stages did, its friction and end stops came from the YAML
    given. A truck_dmf_friction bag read with ``--config truck_dmf`` (its file moved, say) lost
    its friction heat (259 J of 640 J in a tip-in: reported 0) and its end stops; a bag without
    friction read with ``--config truck_dmf_friction`` gained them. Both now keep the bag's."""
    from dmf_sim.analysis.hbm_overlay import model_settings
    from dmf_sim.bags.layout import resolve_bag
    runs = {}
    for name in ('truck_dmf_friction', 'truck_dmf'):
        bag = tmp_path / name
        assert cli_main(['run', 'step:1200:0:1:0.1:0.3:0.3', '--config', name, '--out', str(bag),
                         '--no-progress', '--no-sensors', '--json']) == 0
        runs[name] = (bag, json.loads(capsys.readouterr().out.strip().splitlines()[-1]))
    for name, other in (('truck_dmf_friction', 'truck_dmf'), ('truck_dmf', 'truck_dmf_friction')):
        bag, run = runs[name]
        stored = resolve_bag(bag).metadata
        assert model_settings(stored, config=other)['spring'] == model_settings(stored)['spring']
        reports = []
        for config in ([], ['--config', other]):
            assert cli_main(['durability', str(bag), '--json', '--no-plots', *config]) == 0
            reports.append(json.loads(capsys.readouterr().out))
        own, given = reports
        assert given['model']['driveline'] == other
        assert given['end_stops'] == own['end_stops']
        heat = run.get('friction_heat_j', 0.0)
        for d in reports:
            assert d['dissipated_power']['friction_energy_j'] == pytest.approx(heat, rel=0.02)
    assert runs['truck_dmf_friction'][1]['friction_heat_j'] > 50.0


def test_dmf_faults_of_the_bag_are_counted_with_the_dmf_they_make(tmp_path, capsys):
    """A bag of a run whose DMF damping a fault triples from 0.8 s: the viscous heat is
    c (dw/dt)^2 with c = 49.5 Nms/rad before and 148.5 after (computed here from the bag's own
    joint states), not 49.5 throughout (239 J of the run's, reported before), and the notes
    name the fault."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from dmf_sim.durability.read import bag_durability
    from dmf_sim.physics.model import read_driveline
    faults = tmp_path / 'faults.yaml'
    faults.write_text('faults:\n  - {kind: dmf_damping, factor: 3, start_s: 0.8}\n')
    bag = tmp_path / 'bag'
    assert cli_main(['run', 'step:1200:0:1:0.1:0.5:0.5', '--faults', str(faults), '--out',
                     str(bag), '--no-progress', '--no-sensors']) == 0
    capsys.readouterr()
    res = bag_durability(bag, read_settings()).result
    line = read_driveline('truck_dmf')
    s = line.index(line.dmf.element)
    c0, ratio = line.elements[s].damping, line.elements[s].ratio
    store = get_typestore(Stores.ROS2_JAZZY)
    t, wdot = [], []
    with AnyReader([bag], default_typestore=store) as reader:
        conns = [c for c in reader.connections if c.topic == '/driveline/joint_states']
        for conn, stamp, raw in reader.messages(connections=conns):
            m = store.deserialize_cdr(raw, conn.msgtype)
            i, j = m.name.index(line.names[s - 1]), m.name.index(line.names[s])
            t.append(stamp)
            wdot.append(m.velocity[i] / ratio - m.velocity[j])
    t = (np.array(t) - t[0]) * 1e-9
    wdot = np.array(wdot)
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2]))
    after = t >= 0.8 - 1e-3
    expected = float(np.sum(np.where(after, 3 * c0, c0) * wdot ** 2 * dt))
    nominal = float(np.sum(c0 * wdot ** 2 * dt))
    viscous = res.as_dict()['dissipated_power']['viscous_energy_j']
    assert viscous == pytest.approx(expected, rel=0.01)
    assert abs(viscous - nominal) > 0.2 * nominal           # the fault's share is not lost
    assert any('dmf_damping' in n and 'c = 148.5 Nms/rad' in n for n in res.notes), res.notes
