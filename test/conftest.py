"""Shared fixtures and markers for the whole suite.

Markers (registered in setup.cfg, ``[tool:pytest]``):

``ros``    needs rclpy and DDS (the ``ros`` extra). Without rclpy these tests are skipped with a
           reason naming the extra, so a plain ``pip install -e '.[test]'`` runs every ROS-free
           test; with ``DMF_SIM_REQUIRE_ROS=1`` (``make test``) a missing rclpy stops the run.
``slow``   takes more than ~10 s on a quiet 2-core machine (``-m 'not slow'`` for a quick run).
``bench``  a benchmark's smoke run (small sizes; the full benchmarks are ``make bench``).
``parity`` a compiled kernel against its reference: the tests of
           test/solvers/test_kernel_parity.py, one per case the kernel registry
           (dmf_sim/solvers/kernel_registry.py) names.

Session fixtures: the default engine and the 2500 Nm engine (Load A, excitation grid computed
once) and the DMF driveline model, loaded once for the whole run. They are shared: do not modify
them (``Engine.with_load_set`` and ``read_model(..., alpha=...)`` give variants).
"""
from __future__ import annotations

import importlib.util
import os

import pytest

ROS_EXTRA = "pip install -e '.[ros]'"
REQUIRE_ROS = 'DMF_SIM_REQUIRE_ROS'


def ros_available() -> bool:
    """rclpy importable (found; not imported here, so ROS-free tests stay ROS-free)."""
    return importlib.util.find_spec('rclpy') is not None


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if ros_available():
        return
    ros_items = [item for item in items if item.get_closest_marker('ros') is not None]
    if ros_items and os.environ.get(REQUIRE_ROS) == '1':
        raise pytest.UsageError(f'{REQUIRE_ROS}=1 but rclpy is not installed: {ROS_EXTRA} '
                                f'({len(ros_items)} ROS tests would be skipped)')
    skip = pytest.mark.skip(reason=f'needs rclpy and DDS, the ros extra: {ROS_EXTRA}')
    for item in ros_items:
        item.add_marker(skip)


@pytest.fixture(scope='session')
def engine_d13():
    """The default engine (config/engine_d13.yaml), Load A, every grid node computed."""
    from dmf_sim.physics.engine import read_engine
    engine = read_engine('engine_d13', load_set='A')
    engine.warm_up()
    return engine


@pytest.fixture(scope='session')
def engine_2500():
    """The 2500 Nm rating (config/engine_d13_2500nm.yaml), Load A, every grid node computed."""
    from dmf_sim.physics.engine import read_engine
    engine = read_engine('engine_d13_2500nm', load_set='A')
    engine.warm_up()
    return engine


@pytest.fixture(scope='session')
def truck_dmf():
    """The paper's DMF driveline (config/truck_dmf.yaml) as a reduced model."""
    from dmf_sim.physics.model import read_model
    return read_model('truck_dmf')


@pytest.fixture
def forbid(monkeypatch):
    """``forbid(*targets)``: each ``'module.attribute'`` raises AssertionError when called (a
    computation that must not start). Every ``dmf-sim`` command and every target's module is
    imported first, so that no module imported meanwhile binds a stand-in for good."""
    import importlib

    def no_call(*args, **kwargs):
        raise AssertionError('started before the options and paths were checked')

    def forbid_(*targets: str) -> None:
        from dmf_sim.cli import build_parser
        build_parser()                      # imports every command module
        for target in targets:
            importlib.import_module(target.rsplit('.', 1)[0])
        for target in targets:
            monkeypatch.setattr(target, no_call)
    return forbid_
