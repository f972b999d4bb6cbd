"""The driveline model: elements in series (paper Table 1, Fig. 3-4) read from YAML.

Element i connects element i-1 to element i through gear ratio r_i, a spring k_i and a viscous
damper c_i, followed by the inertia j_i. The spring elongation is

    dphi_i = phi_i - phi_{i-1} / r_i                                   (paper, before eq. 1)

Element equation (eq. 1): k_i dphi_i + c_i d(dphi_i)/dt + tau_{i+1}/r_{i+1} + j_i phi_i'' = p_i.
Assembling it for the chain gives eq. (5)-(6); the damping matrix carries c/r^2 on the diagonal
exactly like K (the printed eq. 6 has c/r, a misprint: the dissipation function is
sum 1/2 c_i (d dphi_i/dt)^2).

Infinite stiffness ("rigid" in YAML) is a rigid connection: rigidly connected inertias are merged
into one degree of freedom (DOF) through the gear ratios, and every element angle is recovered by
``phi = T q``. The DMF (if any) is the piecewise-linear spring of one element
(dmf_sim.physics.spring): its
primary stiffness and damping live in K and C, its extra torque g is the non-linear force of
eq. (7)-(8).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np

from dmf_sim.core.bounds import BOUNDS
from dmf_sim.core.deprecation import renamed
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.paths import read_yaml_mapping
from dmf_sim.core.validation import as_number, bounded, check_keys, field_error
from dmf_sim.physics.sensors import SensorSet, parse_sensors
from dmf_sim.physics.spring import ArcFriction, EndStops, PiecewiseLinearSpring, Stage

__all__ = ['ELEMENT_KEYS', 'TOP_KEYS_REQUIRED', 'TOP_KEYS_OPTIONAL', 'DMF_KEYS_REQUIRED',
           'DMF_KEYS_OPTIONAL', 'FRICTION_KEYS', 'END_STOP_KEYS', 'END_STOP_KEYS_OPTIONAL',
           'COAST_KEYS', 'STAGE_KEYS', 'STAGE_ANGLE_KEYS', 'RIGID_WORDS',
           'Element', 'DMFSpec', 'Driveline', 'driveline_from_dict', 'read_driveline',
           'ReducedModel', 'read_model']

ELEMENT_KEYS = ('name', 'ratio', 'stiffness', 'damping', 'inertia')
TOP_KEYS_REQUIRED = ('name', 'elements')
TOP_KEYS_OPTIONAL = ('description', 'cylinders', 'firing_phases_deg', 'rear_load_element', 'dmf',
                     'sensors')
DMF_KEYS_REQUIRED = ('element',)
DMF_KEYS_OPTIONAL = ('stiffness', 'stages', 'coast_stages', 'theta_rad', 'alpha', 'coast',
                     'friction', 'end_stops')
FRICTION_KEYS = ('torque_nm', 'speed_coefficient', 'regularization_rad_s')
END_STOP_KEYS = ('drive_angle_rad', 'coast_angle_rad', 'stiffness')
END_STOP_KEYS_OPTIONAL = ('damping',)
COAST_KEYS = ('theta_rad', 'alpha')
STAGE_KEYS = ('stiffness_factor',)
STAGE_ANGLE_KEYS = ('angle_rad', 'angle')   # the same quantity [rad]; give one
RIGID_WORDS = ('rigid', 'inf', '.inf', 'infinite', '∞')


@dataclass(frozen=True)
class Element:
    """One torsional element (a row of Table 1). SI units: Nm/rad, Nms/rad, kg m^2."""

    name: str
    ratio: float
    stiffness: float      # math.inf for a rigid connection
    damping: float
    inertia: float

    @property
    def rigid(self) -> bool:
        return math.isinf(self.stiffness)


@dataclass(frozen=True)
class DMFSpec:
    """Which element carries the DMF spring, and its stages (dmf_sim.physics.spring).

    The element's own stiffness is the primary stiffness k, its damping the DMF damping.
    ``stages`` / ``coast_stages``: drive / coast stages; the paper's (theta, alpha) is one drive
    stage (:attr:`theta`, :attr:`alpha` read the first one). ``friction``: the arc springs'
    friction, ``end_stops``: the travel's stops (None: none; dmf_sim.physics.spring).
    """

    element: str
    stages: tuple[Stage, ...] = ()
    coast_stages: tuple[Stage, ...] = ()
    friction: ArcFriction | None = None
    end_stops: EndStops | None = None

    @property
    def theta(self) -> float:
        """First drive knee [rad] (inf without drive stages)."""
        return self.stages[0].angle_rad if self.stages else math.inf

    @property
    def alpha(self) -> float:
        """Stiffness factor of the first drive stage (0 without drive stages)."""
        return self.stages[0].stiffness_factor if self.stages else 0.0

    def spring(self, k: float) -> PiecewiseLinearSpring:
        """The spring with primary stiffness ``k`` [Nm/rad] (validates the stages)."""
        return PiecewiseLinearSpring(k, self.stages, self.coast_stages, self.friction,
                                     self.end_stops)


@dataclass(frozen=True)
class Driveline:
    """A validated driveline description (element level, as in the YAML); ``sensors``: its
    tooth wheels and bus signals (:mod:`dmf_sim.physics.sensors`, empty without a
    ``sensors:`` section)."""

    name: str
    elements: tuple[Element, ...]
    cylinders: tuple[str, ...] = ()
    firing_phases_deg: tuple[float, ...] = ()
    rear_load_element: str | None = None
    dmf: DMFSpec | None = None
    description: str = ''
    sensors: SensorSet = SensorSet()

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.elements]

    def index(self, name: str) -> int:
        """0-based index of the element called ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ConfigError(f'unknown element {name!r}; elements are '
                              f'{", ".join(self.names)}') from None

    @property
    def dmf_element(self) -> Element | None:
        return self.elements[self.index(self.dmf.element)] if self.dmf is not None else None

    @property
    def spring(self) -> PiecewiseLinearSpring | None:
        """The DMF spring (primary stiffness from the DMF element), or None without a DMF."""
        return self.dmf.spring(self.dmf_element.stiffness) if self.dmf is not None else None

    def with_dmf(self, alpha: float | None = None, theta: float | None = None, *,
                 k: float | None = None, damping: float | None = None,
                 stages=None, coast_stages=None, friction=None) -> 'Driveline':
        """A copy with other DMF data. ``alpha``, ``theta`` [rad]: the paper's shorthand on the
        first drive stage; ``stages`` / ``coast_stages``: sequences of :class:`Stage` (or
        (angle_rad, stiffness_factor) pairs) replacing them; ``k`` [Nm/rad] and ``damping``
        [Nms/rad]: the DMF element's primary stiffness and damping; ``friction``: an
        :class:`~dmf_sim.physics.spring.ArcFriction` replacing the arc springs' friction."""
        given = (alpha, theta, k, damping, stages, coast_stages, friction)
        if self.dmf is None:
            if all(v is None for v in given):
                return self
            raise ConfigError(f'driveline {self.name!r} has no dmf section; '
                              'DMF parameters do not apply')
        if stages is not None and (alpha is not None or theta is not None):
            raise ConfigError('dmf: give either stages or the (alpha, theta) shorthand, not both')
        spring = self.spring
        if stages is not None or coast_stages is not None:
            spring = spring.replace(drive=None if stages is None else _as_stages(stages),
                                    coast=(None if coast_stages is None
                                           else _as_stages(coast_stages)))
        spring = spring.with_first_stage(theta=theta, alpha=alpha)
        if k is not None:
            spring = spring.replace(k=k)
        els = list(self.elements)
        s = self.index(self.dmf.element)
        el = els[s]
        if k is not None or damping is not None:
            d = el.damping if damping is None else bounded(damping, 'dmf', 'damping', 'damping')
            els[s] = replace(el, stiffness=spring.k, damping=d)
        dmf = replace(self.dmf, stages=spring.drive, coast_stages=spring.coast)
        if friction is not None:
            dmf = replace(dmf, friction=friction)
        line = replace(self, elements=tuple(els), dmf=dmf)
        _check_spring(dmf, line)
        return line

    def with_spring(self, spring) -> 'Driveline':
        """A copy whose DMF spring is ``spring`` as
        :meth:`~dmf_sim.physics.spring.PiecewiseLinearSpring.as_dict` gives it (what a recording
        stores): k [Nm/rad], the drive and coast stages, and the friction and end stops it holds
        (absent: none; eq. 8a-8b), each checked as in a file (one-line ConfigError)."""
        def pairs(items) -> list[tuple[float, float]]:
            return [(float(s['angle_rad']), float(s['stiffness_factor'])) for s in items or []]
        line = self.with_dmf(k=spring['k'], stages=pairs(spring['stages']),
                             coast_stages=pairs(spring['coast_stages']))
        dmf = replace(line.dmf, friction=_parse_friction(spring.get('friction')),
                      end_stops=_parse_end_stops(spring.get('end_stops')))
        line = replace(line, dmf=dmf)
        _check_spring(dmf, line)
        return line

    def reduce(self) -> 'ReducedModel':
        """Merge rigid connections into DOFs and assemble J, K, C (see ReducedModel)."""
        return ReducedModel(self)


