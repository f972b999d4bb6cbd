"""The ROS 2 Jazzy platform's library versions: constraints/platform-jazzy.txt pins
every rosdep key of package.xml that names a Python library, setup.py's minimums admit every pin
(pip install -c constraints/platform-jazzy.txt must resolve), and the environment that
``make test-platform`` runs in has exactly those versions."""
from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from importlib import metadata
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.version import Version
from support.setup_args import setup_kwargs

ROOT = Path(__file__).resolve().parents[1]
CONSTRAINTS = ROOT / 'constraints' / 'platform-jazzy.txt'
# rosdep keys whose Ubuntu package is a Python library -> its name on the package index
PYTHON_KEYS = {'python3-numpy': 'numpy', 'python3-scipy': 'scipy', 'python3-yaml': 'PyYAML',
               'python3-matplotlib': 'matplotlib', 'python3-tqdm': 'tqdm',
               'python3-numba': 'numba', 'python3-rich': 'rich',
               'python3-websockets': 'websockets', 'python3-pytest': 'pytest'}
# rosdep keys that install the newest release with pip (nothing for a platform to pin), and the
# ROS packages themselves
UNPINNED_KEYS = {'python3-rosbags-pip', 'python3-ruff-pip', 'mcap-ros2-support'}


def _pins() -> dict[str, Version]:
    pins = {}
    for line in CONSTRAINTS.read_text().splitlines():
        line = line.split('#', 1)[0].strip()
        if line:
            req = Requirement(line)
            (spec,) = req.specifier
            assert spec.operator == '==', line
            pins[req.name.lower()] = Version(spec.version)
    return pins


def _setup_requirements() -> list[Requirement]:
    """install_requires, the feature extras ([all]) and the test extra of setup.py."""
    kw = setup_kwargs()
    extras = kw['extras_require']
    return [Requirement(r) for r in kw['install_requires'] + extras['all'] + extras['test']]


def test_every_python_key_of_package_xml_is_pinned():
    keys = {e.text for e in ET.parse(ROOT / 'package.xml').getroot()
            if e.tag in ('exec_depend', 'test_depend') and e.text.startswith(('python3-', 'mcap'))}
    assert keys - set(PYTHON_KEYS) <= UNPINNED_KEYS, keys - set(PYTHON_KEYS)
    pins = _pins()
    for key in keys & set(PYTHON_KEYS):
        assert PYTHON_KEYS[key].lower() in pins, key
    # numba has no apt package on Ubuntu 24.04: no key, but pinned for the pip line
    assert 'python3-numba' not in keys and 'numba' in pins
    for pip_only in ('mcap', 'foxglove-sdk', 'dask', 'distributed', 'pyarrow', 'fatpack',
                     'threadpoolctl', 'optuna'):
        assert pip_only in pins


def test_setup_minimums_admit_the_platform_versions():
    """Before: matplotlib>=3.8 and websockets>=12 refused Ubuntu 24.04's 3.6.3 and 10.4."""
    pins = _pins()
    checked = 0
    for req in _setup_requirements():
        name = req.name.lower()
        if name in pins:
            assert req.specifier.contains(pins[name]), (str(req), str(pins[name]))
            checked += 1
    assert checked >= 17
    assert pins['pyarrow'] < Version('26')        # 26 refuses to import with numpy < 2
    assert pins['numpy'] < Version('2')


@pytest.mark.skipif(os.environ.get('DMF_SIM_PLATFORM') != 'jazzy',
                    reason='only in the platform environment (make test-platform)')
def test_this_environment_has_the_platform_versions():
    for name, version in _pins().items():
        assert Version(metadata.version(name)) == version, name


def test_setup_refuses_the_pyarrow_that_refuses_numpy_1():
    """pyarrow 26 refuses to import with numpy < 2 but does not declare numpy: pip picked it
    beside the platform's numpy 1.26 (`pip install --dry-run -c numpy==1.26.4 -e '.[...]'`
    chose pyarrow 26.0.1 before the bound, 25.0.1 after)."""
    (req,) = [r for r in _setup_requirements() if r.name == 'pyarrow'][:1]
    assert not req.specifier.contains('26.0.1') and req.specifier.contains('25.0.1')


PIP_LINE = re.compile(r"pip install --break-system-packages 'numpy<2' ((?:.*\\\n)*.*)")


@pytest.mark.parametrize('page', ['getting-started.md', 'guide/platform-versions.md'])
def test_the_colcon_pip_line_installs_what_rosdep_does_not(page):
    """The colcon route's pip line names every library of install_requires and the feature
    extras that has no rosdep key in package.xml, at the platform's pin, and nothing else."""
    keys = {e.text for e in ET.parse(ROOT / 'package.xml').getroot() if e.tag == 'exec_depend'}
    by_rosdep = {PYTHON_KEYS[k].lower() for k in keys if k in PYTHON_KEYS} | {'rosbags'}
    kw = setup_kwargs()
    needed = {Requirement(r).name.lower() for r in kw['install_requires']
              + kw['extras_require']['all']} - by_rosdep - {'setuptools'}
    line = PIP_LINE.search((ROOT / 'doc' / page).read_text()).group(1)
    named = {}
    for word in line.replace('\\', ' ').split():
        req = Requirement(word.strip("'"))
        (spec,) = req.specifier
        named[req.name.lower()] = Version(spec.version)
    assert set(named) == needed, (set(named), needed)
    pins = _pins()
    assert all(named[n] == pins[n] for n in named), named
