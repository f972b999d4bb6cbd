"""The public API (``import dmf_sim as dmf``): every advertised name resolves to the object its
layer module defines, the names load lazily, and the example script in the docs runs."""
import os
import subprocess
import sys
from pathlib import Path

import pytest

import dmf_sim as dmf

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize('name', [n for n in dmf.__all__ if n != '__version__'])
def test_every_public_name_is_its_layer_modules_object(name):
    import importlib
    obj = getattr(dmf, name)
    assert obj is getattr(importlib.import_module(dmf._API[name]), name)


def test_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match='no attribute'):
        dmf.no_such_thing  # noqa: B018


def _imported_after(code: str) -> set[str]:
    probe = (f'{code}\nimport sys\n'
             "print(' '.join(m for m in ('numba', 'dask', 'distributed', 'pyarrow', 'rclpy') "
             'if m in sys.modules))')
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, '-c', probe], capture_output=True, text=True, env=env,
                         check=True, timeout=120)
    return set(out.stdout.split())


@pytest.mark.slow
def test_cli_help_and_package_import_load_neither_numba_nor_dask():
    assert _imported_after('import dmf_sim') == set()
    help_code = ('import contextlib, io\nfrom dmf_sim.cli import main\n'
                 'with contextlib.redirect_stdout(io.StringIO()):\n'
                 '    try:\n        main(["--help"])\n    except SystemExit:\n        pass')
    assert _imported_after(help_code) == set()


@pytest.mark.slow
def test_node_core_start_up_does_not_load_dask():
    loaded = _imported_after('import dmf_sim.live.runtime')
    assert not {'dask', 'distributed', 'pyarrow'} & loaded


@pytest.mark.slow
def test_example_script_runs():
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, str(ROOT / 'doc' / 'examples' / 'api_example.py'),
                          '--quick'], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    assert 'worst stable 1.5th order' in out.stdout and 'refused: ' in out.stdout


def test_type_checkers_see_every_public_name_from_its_module():
    """The TYPE_CHECKING imports of dmf_sim/__init__.py (what mypy, pyright and editors read)
    name exactly the public names, each from the module ``_API`` loads it from."""
    import ast
    tree = ast.parse((ROOT / 'dmf_sim' / '__init__.py').read_text())
    block = next(node for node in tree.body if isinstance(node, ast.If)
                 and getattr(node.test, 'id', None) == 'TYPE_CHECKING')
    seen = {}
    for imp in block.body:
        assert isinstance(imp, ast.ImportFrom)
        for alias in imp.names:
            assert alias.asname in (None, alias.name)
            seen[alias.name] = imp.module
    assert seen == dmf._API
