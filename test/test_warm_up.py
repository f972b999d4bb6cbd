"""The numerical kernels compile where one expects to wait: ``dmf-sim warm-up`` (run by ``make
venv``) compiles every kernel of the package into numba's cache; a command that meets a cold
kernel anyway says "compiling ... once" before it compiles and starts its progress bar only
afterwards; a cold cache is found without compiling. Each test runs in processes of its own with
``NUMBA_CACHE_DIR`` on an empty directory (a machine that never compiled), so the tree's own
cache is neither used nor changed."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from dmf_sim.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[1]
DMF_SIM = [sys.executable, '-m', 'dmf_sim.cli']
NOTICE = 'compiling the numerical kernels once (~'


def _run(args, cache: Path, check: bool = True) -> subprocess.CompletedProcess:
    env = {**os.environ, 'NUMBA_CACHE_DIR': str(cache)}
    proc = subprocess.run(args, cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=900)
    if check:
        assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def _cache_files(cache: Path) -> dict[str, int]:
    """numba's index and data files under ``cache`` (name -> modification time [ns])."""
    return {str(p.relative_to(cache)): p.stat().st_mtime_ns for p in cache.rglob('*')
            if p.suffix in ('.nbi', '.nbc')}


def _report(cache: Path) -> dict[str, dict]:
    out = _run(DMF_SIM + ['warm-up', '--check', '--json'], cache).stdout
    return {g['group']: g for g in json.loads(out)['groups']}


_ALL_KERNELS = '''
import importlib, json, pkgutil, sys
import numba
from numba.core.dispatcher import Dispatcher
import dmf_sim
from dmf_sim.core.kernel_cache import cached
found = {}
for info in pkgutil.walk_packages(dmf_sim.__path__, 'dmf_sim.'):
    if info.name == 'dmf_sim.node':                      # rclpy at import; it has no kernel
        continue
    mod = importlib.import_module(info.name)
    for name, obj in vars(mod).items():
        if isinstance(obj, Dispatcher) and obj.py_func.__module__ == info.name:
            found[f'{info.name}.{name}'] = cached(obj)
print(json.dumps(found))
'''


_LOAD_BAG_READING = '''
import json
from dmf_sim.core.kernel_cache import cold
from dmf_sim.live.warm import GROUPS, warm_up
print(json.dumps(sorted(g.name for g in cold(GROUPS))))
warm_up('test', 'bag reading')
'''


@pytest.mark.slow
def test_a_cold_cache_is_found_without_compiling(tmp_path):
    """`warm-up --check` reads numba's cache index only: on an empty cache every group is cold
    and nothing is written; once a group is compiled it is found, the others stay cold, and its
    next load says nothing."""
    report = _report(tmp_path)
    assert set(report) == {'sweep', 'time integration', 'bag reading'}
    assert all(g['cold'] for g in report.values())
    assert _cache_files(tmp_path) == {}                     # nothing compiled, nothing written
    load = [sys.executable, '-c', _LOAD_BAG_READING]
    first = _run(load, tmp_path)
    assert json.loads(first.stdout) == ['bag reading', 'sweep', 'time integration']
    assert first.stderr.startswith(f'dmf-sim test: {NOTICE}2 s on a 2-core machine; later '
                                   'runs load them)'), first.stderr
    files = _cache_files(tmp_path)
    second = _run(load, tmp_path)
    assert json.loads(second.stdout) == ['sweep', 'time integration']
    assert NOTICE not in second.stderr and _cache_files(tmp_path) == files
    # the compile was timed: the next notice (the kernel cold again, e.g. after an update)
    # gives this machine's figure
    for index in tmp_path.rglob('*.nbi'):
        index.unlink()
    third = _run(load, tmp_path)
    assert 's on this machine; later runs load them)' in third.stderr, third.stderr


@pytest.mark.slow
def test_a_command_on_a_cold_cache_says_compiling_once(tmp_path, capsys):
    """dmf-sim durability reads a bag: on a machine that never compiled, one notice line before
    the work, the result as usual; the second run loads the kernel silently."""
    bag = tmp_path / 'bag'
    assert cli_main(['run', 'ramp:900:1000:200', '--out', str(bag), '--no-progress']) == 0
    capsys.readouterr()
    cache = tmp_path / 'numba'
    cache.mkdir()
    args = DMF_SIM + ['durability', str(bag), '--json']
    first = _run(args, cache)
    lines = first.stderr.splitlines()
    assert lines[0].startswith(f'dmf-sim durability: {NOTICE}'), first.stderr
    assert json.loads(first.stdout)['damage']
    second = _run(args, cache)
    assert NOTICE not in second.stderr
    assert json.loads(second.stdout)['damage'] == json.loads(first.stdout)['damage']


@pytest.mark.slow
def test_warm_up_compiles_every_kernel_and_commands_then_compile_nothing(tmp_path):
    """The field report: the first sweep on a machine took 40 s, 35 of them compiling, while its
    bar predicted 5 minutes. On a cold cache the sweep now says so before the bar starts;
    `dmf-sim warm-up` compiles every kernel of the package (each dispatcher of every module is in
    the cache afterwards); after it, a sweep and a run compile nothing and say nothing."""
    sweep = DMF_SIM + ['sweep', '--speeds', '1000', '1040', '10']
    cold = _run(sweep, tmp_path)
    notice = cold.stderr.find(f'dmf-sim sweep: {NOTICE}')
    bar = cold.stderr.find('rpm')
    assert 0 <= notice < bar, cold.stderr[:2000]        # the notice, then (compiled) the bar
    out = _run(DMF_SIM + ['warm-up', '--json'], tmp_path).stdout
    groups = {g['group']: g for g in json.loads(out)['groups']}
    assert not groups['sweep']['compiled']                   # the sweep compiled it already
    assert groups['time integration']['compiled'] and groups['bag reading']['compiled']
    found = json.loads(_run([sys.executable, '-c', _ALL_KERNELS], tmp_path).stdout)
    assert len(found) > 40 and all(found.values()), [k for k, v in found.items() if not v]
    files = _cache_files(tmp_path)
    for args in (sweep, DMF_SIM + ['run', 'ramp:900:1000:200', '--no-write']):
        again = _run(args, tmp_path)
        assert NOTICE not in again.stderr, again.stderr[:2000]
    assert _cache_files(tmp_path) == files                   # nothing compiled


def test_the_warm_up_command_has_its_page_and_the_groups_their_kernels():
    from dmf_sim.live.warm import GROUPS
    assert (ROOT / 'doc' / 'commands' / 'warm-up.md').is_file()
    for g in GROUPS:
        assert g.kernels() and all(hasattr(k, 'signatures') for k in g.kernels()), g.name
