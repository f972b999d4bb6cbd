"""The study file: schema, validation (one line naming the field) and the resolved :class:`Study`.

A study (YAML mapping; ``config/study_example.yaml`` shows every key)::

    name: alpha_theta                 # optional (default: the file name)
    driveline: truck_dmf              # driveline YAML (config name or path): the base design
    engine: engine_d13                # engine YAML or A_n table
    sampling: {method: lhs, n: 200, seed: 1}     # grid | random | lhs
    variables:                        # design parameters (dmf_sim.design.parameters) and ranges
      alpha: {min: 1.0, max: 5.0}     # grid: also n (levels), or values: [...]
      theta: {min: 0.18, max: 0.30}
    fixed: {stages[1].angle_rad: 0.35}           # optional: parameters held at one value
    conditions:
      load_sets: [A, B]
      loads: [1.0]                    # torque demands -1..1 (below 0: engine braking)
      speeds_rpm: {from: 600, to: 2000, step: 10}
      load_steps:                     # optional: tip-ins/tip-outs per design, time domain
        - {speed_rpm: 1200, from: 0, to: 1, rise_s: 0.1}  # (dmf_sim.design.transient)
      road_cycle: {profile: truck_road_cycle, from_s: 10, to_s: 42}   # optional: a drive
                                      # cycle's window per design (friction heat)
    objectives: [worst_order_1_5, worst_torque_3]   # minimized; the first two: Pareto front
    torque_element: INPUT SHAFT       # optional: where the 3rd-order torque is taken
    solver: {harmonics: 24, branch_switching: true, search: true}  # optional; search: the
                                      # full steady-state search (false: continuation only);
                                      # time_limit_s: 30 -> a condition whose sweep takes
                                      # longer is recorded as failed (reason: the time limit)
    plots: {map_variables: [alpha, theta], reference: {alpha: 3, theta: 0.24}}   # optional

Everything is checked, and the driveline and engine are loaded, before any design is evaluated.
"""
from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dmf_sim.core.deprecation import renamed
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.validation import Where
from dmf_sim.design import sampling
from dmf_sim.design.metrics import OBJECTIVES
from dmf_sim.design.parameters import Parameter, check_parameter_set, parse_parameter
from dmf_sim.design.transient import (
    CYCLE,
    TRANSIENT,
    LoadStep,
    RoadCycle,
    parse_load_steps,
    parse_road_cycle,
)
from dmf_sim.physics.model import Driveline
from dmf_sim.solvers.hbm.sweep import TIME_LIMIT_RANGE_S

__all__ = ['REQUIRED', 'OPTIONAL', 'DEFAULT_TORQUE_ELEMENT', 'DEFAULT_HARMONICS', 'MIN_HARMONICS',
           'MAX_DESIGNS', 'MAX_GRID_SPEEDS', 'PAPER_REFERENCE', 'Condition', 'Study', 'read_study',
           'study_from_dict']

REQUIRED = ('driveline', 'engine', 'sampling', 'variables', 'conditions', 'objectives')
OPTIONAL = ('name', 'description', 'fixed', 'torque_element', 'solver', 'plots')
DEFAULT_TORQUE_ELEMENT = 'INPUT SHAFT'
DEFAULT_HARMONICS = 24
MIN_HARMONICS = 6            # the 3rd order is half-order n = 6
MAX_DESIGNS = 1_000_000
MAX_GRID_SPEEDS = 20_000
PAPER_REFERENCE = {'alpha': 3.0, 'theta': 0.24}
"""The paper's design (Fig. 13: alpha 3, theta 0.24 rad), drawn beside the best design."""


@dataclass(frozen=True)
class Condition:
    """One operating condition: load set (A/B/C) and load fraction -1..1 (below 0: braking)."""

    load_set: str
    load: float

    @property
    def label(self) -> str:
        return f'{self.load_set} {self.load:g}'


