"""Writing JSON: the one place every JSON the package prints or writes for a user is made, so that
each is valid JSON (RFC 8259) that any reader parses.

Python's ``json`` writes a float that is not finite as ``NaN``/``Infinity``, which is not JSON
(``jq``, JavaScript's ``JSON.parse`` and most libraries refuse the file). Here a number that is
not defined (NaN: a parameter's relative uncertainty where its value is 0, a peak not yet seen)
or not finite is written as ``null``; NumPy scalars and arrays become numbers and lists, paths
strings, tuples lists. The text is then made with ``allow_nan=False``, so a non-finite number
that slipped past the conversion is our bug, found at once, never a file a reader rejects.
"""
from __future__ import annotations

import json
import math
import numbers
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

__all__ = ['jsonable', 'json_text', 'write_json']


def jsonable(obj: Any, default: Callable[[Any], Any] | None = None) -> Any:
    """``obj`` with JSON types only: numbers not finite -> None, NumPy values -> Python ones,
    paths -> str, tuples and arrays -> lists, mapping keys -> str. Anything else goes through
    ``default`` (e.g. ``str``) if given, else stays (``json`` then refuses it: a bug)."""
    if obj is None or isinstance(obj, (str, bool)):
        return obj
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v, default) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v, default) for v in obj]
    if isinstance(obj, numbers.Integral):
        return int(obj)
    if isinstance(obj, numbers.Real):
        x = float(obj)
        return x if math.isfinite(x) else None
    if isinstance(obj, Path):
        return str(obj)
    if hasattr(obj, 'tolist') and hasattr(obj, 'dtype'):    # a NumPy array or scalar (without
        return jsonable(obj.tolist(), default)              # importing NumPy for the CLI)
    return obj if default is None else jsonable(default(obj))


def json_text(obj: Any, *, indent: int | None = None,
              default: Callable[[Any], Any] | None = None) -> str:
    """``obj`` as JSON text (:func:`jsonable`, then ``json.dumps(..., allow_nan=False)``)."""
    return json.dumps(jsonable(obj, default), indent=indent, allow_nan=False)


def write_json(path: str | Path, obj: Any, *, indent: int | None = 1,
               default: Callable[[Any], Any] | None = None) -> Path:
    """Write :func:`json_text` of ``obj`` (and a final newline) to ``path``; returns the path."""
    path = Path(path)
    path.write_text(json_text(obj, indent=indent, default=default) + '\n', encoding='utf-8')
    return path
