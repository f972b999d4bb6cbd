"""How the package writes a number in a message: every digit it needs, nothing more."""
from __future__ import annotations

import math

__all__ = ['fmt_num']


def fmt_num(value: float) -> str:
    """A number with every digit it needs to be told apart (shortest round-trip repr; integral
    values without '.0'): 2200.001 -> '2200.001', 2200.0 -> '2200'."""
    v = float(value)
    if math.isfinite(v) and v == int(v) and abs(v) < 1e15:
        return str(int(v))
    return repr(v)
