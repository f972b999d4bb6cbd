"""Writing CSV tables: the one place every CSV file of the package is written, so that numbers
read as a person wrote them.

Floats are written with 12 significant digits (``%.12g``): ``0.24`` rather than
``0.24000000000000002`` (a sum of grid steps), ``1e-05`` rather than ``1.0000000000000001e-05``,
still far below every tolerance the package works to (the solvers' relative tolerances are
1e-10 or coarser). Integers and text are written as they are, ``None`` as an empty field, NaN as
``nan``.
"""
from __future__ import annotations

import csv
import math
import numbers
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

FLOAT_FORMAT = '.12g'
"""Format of every float in a CSV file (12 significant digits)."""

__all__ = ['FLOAT_FORMAT', 'csv_value', 'write_csv']


def csv_value(value: Any) -> Any:
    """One field: floats (Python or NumPy) formatted with :data:`FLOAT_FORMAT`, ``None`` as ''."""
    if value is None:
        return ''
    if isinstance(value, (bool, numbers.Integral, str)):
        return value
    if isinstance(value, numbers.Real):
        x = float(value)
        return 'nan' if math.isnan(x) else format(x, FLOAT_FORMAT)
    return value


def write_csv(path: str | Path, header: Sequence[str],
              rows: Iterable[Sequence[Any] | Mapping[str, Any]],
              comments: Sequence[str] = ()) -> Path:
    """Write ``comments`` (each as a ``# `` line), ``header`` and ``rows`` (sequences in header
    order, or mappings by header name; keys not in the header are left out, missing ones are
    empty) to ``path``."""
    path = Path(path)
    with open(path, 'w', newline='') as fh:
        for line in comments:
            fh.write(f'# {line}\n')
        w = csv.writer(fh)
        w.writerow(header)
        for row in rows:
            if isinstance(row, Mapping):
                row = [row.get(k) for k in header]
            w.writerow([csv_value(v) for v in row])
    return path