@dataclass
class Study:
    """A validated study with its base driveline and engines loaded (see the module docstring)."""

    name: str
    source: str
    driveline: str
    engine: str
    method: str
    n_samples: int | None
    seed: int
    params: list[Parameter]
    ranges: list[sampling.VariableRange]
    grid_points: list[int]
    fixed: dict[Parameter, float]
    conditions: list[Condition]
    speeds_rpm: tuple[float, float, float]
    objectives: list[str]
    torque_element: str
    harmonics: int
    branch_switching: bool
    map_variables: tuple[str, ...]
    search: bool = True
    time_limit_s: float | None = None
    reference: dict[Parameter, float] = field(default_factory=dict)
    description: str = ''
    base: Driveline = field(default=None, repr=False)
    engines: dict = field(default_factory=dict, repr=False)
    file_digest: str = ''
    load_steps: list[LoadStep] = field(default_factory=list)
    road_cycle: RoadCycle | None = None

    @property
    def variable_names(self) -> list[str]:
        return [p.name for p in self.params]

    def designs(self) -> np.ndarray:
        """(n_designs, n_variables) values, the same for every run of this study."""
        if self.method == 'grid':
            return sampling.grid(self.ranges, self.grid_points)
        if self.method == 'random':
            return sampling.uniform_random(self.ranges, self.n_samples, self.seed)
        return sampling.latin_hypercube(self.ranges, self.n_samples, self.seed)

    @property
    def n_designs(self) -> int:
        if self.method == 'grid':
            return int(np.prod([len(r.levels(n)) for r, n in zip(self.ranges, self.grid_points)]))
        return int(self.n_samples)

    def as_dict(self) -> dict:
        """The normalized study (JSON-able; stored beside the results)."""
        lo, hi, step = self.speeds_rpm
        return {
            'name': self.name, 'description': self.description, 'source': self.source,
            'driveline': self.driveline, 'engine': self.engine,
            'sampling': {'method': self.method, 'n': self.n_samples, 'seed': self.seed},
            'variables': {r.name: {'min': r.low, 'max': r.high, 'n': n, 'values': list(r.values)}
                          for r, n in zip(self.ranges, self.grid_points)},
            'fixed': {p.name: v for p, v in self.fixed.items()},
            'conditions': {'load_sets': sorted({c.load_set for c in self.conditions}),
                           'loads': sorted({c.load for c in self.conditions}),
                           'speeds_rpm': {'from': lo, 'to': hi, 'step': step},
                           'load_steps': [st.as_dict() for st in self.load_steps],
                           **({'road_cycle': self.road_cycle.as_dict()}
                              if self.road_cycle is not None else {})},
            'objectives': list(self.objectives), 'torque_element': self.torque_element,
            'solver': {'harmonics': self.harmonics, 'branch_switching': self.branch_switching,
                       'search': self.search, 'time_limit_s': self.time_limit_s},
            'plots': {'map_variables': list(self.map_variables),
                      'reference': {p.name: v for p, v in self.reference.items()}},
            'n_designs': self.n_designs,
        }

    def fingerprint(self) -> str:
        """Hash of what determines the stored rows: the normalized study (less its name, text,
        file location, objectives and plots, which only shape the final Pareto front and
        figures) and the driveline and engine file contents."""
        d = self.as_dict()
        for key in ('name', 'description', 'source', 'objectives', 'plots'):
            d.pop(key)
        text = json.dumps(d, sort_keys=True) + self.file_digest
        return hashlib.sha256(text.encode()).hexdigest()[:16]


# ------------------------------------------------------------------------------------------------
# Loading and validation
# ------------------------------------------------------------------------------------------------

def read_study(source) -> Study:
    """A :class:`Study` from a study file (name in config/ or path), a mapping, or a Study."""
    if isinstance(source, Study):
        return source
    from dmf_sim.core.paths import read_yaml_mapping
    if isinstance(source, dict):
        return study_from_dict(source, 'study', base_dir=Path.cwd())
    path, data = read_yaml_mapping(source, 'design study')
    return study_from_dict(data, str(path), base_dir=path.parent, default_name=path.stem)


