"""Every physical field of every input file is bounded by the one table
(dmf_sim.core.bounds.BOUNDS): just inside its bound a file is accepted, just outside it is refused
in one line naming the field and the range; huge finite values (``inertia: 1e308``,
``stiffness: 1e300``, ``damping: 1e300``) never reach a solver."""
from __future__ import annotations

import copy
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from dmf_sim.cli import main as cli_main
from dmf_sim.core.bounds import BOUNDS, Bound
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.paths import config_dir


def _raw(name: str) -> dict:
    return yaml.safe_load((config_dir() / f'{name}.yaml').read_text())


BASE = {name: _raw(name) for name in ('truck_dmf', 'engine_d13', 'study_example',
                                      'optimize_example', 'durability', 'truck_dmf_friction')}


def _edges(b: Bound, positive: bool = False) -> tuple[list[float], list[float]]:
    """(values just inside, values just outside) the bound: the ends themselves where they are
    included, else the next float inward; the next float outward where they are included,
    else the ends."""
    lo_open = b.lo_open or (positive and b.lo == 0.0)
    lo_in = np.nextafter(b.lo, math.inf) if lo_open else b.lo
    hi_in = np.nextafter(b.hi, -math.inf) if b.hi_open else b.hi
    lo_out = b.lo if lo_open else np.nextafter(b.lo, -math.inf)
    hi_out = b.hi if b.hi_open else np.nextafter(b.hi, math.inf)
    inside, outside = [float(lo_in), float(hi_in)], [float(lo_out), float(hi_out)]
    if b.signed:
        inside += [-v for v in inside]
        outside = [float(np.nextafter(b.lo, 0.0)), float(hi_out)]
        outside += [-v for v in outside]
    return inside, outside


# ---- the files: load a changed copy ------------------------------------------------------------
def _driveline(d):
    from dmf_sim.physics.model import driveline_from_dict
    return driveline_from_dict(d, 'truck.yaml')


def _engine(d):
    from dmf_sim.physics.engine.config import engine_config
    return engine_config(d, config_dir() / 'engine_x.yaml')


def _study(d):
    from dmf_sim.design.study import study_from_dict
    return study_from_dict(d, 'study.yaml')


def _problem(d):
    from dmf_sim.optimize.problem import problem_from_dict
    return problem_from_dict(d, 'opt.yaml')


def _durability(d, tmp_path: Path):
    from dmf_sim.durability.settings import read_settings
    path = tmp_path / 'dur.yaml'
    path.write_text(yaml.safe_dump(d))
    return read_settings(path)


def _set(path: str):
    """A mutator setting the dotted ``path`` (list indices as numbers) to the value."""
    keys = [int(k) if k.lstrip('-').isdigit() else k for k in path.split('.')]

    def mutate(d, v):
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = v
    return mutate


def _section(d: dict, section: str) -> tuple[dict, str]:
    *outer, name = section.split('.')
    for k in outer:
        d = d[k]
    return d, name


def _table(section: str, y_key: str):
    """A one-point table (at 1000 rpm) whose y is the value."""
    def mutate(d, v):
        d, name = _section(d, section)
        d[name] = {'speeds_rpm': [1000.0], y_key: [v]}
    return mutate


def _speed_table(section: str, y_key: str, y: float):
    """A one-point table whose speed is the value."""
    def mutate(d, v):
        d, name = _section(d, section)
        d[name] = {'speeds_rpm': [v], y_key: [y]}
    return mutate


def _dmf_stages(attr: str):
    def mutate(d, v):
        stage = {'angle_rad': 0.24, 'stiffness_factor': 2.5, attr: v}
        d['dmf'] = {'element': 'SECONDARY FLYWHEEL', 'stages': [stage]}
    return mutate


def _capacity(d, v):
    d['optimizer']['constraints'].pop('capacity_factor', None)
    d['optimizer']['constraints']['capacity_nm'] = v


def _angle_step(d, v):
    d['variables']['stages[1].angle_step_rad'] = {'min': min(v, 0.005), 'max': max(v, 0.06)}