# --------------------------------------------------------------------------------------------
# YAML loading and validation
# --------------------------------------------------------------------------------------------

def _num(value, where: str, field_name: str, quantity: str, allow_rigid: bool = False) -> float:
    """A finite number within the bound of its physical ``quantity`` (the one table,
    :data:`dmf_sim.core.bounds.BOUNDS`), or with ``allow_rigid`` also 'rigid' = inf."""
    if not allow_rigid:
        return bounded(value, where, field_name, quantity)
    if isinstance(value, str) and value.strip().lower() in RIGID_WORDS:
        return math.inf
    if isinstance(value, (int, float)) and not isinstance(value, bool) and value == math.inf:
        return math.inf
    if not isinstance(as_number(value), (int, float)) or isinstance(value, bool):
        raise field_error(where, field_name, "must be a number or 'rigid'", value)
    try:
        return bounded(value, where, field_name, quantity)
    except ConfigError:
        raise field_error(where, field_name, f"must be {BOUNDS[quantity].text()} or 'rigid'",
                          float(as_number(value))) from None


def _check_keys(data: dict, required, optional, where: str) -> None:
    check_keys(data, where, '', required, optional)


def _parse_element(raw, pos: int) -> Element:
    where = f'element {pos + 1}'
    if isinstance(raw, dict) and 'name' in raw:
        where = f'element {pos + 1} ({raw["name"]})'
    _check_keys(raw, ELEMENT_KEYS, (), where)
    name = str(raw['name'])
    ratio = _num(raw['ratio'], where, 'ratio', 'ratio')
    stiffness = _num(raw['stiffness'], where, 'stiffness', 'stiffness', allow_rigid=True)
    damping = _num(raw['damping'], where, 'damping', 'damping')
    inertia = _num(raw['inertia'], where, 'inertia', 'inertia')
    if math.isinf(stiffness) and damping != 0:
        raise ConfigError(f'{where}: field \'damping\' must be 0 on a rigid connection, '
                          f'got {damping}')
    return Element(name, ratio, stiffness, damping, inertia)


