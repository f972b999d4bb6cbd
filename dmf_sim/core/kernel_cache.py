"""numba's on-disk cache of the package's compiled kernels: whether it holds a kernel (found
without compiling anything), and loading groups of kernels with a notice when they must be
compiled first.

The kernels (:func:`dmf_sim.core.compiled.jit`) are compiled on their first call on a machine
and kept in numba's cache: ``__pycache__`` beside each module, or, where that directory is not
writable (a package installed read-only), numba's per-user cache directory; ``NUMBA_CACHE_DIR``
puts every entry under one directory instead. A cache entry belongs to the kernel's sources,
numba's version and this CPU, so a new release, an edited module or another machine compiles
again. numba itself keys an entry on the kernel's own file only, while the machine code also
holds the kernels it calls and the constants it reads from other modules (the spring's law in
:mod:`dmf_sim.solvers.spring_kernels` is compiled into the Newmark step, the AFT and the
monodromy): an edit there would leave the callers' entries in use, running the old law. The
package's locators (:func:`install_locators`, installed by :mod:`dmf_sim.core.compiled` before
any kernel is made) key every entry of the package on the contents of its module and of every
package module that module imports, directly or not (:func:`source_stamp`).
``dmf-sim warm-up`` (what ``make venv`` runs) compiles every kernel where the user expects to
wait; a command that finds a cold kernel anyway says so before it compiles (:func:`warm_up`),
and starts its progress bar only afterwards, so the bar's rate does not include the compile.

A group of kernels (:class:`KernelGroup`) is defined beside its kernels: its ``warm_up`` calls
every entry point with the argument types of the real calls; ``kernels`` lists those entry points
(the helpers they call are compiled and cached with them).
"""
from __future__ import annotations

import ast
import functools
import hashlib
import json
import re
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from dmf_sim.core.json_out import json_text

__all__ = ['COMPILING', 'TIMES_FILE', 'KernelGroup', 'cached', 'cold', 'warm_up',
           'source_files', 'source_stamp', 'install_locators']

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
            path.write_text(json_text(times))
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


# ---- what a kernel's machine code is made of: its module and the package modules it imports ----
PACKAGE_ROOT = Path(__file__).resolve().parents[1]
"""The package's directory (``dmf_sim/``): the modules whose sources key the cache."""
_THIS = Path(__file__).resolve()     # imported by every kernel module, compiled into none


def _module_file(name: str, root: Path) -> Path | None:
    """The file of module ``name`` (``dmf_sim.a.b``) of the package at ``root``, found without
    importing it; None for a name that is not one of its modules (an attribute imported from
    one, another package)."""
    parts = name.split('.')
    if parts[0] != root.name:
        return None
    base = root.joinpath(*parts[1:])
    for f in (base.with_suffix('.py'), base / '__init__.py'):
        if f.is_file():
            return f.resolve()
    return None


_IMPORT = re.compile(rb'^[ \t]*(from[ \t]+[.\w]+[ \t]+import[ \t]*(?:\([^)]*\)|(?:\\\n|[^\n])*)'
                     rb'|import[ \t]+(?:\\\n|[^\n])*)', re.MULTILINE)
"""An import statement at any indentation, its parenthesized or backslash-continued lines
included (found by pattern rather than by parsing the whole module: a kernel's stamp is
computed as its module is imported)."""


def _statement(text: str) -> ast.stmt | None:
    """The import statement ``text`` parsed; None for text that only looks like one (in a
    string)."""
    try:
        (node,) = ast.parse(text).body
    except (SyntaxError, ValueError):
        return None
    return node


