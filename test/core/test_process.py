"""core/process.py: a process ends with its parent, with Linux's parent-death
signal and with the parent-pid watch used where that does not exist."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CHILD = '''
import os, signal, sys, threading
import dmf_sim.core.process as proc
done = threading.Event()
marker = sys.argv[1]
def finish(why):                     # written whole, then renamed: the test never reads it half
    with open(marker + '.part', 'w') as f:
        f.write(why)
    os.replace(marker + '.part', marker)
    done.set()
signal.signal(signal.SIGTERM, lambda s, f: finish('SIGTERM'))
if sys.argv[2] == 'watch':
    proc.die_with_parent = lambda signum: False        # as on a system without prctl
proc.end_with_parent(lambda pid: finish(f'parent {pid} ended'), poll_s=0.05)
print('ready', flush=True)
done.wait(60)
'''
PARENT = '''
import subprocess, sys
child = subprocess.Popen([sys.executable, '-c', sys.argv[1], sys.argv[2], sys.argv[3]],
                         stdout=subprocess.PIPE, text=True)
assert child.stdout.readline().strip() == 'ready'
print(child.pid, flush=True)
import time; time.sleep(60)
'''


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='/proc and prctl: Linux')
@pytest.mark.parametrize('mode, expected', [('prctl', 'SIGTERM'), ('watch', 'parent ')])
def test_a_process_ends_with_its_parent(tmp_path, mode, expected):
    marker = tmp_path / 'ended'
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO),
                                                       os.environ.get('PYTHONPATH', '')]))
    parent = subprocess.Popen([sys.executable, '-c', PARENT, CHILD, str(marker), mode],
                              env=env, stdout=subprocess.PIPE, text=True)
    child = int(parent.stdout.readline())
    try:
        parent.send_signal(signal.SIGKILL)
        parent.wait(timeout=10)
        deadline = time.monotonic() + 30
        while not marker.exists() and time.monotonic() < deadline:
            time.sleep(0.02)
        assert marker.exists() and marker.read_text().startswith(expected)
    finally:
        if parent.poll() is None:
            parent.kill()
        if not marker.exists():               # the child did not end by itself
            try:
                os.kill(child, signal.SIGKILL)
            except ProcessLookupError:
                pass


@pytest.mark.skipif(not sys.platform.startswith('linux'), reason='prctl: Linux')
def test_a_process_whose_parent_died_before_prctl_ends_at_once():
    """The parent may die while its child is still starting (the monitor's worker imports for a
    second or two before it asks for the parent-death signal); Linux then never sends it, so
    die_with_parent compares the parent pid it is given with the current one."""
    code = ('import os, signal, sys, dmf_sim.core.process as p; '
            'p.die_with_parent(signal.SIGTERM, parent_pid=int(sys.argv[1])); '
            'print("alive", flush=True)')
    env = dict(os.environ, PYTHONPATH=str(REPO))
    gone = subprocess.run([sys.executable, '-c', code, str(2 ** 22 + 7)], capture_output=True,
                          text=True, timeout=60, env=env)          # no such parent pid
    assert gone.returncode == -signal.SIGTERM and 'alive' not in gone.stdout
    alive = subprocess.run([sys.executable, '-c', code, str(os.getpid())], capture_output=True,
                           text=True, timeout=60, env=env)          # its real parent
    assert alive.returncode == 0 and 'alive' in alive.stdout
