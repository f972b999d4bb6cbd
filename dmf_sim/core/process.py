"""A process that ends with its parent: Linux's parent-death signal, a polling fallback.

Used by the node (SIGTERM when its launch parent dies: the same clean shutdown as Ctrl-C,
closing its bag) and by the monitor's worker processes (SIGKILL when the node dies, even of
SIGKILL: orphans must not hold the node's pipes).
"""
from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

__all__ = ['PARENT_POLL_S', 'PR_SET_PDEATHSIG', 'blocked_signals', 'die_with_parent',
           'end_with_parent']

PR_SET_PDEATHSIG = 1        # Linux prctl option: a signal for this process when its parent dies
PARENT_POLL_S = 0.5         # fallback (no prctl): how often the parent pid is checked [s]


def die_with_parent(signum: int = signal.SIGKILL, parent_pid: int | None = None) -> bool:
    """Ask Linux to send ``signum`` to this process when the thread that started it ends
    (``prctl(PR_SET_PDEATHSIG)``). False where that is not available (not Linux).

    ``parent_pid``: the pid of the process that started this one. If it has died already
    (between this process's start and the prctl call, which Linux does not cover), this
    process sends itself ``signum`` at once instead of living on as an orphan."""
    try:
        import ctypes
        libc = ctypes.CDLL(None, use_errno=True)
        zero = ctypes.c_ulong(0)            # prctl reads its arguments as unsigned long
        ok = libc.prctl(PR_SET_PDEATHSIG, ctypes.c_ulong(int(signum)), zero, zero, zero) == 0
    except (OSError, AttributeError):
        ok = False
    if parent_pid is not None and os.getppid() != parent_pid:
        os.kill(os.getpid(), signum)
    return ok


def end_with_parent(on_death: Callable[[int], None], signum: int = signal.SIGTERM,
                    poll_s: float = PARENT_POLL_S) -> int:
    """Make this process end when its parent does: ``signum`` from Linux (its handler decides
    what ending means), else a daemon thread that polls the parent pid and calls
    ``on_death(parent_pid)``. Also calls it at once when the parent has died already (between
    this process's start and now). Returns the parent's pid."""
    parent = os.getppid()
    if not die_with_parent(signum):
        def watch() -> None:
            while os.getppid() == parent:
                threading.Event().wait(poll_s)
            on_death(parent)
        threading.Thread(target=watch, name='parent-watch', daemon=True).start()
    elif os.getppid() != parent:             # died before prctl took effect
        on_death(parent)
    return parent


@contextmanager
def blocked_signals(signums: Sequence[int]) -> Iterator[None]:
    """Block ``signums`` in the calling thread meanwhile (``pthread_sigmask``). A process
    started here inherits them blocked, so a signal to the whole process group (Ctrl-C,
    ``kill -TERM %1``) cannot end it while it is still starting, before it installs its own
    dispositions (the monitor's workers import for seconds first); it unblocks them itself.
    This process misses nothing: another thread takes the signal, or it waits until the end
    of the block."""
    old = signal.pthread_sigmask(signal.SIG_BLOCK, signums)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)

