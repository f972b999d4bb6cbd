"""What combustion faults do to the excitation: the combustion windows of a cylinder and the
persistent combustion factors s_k a steady state sees (doc/theory.md, "Faults").

Cylinder k fires with a combustion factor s_k (1 healthy, 0 misfire, ``factor`` of a weak
cylinder); combustion m of cylinder k owns the crank-angle window [TDC_km - 180 deg, TDC_km +
540 deg) with TDC_km = beta_k + 720 deg m, and its factor is decided when its window opens
(:class:`~dmf_sim.physics.faults.FaultTimeline`).
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Iterable

import numpy as np

from dmf_sim.core.errors import ConfigError

if TYPE_CHECKING:
    from dmf_sim.physics.faults.fault import Fault

__all__ = ['CYCLE_RAD', 'WINDOW_OPEN_RAD', 'combustion_windows', 'combustion_factors']

CYCLE_RAD = 4.0 * math.pi               # one engine cycle, 720 deg
WINDOW_OPEN_RAD = -math.pi              # a combustion's window opens 180 deg before its TDC


def combustion_windows(beta_rad: float, psi_from: float, psi_to: float) -> np.ndarray:
    """Crank angles [rad] in (psi_from, psi_to] where the windows of a cylinder of firing phase
    ``beta_rad`` open (``beta + 720 deg m - 180 deg``)."""
    first = math.floor((psi_from - beta_rad - WINDOW_OPEN_RAD) / CYCLE_RAD) + 1
    last = math.floor((psi_to - beta_rad - WINDOW_OPEN_RAD) / CYCLE_RAD)
    return beta_rad + WINDOW_OPEN_RAD + CYCLE_RAD * np.arange(first, last + 1)


def combustion_factors(faults: Iterable[Fault], n_cylinders: int) -> np.ndarray:
    """Per-cylinder combustion factors s_k (n_cylinders,) of the persistent combustion faults
    among ``faults``: an every-cycle misfire 0, a weak cylinder its factor, healthy 1 (several
    on one cylinder multiply); other faults are left out."""
    s = np.ones(int(n_cylinders))
    for f in faults:
        if f.kind == 'misfire' and f.mode == 'every_cycle':
            factor = 0.0
        elif f.kind == 'weak_cylinder':
            factor = float(f.factor)
        else:
            continue
        for c in f.cylinders:
            if not 1 <= c <= len(s):
                raise ConfigError(f'{f.label()}: cylinder {c} outside 1..{len(s)}')
            s[c - 1] *= factor
    return s
