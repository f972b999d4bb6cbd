"""DMF design parameters by name, and building a design's driveline from them.

A design is a mapping ``{name: value}`` (SI units) applied to the study's base driveline through
:meth:`dmf_sim.physics.model.Driveline.with_dmf`. Names:

========================================  ===================================================
``k``                                     primary stiffness [Nm/rad] (> 0)
``damping``                               DMF damping [Nms/rad] (>= 0)
``theta``                                 first drive knee [rad] (> 0), = ``stages[0].angle_rad``
``alpha``                                 first drive stage factor (>= 0),
                                          = ``stages[0].stiffness_factor``
``stages[i].angle_rad``                   drive stage i: knee [rad] (> 0, increasing with i)
``stages[i].stiffness_factor``            drive stage i: stiffness k (1 + factor) (>= 0)
``coast_stages[j].angle_rad``             coast stage j: knee at -angle [rad] (> 0)
``coast_stages[j].stiffness_factor``      coast stage j: stiffness factor (>= 0)
``friction.torque_nm``                    arc-spring friction: constant part T0 [Nm] (>= 0)
``friction.speed_coefficient``            arc-spring friction: centrifugal part c_Omega
                                          [Nm s^2/rad^2] (>= 0)
========================================  ===================================================

Every value lies within the bound of its physical quantity (the table
:data:`dmf_sim.core.bounds.BOUNDS`, as in the driveline file). Stages not named keep the base
spring's values; a stage index one beyond the base spring's stages adds a stage (both its angle
and its factor must then be given). Stage angles that do not increase with the stage index make
that one design invalid (a per-design failure, reported with the spring's own message), not the
study.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace

from dmf_sim.core.bounds import BOUNDS
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.validation import bounded
from dmf_sim.physics.model import Driveline
from dmf_sim.physics.spring import ArcFriction, Stage

__all__ = ['ALIASES', 'SCALARS', 'FRICTION', 'STAGE_ATTRS', 'ALLOWED_TEXT', 'Parameter',
           'parse_parameter', 'check_parameter_set', 'design_driveline']

ALIASES = {'theta': ('stages', 0, 'angle_rad'), 'alpha': ('stages', 0, 'stiffness_factor')}
SCALARS = ('k', 'damping')
FRICTION = ('friction.torque_nm', 'friction.speed_coefficient')
"""The arc-spring friction's parameters (:class:`dmf_sim.physics.spring.ArcFriction`, eq. 8a);
the slip speed of its regularization stays the base driveline's."""
STAGE_ATTRS = ('angle_rad', 'stiffness_factor')
_STAGE_RE = re.compile(r'^(stages|coast_stages)\[(\d+)\]\.(angle_rad|stiffness_factor)$')
ALLOWED_TEXT = ('k, damping, theta, alpha, stages[i].angle_rad, stages[i].stiffness_factor, '
                'coast_stages[j].angle_rad, coast_stages[j].stiffness_factor, '
                'friction.torque_nm, friction.speed_coefficient')

# the physical quantity of each kind of parameter (its bound: the one table,
# dmf_sim.core.bounds.BOUNDS, as for the driveline file), and whether 0 is excluded
_QUANTITY = {'k': ('stiffness', True), 'damping': ('damping', False),
             'friction.torque_nm': ('friction_torque', False),
             'friction.speed_coefficient': ('friction_speed_coefficient', False),
             'angle_rad': ('windup_angle', False), 'stiffness_factor': ('stiffness_factor', False)}


