"""The tree shows the layers: the import contracts in .importlinter hold (layers, no ROS below the
node shell, no import cycles), and few modules are left loose beside the layer packages."""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_LOOSE_MODULES = 12


def test_import_contracts_hold():
    exe = shutil.which('lint-imports', path=str(Path(sys.executable).parent)) \
        or shutil.which('lint-imports')
    assert exe, 'lint-imports not installed (pip install -e .[test])'
    out = subprocess.run([exe, '--config', str(ROOT / '.importlinter'), '--no-cache'],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert 'BROKEN' not in out.stdout and out.stdout.count('KEPT') >= 3


def test_few_loose_modules():
    loose = sorted(p.name for p in (ROOT / 'dmf_sim').glob('*.py'))
    assert len(loose) <= MAX_LOOSE_MODULES, loose


@pytest.mark.slow
def test_every_public_module_declares_its_public_names():
    """``__all__`` in every public module (not ``_private.py``), naming objects that exist."""
    import ast
    missing = []
    for path in sorted((ROOT / 'dmf_sim').rglob('*.py')):
        if path.name.startswith('_') and path.name != '__init__.py':
            continue
        tree = ast.parse(path.read_text())
        names = {t.id for n in tree.body if isinstance(n, (ast.Assign, ast.AnnAssign))
                 for t in (n.targets if isinstance(n, ast.Assign) else [n.target])
                 if isinstance(t, ast.Name)}
        defined = [n for n in tree.body
                   if not isinstance(n, (ast.Import, ast.ImportFrom, ast.Expr))]
        if '__all__' not in names and (path.name != '__init__.py' or defined):
            missing.append(str(path.relative_to(ROOT)))
    assert not missing, missing


def test_every_package_is_in_the_layers_and_in_the_architecture_diagram():
    """Each package and loose module of dmf_sim has its place in the layers contract of
    .importlinter and in the layer diagram of doc/architecture.md (a new package that is in
    neither would be unconstrained and undocumented)."""
    import configparser
    import re
    cfg = configparser.ConfigParser()
    cfg.read(ROOT / '.importlinter')
    layers = re.findall(r'dmf_sim\.(\w+)', cfg['importlinter:contract:layers']['layers'])
    parts = {p.name for p in (ROOT / 'dmf_sim').iterdir()
             if p.is_dir() and (p / '__init__.py').exists()}
    parts |= {p.stem for p in (ROOT / 'dmf_sim').glob('*.py') if p.name != '__init__.py'}
    assert sorted(parts) == sorted(layers)
    text = (ROOT / 'doc' / 'architecture.md').read_text()
    diagram = text[text.index('## Layers'):].split('```')[1]
    drawn = set(re.findall(r'\b(\w+)(?:/|\.py)', diagram))
    assert parts <= drawn, sorted(parts - drawn)
