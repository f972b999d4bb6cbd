"""Old names of the public API keep working for a deprecation period, each with one warning that
names the new spelling and points at the caller's line (dmf_sim/core/deprecation.py)."""
from __future__ import annotations

import importlib
import warnings

import pytest

import dmf_sim as dmf
from dmf_sim.core.deprecation import DmfSimDeprecationWarning, options_from_keywords

RENAMED_IN_MODULES = [
    ('dmf_sim.physics.model', 'load_model', 'read_model'),
    ('dmf_sim.physics.model', 'load_driveline', 'read_driveline'),
    ('dmf_sim.physics.engine', 'load_engine', 'read_engine'),
    ('dmf_sim.physics.loads', 'DrivelineLoads', 'DrivelineExcitation'),
    ('dmf_sim.design.study', 'load_study', 'read_study'),
]


def _one_warning(record) -> warnings.WarningMessage:
    mine = [w for w in record if issubclass(w.category, DmfSimDeprecationWarning)]
    assert len(mine) == 1, [str(w.message) for w in record]
    assert mine[0].filename == __file__          # at the caller's line, not inside dmf_sim
    return mine[0]


@pytest.mark.parametrize('old', sorted(dmf._RENAMED))
def test_an_old_public_name_is_the_new_object_with_a_warning(old):
    new = dmf._RENAMED[old]
    with pytest.warns(DmfSimDeprecationWarning) as record:
        value = getattr(dmf, old)
    assert value is getattr(dmf, new)
    assert f'dmf_sim.{old} is deprecated; use dmf_sim.{new}' in str(_one_warning(record).message)
    assert old not in dmf.__all__ and new in dmf.__all__


@pytest.mark.parametrize('module, old, new', RENAMED_IN_MODULES)
def test_an_old_name_in_its_module_is_the_new_object_with_a_warning(module, old, new):
    mod = importlib.import_module(module)
    with pytest.warns(DmfSimDeprecationWarning) as record:
        value = getattr(mod, old)
    assert value is getattr(mod, new)
    assert f'{module}.{old} is deprecated; use {module}.{new}' in str(_one_warning(record).message)
    with pytest.raises(AttributeError, match='no attribute'):
        getattr(mod, 'no_such_name')


def test_engine_warm_is_warm_up_with_a_warning(engine_d13):
    with pytest.warns(DmfSimDeprecationWarning) as record:
        engine_d13.warm()
    assert 'Engine.warm() is deprecated; use Engine.warm_up()' in str(
        _one_warning(record).message)
    assert type(engine_d13).warm is type(engine_d13).warm_up   # the class gives the new method


def test_simulate_with_its_old_keywords_is_simulate_with_options(engine_d13):
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_model
    from dmf_sim.solvers.newmark import SimulationOptions, simulate
    excitation = DrivelineExcitation(read_model('truck_dmf', alpha=3.0), engine_d13)
    with pytest.warns(DmfSimDeprecationWarning) as record:
        old = simulate(excitation, 1500.0, 0.5, t_end=0.02, dt=2e-4, record_stride=5)
    message = str(_one_warning(record).message)
    assert 'options=SimulationOptions(dt=..., record_stride=...)' in message
    new = simulate(excitation, 1500.0, 0.5, t_end=0.02,
                   options=SimulationOptions(dt=2e-4, record_stride=5))
    assert len(old.t) == len(new.t) == 20
    assert (old.q == new.q).all() and (old.windup == new.windup).all()
    with pytest.raises(TypeError, match="unexpected keyword argument 'dtt'"):
        simulate(excitation, 1500.0, 0.5, dtt=1e-4)


def test_analyze_bag_with_its_old_keywords_builds_its_options(monkeypatch):
    """The keywords become the options the analysis reads (stopped at its first step)."""
    from dmf_sim.analysis import pipeline

    seen = {}

    def stop(path, **kw):
        seen.update(kw)
        raise RuntimeError('read')
    monkeypatch.setattr(pipeline, 'read_bag_series', stop)
    with pytest.warns(DmfSimDeprecationWarning) as record, pytest.raises(RuntimeError):
        pipeline.analyze_bag('bag', stamp='publish', namespace='/truck1')
    assert ('analyze_bag(stamp=..., namespace=...) is deprecated; use analyze_bag(..., '
            'options=AnalysisOptions(stamp=..., namespace=...))') in str(
        _one_warning(record).message)
    assert seen['stamp'] == 'publish' and seen['namespace'] == '/truck1'
    assert seen['reader'] == pipeline.AnalysisOptions().reader


def test_keywords_on_top_of_options_replace_those_fields():
    from dmf_sim.solvers.newmark import SimulationOptions
    base = SimulationOptions(dt=5e-5, max_cycles=50)
    with pytest.warns(DmfSimDeprecationWarning):
        got = options_from_keywords(SimulationOptions, base, {'max_cycles': 9}, 'simulate')
    assert got == SimulationOptions(dt=5e-5, max_cycles=9)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        assert options_from_keywords(SimulationOptions, None, {}, 'simulate') == \
            SimulationOptions()


def test_the_package_itself_uses_no_old_name(tmp_path):
    """setup.cfg makes a deprecation warning raised from inside dmf_sim an error; check the
    filter is active (a module of the package using an old name fails)."""
    with pytest.raises(DmfSimDeprecationWarning):
        exec(compile('import dmf_sim\ndmf_sim.load_model\n', 'inside.py', 'exec'),
             {'__name__': 'dmf_sim.some_module'})


def test_the_reader_called_reference_is_the_message_reader_with_a_warning(monkeypatch):
    from dmf_sim.analysis import pipeline, series
    from dmf_sim.core.errors import BagError

    seen = {}

    def stop(path, **kw):
        seen.update(kw)
        raise RuntimeError('read')
    with pytest.warns(DmfSimDeprecationWarning) as record, pytest.raises(BagError):
        series.read_bag_series('no/such/bag', reader='reference')
    assert "reader='messages'" in str(_one_warning(record).message)
    monkeypatch.setattr(pipeline, 'read_bag_series', stop)
    with pytest.warns(DmfSimDeprecationWarning) as record, pytest.raises(RuntimeError):
        pipeline.analyze_bag('bag', options=pipeline.AnalysisOptions(reader='reference'))
    _one_warning(record)
    assert seen['reader'] == 'messages'
