"""numba's on-disk cache of the package's compiled kernels: whether it holds a kernel (found
without compiling anything), and loading groups of kernels with a notice when they must be
compiled first.

The kernels (:func:`dmf_sim.core.compiled.jit`) are compiled on their first call on a machine
and kept in numba's cache: ``__pycache__`` beside each module, or, where that directory is not
writable (a package installed read-only), numba's per-user cache directory; ``NUMBA_CACHE_DIR``
puts every entry under one directory instead. A cache entry belongs to the source file (size and
time stamp), the function's bytecode, numba's version and this CPU, so a new release, an edited
module or another machine compiles again. ``dmf-sim warm-up`` (what ``make venv`` runs) compiles
every kernel where the user expects to wait; a command that finds a cold kernel anyway says so
before it compiles (:func:`warm_up`), and starts its progress bar only afterwards, so the bar's
rate does not include the compile.

A group of kernels (:class:`KernelGroup`) is defined beside its kernels: its ``warm_up`` calls
every entry point with the argument types of the real calls; ``kernels`` lists those entry points
(the helpers they call are compiled and cached with them).
"""
from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

__all__ = ['COMPILING', 'TIMES_FILE', 'KernelGroup', 'cached', 'cold', 'warm_up']

COMPILING = ('compiling the numerical kernels once (~{seconds:.0f} s {where}; later runs load '
             'them)')
"""The notice before a compile (``where``: 'on this machine' once a compile was timed here)."""

TIMES_FILE = 'dmf_sim_compile_seconds.json'
"""Beside a group's first kernel in numba's cache: the seconds its last compile took here."""


@dataclass(frozen=True)
class KernelGroup:
    """Kernels compiled and loaded together.

    name: short name (``sweep``); what: what uses them, for people; warm_up: calls every entry
    point
    once on a tiny problem with the real argument types; kernels: the entry points (numba
    dispatchers); estimate_s: compile seconds measured on a 2-core machine, the notice's figure
    until a compile was timed on this one.
    """

    name: str
    what: str
    warm_up: Callable[[], object]
    kernels: Callable[[], Sequence]
    estimate_s: float

    def cold(self) -> bool:
        """Whether loading the group compiles (a kernel neither loaded in this process nor in
        numba's cache)."""
        return any(not k.signatures and not cached(k) for k in self.kernels())

    def seconds(self) -> tuple[float, bool]:
        """(expected compile seconds, measured here) for the notice."""
        path = _times_path(self)
        try:
            return float(json.loads(path.read_text())[self.name]), True
        except (OSError, ValueError, KeyError, TypeError):
            return self.estimate_s, False

    def record(self, seconds: float) -> None:
        """Keep the seconds a compile of the group took here (nothing if it cannot be written)."""
        path = _times_path(self)
        try:
            times = json.loads(path.read_text()) if path.is_file() else {}
            times[self.name] = round(seconds, 1)
            path.write_text(json.dumps(times))
        except (OSError, ValueError, TypeError):
            pass


def cached(dispatcher) -> bool:
    """Whether numba's cache holds a compiled version of ``dispatcher`` for this machine, this
    numba and this source (any signature), read from the cache's index: nothing is compiled."""
    cache = getattr(dispatcher, '_cache', None)
    index_key = getattr(cache, '_index_key', None)
    if index_key is None:                 # a kernel without on-disk caching
        return False
    try:
        entries = cache._cache_file._load_index()
    except Exception:  # noqa: BLE001 - an unreadable index is a cold cache, never an error
        return False
    ref = index_key(None, dispatcher.targetctx.codegen())
    return any(key[1:] == ref[1:] for key in entries)


def cold(groups: Sequence[KernelGroup]) -> list[KernelGroup]:
    """The groups whose loading compiles."""
    return [g for g in groups if g.cold()]


def warm_up(groups: Sequence[KernelGroup], say: Callable[[str], None] | None = None,
         prefix: str = 'dmf-sim') -> list[tuple[KernelGroup, float, bool]]:
    """Load every group (compile the cold ones into the cache first); before a compile, one line
    :data:`COMPILING` through ``say`` (default: stderr, after ``prefix``). Returns (group,
    seconds, compiled) per group."""
    to_compile = cold(groups)
    if to_compile:
        times = [g.seconds() for g in to_compile]
        where = 'on this machine' if all(here for _, here in times) else 'on a 2-core machine'
        text = COMPILING.format(seconds=sum(s for s, _ in times), where=where)
        if say is None:
            print(f'{prefix}: {text}', file=sys.stderr, flush=True)
        else:
            say(text)
    done = []
    for g in groups:
        t0 = time.perf_counter()
        g.warm_up()
        seconds = time.perf_counter() - t0
        compiled = g in to_compile
        if compiled:
            g.record(seconds)
        done.append((g, seconds, compiled))
    return done


def _times_path(group: KernelGroup) -> Path:
    first = group.kernels()[0]
    return Path(first.stats.cache_path) / TIMES_FILE
