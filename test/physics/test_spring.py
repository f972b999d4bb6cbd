"""The piecewise-linear DMF spring (dmf_sim.physics.spring) and its YAML forms (two-step shorthand,
multi-stage drive and coast stages)."""
import copy

import numpy as np
import pytest
import yaml

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.paths import config_file
from dmf_sim.physics.model import driveline_from_dict, read_driveline
from dmf_sim.physics.spring import PiecewiseLinearSpring, Stage

K = 10890.0


def three_stage():
    return PiecewiseLinearSpring(K, (Stage(0.24, 2.5), Stage(0.30, 4.0), Stage(0.36, 8.0)),
                                 (Stage(0.10, 1.0), Stage(0.20, 3.0)))


def test_two_step_shorthand_is_the_paper_spring():
    s = PiecewiseLinearSpring.two_step(K, 0.24, 2.0, theta_coast=0.1, alpha_coast=1.0)
    w = np.linspace(-0.5, 0.5, 2001)
    T = s.torque(w)
    assert np.all(np.diff(T) > 0)
    assert s.stiffness(0.0) == pytest.approx(K)
    assert s.stiffness(0.3) == pytest.approx(3 * K)
    assert s.stiffness(-0.3) == pytest.approx(2 * K)
    # eq. (3)/(8) with the (dphi - theta) factor: g = alpha k (w - theta) beyond the knee
    assert s.extra_torque(0.34) == pytest.approx(2.0 * K * 0.10)
    assert s.extra_torque(-0.15) == pytest.approx(-1.0 * K * 0.05)
    assert (s.region(0.3) == 'secondary' and s.region(0.0) == 'primary'
            and s.region(-0.3) == 'coast')
    assert s.theta == 0.24 and s.alpha == 2.0


def test_multi_stage_law_continuous_monotone_energy_and_inverses():
    s = three_stage()
    w = np.linspace(-0.6, 0.6, 24001)
    T = s.torque(w)
    assert np.all(np.diff(T) > 0)
    # slopes per stage: k (1 + f)
    for wi, f in ((0.27, 2.5), (0.33, 4.0), (0.5, 8.0), (0.0, 0.0), (-0.15, 1.0), (-0.4, 3.0)):
        assert s.stiffness(wi) == pytest.approx(K * (1 + f))
    # continuity at every knee
    for x in s.knees:
        assert s.torque(x + 1e-12) == pytest.approx(s.torque(x - 1e-12), abs=1e-6)
    # g is the sum of its ramps
    g_ramps = sum(c * (w - x) * (side * (w - x) > 0) for x, c, side in s.ramps())
    np.testing.assert_allclose(s.extra_torque(w), g_ramps, atol=1e-9)
    # energy is the integral of the torque
    E = s.energy(w)
    np.testing.assert_allclose(np.gradient(E, w)[5:-5], T[5:-5], rtol=1e-4, atol=0.5)
    for torque in (-9000.0, -1500.0, 100.0, 2614.0, 3500.0, 6000.0, 20000.0):
        assert s.torque(s.windup_for_torque(torque)) == pytest.approx(torque)
    for w_lin in (-0.9, -0.25, -0.05, 0.1, 0.25, 0.31, 0.5, 1.5):
        for h in (1e-5, 1e-4, 1e-3):
            w_sol = s.solve_condensed(w_lin, h)
            assert w_sol + h * s.extra_torque(w_sol) == pytest.approx(w_lin)
    assert [s.region_name(st) for st in s.stages()] == [
        'coast stage 2', 'coast', 'primary', 'secondary', 'drive stage 2', 'drive stage 3']
    assert s.primary_bounds() == (-0.10, 0.24)


def test_stage_validation_one_line_errors():
    with pytest.raises(ConfigError,
                       match=r'dmf.stages\[1\].angle_rad must be finite, > the previous'):
        PiecewiseLinearSpring(K, (Stage(0.24, 2.5), Stage(0.20, 3.0)))
    with pytest.raises(ConfigError,
                       match=r'coast_stages\[0\].stiffness_factor must be finite and in \[0, 50'):
        PiecewiseLinearSpring(K, (), (Stage(0.1, -2.0),))
    with pytest.raises(ConfigError, match='> 0 rad'):
        PiecewiseLinearSpring.two_step(K, 0.0, 1.0)
    # bounded above too (a YAML `alpha: 1e300` is a number now, refused by its range)
    with pytest.raises(ConfigError, match=r'stiffness_factor must be finite and in \[0, 50\]'):
        PiecewiseLinearSpring.two_step(K, 0.24, 1e300)
    with pytest.raises(ConfigError, match=r'angle_rad must be finite, > 0 rad and <= 2 rad'):
        PiecewiseLinearSpring.two_step(K, 3.0, 1.0)