@functools.lru_cache(maxsize=None)
def _imported_files(path: Path, root: Path) -> tuple[Path, ...]:
    """The files of the modules of the package at ``root`` that the module at ``path`` imports
    (``import dmf_sim.x``, ``from dmf_sim.x import y``, ``from . import y``: for the last two
    both ``x`` and ``x.y``, as either may be a module). Imports inside functions count too: more
    than a kernel can read, never less."""
    package = path.parent.relative_to(root.parent).parts
    names: set[str] = set()
    for match in _IMPORT.finditer(path.read_bytes()):
        node = _statement(match.group(1).decode())
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                up = package[:len(package) - node.level + 1]
                module = '.'.join(up + ((node.module,) if node.module else ()))
            else:
                module = node.module or ''
            names.add(module)
            names.update(f'{module}.{a.name}' for a in node.names)
    files = {_module_file(n, root) for n in names} - {None, _THIS}
    return tuple(sorted(files))


@functools.lru_cache(maxsize=None)
def _compiles(path: Path) -> bool:
    """Whether the module at ``path`` makes kernels (calls ``jit``): only such a module's
    imports reach further into a kernel's machine code."""
    return b'jit(' in path.read_bytes()


@functools.lru_cache(maxsize=None)
def source_files(path: Path, root: Path = PACKAGE_ROOT) -> tuple[Path, ...]:
    """The module at ``path``, the modules of the package at ``root`` it imports, and theirs
    through every module that makes kernels or is a package's ``__init__`` (which may pass on a
    kernel it imports): everything a kernel defined there can compile in (the kernels it calls,
    wherever they are defined, and the constants it and they read from the modules they
    import). Another module without kernels is included, not followed: nothing of what it
    imports is compiled unless a kernel module imports that too."""
    path, root = path.resolve(), root.resolve()
    seen = {path}
    todo = [path]
    while todo:
        f = todo.pop()
        if f != path and f.name != '__init__.py' and not _compiles(f):
            continue
        for g in _imported_files(f, root):
            if g not in seen:
                seen.add(g)
                todo.append(g)
    return tuple(sorted(seen))


@functools.lru_cache(maxsize=None)
def source_stamp(path: Path, root: Path = PACKAGE_ROOT) -> bytes:
    """SHA-256 over the contents of :func:`source_files` (with their paths in the package): the
    key of every cache entry of a kernel defined in the module at ``path``."""
    root = root.resolve()
    h = hashlib.sha256()
    for f in source_files(path, root):
        h.update(str(f.relative_to(root)).encode())
        h.update(hashlib.sha256(f.read_bytes()).digest())
    return h.digest()


@functools.lru_cache(maxsize=None)
def _inside(py_file: str, root: Path) -> bool:
    return Path(py_file).resolve().is_relative_to(root)


def install_locators(root: Path = PACKAGE_ROOT) -> bool:
    """Put cache locators for the package at ``root`` before numba's own: numba's locators
    (cache beside the module; per-user; ``NUMBA_CACHE_DIR``) with the entries of the package's
    kernels keyed by :func:`source_stamp` instead of the kernel's file alone; a function outside
    the package is left to numba's. Once per process and root; returns whether they are
    installed (False where this numba has no locators to extend: numba's own keys stay)."""
    try:
        from numba.core import caching
    except ImportError:  # pragma: no cover - numba is a hard dependency
        return False
    impl = getattr(caching, 'CacheImpl', None) or getattr(caching, '_CacheImpl', None)
    bases = [getattr(caching, n, None) or getattr(caching, '_' + n, None)
             for n in ('UserProvidedCacheLocator', 'InTreeCacheLocator', 'UserWideCacheLocator')]
    current = getattr(impl, '_locator_classes', None)
    if current is None or None in bases:    # pragma: no cover - another numba's layout
        return False
    root = root.resolve()
    if any(getattr(c, 'package_root', None) == root for c in current):
        return True

    class _PackageSources:
        package_root = root

        @classmethod
        def from_function(cls, py_func, py_file):
            if not _inside(py_file, root):
                return None
            return super().from_function(py_func, py_file)

        def get_source_stamp(self):
            return source_stamp(Path(self._py_file), root)

    ours = [type(f'Package{b.__name__.lstrip("_")}', (_PackageSources, b), {}) for b in bases]
    impl._locator_classes = [*ours, *current]
    return True