def study_from_dict(data: dict, source: str = 'study', *, base_dir: Path | None = None,
                    default_name: str = 'study') -> Study:
    """Validate a parsed study mapping; load its driveline and engines. One-line ConfigErrors."""
    w = Where(source)
    w.mapping(data, '', REQUIRED, OPTIONAL)
    base_dir = base_dir or Path.cwd()
    name = str(data.get('name') or default_name)

    samp = w.mapping(data['sampling'], 'sampling', ('method',), ('n', 'seed'))
    method = samp['method']
    if method not in sampling.METHODS:
        raise w.error('sampling.method', f'must be one of {", ".join(sampling.METHODS)}',
                      method)
    seed = w.integer(samp.get('seed', 0), 'sampling.seed', 0, 2**32 - 1)
    n_samples = None
    if method == 'grid':
        if 'n' in samp:
            raise w.error('sampling.n', 'not used by the grid method (give n or values per '
                          'variable)')
    else:
        if 'n' not in samp:
            raise ConfigError(f"{w.source}: missing key 'sampling.n' (number of {method} "
                              'designs)')
        n_samples = w.integer(samp['n'], 'sampling.n', 1, MAX_DESIGNS)

    base = _load_driveline(w, data['driveline'], base_dir)
    params, ranges, points = _variables(w, data['variables'], method)
    fixed = {}
    for key, value in w.mapping(data.get('fixed') or {}, 'fixed').items():
        p = parse_parameter(key, f'{source}: fixed')
        fixed[p] = p.check_value(value, source, f'fixed.{key}')
    check_parameter_set(params + list(fixed), base, f'{source}: variables/fixed')
    n_designs = int(np.prod([len(r.levels(n)) for r, n in zip(ranges, points)])) \
        if method == 'grid' else n_samples
    if n_designs > MAX_DESIGNS:
        raise w.error('variables', f'the grid has {n_designs} designs; at most {MAX_DESIGNS}')

    engines, conditions, speeds, load_steps, cycle = _conditions(w, data['conditions'],
                                                                 data['engine'], base_dir)
    objectives = _objectives(w, data['objectives'], bool(load_steps), cycle is not None)
    torque_element = str(data.get('torque_element', DEFAULT_TORQUE_ELEMENT))
    if torque_element not in base.names:
        raise w.error('torque_element', f'no element {torque_element!r} in driveline '
                      f'{base.name!r} (elements: {", ".join(base.names)})')
    solver = w.mapping(data.get('solver') or {}, 'solver', (),
                       ('harmonics', 'branch_switching', 'search', 'time_limit_s'))
    harmonics = w.integer(solver.get('harmonics', DEFAULT_HARMONICS), 'solver.harmonics',
                          MIN_HARMONICS, 64)
    switching = solver.get('branch_switching', True)
    if not isinstance(switching, bool):
        raise w.error('solver.branch_switching', 'must be true or false', switching)
    search = solver.get('search', True)
    if not isinstance(search, bool):
        raise w.error('solver.search', 'must be true or false', search)
    time_limit = solver.get('time_limit_s')
    if time_limit is not None:
        time_limit = w.number(time_limit, 'solver.time_limit_s', *TIME_LIMIT_RANGE_S, 's')
    plots = w.mapping(data.get('plots') or {}, 'plots', (), ('map_variables', 'reference'))
    reference = {}
    ref_raw = w.mapping(plots.get('reference', PAPER_REFERENCE), 'plots.reference')
    for key, value in ref_raw.items():
        p = parse_parameter(key, f'{source}: plots.reference')
        reference[p] = p.check_value(value, source, f'plots.reference.{key}')
    check_parameter_set(list(reference), base, f'{source}: plots.reference')
    names = [p.name for p in params]
    map_vars = tuple(plots.get('map_variables', names[:2]))
    for i, v in enumerate(map_vars):
        if v not in names:
            raise w.error(f'plots.map_variables[{i}]', f'{v!r} is not a design variable '
                          f'(variables: {", ".join(names)})')
    if len(map_vars) != min(2, len(names)) or len(set(map_vars)) != len(map_vars):
        raise w.error('plots.map_variables', f'need {min(2, len(names))} different design '
                      f'variables, got {list(map_vars)!r}')
    return Study(name=name, source=source, driveline=str(data['driveline']),
                 engine=str(data['engine']), method=method, n_samples=n_samples, seed=seed,
                 params=params, ranges=ranges, grid_points=points, fixed=fixed,
                 conditions=conditions, speeds_rpm=speeds, objectives=objectives,
                 torque_element=torque_element, harmonics=harmonics,
                 branch_switching=switching, search=search, time_limit_s=time_limit,
                 map_variables=map_vars,
                 reference=reference,
                 description=str(data.get('description') or ''), base=base, engines=engines,
                 file_digest=_digest(base_dir, data['driveline'], data['engine']),
                 load_steps=load_steps, road_cycle=cycle)