def _raw():
    return yaml.safe_load(config_file('truck_dmf').read_text())


def test_yaml_stages_and_shorthand_agree():
    d = _raw()
    short = driveline_from_dict(copy.deepcopy(d))
    d['dmf'].pop('theta_rad'), d['dmf'].pop('alpha')
    d['dmf']['stages'] = [{'angle_rad': 0.24, 'stiffness_factor': 2.5}]
    d['dmf']['stiffness'] = 10890
    long = driveline_from_dict(d)
    assert long.spring == short.spring
    d['dmf']['stages'] = [{'angle': 0.24, 'stiffness_factor': 2.5},
                          {'angle': 0.30, 'stiffness_factor': 5}]
    d['dmf']['coast_stages'] = [{'angle_rad': 0.12, 'stiffness_factor': 1.5}]
    line = driveline_from_dict(d)
    assert line.spring.knees.tolist() == [-0.12, 0.24, 0.30]
    # the (alpha, theta) shorthand acts on the first drive stage
    line2 = line.with_dmf(alpha=3.0, theta=0.22)
    assert ([(s.angle_rad, s.stiffness_factor) for s in line2.dmf.stages]
            == [(0.22, 3.0), (0.30, 5.0)])
    assert line2.dmf.coast_stages == line.dmf.coast_stages
    line3 = line.with_dmf(k=12000.0, damping=10.0)
    assert line3.spring.k == 12000.0 and line3.dmf_element.damping == 10.0


@pytest.mark.parametrize('mutate, message', [
    (lambda d: d.update(stages=[{'angle_rad': 0.2, 'stiffness_factor': 1}]),
     "either 'stages' or the shorthand"),
    (lambda d: (d.pop('theta_rad'), d.pop('alpha'), d.update(stages=[{'angle_rad': 0.2}])),
     "missing key 'stiffness_factor'"),
    (lambda d: (d.pop('theta_rad'), d.pop('alpha'), d.update(stages={'a': 1})), 'expected a list'),
    (lambda d: d.update(stiffness=12000), "differs from the stiffness 10890"),
    (lambda d: (d.pop('alpha'), d.pop('theta_rad')), "missing key 'stages'"),
    (lambda d: d.pop('alpha'), "missing key 'alpha'"),
    (lambda d: d.update(coast={'theta_rad': 0.1, 'alpha': 1}, coast_stages=[]),
     "either 'coast_stages'"),
    (lambda d: (d.pop('theta_rad'), d.pop('alpha'),
                d.update(stages=[{'angle_rad': 0.3, 'stiffness_factor': 1},
                                 {'angle_rad': 0.2, 'stiffness_factor': 1}])),
     'stages[1].angle_rad'),
])
def test_bad_dmf_yaml_one_line(mutate, message):
    d = _raw()
    mutate(d['dmf'])
    with pytest.raises(ConfigError) as exc:
        driveline_from_dict(d)
    assert message in str(exc.value) and '\n' not in str(exc.value)


def test_config_file_errors_say_what_is_wrong(tmp_path):
    with pytest.raises(ConfigError, match='not a driveline YAML mapping'):
        read_driveline('/dev/null')
    with pytest.raises(ConfigError, match='is a directory'):
        read_driveline(str(tmp_path))
    bad = tmp_path / 'bad.yaml'
    bad.write_text('name: x\nelements: [\n  {name: a, ratio: 1,\n')
    with pytest.raises(ConfigError, match=r'bad.yaml:\d+:\d+: invalid YAML'):
        read_driveline(str(bad))
    binary = tmp_path / 'blob.yaml'
    binary.write_bytes(bytes(range(256)))
    with pytest.raises(ConfigError, match='not a text file'):
        read_driveline(str(binary))
    with pytest.raises(ConfigError, match='config file not found'):
        read_driveline('no_such_driveline')


def test_describe_names_every_stage():
    from dmf_sim.physics.spring import PiecewiseLinearSpring, Stage
    assert PiecewiseLinearSpring(10890.0, [Stage(0.24, 2.5)]).describe() == \
        'alpha=2.5 theta=0.24 rad'
    text = PiecewiseLinearSpring(10890.0, [Stage(0.1, 1.0), Stage(0.14, 2.5)],
                                 [Stage(0.02, 1.5)]).describe()
    assert text == ('k=10890 Nm/rad, drive stages [0.1 rad: +1k, 0.14 rad: +2.5k], '
                    'coast stages [-0.02 rad: +1.5k]')
