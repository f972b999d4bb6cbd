"""What DMF faults do to the spring and its damping, and the stage names they refer to.

The spring is read as springs in parallel (:meth:`PiecewiseLinearSpring.ramps
<dmf_sim.physics.spring.PiecewiseLinearSpring.ramps>`): the primary stiffness k acts
everywhere, each stage's increment beyond its knee. Stage 1 ``dmf_stiffness`` scales k (the
stages' increments [Nm/rad] stay), stage i >= 2 (drive stage i-1) or ``coast_j`` scales that
stage's increment, ``dmf_broken`` removes it; ``dmf_damping`` scales the DMF element's damping.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Iterable, Sequence

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.validation import field_error
from dmf_sim.physics.model import Driveline

if TYPE_CHECKING:
    from dmf_sim.physics.faults.fault import Fault

__all__ = ['DMF_DAMPING_FACTOR_MAX', 'check_stage', 'apply_dmf_faults']

DMF_DAMPING_FACTOR_MAX = 100.0
"""Largest DMF damping factor [-]: 100 times the design damping is far beyond any worn or
seized DMF; above it the damping term, not the spring, would set the wind-up."""


def check_stage(value: Any, where: str, line: Driveline | None, kind: str) -> str:
    """'1', '2', .. or 'coast_j', checked against the driveline's DMF when given."""
    if isinstance(value, str) and value.strip().isdigit():
        value = int(value.strip())
    if isinstance(value, str) and value.startswith('coast_') and value[6:].isdigit():
        side, idx = 'coast', int(value[6:])
    elif isinstance(value, int) and not isinstance(value, bool):
        side, idx = 'drive', int(value)
    else:
        raise field_error(where, 'stage', "must be a stage number >= 1 (1 = the primary "
                          "stiffness) or 'coast_1', 'coast_2', ...", value)
    if idx < 1:
        raise field_error(where, 'stage', 'must be >= 1 (1 = the primary stiffness)', value)
    text = str(idx) if side == 'drive' else f'coast_{idx}'
    if kind == 'dmf_broken' and text == '1':
        raise field_error(where, 'stage', "1 (the primary stiffness) cannot break: no spring "
                          "would be left below the first knee; give dmf_stiffness with a small "
                          "factor instead", value)
    if line is not None:
        if line.dmf is None:
            raise field_error(where, 'stage', f'refers to the DMF, but driveline {line.name!r} '
                              'has none')
        n_drive, n_coast = len(line.dmf.stages), len(line.dmf.coast_stages)
        have = [str(i) for i in range(1, n_drive + 2)] + [f'coast_{j}'
                                                          for j in range(1, n_coast + 1)]
        if text not in have:
            raise field_error(where, 'stage', f'{text} does not exist: the DMF of '
                              f'{line.name!r} has stages {", ".join(have)}')
    return text


def apply_dmf_faults(faults: Iterable[Fault], line: Driveline) -> Driveline:
    """The driveline with the DMF faults ``faults`` applied (the module docstring), built
    through :meth:`Driveline.with_dmf` (the one spring object); ``line`` itself when there are
    none. One-line ConfigError when the result is no valid spring (a stage factor beyond its
    limit)."""
    dmf = tuple(faults)
    if not dmf:
        return line
    if line.dmf is None:
        raise ConfigError(f'{dmf[0].label()}: driveline {line.name!r} has no DMF')
    spring = line.spring
    k = spring.k
    inc = {'drive': _increments(spring.drive, k), 'coast': _increments(spring.coast, k)}
    k_new = k
    damping = None
    for f in dmf:
        if f.kind == 'dmf_damping':
            damping = (line.dmf_element.damping if damping is None else damping) * f.factor
            continue
        side, idx = (('coast', int(f.stage[6:])) if f.stage.startswith('coast_')
                     else ('drive', int(f.stage) - 1))
        scale = 0.0 if f.kind == 'dmf_broken' else float(f.factor)
        if side == 'drive' and idx == 0:
            k_new *= scale
            continue
        stages = inc[side]
        if not 1 <= idx <= len(stages):
            raise ConfigError(f'{f.label()}: stage {f.stage} does not exist')
        stages[idx - 1] *= scale
    drive = _cumulative(spring.drive, inc['drive'], k_new)
    coast = _cumulative(spring.coast, inc['coast'], k_new)
    return line.with_dmf(k=k_new, stages=drive, coast_stages=coast, damping=damping)


def _increments(stages, k: float) -> list[float]:
    """Stiffness increment [Nm/rad] of each stage over the one before (ramp slopes)."""
    out, prev = [], 0.0
    for st in stages:
        out.append(k * (st.stiffness_factor - prev))
        prev = st.stiffness_factor
    return out


def _cumulative(stages, increments: Sequence[float], k: float) -> list[tuple[float, float]]:
    """(angle, stiffness factor) per stage from increments [Nm/rad] over primary stiffness k."""
    total, out = 0.0, []
    for st, c in zip(stages, increments):
        total += c
        out.append((st.angle_rad, total / k))
    return out