def _resolve(value, base_dir: Path) -> str:
    """A config name as given, or a path relative to the study file's directory if one is there."""
    text = os.fspath(value) if isinstance(value, (str, os.PathLike)) else value
    if isinstance(text, str) and text.strip():
        beside = base_dir / text
        if not Path(text).is_absolute() and beside.is_file():
            return str(beside)
    return text


def _load_driveline(w: Where, value, base_dir: Path) -> Driveline:
    from dmf_sim.physics.model import read_driveline
    if not isinstance(value, str) or not value.strip():
        raise w.error('driveline', f'must be a driveline YAML name or path, got {value!r}')
    try:
        line = read_driveline(_resolve(value, base_dir))
    except ConfigError as exc:
        raise w.error('driveline', str(exc)) from None
    if line.dmf is None:
        raise w.error('driveline', f'driveline {line.name!r} has no dmf section: nothing to '
                      'design')
    return line


def _variables(w: Where, raw, method: str):
    if not isinstance(raw, dict) or not raw:
        raise w.error('variables', f'must be a non-empty mapping of design parameters, '
                      f'got {raw!r}')
    params, ranges, points = [], [], []
    for name, spec in raw.items():
        where = f'variables.{name}'
        p = parse_parameter(name, f'{w.source}: variables')
        keys = ('min', 'max', 'n', 'values') if method == 'grid' else ('min', 'max')
        w.mapping(spec, where, (), keys)
        if 'values' in spec:
            if set(spec) != {'values'}:
                raise w.error(where, "give either 'values' or 'min'/'max'/'n', not both")
            vals = w.nonempty_list(spec['values'], f'{where}.values')
            vals = tuple(p.check_value(v, w.source, f'{where}.values[{i}]')
                         for i, v in enumerate(vals))
            if len(set(vals)) != len(vals):
                raise w.error(f'{where}.values', 'repeated values')
            ranges.append(sampling.VariableRange(name, min(vals), max(vals), vals))
            points.append(len(vals))
            params.append(p)
            continue
        for key in ('min', 'max') + (('n',) if method == 'grid' else ()):
            if key not in spec:
                raise ConfigError(f"{w.source}: missing key '{where}.{key}'")
        lo = p.check_value(spec['min'], w.source, f'{where}.min')
        hi = p.check_value(spec['max'], w.source, f'{where}.max')
        if not lo < hi:
            raise w.error(where, f'empty range: min {lo:g} must be < max {hi:g} {p.unit}'.rstrip())
        n = w.integer(spec['n'], f'{where}.n', 2, MAX_DESIGNS) if method == 'grid' else 0
        ranges.append(sampling.VariableRange(name, lo, hi))
        points.append(n)
        params.append(p)
    return params, ranges, points