def _as_stages(items) -> tuple[Stage, ...]:
    out = []
    for it in items:
        out.append(it if isinstance(it, Stage) else Stage(float(it[0]), float(it[1])))
    return tuple(out)


def _parse_stages(raw, where: str) -> tuple[Stage, ...]:
    if not isinstance(raw, list):
        raise ConfigError(f'{where}: expected a list of {{angle_rad, stiffness_factor}} mappings, '
                          f'got {type(raw).__name__}')
    out = []
    for i, item in enumerate(raw):
        w = f'{where}[{i}]'
        _check_keys(item, STAGE_KEYS, STAGE_ANGLE_KEYS, w)
        angles = [key for key in STAGE_ANGLE_KEYS if key in item]
        if len(angles) != 1:
            raise ConfigError(f'{w}: give the stage angle [rad] once, '
                              'as \'angle_rad\' (or \'angle\')')
        out.append(Stage(_num(item[angles[0]], w, angles[0], 'windup_angle'),
                         _num(item['stiffness_factor'], w, 'stiffness_factor',
                              'stiffness_factor')))
    return tuple(out)


def _shorthand_stage(raw: dict, where: str) -> Stage:
    """The paper's (theta_rad, alpha) as one stage, with errors naming those fields."""
    return Stage(bounded(raw['theta_rad'], where, 'theta_rad', 'windup_angle'),
                 bounded(raw['alpha'], where, 'alpha', 'stiffness_factor'))


