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
``phi = T q``. The DMF (if any) is the two-step spring of one element: its primary stiffness and
damping live in K and C, its extra stiffness is the non-linear force of eq. (7)-(8).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np
import yaml

from dmf_sim.dmf_spring import TwoStepSpring
from dmf_sim.paths import config_file

ELEMENT_KEYS = ('name', 'ratio', 'stiffness', 'damping', 'inertia')
TOP_KEYS_REQUIRED = ('name', 'elements')
TOP_KEYS_OPTIONAL = ('description', 'cylinders', 'firing_phases_deg', 'rear_load_element', 'dmf')
DMF_KEYS_REQUIRED = ('element', 'theta_rad', 'alpha')
DMF_KEYS_OPTIONAL = ('coast',)
COAST_KEYS = ('theta_rad', 'alpha')
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
    """Which element carries the two-step spring, and its knee parameters."""

    element: str
    theta: float
    alpha: float
    theta_coast: float | None = None
    alpha_coast: float = 0.0


@dataclass(frozen=True)
class Driveline:
    """A validated driveline description (element level, as in the YAML)."""

    name: str
    elements: tuple[Element, ...]
    cylinders: tuple[str, ...] = ()
    firing_phases_deg: tuple[float, ...] = ()
    rear_load_element: str | None = None
    dmf: DMFSpec | None = None
    description: str = ''

    @property
    def names(self) -> list[str]:
        return [e.name for e in self.elements]

    def index(self, name: str) -> int:
        """0-based index of the element called ``name``."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f'unknown element {name!r}; elements are {", ".join(self.names)}') from None

    def with_dmf(self, alpha: float | None = None, theta: float | None = None) -> 'Driveline':
        """A copy with other DMF knee parameters (alpha, theta [rad])."""
        if self.dmf is None:
            if alpha is None and theta is None:
                return self
            raise ValueError(f'driveline {self.name!r} has no dmf section; alpha/theta do not apply')
        dmf = replace(self.dmf,
                      alpha=self.dmf.alpha if alpha is None else float(alpha),
                      theta=self.dmf.theta if theta is None else float(theta))
        _check_spring(dmf, self)
        return replace(self, dmf=dmf)

    def reduce(self) -> 'ReducedModel':
        """Merge rigid connections into DOFs and assemble J, K, C (see ReducedModel)."""
        return ReducedModel(self)


# --------------------------------------------------------------------------------------------
# YAML loading and validation
# --------------------------------------------------------------------------------------------

def _num(value, where: str, field_name: str, allow_rigid: bool = False) -> float:
    if allow_rigid and isinstance(value, str) and value.strip().lower() in RIGID_WORDS:
        return math.inf
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        extra = " or 'rigid'" if allow_rigid else ''
        raise ValueError(f'{where}: field {field_name!r} must be a number{extra}, got {value!r}')
    v = float(value)
    if math.isnan(v) or (math.isinf(v) and not allow_rigid):
        raise ValueError(f'{where}: field {field_name!r} must be finite, got {value!r}')
    return v


def _check_keys(data: dict, required, optional, where: str) -> None:
    if not isinstance(data, dict):
        raise ValueError(f'{where}: expected a mapping, got {type(data).__name__}')
    for key in required:
        if key not in data:
            raise ValueError(f'{where}: missing key {key!r}')
    allowed = set(required) | set(optional)
    for key in data:
        if key not in allowed:
            raise ValueError(f'{where}: unknown key {key!r} (allowed: {", ".join(sorted(allowed))})')


def _parse_element(raw, pos: int) -> Element:
    where = f'element {pos + 1}'
    if isinstance(raw, dict) and 'name' in raw:
        where = f'element {pos + 1} ({raw["name"]})'
    _check_keys(raw, ELEMENT_KEYS, (), where)
    name = str(raw['name'])
    ratio = _num(raw['ratio'], where, 'ratio')
    if ratio == 0:
        raise ValueError(f'{where}: field \'ratio\' must be non-zero (allowed: any finite number != 0)')
    stiffness = _num(raw['stiffness'], where, 'stiffness', allow_rigid=True)
    if stiffness < 0:
        raise ValueError(f'{where}: field \'stiffness\' must be >= 0 Nm/rad or \'rigid\', got {stiffness}')
    damping = _num(raw['damping'], where, 'damping')
    if damping < 0:
        raise ValueError(f'{where}: field \'damping\' must be >= 0 Nms/rad, got {damping}')
    inertia = _num(raw['inertia'], where, 'inertia')
    if inertia <= 0:
        raise ValueError(f'{where}: field \'inertia\' must be > 0 kg m^2, got {inertia}')
    if math.isinf(stiffness) and damping != 0:
        raise ValueError(f'{where}: field \'damping\' must be 0 on a rigid connection, got {damping}')
    return Element(name, ratio, stiffness, damping, inertia)


def _check_spring(dmf: DMFSpec, line: 'Driveline') -> None:
    el = line.elements[line.index(dmf.element)]
    where = f'dmf (element {dmf.element})'
    if el.rigid:
        raise ValueError(f'{where}: the DMF cannot sit on a rigid element; field \'stiffness\' must be finite > 0')
    if el.stiffness <= 0:
        raise ValueError(f'{where}: field \'stiffness\' of the DMF element must be > 0 Nm/rad, got {el.stiffness}')
    if line.index(dmf.element) == 0:
        raise ValueError(f'{where}: the DMF cannot be the first element (it needs a primary side)')
    if not dmf.theta > 0:
        raise ValueError(f'{where}: field \'theta_rad\' must be > 0 rad, got {dmf.theta}')
    if not dmf.alpha >= 0:
        raise ValueError(f'{where}: field \'alpha\' must be >= 0, got {dmf.alpha}')
    if dmf.theta_coast is not None and not dmf.theta_coast > 0:
        raise ValueError(f'{where}: field \'coast.theta_rad\' must be > 0 rad, got {dmf.theta_coast}')
    if not dmf.alpha_coast >= 0:
        raise ValueError(f'{where}: field \'coast.alpha\' must be >= 0, got {dmf.alpha_coast}')


def driveline_from_dict(data: dict, source: str = 'driveline') -> Driveline:
    """Validate a parsed YAML mapping and build a Driveline. Errors are one line naming the field."""
    _check_keys(data, TOP_KEYS_REQUIRED, TOP_KEYS_OPTIONAL, source)
    raw_elements = data['elements']
    if not isinstance(raw_elements, list) or len(raw_elements) < 2:
        raise ValueError(f'{source}: field \'elements\' must be a list of at least 2 elements')
    elements = tuple(_parse_element(raw, i) for i, raw in enumerate(raw_elements))
    names = [e.name for e in elements]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ValueError(f'{source}: element names must be unique; repeated: {", ".join(dupes)}')
    if elements[0].rigid:
        raise ValueError(f'element 1 ({elements[0].name}): field \'stiffness\' cannot be rigid (it connects to ground)')

    cylinders = tuple(str(c) for c in data.get('cylinders') or ())
    phases = tuple(_num(p, source, 'firing_phases_deg') for p in data.get('firing_phases_deg') or ())
    if len(cylinders) != len(phases):
        raise ValueError(f'{source}: field \'firing_phases_deg\' needs one phase per cylinder '
                         f'({len(cylinders)} cylinders, {len(phases)} phases)')
    for c in cylinders:
        if c not in names:
            raise ValueError(f'{source}: field \'cylinders\' names unknown element {c!r}')
    rear = data.get('rear_load_element') or names[-1]
    if rear not in names:
        raise ValueError(f'{source}: field \'rear_load_element\' names unknown element {rear!r}')

    line = Driveline(name=str(data['name']), elements=elements, cylinders=cylinders,
                     firing_phases_deg=phases, rear_load_element=rear,
                     description=str(data.get('description') or ''))
    raw_dmf = data.get('dmf')
    if raw_dmf is not None:
        _check_keys(raw_dmf, DMF_KEYS_REQUIRED, DMF_KEYS_OPTIONAL, 'dmf')
        coast = raw_dmf.get('coast')
        theta_c, alpha_c = None, 0.0
        if coast is not None:
            _check_keys(coast, COAST_KEYS, (), 'dmf.coast')
            theta_c = _num(coast['theta_rad'], 'dmf.coast', 'theta_rad')
            alpha_c = _num(coast['alpha'], 'dmf.coast', 'alpha')
        element = str(raw_dmf['element'])
        if element not in names:
            raise ValueError(f'dmf: field \'element\' names unknown element {element!r}')
        dmf = DMFSpec(element=element,
                      theta=_num(raw_dmf['theta_rad'], 'dmf', 'theta_rad'),
                      alpha=_num(raw_dmf['alpha'], 'dmf', 'alpha'),
                      theta_coast=theta_c, alpha_coast=alpha_c)
        _check_spring(dmf, line)
        line = replace(line, dmf=dmf)
    return line


def load_driveline(source: str | os.PathLike = 'truck_dmf', *, alpha: float | None = None,
                   theta: float | None = None) -> Driveline:
    """Load and validate a driveline YAML: a config name (``truck_dmf``, ``truck_conventional``)
    or a path. ``alpha`` and ``theta`` [rad] override the DMF knee parameters."""
    path = config_file(source)
    try:
        data = yaml.safe_load(Path(path).read_text())
    except yaml.YAMLError as exc:
        raise ValueError(f'{path}: not valid YAML: {str(exc).splitlines()[0]}') from None
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
    spring: TwoStepSpring | None = field(init=False)
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
            d = self.line.dmf
            self.spring = TwoStepSpring(k=els[s].stiffness, theta=d.theta, alpha=d.alpha,
                                        theta_coast=d.theta_coast, alpha_coast=d.alpha_coast)

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

    def transmitted_torques(self, q, qd, qdd, element_loads) -> np.ndarray:
        """Torque [Nm] transmitted through every connection into element i, positive when driving.

        Flexible connection: T_i = -(k_i dphi_i + c_i d(dphi_i)/dt) (+ DMF non-linear part).
        Rigid connection: from element i's equation, T_i = j_i phi_i'' - p_i + T_{i+1}/r_{i+1}.
        ``element_loads`` are all external element torques (..., m), including any d'Alembert
        load of the reference motion; qdd the vibratory DOF accelerations consistent with them.
        """
        q, qd, qdd = (np.asarray(a, dtype=float) for a in (q, qd, qdd))
        p = np.asarray(element_loads, dtype=float)
        shape = q.shape[:-1] + (self.n_elements,)
        out = np.zeros(shape)
        dphi = q @ self.D.T
        dphid = qd @ self.D.T
        out[..., self.spring_elements] = -(self.spring_k * dphi + self.spring_c * dphid)
        if self.spring is not None:
            out[..., self.dmf_element] += self.spring.extra_torque(q @ self.e)
        acc = qdd @ self.T.T
        els = self.line.elements
        for i in range(self.n_elements - 1, 0, -1):
            if els[i].rigid:
                nxt = out[..., i + 1] / els[i + 1].ratio if i + 1 < self.n_elements else 0.0
                out[..., i] = els[i].inertia * acc[..., i] - p[..., i] + nxt
        return out


def load_model(source: str | os.PathLike = 'truck_dmf', *, alpha: float | None = None,
               theta: float | None = None) -> ReducedModel:
    """Shortcut: ``load_driveline(...).reduce()``."""
    return load_driveline(source, alpha=alpha, theta=theta).reduce()
