"""The ``sensors:`` section of the driveline YAML: the shipped sensors, the pitch-error pattern,
and every bad input refused in one line naming its field (dmf_sim.physics.sensors)."""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import yaml

from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.paths import config_file
from dmf_sim.physics.model import driveline_from_dict, read_driveline
from dmf_sim.physics.sensors import SensorSet, parse_sensors


def raw(name='truck_dmf'):
    return yaml.safe_load(config_file(name).read_text())


def test_edge_batch_period_is_whole_publish_periods():
    from dmf_sim.physics.sensors import SensorSet
    assert SensorSet().edge_batch_ns(1e-3) == 1e6                    # 0: one publish period
    assert SensorSet(edge_batch_s=0.01).edge_batch_ns(1e-3) == 1e7
    assert SensorSet(edge_batch_s=0.0104).edge_batch_ns(2e-3) == 1e7  # rounded to 5 periods
    assert SensorSet(edge_batch_s=1e-4).edge_batch_ns(1e-3) == 1e6   # at least one
    shipped = driveline_from_dict(raw(), 'truck.yaml').sensors
    assert shipped.edge_batch_s == 0.01
    assert driveline_from_dict({**raw(), 'sensors': shipped.as_dict()}).sensors == shipped


def test_shipped_sensors_of_the_dmf_truck():
    s = read_driveline('truck_dmf').sensors
    crank, secondary = s.wheel('crank'), s.wheel('flywheel_secondary')
    assert (crank.element, crank.teeth, crank.gap) == ('PRIMARY FLYWHEEL', 60, 2)
    assert (secondary.element, secondary.teeth, secondary.gap) == ('SECONDARY FLYWHEEL', 60, 2)
    assert s.wheel('gearbox_input').element == 'INPUT SHAFT'
    assert s.wheel('output_shaft').element == 'OUTPUT SHAFT'
    assert crank.timer_resolution_s == 1e-7 and crank.timer_jitter_s == 2e-7
    eng = s.signal('engine_speed')
    assert (eng.element, eng.wheel, eng.period_s, eng.resolution_rpm) == (
        'PRIMARY FLYWHEEL', 'crank', 0.02, 0.125)
    for name in ('gearbox_input_speed', 'output_shaft_speed'):
        assert (s.signal(name).period_s, s.signal(name).resolution_rpm) == (0.01, 0.125)
    conv = read_driveline('truck_conventional').sensors
    assert conv.wheel('crank').element == 'FLYWHEEL'
    assert 'flywheel_secondary' not in conv.names


@pytest.mark.parametrize('name', ['truck_dmf_friction', 'truck_dmf_coast'])
def test_every_shipped_dmf_truck_has_the_dmf_trucks_sensors(name):
    """The example DMF drivelines had no sensors: their bags carried no sensor topics and a
    sensor fault (config/faults_example.yaml) was refused ("known: none")."""
    assert read_driveline(name).sensors == read_driveline('truck_dmf').sensors
    assert 'crank' in read_driveline(name).sensors.names


def test_drawn_pitch_pattern_is_fixed_zero_mean_and_of_its_sigma():
    w = read_driveline('truck_dmf').sensors.wheel('crank')
    e = np.array(w.pitch_errors_deg)
    assert len(e) == 58 and abs(e.mean()) < 1e-15
    assert 0.01 < e.std() < 0.03              # sigma 0.02 deg, 58 draws
    # the same numbers on every load (counter-based, machine independent): two values pinned
    again = read_driveline('truck_dmf').sensors.wheel('crank').pitch_errors_deg
    assert again == w.pitch_errors_deg
    assert e[0] == pytest.approx(-0.0019075, abs=1e-7)
    # another seed, another pattern
    assert read_driveline('truck_dmf').sensors.wheel('flywheel_secondary').pitch_errors_deg != \
        w.pitch_errors_deg


def test_tooth_angles_with_given_pitch_errors_and_offset():
    s = parse_sensors({'tooth_wheels': [
        {'name': 'w', 'element': 'A', 'teeth': 6, 'gap': 2, 'offset_deg': 10.0,
         'pitch_errors_deg': [0.0, 0.5, -0.5, 1.0]}]}, ['A'])
    w = s.wheel('w')
    assert w.present_teeth == 4
    np.testing.assert_allclose(np.degrees(w.tooth_angles_rad()),
                               [10.0, 70.5, 129.5, 191.0], rtol=0, atol=1e-12)


def test_round_trip_through_as_dict():
    s = read_driveline('truck_dmf').sensors
    assert parse_sensors(s.as_dict()) == s
    assert parse_sensors(None) == SensorSet() and not SensorSet()


def test_driveline_without_sensors_has_an_empty_set():
    data = raw()
    del data['sensors']
    assert not driveline_from_dict(data).sensors


def _wheel(**kw):
    w = {'name': 'crank', 'element': 'PRIMARY FLYWHEEL', 'teeth': 60, 'gap': 2}
    w.update(kw)
    return {k: v for k, v in w.items() if v is not None}


def _bus(**kw):
    b = {'name': 'engine_speed', 'wheel': 'crank', 'period_s': 0.01, 'resolution_rpm': 0.125}
    b.update(kw)
    return {k: v for k, v in b.items() if v is not None}