def _parse_dmf(raw, names: list[str]) -> DMFSpec:
    _check_keys(raw, DMF_KEYS_REQUIRED, DMF_KEYS_OPTIONAL, 'dmf')
    element = str(raw['element'])
    if element not in names:
        raise ConfigError(f'dmf: field \'element\' names unknown element {element!r}')
    short = [key for key in ('theta_rad', 'alpha') if key in raw]
    if 'stages' in raw:
        if short:
            raise ConfigError(f'dmf: give either \'stages\' or the shorthand '
                              f'\'theta_rad\'/\'alpha\', not both (found {", ".join(short)})')
        stages = _parse_stages(raw['stages'], 'dmf.stages')
    elif len(short) == 2:
        stages = (_shorthand_stage(raw, 'dmf'),)
    elif short:
        missing = 'alpha' if short == ['theta_rad'] else 'theta_rad'
        raise ConfigError(f"dmf: missing key {missing!r} (the shorthand needs 'theta_rad' and "
                          "'alpha'; or give 'stages')")
    else:
        raise ConfigError('dmf: missing key \'stages\' '
                          '(or the shorthand \'theta_rad\' and \'alpha\')')
    coast = raw.get('coast')
    if 'coast_stages' in raw:
        if coast is not None:
            raise ConfigError('dmf: give either \'coast_stages\' or the shorthand \'coast\', '
                              'not both')
        coast_stages = _parse_stages(raw['coast_stages'], 'dmf.coast_stages')
    elif coast is not None:
        _check_keys(coast, COAST_KEYS, (), 'dmf.coast')
        coast_stages = (_shorthand_stage(coast, 'dmf.coast'),)
    else:
        coast_stages = ()
    return DMFSpec(element=element, stages=stages, coast_stages=coast_stages,
                   friction=_parse_friction(raw.get('friction')),
                   end_stops=_parse_end_stops(raw.get('end_stops')))


def _parse_friction(raw) -> ArcFriction | None:
    """``dmf.friction``: {torque_nm, speed_coefficient, regularization_rad_s} (eq. 8a; every key
    optional, the defaults of :class:`ArcFriction`); absent or all zero: no friction."""
    if raw is None:
        return None
    check_keys(raw, 'dmf.friction', '', (), FRICTION_KEYS)
    law = ArcFriction(**{key: raw[key] for key in FRICTION_KEYS if key in raw})
    return law if law.active else None


def _parse_end_stops(raw) -> EndStops | None:
    """``dmf.end_stops``: {drive_angle_rad, coast_angle_rad, stiffness, damping} (eq. 8b)."""
    if raw is None:
        return None
    check_keys(raw, 'dmf.end_stops', '', END_STOP_KEYS, END_STOP_KEYS_OPTIONAL)
    return EndStops(**{key: raw[key] for key in END_STOP_KEYS + END_STOP_KEYS_OPTIONAL
                       if key in raw})


