"""Processes a test started: end them, tell whether one has ended (helpers)."""
from __future__ import annotations

from pathlib import Path


def kill_started(procs) -> None:
    """End the subprocesses this test started that still run (by their own pid)."""
    for p in procs:
        if p.poll() is None:
            p.kill()
            p.wait(timeout=10)


def gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (a zombie nobody reaps counts as ended)."""
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return True
    return state in ('Z', 'X')
