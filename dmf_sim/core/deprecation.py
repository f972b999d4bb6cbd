"""Old names of the public API, kept working for a deprecation period: warned about in one place.

A public name that is renamed (``dmf_sim.__all__``, and the names the guides show) keeps its old
name as an alias that warns once per call site and then does what the new name does:

* a module-level name: the module lists ``{old: new}`` and delegates its PEP 562
  ``__getattr__`` to :func:`renamed` (``__getattr__ = renamed(__name__, {...}, globals())``);
* a method: ``old = renamed_method('new')`` in the class body;
* keywords that moved into an options object (``simulate(dt=...)`` ->
  ``simulate(options=SimulationOptions(dt=...))``): :func:`options_from_keywords` builds the
  options from them, so the old keywords and the options object take one code path.

Every warning is a :class:`DmfSimDeprecationWarning` (a ``DeprecationWarning``) naming the old
and the new spelling, raised at the caller's line (``stacklevel``). The test suite turns one
raised from inside ``dmf_sim`` into an error (``setup.cfg``), so the package itself never uses
an old name.
"""
from __future__ import annotations

import dataclasses
import functools
import warnings
from collections.abc import Callable, Mapping
from typing import Any, TypeVar

__all__ = ['DmfSimDeprecationWarning', 'warn_renamed', 'renamed', 'renamed_method',
           'options_from_keywords']

T = TypeVar('T')


class DmfSimDeprecationWarning(DeprecationWarning):
    """An old name or keyword of dmf_sim's API: it still works, the message names the new one."""


def warn_renamed(old: str, new: str, stacklevel: int = 3) -> None:
    """Warn that ``old`` is deprecated in favour of ``new``; ``stacklevel`` 3 points at the caller
    of the function that calls this one."""
    warnings.warn(f'{old} is deprecated; use {new}', DmfSimDeprecationWarning,
                  stacklevel=stacklevel)


def renamed(module: str, names: Mapping[str, str], namespace: dict[str, Any]
            ) -> Callable[[str], Any]:
    """A module's ``__getattr__`` (PEP 562) serving the old ``names`` (old -> new, the new one
    defined in ``namespace``, the module's ``globals()``) with a warning; any other missing
    name is the usual AttributeError."""
    def __getattr__(name: str) -> Any:
        new = names.get(name)
        if new is None:
            raise AttributeError(f'module {module!r} has no attribute {name!r}')
        warn_renamed(f'{module}.{name}', f'{module}.{new}')
        return namespace[new]
    return __getattr__


def renamed_method(new: str) -> Any:
    """A method alias: ``old = renamed_method('new')`` in a class body calls ``self.new`` after
    warning that ``Class.old`` is deprecated."""
    class _Alias:
        def __set_name__(self, owner: type, name: str) -> None:
            self.old, self.owner = name, owner.__name__

        def __get__(self, obj: Any, objtype: type | None = None) -> Any:
            target = getattr(objtype if obj is None else obj, new)
            if obj is None:
                return target

            @functools.wraps(target)
            def call(*args: Any, **kwargs: Any) -> Any:
                warn_renamed(f'{self.owner}.{self.old}()', f'{self.owner}.{new}()')
                return target(*args, **kwargs)
            return call
    return _Alias()


def options_from_keywords(cls: type[T], options: T | None, keywords: Mapping[str, Any],
                          function: str, stacklevel: int = 3) -> T:
    """The options object of a call: ``options`` (default ``cls()``) with the fields given as
    keywords the old way (a warning naming ``options=cls(...)``). A keyword that is no field of
    ``cls`` is the TypeError Python gives for an unexpected keyword. ``stacklevel`` 3: the
    caller of the public function that calls this one."""
    base = cls() if options is None else options
    if not keywords:
        return base
    fields = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(keywords) - fields)
    if unknown:
        raise TypeError(f'{function}() got an unexpected keyword argument {unknown[0]!r}')
    given = ', '.join(f'{k}=...' for k in keywords)
    warnings.warn(f'{function}({given}) is deprecated; use {function}(..., '
                  f'options={cls.__name__}({given}))', DmfSimDeprecationWarning,
                  stacklevel=stacklevel)
    return dataclasses.replace(base, **keywords)