# (quantity, 0 excluded by the use, file, loader, mutator, the field as the message names it,
#  strict: True = accepted means the whole file loads; False = the file may still be refused
#  for a rule between fields (e.g. conrod > stroke/2), but never for this field's range)
E, G, C, S = 'elements', 'engine', 'combustion', 'gas_exchange'
CASES = [
    ('inertia', False, 'truck_dmf', _driveline, _set('elements.3.inertia'),
     "element 4 (CYL2): field 'inertia'", True),
    ('stiffness', False, 'truck_dmf', _driveline, _set('elements.3.stiffness'),
     "element 4 (CYL2): field 'stiffness'", True),
    ('damping', False, 'truck_dmf', _driveline, _set('elements.3.damping'),
     "element 4 (CYL2): field 'damping'", True),
    ('ratio', False, 'truck_dmf', _driveline, _set('elements.14.ratio'),
     "element 15 (COUNTER SHAFT): field 'ratio'", True),
    ('firing_phase', False, 'truck_dmf', _driveline, _set('firing_phases_deg.1'),
     "truck.yaml: field 'firing_phases_deg[1]'", True),
    ('windup_angle', False, 'truck_dmf', _driveline, _set('dmf.theta_rad'),
     "dmf: field 'theta_rad'", True),
    ('stiffness_factor', False, 'truck_dmf', _driveline, _set('dmf.alpha'),
     "dmf: field 'alpha'", True),
    ('windup_angle', False, 'truck_dmf', _driveline, _dmf_stages('angle_rad'),
     "dmf.stages[0]: field 'angle_rad'", True),
    # the DMF's arc-spring friction and end stops
    ('friction_torque', False, 'truck_dmf_friction', _driveline, _set('dmf.friction.torque_nm'),
     "dmf.friction: field 'torque_nm'", True),
    ('friction_speed_coefficient', False, 'truck_dmf_friction', _driveline,
     _set('dmf.friction.speed_coefficient'), "dmf.friction: field 'speed_coefficient'", True),
    ('friction_regularization', False, 'truck_dmf_friction', _driveline,
     _set('dmf.friction.regularization_rad_s'), "dmf.friction: field 'regularization_rad_s'",
     True),
    ('windup_angle', False, 'truck_dmf_friction', _driveline,
     _set('dmf.end_stops.drive_angle_rad'), "dmf.end_stops: field 'drive_angle_rad'", False),
    ('stiffness', True, 'truck_dmf_friction', _driveline, _set('dmf.end_stops.stiffness'),
     "dmf.end_stops: field 'stiffness'", True),
    ('damping', False, 'truck_dmf_friction', _driveline, _set('dmf.end_stops.damping'),
     "dmf.end_stops: field 'damping'", True),
    ('stiffness_factor', False, 'truck_dmf', _driveline, _dmf_stages('stiffness_factor'),
     "dmf.stages[0]: field 'stiffness_factor'", True),
    # the engine file
    ('firing_phase', False, 'engine_d13', _engine, _set('firing_phases_deg.1'),
     "field 'firing_phases_deg[1]'", True),
    ('bore', False, 'engine_d13', _engine, _set('geometry.bore_m'),
     "field 'geometry.bore_m'", True),
    ('stroke', False, 'engine_d13', _engine, _set('geometry.stroke_m'),
     "field 'geometry.stroke_m'", False),
    ('conrod', False, 'engine_d13', _engine, _set('geometry.conrod_m'),
     "field 'geometry.conrod_m'", False),
    ('compression_ratio', False, 'engine_d13', _engine, _set('geometry.compression_ratio'),
     "field 'geometry.compression_ratio'", True),
    ('oscillating_mass', False, 'engine_d13', _engine, _set('geometry.oscillating_mass_kg'),
     "field 'geometry.oscillating_mass_kg'", True),
    ('engine_speed', True, 'engine_d13', _engine, _set('load_sets.limit_rpm'),
     "field 'load_sets.limit_rpm'", False),
    ('engine_speed', False, 'engine_d13', _engine,
     _speed_table('full_load_curve', 'torque_nm', 2000.0),
     "field 'full_load_curve.speeds_rpm[0]'", True),
    ('torque', False, 'engine_d13', _engine, _table('full_load_curve', 'torque_nm'),
     "field 'full_load_curve.torque_nm[0]'", True),
    ('ambient_pressure', False, 'engine_d13', _engine, _set(f'{S}.ambient_pa'),
     f"field '{S}.ambient_pa'", True),
    ('ambient_pressure', False, 'engine_d13', _engine, _set(f'{S}.crankcase_pa'),
     f"field '{S}.crankcase_pa'", True),
    ('ivc_angle', False, 'engine_d13', _engine, _set(f'{S}.ivc_deg'),
     f"field '{S}.ivc_deg'", True),
    ('evo_angle', False, 'engine_d13', _engine, _set(f'{S}.evo_deg'),
     f"field '{S}.evo_deg'", True),
    ('blowdown_duration', False, 'engine_d13', _engine, _set(f'{S}.blowdown_deg'),
     f"field '{S}.blowdown_deg'", True),
    ('valve_overlap', False, 'engine_d13', _engine, _set(f'{S}.overlap_deg'),
     f"field '{S}.overlap_deg'", True),
    ('boost_pressure', False, 'engine_d13', _engine,
     _table(f'{S}.boost_gauge_full_load', 'pressure_pa'),
     f"field '{S}.boost_gauge_full_load.pressure_pa[0]'", True),
    ('exhaust_backpressure', False, 'engine_d13', _engine,
     _set(f'{S}.exhaust_backpressure_zero_load_pa'),
     f"field '{S}.exhaust_backpressure_zero_load_pa'", True),
    ('exhaust_backpressure', False, 'engine_d13', _engine,
     _set(f'{S}.exhaust_backpressure_full_load_pa'),
     f"field '{S}.exhaust_backpressure_full_load_pa'", True),
    ('polytropic_exponent', False, 'engine_d13', _engine, _set(f'{C}.polytropic_exponent'),
     f"field '{C}.polytropic_exponent'", True),
    ('wiebe_efficiency', False, 'engine_d13', _engine, _set(f'{C}.wiebe_a'),
     f"field '{C}.wiebe_a'", True),
    ('combustion_start', False, 'engine_d13', _engine, _table(f'{C}.start_deg', 'angle_deg'),
     f"field '{C}.start_deg.angle_deg[0]'", True),
    ('fraction', False, 'engine_d13', _engine, _set(f'{C}.premixed_fraction_zero_load'),
     f"field '{C}.premixed_fraction_zero_load'", True),
    ('fraction', False, 'engine_d13', _engine, _set(f'{C}.premixed_fraction_full_load'),
     f"field '{C}.premixed_fraction_full_load'", True),
    ('premixed_duration', False, 'engine_d13', _engine, _set(f'{C}.premixed_duration_deg'),
     f"field '{C}.premixed_duration_deg'", True),
    ('wiebe_shape', False, 'engine_d13', _engine, _set(f'{C}.premixed_shape'),
     f"field '{C}.premixed_shape'", True),
    ('diffusion_duration', False, 'engine_d13', _engine,
     _table(f'{C}.diffusion_duration_full_load_deg', 'duration_deg'),
     f"field '{C}.diffusion_duration_full_load_deg.duration_deg[0]'", True),
    ('duration_factor', False, 'engine_d13', _engine,
     _set(f'{C}.diffusion_duration_zero_load_factor'),
     f"field '{C}.diffusion_duration_zero_load_factor'", True),
    ('wiebe_shape', False, 'engine_d13', _engine, _set(f'{C}.diffusion_shape'),
     f"field '{C}.diffusion_shape'", True),
    ('brake_torque', False, 'engine_d13', _engine, _table('brake_curve', 'torque_nm'),
     "field 'brake_curve.torque_nm[0]'", True),
    ('brake_charge_duration', False, 'engine_d13', _engine,
     _set('compression_release_brake.charge_duration_deg'),
     "field 'compression_release_brake.charge_duration_deg'", True),
    ('brake_release_angle', False, 'engine_d13', _engine,
     _set('compression_release_brake.release_deg'),
     "field 'compression_release_brake.release_deg'", True),
    ('blowdown_duration', False, 'engine_d13', _engine,
     _set('compression_release_brake.release_duration_deg'),
     "field 'compression_release_brake.release_duration_deg'", True),
    ('brake_close_angle', False, 'engine_d13', _engine,
     _set('compression_release_brake.close_deg'),
     "field 'compression_release_brake.close_deg'", True),
    # the design study file
    ('stiffness', True, 'study_example', _study, _set('fixed.k'),
     "study.yaml: field 'fixed.k'", True),
    ('damping', False, 'study_example', _study, _set('fixed.damping'),
     "study.yaml: field 'fixed.damping'", True),
    ('windup_angle', False, 'study_example', _study, _set('plots.reference.theta'),
     "study.yaml: field 'plots.reference.theta'", True),
    ('stiffness_factor', False, 'study_example', _study, _set('plots.reference.alpha'),
     "study.yaml: field 'plots.reference.alpha'", True),
    ('engine_speed', False, 'study_example', _study, _set('conditions.speeds_rpm.from'),
     "study.yaml: field 'conditions.speeds_rpm.from'", False),
    ('engine_speed', False, 'study_example', _study, _set('conditions.speeds_rpm.to'),
     "study.yaml: field 'conditions.speeds_rpm.to'", False),
    ('engine_speed', True, 'study_example', _study, _set('conditions.speeds_rpm.step'),
     "study.yaml: field 'conditions.speeds_rpm.step'", False),
    ('load', False, 'study_example', _study, _set('conditions.loads.0'),
     "study.yaml: field 'conditions.loads[0]'", True),
    # the optimizer file
    ('windup_angle', False, 'optimize_example', _problem, _angle_step,
     "opt.yaml: field 'variables.stages[1].angle_step_rad.m", False),
    ('windup_angle', False, 'optimize_example', _problem,
     _set('optimizer.constraints.max_travel_rad'),
     "opt.yaml: optimizer.constraints: field 'max_travel_rad'", True),
    ('torque', True, 'optimize_example', _problem, _capacity,
     "opt.yaml: optimizer.constraints: field 'capacity_nm'", True),
    # the durability settings
    ('sn_exponent', False, 'durability', _durability, _set('sn_curve.exponent'),
     "field 'sn_curve.exponent'", True),
    ('torque_range', True, 'durability', _durability, _set('sn_curve.reference_range_nm'),
     "field 'sn_curve.reference_range_nm'", True),
    ('sn_cycles', False, 'durability', _durability, _set('sn_curve.reference_cycles'),
     "field 'sn_curve.reference_cycles'", True),
    ('torque_range', False, 'durability', _durability, _set('sn_curve.endurance_range_nm'),
     "field 'sn_curve.endurance_range_nm'", True),
]
IDS = [f'{c[2]}:{c[5].split("field ")[-1]}' for c in CASES]


