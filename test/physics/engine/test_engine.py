"""Tests of the engine excitation (dmf_sim.physics.engine): default pressure model, ratings,
tables, Load A/B/C, and how bad engine files are reported."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from support.nested_edit import DELETE, edited

from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.paths import config_file
from dmf_sim.physics.engine import (
    LOAD_SETS,
    EngineExcitation,
    cylinder_torque_signal,
    engine_from_mapping,
    engine_torque_orders,
    read_engine,
    write_coefficient_table,
)
from dmf_sim.physics.model import read_model

N_MAX = 24
THIRD, SIXTH = 6, 12      # half-order indices of the 3rd and 6th engine orders


@pytest.fixture(scope='module')
def engines():
    a = read_engine('engine_d13', 'A')
    a.warm_up()
    return {'A': a, 'B': a.with_load_set('B'), 'C': a.with_load_set('C')}


@pytest.fixture(scope='module')
def engine(engines):
    return engines['A']


@pytest.fixture(scope='module')
def curve():
    doc = yaml.safe_load(config_file('engine_d13').read_text())['full_load_curve']
    return lambda s: float(np.interp(s, doc['speeds_rpm'], doc['torque_nm']))


@pytest.fixture()
def base_yaml() -> dict:
    return yaml.safe_load(config_file('engine_d13').read_text())


def _one_line_error(excinfo, *needles: str) -> None:
    assert isinstance(excinfo.value, ConfigError), type(excinfo.value)   # the CLI's exit 2
    msg = str(excinfo.value)
    assert '\n' not in msg, msg
    for needle in needles:
        assert needle in msg, msg


# ------------------------------------------------------------------------------------------------
def test_config_and_api(engine):
    assert config_file('engine_d13').name == 'engine_d13.yaml'
    assert set(LOAD_SETS) == {'A', 'B', 'C'}
    assert isinstance(engine, EngineExcitation)
    assert engine.n_cylinders == 6 and engine.n_max == N_MAX
    np.testing.assert_array_equal(engine.firing_phases_deg, [0, 480, 240, 600, 120, 360])
    A = engine.coefficients(1000, 1.0)
    assert A.shape == (N_MAX + 1,) and A.dtype == complex
    assert A[0].imag == 0.0
    assert engine.mean_torque(1000, 1.0) == pytest.approx(6 * A[0].real)


@pytest.mark.parametrize('name', ['A', 'B', 'C'])
def test_mean_torque_follows_curve(engines, curve, name):
    eng = engines[name]
    shift = {'A': 0, 'B': 50, 'C': 100}[name]
    for s in np.arange(600, 2001, 25.0):
        expected = curve(min(s + shift, max(s, 1000)))
        assert eng.full_load_torque(s) == pytest.approx(expected, rel=1e-12)
        assert eng.mean_torque(s, 1.0) == pytest.approx(expected, rel=0.01, abs=1.0)
        assert eng.mean_torque(s, 0.5) == pytest.approx(0.5 * expected, rel=0.01, abs=1.0)
        assert abs(eng.mean_torque(s, 0.0)) < 1.0
    # B/C give more torque at low speed, nothing changes above 1000 rpm
    assert engines['C'].full_load_torque(700) > engines['B'].full_load_torque(700) > curve(700)
    assert engines['C'].full_load_torque(1200) == curve(1200)


def test_rigid_crank_orders(engine):
    for s in (600, 1000, 1400, 1800):
        for load in (0.0, 0.5, 1.0):
            B = engine_torque_orders(engine, s, load)
            n = np.arange(B.size)
            survivors = n % 6 == 0
            assert np.max(np.abs(B[~survivors])) < 1e-9 * np.max(np.abs(B))
            assert B[0] == pytest.approx(engine.mean_torque(s, load))
            if load == 1.0:   # the 3rd order dominates the alternating part
                assert np.argmax(np.abs(B[1:])) + 1 == THIRD


def test_third_and_sixth_order_at_full_load(engine):
    for s in (600, 800, 1000):
        B = engine_torque_orders(engine, s, 1.0)
        assert 1.2 < abs(B[THIRD]) / B[0].real < 2.5, s
        assert 0.2 < abs(B[SIXTH]) / abs(B[THIRD]) < 0.7, s
    r = engine.model.cycle(1400, 1.0)   # peak firing pressure of a current truck diesel
    assert 170e5 < r.peak_pressure_pa < 240e5


def test_gas_and_inertia_oppose_in_third_order(engine):
    for s in (800, 1400, 2000):
        g = engine.gas_coefficients(s, 0.0)[THIRD]
        i = engine.inertia_coefficients(s)[THIRD]
        assert abs(np.angle(g / i, deg=True)) > 150.0
    speeds = np.arange(600, 2201, 50.0)
    third = [abs(engine_torque_orders(engine, s, 0.0)[THIRD]) for s in speeds]
    s_min = speeds[int(np.argmin(third))]
    assert 1100 <= s_min <= 1800
    assert min(third) < 0.2 * third[0]
    # at full load the 3rd order shrinks at high speed
    assert (abs(engine_torque_orders(engine, 1800, 1.0)[THIRD])
            < abs(engine_torque_orders(engine, 1200, 1.0)[THIRD]))


def test_truncation_error_full_load(engine):
    model = engine.model
    for s in range(600, 1901, 100):
        r = model.cycle(s, 1.0)
        A = model.gas_coefficients(s, 1.0) + model.inertia_coefficients(s)
        psi = np.radians(r.psi_deg)
        series = cylinder_torque_signal(A, psi, 0.0)   # eq. 16
        err = np.sqrt(np.mean((r.torque_nm - series) ** 2) / np.mean(r.torque_nm ** 2))
        assert err < 0.01, (s, err)
        assert model.truncation_error(s, 1.0) == pytest.approx(err, rel=1e-6)
    # part load: the motored compression peak is sharper, error stays a few percent
    assert max(model.truncation_error(s, ld) for s in (600, 1400, 2200) for ld in (0, 0.5)) < 0.03


def test_cylinder_signal_phase(engine):
    A = engine.coefficients(1200, 0.8)
    psi = np.linspace(0, 4 * np.pi, 97)
    beta = np.radians(480.0)
    np.testing.assert_allclose(cylinder_torque_signal(A, psi, beta),
                               cylinder_torque_signal(A, psi - beta, 0.0), atol=1e-9)
    psi = np.linspace(0, 4 * np.pi, 720, endpoint=False)
    assert np.mean(cylinder_torque_signal(A, psi, 0.0)) == pytest.approx(A[0].real)


def test_load_sets_shift_gas_part_only(engines):
    a, b, c = engines['A'], engines['B'], engines['C']
    for s_b, s_a, eng in ((900, 950, b), (980, 1000, b), (1000, 1000, b), (1200, 1200, b),
                          (600, 700, c), (850, 950, c), (950, 1000, c), (1500, 1500, c)):
        for load in (0.3, 1.0):
            np.testing.assert_allclose(eng.gas_coefficients(s_b, load),
                                       a.gas_coefficients(s_a, load), rtol=0, atol=1e-9)
        np.testing.assert_allclose(eng.inertia_coefficients(s_b), a.inertia_coefficients(s_b))
        np.testing.assert_allclose(eng.coefficients(s_b, 1.0), a.gas_coefficients(s_a, 1.0)
                                   + a.inertia_coefficients(s_b), atol=1e-9)


def test_load_changes_only_gas_part(engine):
    for s in (700, 1300, 2100):
        full, zero = engine.coefficients(s, 1.0), engine.coefficients(s, 0.0)
        gas = engine.gas_coefficients
        np.testing.assert_allclose(full - zero, gas(s, 1.0) - gas(s, 0.0), atol=1e-9)
        r0, r1 = engine.model.cycle(s, 0.0), engine.model.cycle(s, 1.0)
        np.testing.assert_array_equal(r0.inertia_torque_nm, r1.inertia_torque_nm)
        assert np.max(np.abs(gas(s, 0.0)[1:])) > 100.0   # motored torque remains
        assert r1.heat_release_j > r0.heat_release_j >= 0.0


def test_cache_interpolation_close_to_exact(engine):
    for s, load in ((1234.0, 0.6), (777.0, 0.9), (1975.0, 0.1)):
        exact = engine.model.gas_coefficients(s, load) + engine.model.inertia_coefficients(s)
        interp = engine.coefficients(s, load)
        assert abs(interp[THIRD] - exact[THIRD]) < 0.02 * abs(exact[THIRD])
        assert abs(interp[0] - exact[0]) < 0.01 * max(abs(exact[0]), 100.0)


def test_warm_query_is_fast(engine):
    speeds = np.linspace(600, 2100, 2000)
    t0 = time.process_time()          # CPU time: the same when both cores are busy
    for s in speeds:
        engine.coefficients(s, 0.7)
    per_call = (time.process_time() - t0) / speeds.size
    assert per_call < 1e-3


def test_bad_queries(engine):
    with pytest.raises(ValueError) as exc:
        engine.coefficients(3000, 0.5)
    _one_line_error(exc, 'speed_rpm', '400', '2200')
    with pytest.raises(ValueError) as exc:
        engine.coefficients(1000, 1.5)
    _one_line_error(exc, 'load', '[-1, 1]')        # the default engine brakes: -1..1
    with pytest.raises(ValueError):
        engine.coefficients(float('nan'), 0.5)
    with pytest.raises(ValueError) as exc:
        read_engine('engine_d13', 'D')
    _one_line_error(exc, 'load_set', 'A')


@pytest.mark.parametrize('load_set', ['A', 'B', 'C'])
def test_vectorized_query_equals_one_by_one(engines, load_set):
    """coefficients_many (a sweep's batch of speeds) gives bitwise the values of one query per
    speed, at grid nodes, between them and at the ends; a bad speed or load is refused with the
    same one-line message."""
    eng = engines[load_set]
    lo, hi = eng.speed_range_rpm
    speeds = np.concatenate([np.linspace(lo, hi, 301), [lo, hi, 1000.0, 1000.05, 1234.5678]])
    for load in (1.0, 0.37, 0.0, -0.37, -1.0):
        one = np.stack([eng.coefficients(s, load) for s in speeds.tolist()])
        assert np.array_equal(eng.coefficients_many(speeds, load), one)
    for bad_speed, load, needles in ((hi + 1.0, 0.5, ('speed_rpm', '2200')),
                                     (float('nan'), 0.5, ('speed_rpm',)),
                                     (1000.0, 1.5, ('load', '[-1, 1]'))):
        with pytest.raises(ValueError) as exc:
            eng.coefficients_many([1000.0, bad_speed], load)
        _one_line_error(exc, *needles)
        with pytest.raises(ValueError) as ref:
            eng.coefficients(bad_speed, load)
        assert str(exc.value) == str(ref.value)


# ------------------------------------------------------------------------------------------------
# User tables
# ------------------------------------------------------------------------------------------------
def test_example_table_matches_model(engine):
    table = read_engine('engine_table_example.csv')
    assert config_file('engine_table_example.csv').stat().st_size < 100_000
    assert table.n_max == N_MAX and table.speed_range_rpm == (600.0, 2000.0)
    for s in (600, 1000, 1700):
        for load in (0.0, 0.5, 1.0):
            np.testing.assert_allclose(table.coefficients(s, load), engine.coefficients(s, load),
                                       rtol=0, atol=1e-3)
    assert table.full_load_torque(1000) == pytest.approx(2800.0, rel=1e-5)
    assert table.mean_torque(1250, 0.75) == pytest.approx(engine.mean_torque(1250, 0.75), rel=1e-3)
    # load sets work on tables too
    tb = read_engine('engine_table_example.csv', 'B')
    np.testing.assert_allclose(tb.gas_coefficients(900, 1.0), table.gas_coefficients(950, 1.0))


def test_full_load_table_scales_gas_part(engine, tmp_path):
    path = write_coefficient_table(engine, tmp_path / 'full.csv', [600, 1000, 1500, 2000])
    tab = read_engine(path)
    for s in (600, 1000, 1500):
        close = lambda a, b: np.testing.assert_allclose(a, b, atol=1e-3)  # noqa: E731
        close(tab.coefficients(s, 1.0), engine.coefficients(s, 1.0))
        close(tab.coefficients(s, 0.0), engine.inertia_coefficients(s))
        close(tab.gas_coefficients(s, 0.4), 0.4 * engine.gas_coefficients(s, 1.0))
    assert tab.mean_torque(1000, 0.4) == pytest.approx(0.4 * engine.full_load_torque(1000),
                                                       rel=1e-5)


def test_yaml_table(engine, tmp_path):
    speeds, loads = [800, 1200, 1600], [0.0, 1.0]
    coeffs = [[[[float(a.real), 0.0 if n == 0 else float(a.imag)]
                for n, a in enumerate(engine.coefficients(s, ld))] for ld in loads]
              for s in speeds]
    doc = {'engine': 'engine_d13', 'speeds_rpm': speeds, 'loads': loads,
           'orders': list(range(N_MAX + 1)), 'coefficients': coeffs}
    path = tmp_path / 'tab.yaml'
    path.write_text(yaml.safe_dump(doc))
    tab = read_engine(path, 'C')
    np.testing.assert_allclose(tab.coefficients(1200, 1.0), engine.coefficients(1200, 1.0),
                               atol=1e-9)
    # without a load axis: full-load data
    doc2 = dict(doc, loads=None, coefficients=[c[1] for c in coeffs])
    del doc2['loads']
    path.write_text(yaml.safe_dump(doc2))
    np.testing.assert_allclose(read_engine(path).coefficients(1600, 1.0),
                               engine.coefficients(1600, 1.0), atol=1e-9)
    doc2['orders'] = list(range(N_MAX))
    path.write_text(yaml.safe_dump(doc2))
    with pytest.raises(ValueError) as exc:
        read_engine(path)
    _one_line_error(exc, 'coefficients', 'shape')


def _csv(tmp_path: Path, rows: list[str], header: str = 'speed_rpm,n,re,im') -> Path:
    path = tmp_path / 'bad.csv'
    path.write_text('\n'.join([header] + rows) + '\n')
    return path


def _rows(speeds, orders=range(N_MAX + 1), value='1.0,0.5'):
    return [f'{s},{n},{value if n else "100,0"}' for s in speeds for n in orders]


@pytest.mark.parametrize('rows, header, needles', [
    (_rows([800, 1000], orders=[n for n in range(N_MAX + 1) if n != 7]), None,
     ('n', 'missing', '7')),
    (_rows([1000, 800]), None, ('speed_rpm', 'non-decreasing')),
    (_rows([800, 1000], value='nan,0'), None, ('re', 'finite')),
    (_rows([800, 1000], value='1,inf'), None, ('im', 'finite')),
    (_rows([800, 9000]), None, ('speed_rpm', '100', '5000')),
    (_rows([800]), None, ('speed_rpm', 'at least 2')),
    (_rows([800, 1000]), 'rpm,n,re,im', ('header', 'speed_rpm,n,re,im')),
    ([r.replace(',0,100,0', ',0,100,3') for r in _rows([800, 1000])], None, ('im', 'A_0', 'real')),
    (_rows([800, 1000]) + ['1000,3,1,1'], None, ('n', 'duplicate')),
])
def test_bad_tables_refused(tmp_path, rows, header, needles):
    path = _csv(tmp_path, rows, header or 'speed_rpm,n,re,im')
    with pytest.raises(ValueError) as exc:
        read_engine(path)
    _one_line_error(exc, 'bad.csv', *needles)


def test_minimal_good_csv(tmp_path):
    eng = read_engine(_csv(tmp_path, _rows([800, 1000])))
    assert eng.mean_torque(900, 1.0) == pytest.approx(600.0)


# ------------------------------------------------------------------------------------------------
# Engine YAML validation
# ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize('field, value, needles', [
    ('geometry.bore_m', -0.131, ('geometry.bore_m', '(0, 2]')),
    ('geometry.bore_m', DELETE, ('geometry.bore_m', 'missing')),
    ('geometry.piston_mass', 3.0, ('geometry.piston_mass', 'unknown')),
    ('geometry.conrod_m', 0.05, ('geometry.conrod_m', 'crank radius')),
    ('geometry.compression_ratio', 'high', ('geometry.compression_ratio', 'number')),
    ('n_cylinders', 0, ('n_cylinders', '[1, 24]')),
    ('firing_phases_deg', [0, 480, 240], ('firing_phases_deg', '6')),
    ('n_max', 100, ('n_max', '[1, 48]')),
    ('combustion', DELETE, ('combustion', 'missing')),
    ('combustion.polytropic_exponent', 0.9, ('combustion.polytropic_exponent', '1.67')),
    ('full_load_curve.speeds_rpm', [1000, 800], ('full_load_curve.speeds_rpm', 'increasing')),
    ('grid.loads', [0.25, 1.0], ('grid.loads', 'start at 0')),
    ('grid.speed_step_rpm', 70, ('grid.speed_step_rpm', 'divide')),
    # min above max: both fields named, whichever was changed (not speed_max_rpm blamed)
    ('grid.speed_min_rpm', 3000, ("'grid.speed_min_rpm' and 'grid.speed_max_rpm'",
                                  'speed_min_rpm < speed_max_rpm, got 3000 and 2200 rpm')),
    ('grid.speed_max_rpm', 300, ("'grid.speed_min_rpm' and 'grid.speed_max_rpm'",
                                 'got 400 and 300 rpm')),
    ('load_sets.shift_rpm', {'B': 50}, ('load_sets.shift_rpm', 'A')),
    ('load_sets.shift_rpm.C', 2000, ('load_sets.shift_rpm.C', '[0, 1000)')),
    ('gas_exchange.evo_deg', float('nan'), ('gas_exchange.evo_deg', '[90, 200]')),
    ('wheels', 4, ('wheels', 'unknown')),
])
def test_bad_engine_yaml_refused(tmp_path, base_yaml, field, value, needles):
    path = tmp_path / 'engine_bad.yaml'
    path.write_text(yaml.safe_dump(edited(base_yaml, field.split('.'), value)))
    with pytest.raises(ValueError) as exc:
        read_engine(path)
    _one_line_error(exc, 'engine_bad.yaml', *needles)


def test_bad_table_references_and_yaml_fields(tmp_path):
    path = tmp_path / 'ref.csv'
    path.write_text('# engine: no_such_engine\n'
                    + '\n'.join(['speed_rpm,n,re,im'] + _rows([800, 1000])))
    with pytest.raises(ValueError) as exc:
        read_engine(path)
    _one_line_error(exc, 'ref.csv', 'engine', 'no_such_engine')
    doc = {'speeds_rpm': [1000, 800], 'orders': [0, 1, 2],
           'coefficients': [[[100, 0], [1, 1], [2, 2]]] * 2}
    ypath = tmp_path / 'tab.yaml'
    ypath.write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError) as exc:
        read_engine(ypath)
    _one_line_error(exc, 'tab.yaml', 'speeds_rpm', 'increasing')
    doc['speeds_rpm'] = [800, 1000]
    doc['coefficients'][1] = [[100, 0], [float('nan'), 1], [2, 2]]
    ypath.write_text(yaml.safe_dump(doc))
    with pytest.raises(ValueError) as exc:
        read_engine(ypath)
    _one_line_error(exc, 'tab.yaml', 'coefficients', 'finite')


# ------------------------------------------------------------------------------------------------
# Ratings: the default reaches the DMF knee, the 2500 Nm rating is the same engine otherwise
# ------------------------------------------------------------------------------------------------
def test_default_rating_reaches_the_dmf_knee(engine):
    """The default 13-litre curve has a ~2800 Nm plateau reached by 1000 rpm, above the
    paper DMF's knee torque k theta, so full Load A puts the mean wind-up at the knee."""
    spring = read_model('truck_dmf').spring
    knee_torque = spring.k * spring.theta
    assert knee_torque == pytest.approx(2613.6)
    plateau = [engine.full_load_torque(s) for s in np.arange(1000, 1301, 50.0)]
    assert np.allclose(plateau, 2800.0)
    assert max(engine.full_load_torque(s) for s in np.arange(600, 2201, 10.0)) == 2800.0
    assert engine.full_load_torque(900) < knee_torque < engine.full_load_torque(1000)
    r = engine.model.cycle(1200, 1.0)   # still a plausible truck diesel peak pressure
    assert 170e5 < r.peak_pressure_pa < 240e5


def test_2500nm_rating_shares_everything_but_the_curve(engine):
    low = read_engine('engine_d13_2500nm', 'B')
    assert low.config.name == 'engine_d13_2500nm'
    assert low.config.path.name == 'engine_d13_2500nm.yaml'
    assert low.full_load_torque(1200) == 2500.0 and low.full_load_torque(950) == 2500.0
    assert max(low.full_load_torque(s) for s in np.arange(600, 2201, 10.0)) < 2614.0
    assert low.config.geometry == engine.config.geometry
    np.testing.assert_array_equal(low.config.grid.speeds_rpm, engine.config.grid.speeds_rpm)
    for s in (700, 1250, 1900):      # load 0: no combustion, so the rating does not matter
        np.testing.assert_allclose(low.with_load_set('A').coefficients(s, 0.0),
                                   engine.coefficients(s, 0.0), atol=1e-9)
    assert low.mean_torque(1200, 0.5) == pytest.approx(1250.0, rel=1e-3)


def test_engine_from_mapping_variant(engine, base_yaml, tmp_path):
    """A study's variant (another full-load curve) built from a mapping, no file written."""
    doc = dict(base_yaml, name='scaled', full_load_curve={
        'speeds_rpm': base_yaml['full_load_curve']['speeds_rpm'],
        'torque_nm': [1.1 * t for t in base_yaml['full_load_curve']['torque_nm']]})
    var = engine_from_mapping(doc, tmp_path / 'scaled.yaml')
    assert var.full_load_torque(1100) == pytest.approx(3080.0)
    assert var.mean_torque(1100, 1.0) == pytest.approx(3080.0, rel=0.01)


# ------------------------------------------------------------------------------------------------
# base: files and files that are not engine YAMLs
# ------------------------------------------------------------------------------------------------
def test_base_file_relative_and_override(tmp_path):
    (tmp_path / 'mine.yaml').write_text(
        'base: engine_d13\nname: mine\nload_sets: {limit_rpm: 1200, shift_rpm: {A: 0, D: 150}}\n')
    (tmp_path / 'child.yaml').write_text('base: mine.yaml\nname: child\n')
    eng = read_engine(tmp_path / 'child.yaml', 'D')
    assert eng.config.name == 'child' and eng.limit_rpm == 1200.0 and eng.shift_rpm == 150.0
    assert eng.full_load_torque(1000) == 2800.0    # 1000 + 150 rpm, on the plateau
    assert eng.full_load_torque(700) == pytest.approx(0.5 * (2016.0 + 2408.0))   # at 850 rpm


@pytest.mark.parametrize('text, needles', [
    ('base: no_such_engine\nname: x\n', ('x.yaml', 'base', 'no_such_engine', 'not found')),
    ('base: x.yaml\nname: x\n', ('x.yaml', 'base', 'cycle')),
    ('base: engine_table_example.yaml\nname: x\n', ('x.yaml', 'base', 'table')),
    ('base: 3\nname: x\n', ('x.yaml', 'base', 'name or path')),
    ('base: engine_d13\nname: x\ngeometry: {bore_m: 0.1}\n', ('x.yaml (base engine_d13.yaml)',
                                                             'geometry.stroke_m', 'missing')),
])
def test_bad_base_refused(tmp_path, text, needles):
    (tmp_path / 'engine_table_example.yaml').write_text(
        'speeds_rpm: [800, 1000]\norders: [0, 1]\n'
        'coefficients: [[[1, 0], [1, 1]], [[1, 0], [1, 1]]]\n')
    path = tmp_path / 'x.yaml'
    path.write_text(text)
    with pytest.raises(ValueError) as exc:
        read_engine(path)
    _one_line_error(exc, *needles)


def test_files_that_are_not_engine_yamls(tmp_path, capsys):
    bad = tmp_path / 'broken.yaml'
    bad.write_text('name: x\ngeometry:\n  bore_m: [0.1\n')
    empty = tmp_path / 'empty.yaml'
    empty.write_text('')
    cases = [('/etc/passwd', 'not an engine YAML mapping'),
             (str(tmp_path), 'is a directory'),
             (str(bad), f'{bad}:4:1: invalid YAML'),
             (str(empty), 'not an engine YAML mapping (the file holds nothing'),
             (str(tmp_path / 'missing.yaml'), 'not found')]
    for source, needle in cases:
        if source == '/etc/passwd' and not Path(source).is_file():
            continue
        with pytest.raises(ValueError) as exc:
            read_engine(source)
        _one_line_error(exc, needle)
        assert cli_main(['loads', '--engine', source]) == 2
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and needle in err, err
