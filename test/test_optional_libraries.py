"""The optional libraries (design, optimize, durability, foxglove extras): imported only through
dmf_sim.core.optional.require, declared by setup.py's extras, and a missing or unusable one is
one line naming the extra and the pip line (exit 2), for every command that needs one."""
from __future__ import annotations

import ast
import importlib.abc
import importlib.util
import sys
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from support.setup_args import setup_kwargs

from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import MissingExtraError
from dmf_sim.core.optional import EXTRAS, FEATURES, OPTIONAL, pip_line, require

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / 'dmf_sim'

# third-party imports of the package that are not optional: import name -> what provides it
CORE = {'numpy': 'numpy', 'scipy': 'scipy', 'yaml': 'pyyaml', 'matplotlib': 'matplotlib',
        'numba': 'numba', 'llvmlite': 'numba', 'tqdm': 'tqdm', 'rosbags': 'rosbags',
        'mcap': 'mcap', 'rich': 'rich', 'threadpoolctl': 'threadpoolctl', 'zlib_ng': 'zlib-ng'}
ROS = {'rclpy', 'std_msgs', 'sensor_msgs', 'diagnostic_msgs', 'rosgraph_msgs', 'std_srvs',
       'builtin_interfaces', 'rcl_interfaces', 'ament_index_python'}


def _imports() -> dict[str, set[str]]:
    """Top-level name of every absolute import in the package -> the modules importing it."""
    found: dict[str, set[str]] = {}
    for path in PACKAGE.rglob('*.py'):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                     [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0
                     else [])
            for name in names:
                found.setdefault(name.split('.')[0], set()).add(
                    str(path.relative_to(ROOT)))
    return found


def _provides(req: str) -> set[str]:
    """Distributions a requirement installs that the package imports (dask[distributed]: both)."""
    r = Requirement(req)
    return {r.name.lower()} | {e.lower() for e in r.extras}


@pytest.mark.slow
def test_optional_libraries_are_imported_only_through_require():
    imports = _imports()
    for name in OPTIONAL:
        direct = imports.get(name, set()) - {'dmf_sim/core/optional.py'}
        assert not direct, f'{name} imported directly in {sorted(direct)}: use core.optional'


@pytest.mark.slow
def test_every_third_party_import_is_declared():
    kw = setup_kwargs()
    core = {Requirement(r).name.lower() for r in kw['install_requires']}
    third = set(_imports()) - set(sys.stdlib_module_names) - {'dmf_sim'}
    for name in sorted(third):
        if name in OPTIONAL:
            continue
        assert name in ROS or CORE.get(name) in core, f'{name}: not in install_requires'
    for name in OPTIONAL:
        assert OPTIONAL[name][0].lower() not in core, f'{name} is optional: not a core dependency'


def test_setup_extras_cover_every_optional_library():
    extras = setup_kwargs()['extras_require']
    for name, (dist, own) in OPTIONAL.items():
        for extra in [own] + [e for e, libs in EXTRAS.items() if name in libs]:
            provided = set().union(*(_provides(r) for r in extras[extra]))
            assert dist.lower() in provided, (name, extra, extras[extra])
        assert dist.lower() in set().union(*(_provides(r) for r in extras['all']))
    assert set(EXTRAS) == set(FEATURES) <= set(extras)
    assert set(extras['all']) == {r for e in EXTRAS for r in extras[e]}


def test_the_pip_line_is_the_installed_extra():
    """The pip line is the extra's requirements as this installation declares them (pip or
    colcon alike), e.g. pyarrow's upper bound."""
    extras = setup_kwargs()['extras_require']
    for extra in EXTRAS:
        expected = {str(Requirement(r)) for r in extras[extra]}
        words = pip_line(extra).removeprefix('pip install ').split()
        assert {str(Requirement(w.strip("'"))) for w in words} == expected, extra