def _conditions(w: Where, raw, engine_source, base_dir: Path):
    from dmf_sim.physics.engine import load_error, read_engine
    w.mapping(raw, 'conditions', ('load_sets', 'loads', 'speeds_rpm'),
              ('load_steps', 'road_cycle'))
    load_sets = w.nonempty_list(raw['load_sets'], 'conditions.load_sets')
    loads = w.nonempty_list(raw['loads'], 'conditions.loads')
    loads = [w.bounded(x, f'conditions.loads[{i}]', 'load') for i, x in enumerate(loads)]
    sp = w.mapping(raw['speeds_rpm'], 'conditions.speeds_rpm', ('from', 'to', 'step'), ())
    lo = w.bounded(sp['from'], 'conditions.speeds_rpm.from', 'engine_speed')
    hi = w.bounded(sp['to'], 'conditions.speeds_rpm.to', 'engine_speed')
    step = w.bounded(sp['step'], 'conditions.speeds_rpm.step', 'engine_speed', positive=True)
    if not (hi > lo and step > 0):
        raise w.error('conditions.speeds_rpm', f'need to > from and step > 0 rpm, got from '
                      f'{lo:g}, to {hi:g}, step {step:g}')
    if (hi - lo) / step > MAX_GRID_SPEEDS:
        raise w.error('conditions.speeds_rpm.step', f'{(hi - lo) / step:.0f} speeds; at most '
                      f'{MAX_GRID_SPEEDS}')
    if not isinstance(engine_source, str) or not engine_source.strip():
        raise w.error('engine', f'must be an engine YAML or table name or path, '
                      f'got {engine_source!r}')
    src = _resolve(engine_source, base_dir)
    engines: dict = {}
    for i, ls in enumerate(load_sets):
        if not isinstance(ls, str):
            raise w.error(f'conditions.load_sets[{i}]', f'must be a load set name, got {ls!r}')
        if ls in engines:
            raise w.error(f'conditions.load_sets[{i}]', f'{ls!r} is listed twice')
        try:
            engines[ls] = (engines[load_sets[0]].with_load_set(ls) if engines
                           else read_engine(src, load_set=ls))
        except ConfigError as exc:
            if not engines and _engine_error(src):    # the file itself, not the load set
                raise w.error('engine', str(exc)) from None
            raise w.error(f'conditions.load_sets[{i}]', str(exc)) from None
        if i == 0 and hasattr(engines[ls], 'warm'):
            engines[ls].warm_up()          # the gas-pressure grid, once, shared by every load set
        rng = getattr(engines[ls], 'speed_range_rpm', None)
        if rng is not None and not (rng[0] <= lo and hi <= rng[1]):
            raise w.error('conditions.speeds_rpm', f'{lo:g}..{hi:g} rpm is outside the engine '
                          f'data ({rng[0]:g}..{rng[1]:g} rpm)')
    for i, ld in enumerate(loads):           # below 0 only for an engine with a brake curve
        if reason := load_error(engines[load_sets[0]], ld, f'conditions.loads[{i}]'):
            raise ConfigError(f'{w.source}: {reason}')
    conditions = [Condition(ls, ld) for ls in engines for ld in loads]
    if len(set(conditions)) != len(conditions):
        raise w.error('conditions.loads', 'repeated load fractions')
    return (engines, conditions, (lo, hi, step),
            parse_load_steps(w, raw.get('load_steps'), engines),
            parse_road_cycle(w, raw.get('road_cycle'), engines))


def _engine_error(src) -> bool:
    """True when the engine file cannot be loaded with its default load set."""
    from dmf_sim.physics.engine import read_engine
    try:
        read_engine(src)
    except ConfigError:
        return True
    return False


def _objectives(w: Where, raw, load_steps: bool, road_cycle: bool = False) -> list[str]:
    objs = w.nonempty_list(raw, 'objectives')
    for i, o in enumerate(objs):
        if o not in OBJECTIVES:
            raise w.error(f'objectives[{i}]', f'unknown objective {o!r} (allowed: '
                          f'{", ".join(OBJECTIVES)})')
        if o in TRANSIENT and not load_steps:
            raise w.error(f'objectives[{i}]', f'{o!r} is measured in load steps: give '
                          'conditions.load_steps')
        if o in CYCLE and not road_cycle:
            raise w.error(f'objectives[{i}]', f'{o!r} is measured in the road cycle: give '
                          'conditions.road_cycle')
    if len(objs) < 2 or len(set(objs)) != len(objs):
        raise w.error('objectives', f'need at least 2 different objectives (the first two span '
                      f'the Pareto front), got {objs!r}')
    return list(objs)


def _digest(base_dir: Path, *sources) -> str:
    """Hash of the contents of the study's driveline and engine files."""
    from dmf_sim.core.paths import config_file
    h = hashlib.sha256()
    for src in sources:
        h.update(Path(config_file(_resolve(src, base_dir))).read_bytes())
    return h.hexdigest()[:16]


__getattr__ = renamed(__name__, {'load_study': 'read_study'}, globals())
