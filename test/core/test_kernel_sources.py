"""numba's cache keyed on every source a kernel is compiled from (dmf_sim.core.kernel_cache):
an edit to a module a kernel imports (the spring's law, a helper kernel, a constant) compiles the
kernel again instead of loading machine code made from the old source."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from dmf_sim.core import kernel_cache
from dmf_sim.core.kernel_cache import PACKAGE_ROOT, source_files, source_stamp


def _rel(files):
    return {str(f.relative_to(PACKAGE_ROOT)) for f in files}


def test_a_kernel_module_s_sources_are_what_it_imports_from_the_package():
    newmark = _rel(source_files(PACKAGE_ROOT / 'solvers' / 'newmark_kernel.py'))
    assert newmark == {'solvers/newmark_kernel.py', 'solvers/spring_kernels.py',
                       'core/compiled.py'}
    grid = _rel(source_files(PACKAGE_ROOT / 'solvers' / 'hbm' / 'continuation_kernels.py'))
    # the helpers it calls, through hbm/kernels.py the spring's law, and the constants' module
    assert {'solvers/hbm/kernels.py', 'solvers/hbm/dense_kernels.py', 'solvers/spring_kernels.py',
            'solvers/step_control.py', 'solvers/hbm/linear_kernels.py',
            'core/units.py'} <= grid
    assert 'solvers/newmark_kernel.py' not in grid
    assert 'core/kernel_cache.py' not in grid | newmark     # compiled into no kernel


def _package(tmp_path: Path, name: str = 'kpkg') -> Path:
    """A package laid out as dmf_sim is: kernels made by a call to jit at the end of their module,
    a constant in a module without kernels, a module without kernels that imports another."""
    root = tmp_path / name
    (root / 'sub').mkdir(parents=True)
    (root / '__init__.py').write_text('')
    (root / 'sub' / '__init__.py').write_text('')
    (root / 'law.py').write_text('SCALE = 2.0\n')
    (root / 'sub' / 'helper.py').write_text(
        'from numba import njit\n\nfrom ..law import SCALE\n\n\ndef g(x):\n'
        '    return SCALE * x\n\n\ng = njit(cache=True)(g)\n')
    (root / 'sub' / 'kernel.py').write_text(
        f'from numba import njit\n\nfrom {name}.sub import helper\nfrom {name} import \\\n'
        '    plain\n\n\n'
        'def f(x):\n    return helper.g(x) + 1.0\n\n\nf = njit(cache=True)(f)\n')
    (root / 'plain.py').write_text(f'import {name}.deep\n"""\nimport of nothing: text\n"""\n')
    (root / 'deep.py').write_text('Z = 0\n')
    return root


def test_the_stamp_follows_imports_absolute_relative_continued_and_transitive(tmp_path):
    root = _package(tmp_path)
    kernel = root / 'sub' / 'kernel.py'
    files = {str(f.relative_to(root)) for f in source_files(kernel, root)}
    # a module without kernels (plain) is part of it, not what it imports (deep)
    assert files == {'sub/kernel.py', 'sub/__init__.py', 'sub/helper.py', 'law.py', 'plain.py',
                     '__init__.py'}
    before = source_stamp(kernel, root)
    (root / 'deep.py').write_text('Z = 1\n')           # compiled into no kernel: the same key
    source_stamp.cache_clear()
    assert source_stamp(kernel, root) == before
    (root / 'law.py').write_text('SCALE = 3.0\n')      # imported through the helper: a new key
    source_stamp.cache_clear()
    assert source_stamp(kernel, root) != before


_RUN = """
import sys
sys.path.insert(0, {parent!r})
from pathlib import Path
from dmf_sim.core.kernel_cache import install_locators
assert install_locators(Path({root!r}))
from kpkg.sub.kernel import f
print(f(1.0))
"""


@pytest.mark.parametrize('where', ['beside the module', 'NUMBA_CACHE_DIR'])
def test_an_edited_helper_module_compiles_its_callers_again(tmp_path, where):
    """numba alone keys a cache entry on the kernel's own file: the caller would load machine
    code with the old helper inlined. With the package's locators it compiles again."""
    root = _package(tmp_path)
    env = {k: v for k, v in os.environ.items() if k != 'NUMBA_CACHE_DIR'}
    if where == 'NUMBA_CACHE_DIR':
        env['NUMBA_CACHE_DIR'] = str(tmp_path / 'cache')
    script = _RUN.format(parent=str(tmp_path), root=str(root))

    def run() -> float:
        out = subprocess.run([sys.executable, '-c', script], env=env, capture_output=True,
                             text=True, timeout=300, check=True)
        return float(out.stdout.split()[-1])

    assert run() == 3.0
    assert run() == 3.0                                   # loaded from the cache
    cached = list(tmp_path.rglob('*.nbi'))
    assert cached, 'the kernels were not cached'
    (root / 'law.py').write_text('SCALE = 100.0\n')
    assert run() == 101.0


def test_functions_outside_the_package_keep_numba_s_own_locators():
    from numba.core import caching

    import dmf_sim.core.compiled  # noqa: F401 - installs the locators, before any kernel
    impl = getattr(caching, 'CacheImpl', None) or getattr(caching, '_CacheImpl')
    ours = [c for c in impl._locator_classes if getattr(c, 'package_root', None) == PACKAGE_ROOT]
    assert len(ours) == 3
    assert all(c.from_function(test_functions_outside_the_package_keep_numba_s_own_locators,
                               __file__) is None for c in ours)
    assert kernel_cache.install_locators()                 # once: nothing added the second time
    assert len(impl._locator_classes) == len([*{id(c) for c in impl._locator_classes}])


def test_every_kernel_of_the_package_is_made_by_its_jit():
    """The locators are installed when dmf_sim.core.compiled is imported: a kernel made by
    numba's decorators directly could be made before that, with numba's own key in one process
    and the package's in another, each finding the other's cache entries stale."""
    import re
    direct = re.compile(r'numba\s*\.\s*(n?jit|vectorize|guvectorize|cfunc)\b|'
                        r'from\s+numba\s+import\s+[^\n]*\b(n?jit|vectorize|guvectorize|cfunc)\b')
    made_directly = [str(f.relative_to(PACKAGE_ROOT)) for f in sorted(PACKAGE_ROOT.rglob('*.py'))
                     if f.name != 'compiled.py' and direct.search(f.read_text())]
    assert made_directly == []