@dataclass(frozen=True)
class Parameter:
    """One design parameter: its name as written and what it sets.

    ``kind`` is 'k', 'damping' or a stage attribute ('angle_rad' / 'stiffness_factor');
    ``side`` 'stages' / 'coast_stages' and ``index`` the stage for stage attributes."""

    name: str
    kind: str
    side: str | None = None
    index: int | None = None

    @property
    def key(self) -> tuple:
        """What the parameter sets (``theta`` and ``stages[0].angle_rad`` share one key)."""
        return (self.kind,) if self.side is None else (self.side, self.index, self.kind)

    @property
    def unit(self) -> str:
        return self.bound.unit

    @property
    def bound(self):
        """The :class:`~dmf_sim.core.bounds.Bound` of the parameter's physical quantity."""
        return BOUNDS[_QUANTITY[self.kind][0]]

    def check_value(self, value, where: str, field: str | None = None) -> float:
        """``value`` as a float within the parameter's allowed range (the bound of its physical
        quantity), else a one-line error naming ``where`` and ``field`` (default: the
        parameter's name)."""
        quantity, positive = _QUANTITY[self.kind]
        return bounded(value, where, field or self.name, quantity, positive=positive)


def parse_parameter(name: str, where: str) -> Parameter:
    """The :class:`Parameter` called ``name``; one-line ConfigError naming ``where`` otherwise."""
    if not isinstance(name, str):
        raise ConfigError(f'{where}: a parameter name must be text, got {name!r}')
    if name in SCALARS or name in FRICTION:
        return Parameter(name, name)
    if name in ALIASES:
        side, index, kind = ALIASES[name]
        return Parameter(name, kind, side, index)
    m = _STAGE_RE.match(name.replace(' ', ''))
    if m:
        return Parameter(name, m.group(3), m.group(1), int(m.group(2)))
    raise ConfigError(f'{where}: unknown design parameter {name!r} (allowed: {ALLOWED_TEXT})')


def check_parameter_set(params: list[Parameter], base: Driveline, where: str) -> None:
    """Study-level checks: no quantity named twice (``theta`` and ``stages[0].angle_rad``), and
    every stage named exists on the base spring or is added whole, right after its last stage."""
    seen: dict[tuple, str] = {}
    for p in params:
        if p.key in seen:
            raise ConfigError(f'{where}: {p.name!r} and {seen[p.key]!r} set the same quantity; '
                              'give it once')
        seen[p.key] = p.name
    spring = base.spring
    for side, have in (('stages', len(spring.drive)), ('coast_stages', len(spring.coast))):
        new = sorted({p.index for p in params if p.side == side and p.index >= have})
        for n, idx in enumerate(new):
            if idx != have + n:
                raise ConfigError(f'{where}: {side}[{idx}] does not exist (the base spring has '
                                  f'{have} {side.replace("_", " ")}); add stages in order from '
                                  f'{side}[{have}]')
            attrs = {p.kind for p in params if p.side == side and p.index == idx}
            if attrs != set(STAGE_ATTRS):
                missing = (set(STAGE_ATTRS) - attrs).pop()
                raise ConfigError(f'{where}: {side}[{idx}] is a new stage; give its {missing} too '
                                  '(as a variable or in fixed)')


def design_driveline(base: Driveline, values: dict[Parameter, float]) -> Driveline:
    """The base driveline with the design's DMF parameters (validated by the spring itself)."""
    spring = base.spring
    sides = {'stages': [[s.angle_rad, s.stiffness_factor] for s in spring.drive],
             'coast_stages': [[s.angle_rad, s.stiffness_factor] for s in spring.coast]}
    scalars: dict[str, float] = {}
    for p, v in sorted(values.items(), key=lambda item: (item[0].index or 0)):
        if p.side is None:
            scalars[p.kind] = float(v)
            continue
        stages = sides[p.side]
        while len(stages) <= p.index:
            stages.append([math.nan, math.nan])
        stages[p.index][STAGE_ATTRS.index(p.kind)] = float(v)
    friction = None
    if any(name in scalars for name in FRICTION):
        friction = replace(base.dmf.friction or ArcFriction(),
                           **{n.split('.', 1)[1]: scalars[n] for n in FRICTION if n in scalars})
    return base.with_dmf(k=scalars.get('k'), damping=scalars.get('damping'),
                         stages=tuple(Stage(a, f) for a, f in sides['stages']),
                         coast_stages=tuple(Stage(a, f) for a, f in sides['coast_stages']),
                         friction=friction)
