"""The code style is checked, not hoped for: `ruff check` (settings in ruff.toml: 99-character
lines as ROS 2's ament_flake8, pyflakes, pycodestyle, import order) passes on the whole tree."""
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _ruff() -> list[str]:
    exe = Path(sys.executable).with_name('ruff')
    if exe.exists():
        return [str(exe)]
    found = shutil.which('ruff')
    assert found, "ruff is not installed: it is in setup.py's 'test' extra (make test installs it)"
    return [found]


def test_ruff_check_passes():
    out = subprocess.run(_ruff() + ['check', '--output-format', 'concise', str(ROOT)],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
