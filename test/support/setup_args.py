"""setup.py's arguments as setup() receives them (install_requires, extras_require ...): the file
is run with setuptools.setup replaced, so what it computes (the extras, [all]) is read as pip
sees it, without building anything."""
from __future__ import annotations

import runpy
from pathlib import Path
from unittest import mock

ROOT = Path(__file__).resolve().parents[2]


def setup_kwargs() -> dict:
    captured: dict = {}
    with mock.patch('setuptools.setup', lambda **kw: captured.update(kw)):
        runpy.run_path(str(ROOT / 'setup.py'), run_name='__main__')
    return captured
