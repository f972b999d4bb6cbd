"""The tree shows the layers: the import contracts in .importlinter hold (layers, no ROS below the
node shell, no import cycles), and few modules are left loose beside the layer packages."""
import shutil
import subprocess
import sys
from pathlib import Path

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