# ---- a missing or unusable library ------------------------------------------------------------
@pytest.fixture
def missing(monkeypatch):
    """missing(name): the library (and its submodules) cannot be imported, as if not
    installed (sys.modules[name] = None: import raises ModuleNotFoundError)."""
    def hide(name: str) -> None:
        for mod in [m for m in sys.modules if m == name or m.startswith(name + '.')]:
            monkeypatch.setitem(sys.modules, mod, None)
        monkeypatch.setitem(sys.modules, name, None)
    return hide


class _Refusing(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports ``name`` as a release that refuses this environment at import (as pyarrow 26
    does with numpy < 2)."""

    def __init__(self, name: str, message: str):
        self.name, self.message = name, message

    def find_spec(self, fullname, path, target=None):
        if fullname == self.name:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        raise ImportError(self.message)


def _one_line(argv, capsys) -> str:
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1, err
    return err.strip()


@pytest.mark.parametrize('argv, library, extra', [
    (['design', 'study_example', '--out', '{tmp}/d'], 'pyarrow', 'design'),
    (['design', 'study_example', '--out', '{tmp}/d'], 'distributed', 'design'),
    (['optimize', 'optimize_example', '--out', '{tmp}/o'], 'optuna', 'optimize'),
    (['optimize', 'optimize_example', '--out', '{tmp}/o'], 'dask', 'optimize'),
    (['durability', '{tmp}/bag'], 'fatpack', 'durability'),
])
def test_a_command_without_its_extra_is_one_line_with_the_pip_line(argv, library, extra,
                                                                    missing, tmp_path, capsys):
    missing(library)
    argv = [a.replace('{tmp}', str(tmp_path)) for a in argv]
    err = _one_line(argv, capsys)
    dist = OPTIONAL[library][0]
    assert err == (f"dmf-sim {argv[0]}: error: {dist} is not installed; install the '{extra}' "
                   f'extra for {FEATURES[extra]}: {pip_line(extra)}')
    assert "pip install '" in err
    assert not (tmp_path / 'd').exists() and not (tmp_path / 'o').exists()


def test_an_unusable_release_is_one_line_naming_it(monkeypatch, capsys, tmp_path):
    """pyarrow 26 with numpy 1.26: ImportError at import; before, three test files errored at
    collection and the design commands ended in a traceback."""
    for mod in [m for m in sys.modules if m == 'pyarrow' or m.startswith('pyarrow.')]:
        monkeypatch.delitem(sys.modules, mod)
    monkeypatch.setattr(sys, 'meta_path', [_Refusing(
        'pyarrow', 'pyarrow requires NumPy 2.0 or newer, found 1.26.4')] + sys.meta_path)
    err = _one_line(['design', 'study_example', '--out', str(tmp_path / 'd')], capsys)
    assert 'pyarrow ' in err and 'cannot be used here (pyarrow requires NumPy 2.0 or newer, ' \
        "found 1.26.4); install the 'design' extra for design studies (dmf-sim design, " \
        'run_study): pip install ' in err, err
    assert "'pyarrow<26,>=14'" in err or "-e '.[design]'" in err


def test_the_node_foxglove_server_without_its_extra_is_one_line(missing):
    """The node builds the Foxglove server when foxglove_port is set (live/runtime.py); a
    missing foxglove-sdk is a DmfSimError there, which the node logs as one line at start-up
    (exit 2), and an ImportError for a script."""
    from dmf_sim.core.errors import DmfSimError
    from dmf_sim.live.foxglove_bridge import FoxgloveBridge
    missing('foxglove')
    with pytest.raises(MissingExtraError) as e:
        FoxgloveBridge({'/x': 'std_msgs/msg/Float64'}, port=0)
    assert isinstance(e.value, DmfSimError) and isinstance(e.value, ImportError)
    assert str(e.value) == ("foxglove-sdk is not installed; install the 'foxglove' extra for "
                            f"the node's Foxglove server (foxglove_port): {pip_line('foxglove')}")
    with pytest.raises(MissingExtraError, match="the 'durability' extra"):
        missing('fatpack')
        require('fatpack')