def _check_spring(dmf: DMFSpec, line: 'Driveline') -> None:
    el = line.elements[line.index(dmf.element)]
    where = f'dmf (element {dmf.element})'
    if el.rigid:
        raise ConfigError(f'{where}: the DMF cannot sit on a rigid element; '
                          'field \'stiffness\' must be finite > 0')
    if el.stiffness <= 0:
        raise ConfigError(f'{where}: field \'stiffness\' of the DMF element must be > 0 Nm/rad, '
                          f'got {el.stiffness}')
    if line.index(dmf.element) == 0:
        raise ConfigError(f'{where}: the DMF cannot be the first element '
                          '(it needs a primary side)')
    dmf.spring(el.stiffness)          # validates the stages (one-line ConfigError)


def driveline_from_dict(data: dict, source: str = 'driveline') -> Driveline:
    """Validate a parsed YAML mapping and build a Driveline. Errors are one line naming the
    field."""
    _check_keys(data, TOP_KEYS_REQUIRED, TOP_KEYS_OPTIONAL, source)
    raw_elements = data['elements']
    if not isinstance(raw_elements, list) or len(raw_elements) < 2:
        raise ConfigError(f'{source}: field \'elements\' must be a list of at least 2 elements')
    elements = tuple(_parse_element(raw, i) for i, raw in enumerate(raw_elements))
    names = [e.name for e in elements]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ConfigError(f'{source}: element names must be unique; repeated: {", ".join(dupes)}')
    if elements[0].rigid:
        raise ConfigError(f'element 1 ({elements[0].name}): field \'stiffness\' cannot be rigid '
                          '(it connects to ground)')

    cylinders = tuple(str(c) for c in data.get('cylinders') or ())
    phases = tuple(_num(p, source, f'firing_phases_deg[{i}]', 'firing_phase')
                   for i, p in enumerate(data.get('firing_phases_deg') or ()))
    if len(cylinders) != len(phases):
        raise ConfigError(f'{source}: field \'firing_phases_deg\' needs one phase per cylinder '
                          f'({len(cylinders)} cylinders, {len(phases)} phases)')
    for c in cylinders:
        if c not in names:
            raise ConfigError(f'{source}: field \'cylinders\' names unknown element {c!r}')
    rear = data.get('rear_load_element') or names[-1]
    if rear not in names:
        raise ConfigError(f'{source}: field \'rear_load_element\' names unknown element {rear!r}')

    line = Driveline(name=str(data['name']), elements=elements, cylinders=cylinders,
                     firing_phases_deg=phases, rear_load_element=rear,
                     description=str(data.get('description') or ''),
                     sensors=parse_sensors(data.get('sensors'), names))
    raw_dmf = data.get('dmf')
    if raw_dmf is not None:
        dmf = _parse_dmf(raw_dmf, names)
        if 'stiffness' in raw_dmf:
            k = _num(raw_dmf['stiffness'], 'dmf', 'stiffness', 'stiffness')
            el = elements[names.index(dmf.element)]
            if k != el.stiffness:
                raise ConfigError(f'dmf: field \'stiffness\' = {k:g} Nm/rad differs from the '
                                  f'stiffness {el.stiffness:g} Nm/rad of element '
                                  f'{dmf.element!r}; give the primary stiffness in one place')
        _check_spring(dmf, line)
        line = replace(line, dmf=dmf)
    return line


def read_driveline(source: str | os.PathLike = 'truck_dmf', *, alpha: float | None = None,
                   theta: float | None = None) -> Driveline:
    """Load and validate a driveline YAML: a config name (``truck_dmf``, ``truck_conventional``)
    or a path. ``alpha`` and ``theta`` [rad] override the first drive stage of the DMF."""
    path, data = read_yaml_mapping(source, 'driveline')
    line = driveline_from_dict(data, source=str(path))
    return line.with_dmf(alpha=alpha, theta=theta)