def _load(case, value, tmp_path):
    quantity, _, base, loader, mutate, _, _ = case
    d = copy.deepcopy(BASE[base])
    mutate(d, value)
    return loader(d, tmp_path) if loader is _durability else loader(d)


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_just_inside_the_bound_is_accepted(case, tmp_path):
    quantity, positive, _, _, _, field, strict = case
    for value in _edges(BOUNDS[quantity], positive)[0]:
        try:
            _load(case, value, tmp_path)
        except ConfigError as exc:
            assert not strict, f'{value!r} refused: {exc}'
            assert f'{field}' not in str(exc) or 'must be in' not in str(exc), str(exc)


@pytest.mark.parametrize('case', CASES, ids=IDS)
def test_just_outside_the_bound_is_one_line_naming_the_field(case, tmp_path):
    quantity, positive, _, _, _, field, _ = case
    b = BOUNDS[quantity]
    if positive:
        b = replace(b, lo_open=True)
    for value in _edges(b)[1]:
        with pytest.raises(ConfigError) as e:
            _load(case, value, tmp_path)
        msg = str(e.value)
        assert field in msg and '\n' not in msg, (value, msg)
        rng = b.text().split(' ')[1]            # '(0,' / '[0,': the range as written
        assert rng in msg and f'got {value!r}' in msg, (value, msg)