BAD = [
    ({'edge_batch_s': -0.01, 'tooth_wheels': [_wheel()]}, ("'edge_batch_s'", '[0, 1]')),
    ({'edge_batch_s': 2.0, 'tooth_wheels': [_wheel()]}, ("'edge_batch_s'", 'got 2.0')),
    ({'edge_batch_s': float('nan'), 'tooth_wheels': [_wheel()]}, ("'edge_batch_s'",)),
    ({'tooth_wheels': [_wheel(teeth=0)]}, ('tooth_wheels[0] (crank)', "'teeth'", '[1, 3600]')),
    ({'tooth_wheels': [_wheel(teeth=-60)]}, ("'teeth'", 'got -60')),
    ({'tooth_wheels': [_wheel(teeth=60.5)]}, ("'teeth'", 'integer')),
    ({'tooth_wheels': [_wheel(gap=60)]}, ("'gap'", '[0, 59]', 'got 60')),
    ({'tooth_wheels': [_wheel(gap=-1)]}, ("'gap'",)),
    ({'tooth_wheels': [_wheel(timer_resolution_s=0.0)]}, ("'timer_resolution_s'", 'got 0.0')),
    ({'tooth_wheels': [_wheel(timer_resolution_s=-1e-7)]}, ("'timer_resolution_s'",)),
    ({'tooth_wheels': [_wheel(timer_jitter_s=math.nan)]}, ("'timer_jitter_s'", 'nan')),
    ({'tooth_wheels': [_wheel(offset_deg='.nan')]}, ("'offset_deg'",)),
    ({'tooth_wheels': [_wheel(element='FLYWHEEL X')]}, ("'element'", 'FLYWHEEL X')),
    ({'tooth_wheels': [_wheel(name='crank wheel')]}, ("'name'", 'topic')),
    ({'tooth_wheels': [_wheel(pitch_errors_deg=[0.0] * 60)]},
     ("'pitch_errors_deg'", 'list of 58 numbers')),
    ({'tooth_wheels': [_wheel(pitch_errors_deg=[0.0] * 57 + [math.nan])]},
     ("'pitch_errors_deg[57]'",)),
    ({'tooth_wheels': [_wheel(pitch_errors_deg=[0.0] * 57 + [3.0])]},
     ("'pitch_errors_deg[57]'", 'half a pitch')),
    ({'tooth_wheels': [_wheel(pitch_errors_deg=[0.0] * 58, pitch_error_sigma_deg=0.01)]},
     ('pitch_errors_deg', 'pitch_error_sigma_deg', 'not both')),
    ({'tooth_wheels': [_wheel(pitch_error_sigma_deg=1.0)]}, ("'pitch_error_sigma_deg'",)),
    ({'tooth_wheels': [_wheel(seed=-1)]}, ("'seed'",)),
    ({'tooth_wheels': [_wheel(teeth_count=60)]}, ("unknown key 'teeth_count'",)),
    ({'tooth_wheels': [_wheel(), _wheel()]}, ('tooth_wheels[1]', "'crank'", 'unique')),
    ({'tooth_wheels': [_wheel()], 'bus_signals': [_bus(name='crank')]},
     ('bus_signals[0]', "'crank'", 'unique')),
    ({'tooth_wheels': [_wheel()], 'bus_signals': [_bus(), _bus()]},
     ('bus_signals[1]', 'unique')),
    ({'tooth_wheels': [_wheel()], 'bus_signals': [_bus(resolution_rpm=0)]},
     ("'resolution_rpm'", '(0, 1000] rpm')),
    ({'tooth_wheels': [_wheel()], 'bus_signals': [_bus(resolution_rpm=-0.125)]},
     ("'resolution_rpm'",)),
    ({'tooth_wheels': [_wheel()], 'bus_signals': [_bus(period_s=math.nan)]}, ("'period_s'",)),
    ({'tooth_wheels': [_wheel()], 'bus_signals': [_bus(period_s=0)]}, ("'period_s'",)),
    ({'tooth_wheels': [_wheel()], 'bus_signals': [_bus(delay_s=-0.01)]}, ("'delay_s'",)),
    ({'tooth_wheels': [_wheel()], 'bus_signals': [_bus(noise_rpm=math.inf)]}, ("'noise_rpm'",)),
    ({'bus_signals': [_bus()]}, ("'wheel'", 'names no tooth wheel')),
    ({'bus_signals': [_bus(wheel=None, element='NOWHERE')]}, ("'element'", 'NOWHERE')),
    ({'bus_signals': [_bus(element='PRIMARY FLYWHEEL')]}, ("'wheel'", "'element'", 'not both')),
    ({'bus_signals': [_bus(wheel=None)]}, ("'wheel'", "'element'")),
    ({'tooth_wheels': {'name': 'crank'}}, ("'tooth_wheels'", 'list')),
    ({'wheels': []}, ("unknown key 'wheels'",)),
]


@pytest.mark.parametrize('section, needles', BAD)
def test_bad_sensor_input_is_one_line_naming_the_field(section, needles):
    data = raw()
    data['sensors'] = copy.deepcopy(section)
    with pytest.raises(ConfigError) as exc:
        driveline_from_dict(data, 'truck.yaml')
    msg = str(exc.value)
    assert '\n' not in msg
    for needle in needles:
        assert needle in msg, msg


def test_cli_refuses_a_bad_sensor_file_in_one_line(tmp_path, capsys):
    data = raw()
    data['sensors']['tooth_wheels'][0]['teeth'] = 0
    path = tmp_path / 'bad_truck.yaml'
    path.write_text(yaml.safe_dump(data))
    assert cli_main(['steady', '--config', str(path), '--speed', '1000']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and "'teeth'" in err and 'crank' in err, err
