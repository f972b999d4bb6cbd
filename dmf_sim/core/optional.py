"""The optional libraries, imported in one place: a feature that needs one calls :func:`require`.

Design studies, the optimizer, durability and the node's Foxglove server use libraries the rest
of the package does not need; they come with the extras of ``setup.py`` (``pip install -e
'.[design]'``; ``[all]`` is every one, what ``make`` installs). :func:`require` imports such a
library and turns a missing one, or one that cannot be imported here (e.g. pyarrow 26 refuses
numpy < 2 when it is imported), into one line naming the library, the extra and the pip line
that installs it (:class:`~dmf_sim.core.errors.MissingExtraError`, exit 2 from ``dmf-sim``)
instead of a traceback. No module of the package imports these libraries otherwise
(``test/test_optional_libraries.py`` checks it).
"""
from __future__ import annotations

import importlib
import importlib.metadata
import re
from types import ModuleType

from dmf_sim.core.errors import MissingExtraError, one_line

__all__ = ['PACKAGE', 'OPTIONAL', 'EXTRAS', 'FEATURES', 'require', 'require_extra', 'pip_line']

PACKAGE = 'dmf_sim'

OPTIONAL: dict[str, tuple[str, str]] = {
    'dask': ('dask', 'design'),
    'distributed': ('distributed', 'design'),
    'pyarrow': ('pyarrow', 'design'),
    'optuna': ('optuna', 'optimize'),
    'fatpack': ('fatpack', 'durability'),
    'foxglove': ('foxglove-sdk', 'foxglove'),
}
"""Top-level import name -> (distribution, the extra of setup.py that installs it)."""

EXTRAS: dict[str, tuple[str, ...]] = {
    'design': ('dask', 'distributed', 'pyarrow'),
    'optimize': ('dask', 'distributed', 'pyarrow', 'optuna'),
    'durability': ('fatpack',),
    'foxglove': ('foxglove',),
}
"""Extra -> the optional libraries its feature imports (``[all]``: every extra)."""

FEATURES = {
    'design': 'design studies (dmf-sim design, run_study)',
    'optimize': 'the optimizer (dmf-sim optimize)',
    'durability': 'durability (dmf-sim durability)',
    'foxglove': "the node's Foxglove server (foxglove_port)",
}
"""Extra -> what needs it, as a message names it."""


def require(module: str, extra: str | None = None) -> ModuleType:
    """Import ``module`` (``'pyarrow.parquet'``) of an optional library; a missing or unusable
    library is a one-line :class:`MissingExtraError` naming it, the extra that installs it
    (``extra``: for a library two features share, the one the caller belongs to; default the
    library's own) and the pip line."""
    top = module.split('.')[0]
    dist, own = OPTIONAL[top]
    extra = extra or own
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.split('.')[0] != top:
            problem = f'{dist} cannot be imported ({one_line(exc)})'
        else:
            problem = f'{dist} is not installed'
    except Exception as exc:  # noqa: BLE001 - a library refusing this environment at import
        problem = f'{dist} {_version(dist)} cannot be used here ({one_line(exc)})'
    raise MissingExtraError(f'{problem}; install the {extra!r} extra for {FEATURES[extra]}: '
                            f'{pip_line(extra)}')


def require_extra(extra: str) -> None:
    """Every library of ``extra`` importable, else the one-line error of the first that is not
    (what a command calls before it starts any work)."""
    for module in EXTRAS[extra]:
        require(module, extra)


def pip_line(extra: str) -> str:
    """The pip command that installs ``extra``: its requirements as this installation of the
    package declares them (pip or colcon alike), else the extra from the source tree."""
    reqs = _requirements(extra)
    if reqs:
        return 'pip install ' + ' '.join(f"'{r}'" for r in reqs)
    return f"pip install -e '.[{extra}]' in the dmf_sim source tree"


def _requirements(extra: str) -> list[str]:
    try:
        declared = importlib.metadata.requires(PACKAGE) or []
    except importlib.metadata.PackageNotFoundError:
        return []
    marker = re.compile(rf'extra\s*==\s*["\']{re.escape(extra)}["\']')
    out = []
    for req in declared:
        spec, _, cond = req.partition(';')
        if marker.search(cond):
            out.append(spec.replace(' ', ''))
    return out


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return '(version unknown)'
