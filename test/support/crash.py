"""Crashing a recording on purpose: run a child process, SIGKILL it once it is ready (helper)."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

TEST_DIR = Path(__file__).resolve().parents[1]      # test/: the helpers are support.*
REPO = TEST_DIR.parent


def sigkill_when_ready(script: Path, args: list[str],
                       ready: Callable[[subprocess.Popen], None]) -> int:
    """Run ``python script *args`` (stdout piped, this repository importable), call
    ``ready(proc)`` until it returns, then SIGKILL the child. Returns the kill time [ns]. The
    test helpers (e.g. ``support.cdr``) are importable in the child too."""
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join(
        [str(REPO), str(TEST_DIR), os.environ.get('PYTHONPATH', '')])}
    proc = subprocess.Popen([sys.executable, str(script), *args], stdout=subprocess.PIPE,
                            text=True, env=env)
    try:
        ready(proc)
        t_kill = time.time_ns()
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == -signal.SIGKILL
    return t_kill