INDIRECT = {'cylinder_pressure': 'no file field holds it: it bounds the A_n of a coefficient '
                                 'table (test_user_mistakes.py, the table beyond any cylinder '
                                 'pressure)',
            'brake_manifold_pressure': 'no file field holds it: it bounds the manifold pressure '
                                       'calibrated to the brake curve (test_engine_braking.py, '
                                       'a brake curve this brake cannot give)'}


def test_every_bound_of_the_table_is_tested():
    assert {c[0] for c in CASES} | set(INDIRECT) == set(BOUNDS)
    for name, b in BOUNDS.items():
        assert b.lo < b.hi and len(b.reason) > 20, name


def test_the_library_route_uses_the_same_bounds():
    from dmf_sim.design.parameters import design_driveline, parse_parameter
    from dmf_sim.physics.model import read_driveline
    line = read_driveline('truck_dmf')
    with pytest.raises(ConfigError, match=r"dmf: field 'damping' must be in \[0, 1e\+06\]"):
        line.with_dmf(damping=1e300)
    with pytest.raises(ConfigError, match=r"dmf: field 'k' must be in \(0, 1e\+10\] Nm/rad"):
        line.with_dmf(k=1e300)
    assert line.with_dmf(k=1e10, damping=1e6).dmf_element.damping == 1e6
    k = parse_parameter('k', 'study')
    assert design_driveline(line, {k: 1e10}).spring.k == 1e10