# --------------------------------------------------------------------------------------------
# Reduced (merged) model
# --------------------------------------------------------------------------------------------

@dataclass
class ReducedModel:
    """J, K, C in DOF space with rigid connections merged.

    Attributes (n = number of DOFs, m = number of elements):
        T: (m, n) element angles from DOFs, ``phi = T q``.
        J, K, C: (n, n) inertia [kg m^2], stiffness [Nm/rad], damping [Nms/rad] (eq. 5-6).
        D: (n_springs, n) elongation rows ``dphi_i = D[row] q`` of every flexible connection.
        spring_elements: element index of each row of D.
        spring_k, spring_c: stiffness [Nm/rad] and damping [Nms/rad] of each row of D.
        e: (n,) wind-up row ``w = e q`` of the DMF (zeros without a DMF).
        R: (m,) cumulative gear ratio of each element; a rigid rotation is ``phi_i = psi / R_i``.
        rigid_mode: (n,) DOF vector of the rigid rotation (psi = 1 rad), or None if grounded.
    """

    line: Driveline
    T: np.ndarray = field(init=False)
    J: np.ndarray = field(init=False)
    K: np.ndarray = field(init=False)
    C: np.ndarray = field(init=False)
    D: np.ndarray = field(init=False)
    spring_elements: np.ndarray = field(init=False)
    spring_k: np.ndarray = field(init=False)
    spring_c: np.ndarray = field(init=False)
    e: np.ndarray = field(init=False)
    R: np.ndarray = field(init=False)
    dof_of_element: np.ndarray = field(init=False)
    spring: PiecewiseLinearSpring | None = field(init=False)
    dmf_element: int | None = field(init=False)

    def __post_init__(self) -> None:
        els = self.line.elements
        m = len(els)
        ratios = np.array([e.ratio for e in els])
        self.R = np.cumprod(ratios)
        # Group elements: a new DOF starts at every non-rigid connection.
        dof = np.zeros(m, dtype=int)
        T = np.zeros((m, m))
        n = -1
        for i, el in enumerate(els):
            if i == 0 or not el.rigid:
                n += 1
                T[i, n] = 1.0
            else:  # rigid: phi_i = phi_{i-1} / r_i
                T[i, n] = T[i - 1, n] / el.ratio
            dof[i] = n
        self.T = T[:, :n + 1]
        self.dof_of_element = dof
        n_dof = n + 1
        self.J = self.T.T @ np.diag([e.inertia for e in els]) @ self.T

        rows, spring_el, ks, cs = [], [], [], []
        for i, el in enumerate(els):
            if el.rigid or (el.stiffness == 0 and el.damping == 0):
                continue
            row = self.T[i].copy()
            if i > 0:
                row -= self.T[i - 1] / el.ratio          # dphi_i = phi_i - phi_{i-1}/r_i
            rows.append(row)
            spring_el.append(i)
            ks.append(el.stiffness)
            cs.append(el.damping)
        self.D = np.array(rows).reshape(len(rows), n_dof)
        self.spring_elements = np.array(spring_el, dtype=int)
        self.spring_k = np.array(ks)
        self.spring_c = np.array(cs)
        # Eq. (6) with the misprint fixed: both K and C are D^T diag(.) D (c/r^2 on the diagonal).
        self.K = self.D.T @ (self.spring_k[:, None] * self.D)
        self.C = self.D.T @ (self.spring_c[:, None] * self.D)

        self.e = np.zeros(n_dof)
        self.spring = None
        self.dmf_element = None
        if self.line.dmf is not None:
            s = self.line.index(self.line.dmf.element)
            self.dmf_element = s
            row = int(np.flatnonzero(self.spring_elements == s)[0])
            self.e = -self.D[row].copy()                 # w = -dphi_s, positive when driving
            self.spring = self.line.spring

    # ---- sizes and names ------------------------------------------------------------------
    @property
    def n_dof(self) -> int:
        return self.T.shape[1]

    @property
    def n_elements(self) -> int:
        return self.T.shape[0]

    @property
    def names(self) -> list[str]:
        return self.line.names

    @cached_property
    def rigid_mode(self) -> np.ndarray | None:
        """DOF vector of a rigid rotation of 1 rad at element 1, or None if K is regular."""
        q = np.linalg.lstsq(self.T, 1.0 / self.R, rcond=None)[0]
        if self.line.elements[0].stiffness > 0 or not np.allclose(self.T @ q, 1.0 / self.R):
            return None
        return q

    @cached_property
    def equivalent_inertia(self) -> float:
        """J_eq = sum j_i / R_i^2 [kg m^2]: the whole driveline's inertia seen at element 1."""
        return float(sum(e.inertia / r**2 for e, r in zip(self.line.elements, self.R)))

    def element_vector(self, element_loads: np.ndarray) -> np.ndarray:
        """Generalized DOF load from element loads [Nm]: ``T^T p`` (virtual work)."""
        return np.asarray(element_loads) @ self.T

    # ---- recovering element quantities ----------------------------------------------------
    def windup(self, q: np.ndarray) -> np.ndarray:
        """DMF wind-up [rad] for DOF vectors q (..., n)."""
        return np.asarray(q) @ self.e

    def element_angles(self, q: np.ndarray) -> np.ndarray:
        """Element angles (..., m) from DOF vectors (..., n) through the rigid constraints."""
        return np.asarray(q) @ self.T.T

    def transmitted_torques(self, q, qd, qdd, element_loads, extra_torque=None) -> np.ndarray:
        """Torque [Nm] transmitted through every connection into element i, positive when driving.

        Flexible connection: T_i = -(k_i dphi_i + c_i d(dphi_i)/dt) (+ DMF non-linear part).
        Rigid connection: from element i's equation, T_i = j_i phi_i'' - p_i + T_{i+1}/r_{i+1}.
        ``element_loads`` are all external element torques (..., m), including any d'Alembert
        load of the reference motion; qdd the vibratory DOF accelerations consistent with them.
        ``extra_torque``: the DMF's non-linear torque g [Nm] (...,); default g(e q) of the spring.
        Real states, or complex harmonics (q_n, i Om q_n, -Om^2 q_n, p_n, g_n) alike.
        """
        q, qd, qdd, p = (np.asarray(a) for a in (q, qd, qdd, element_loads))
        dtype = np.result_type(q, qd, qdd, p, float)
        out = np.zeros(q.shape[:-1] + (self.n_elements,), dtype=dtype)
        dphi = q @ self.D.T
        dphid = qd @ self.D.T
        out[..., self.spring_elements] = -(self.spring_k * dphi + self.spring_c * dphid)
        if extra_torque is not None:
            out[..., self.dmf_element] += extra_torque
        elif self.spring is not None:
            out[..., self.dmf_element] += self.spring.extra_torque(q @ self.e)
        acc = qdd @ self.T.T
        els = self.line.elements
        for i in range(self.n_elements - 1, 0, -1):
            if els[i].rigid:
                nxt = out[..., i + 1] / els[i + 1].ratio if i + 1 < self.n_elements else 0.0
                out[..., i] = els[i].inertia * acc[..., i] - p[..., i] + nxt
        return out


def read_model(source: str | os.PathLike = 'truck_dmf', *, alpha: float | None = None,
               theta: float | None = None) -> ReducedModel:
    """Shortcut: ``read_driveline(...).reduce()``."""
    return read_driveline(source, alpha=alpha, theta=theta).reduce()


__getattr__ = renamed(__name__, {'load_model': 'read_model', 'load_driveline': 'read_driveline'},
                      globals())