def test_node_dmf_parameters_share_the_bounds():
    from dmf_sim.live.parameters import DMF_PARAMETERS
    assert DMF_PARAMETERS['alpha'].range[1] == BOUNDS['stiffness_factor'].hi
    assert DMF_PARAMETERS['theta'].range[1] == BOUNDS['windup_angle'].hi


# ---- the three reported cases through the command line -----------------------------------------
def _driveline_file(tmp_path, old: str, new: str) -> Path:
    text = (config_dir() / 'truck_dmf.yaml').read_text()
    assert old in text
    path = tmp_path / 'truck.yaml'
    path.write_text(text.replace(old, new, 1))
    return path


def _refused(argv, capsys, expected: str) -> None:
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.strip().endswith(expected), err


def test_cli_huge_inertia_is_refused_before_a_run(tmp_path, capsys):
    """`inertia: 1e308` gave a bag of 0 samples, overflow warnings and exit 0."""
    path = _driveline_file(tmp_path, '{name: CYL2, ratio: 1, stiffness: 3088151, damping: 0, '
                           'inertia: 0.1065}', '{name: CYL2, ratio: 1, stiffness: 3088151, '
                           'damping: 0, inertia: 1e308}')
    bag = tmp_path / 'bag'
    _refused(['run', 'ramp:800:900:100', '--out', str(bag), '--config', str(path)], capsys,
             "dmf-sim run: error: element 4 (CYL2): field 'inertia' must be in (0, 1e+06] kg m^2, "
             'got 1e+308')
    assert not bag.exists()


def test_cli_huge_stiffness_is_refused_and_the_bound_itself_gives_modes(tmp_path, capsys):
    """`stiffness: 1e300` gave modes of 0.00 Hz."""
    old = '{name: CYL1, ratio: 1, stiffness: 4440282,'
    path = _driveline_file(tmp_path, old, '{name: CYL1, ratio: 1, stiffness: 1e300,')
    _refused(['modes', '--config', str(path)], capsys,
             "element 3 (CYL1): field 'stiffness' must be in [0, 1e+10] Nm/rad or 'rigid', "
             'got 1e+300')
    path = _driveline_file(tmp_path, old, '{name: CYL1, ratio: 1, stiffness: 1.0e+10,')
    assert cli_main(['modes', '--config', str(path), '--json']) == 0
    import json
    f = np.array(json.loads(capsys.readouterr().out)['frequencies_hz'])
    reference = modes_of('truck_dmf')
    assert f[0] == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(f[1:6], reference[1:6], rtol=1e-4)     # CYL1 nearly rigid


def modes_of(name: str) -> np.ndarray:
    from dmf_sim.physics.modal import modes
    from dmf_sim.physics.model import read_model
    return modes(read_model(name)).frequencies_hz


def test_cli_study_with_huge_damping_is_refused_before_any_design(tmp_path, capsys):
    """A study with `damping: 1e300` ended with every design failed on 'state matrix not
    diagonalizable (4.8e+299)'."""
    d = copy.deepcopy(BASE['study_example'])
    d['variables'] = {'alpha': d['variables']['alpha'],
                      'damping': {'min': 10, 'max': '1e300', 'n': 2}}
    d['plots']['map_variables'] = ['alpha', 'damping']
    path = tmp_path / 'study.yaml'
    path.write_text(yaml.safe_dump(d).replace("'1e300'", '1e300'))
    _refused(['design', str(path), '--out', str(tmp_path / 'out')], capsys,
             f"{path}: field 'variables.damping.max' must be in [0, 1e+06] Nms/rad, "
             'got 1e+300')
    assert not (tmp_path / 'out').exists()
