"""The optimization problem: a design study file plus an ``optimizer`` section.

The file is a ``dmf-sim design`` study (``dmf_sim.design.study``; its ``sampling`` section may be
left out) with::

    variables:                        # design parameters (dmf_sim.design.parameters) and bounds
      theta: {min: 0.16, max: 0.30}
      alpha: {min: 0.5, max: 5.0}
      stages[1].angle_step_rad: {min: 0.005, max: 0.06}   # stage 1 knee = stage 0 knee + step
      stages[1].stiffness_factor: {min: 0.5, max: 10}
    optimizer:
      method: tpe                     # tpe | nsga2 (optuna) | lhs | random (the baselines)
      budget: 200                     # designs evaluated in all
      batch_size: 16                  # designs evaluated in parallel per generation (ask)
      seed: 1
      initial:                        # optional: designs evaluated first (e.g. the paper's)
        - {theta: 0.24, alpha: 3.0, stages[1].angle_step_rad: 0.03, ...}
      constraints:
        max_travel_rad: 0.29          # the spring's travel (end stop) [rad]
        capacity_factor: 1.2          # torque capacity = factor x the engine's largest mean
                                      # torque (or capacity_nm: 3400)
        max_dmf_torque: true          # the largest DMF torque in operation <= capacity
        metrics: {rpm_nonperiodic: {max: 100}}   # optional bounds on any metric

Stage angles after the first of a side are written as *increments* ``stages[i].angle_step_rad``
(> 0) over the stage before, so every design the optimizer proposes has ascending knees by
construction; an absolute ``stages[i].angle_rad`` (i >= 1) is refused with that advice. The
design study the problem wraps (:attr:`Problem.study`) names the absolute angles, so the result
table has the same columns as a study's.
"""
from __future__ import annotations

import copy
import hashlib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.validation import Where, bounded
from dmf_sim.design.parameters import Parameter, parse_parameter
from dmf_sim.design.study import Study, study_from_dict
from dmf_sim.optimize.constraints import Constraints, parse_constraints

__all__ = ['METHODS', 'OPTIMIZER_REQUIRED', 'OPTIMIZER_OPTIONAL', 'DEFAULT_BATCH_SIZE',
           'MAX_BUDGET', 'Variable', 'Problem', 'read_problem', 'problem_from_dict',
           'unit_to_values']

METHODS = {
    'nsga2': 'NSGA-II (optuna NSGAIISampler): evolutionary, constraint-dominance ranking',
    'tpe': 'multi-objective TPE (optuna TPESampler, multivariate, constrained): model-based',
    'lhs': 'Latin hypercube of the budget (baseline, scipy.stats.qmc)',
    'random': 'uniform random samples (baseline)',
}
OPTIMIZER_REQUIRED = ('method', 'budget')
OPTIMIZER_OPTIONAL = ('batch_size', 'seed', 'constraints', 'initial')
DEFAULT_BATCH_SIZE = 16
MAX_BUDGET = 100_000
_STEP_RE = re.compile(r'^(stages|coast_stages)\[(\d+)\]\.angle_step_rad$')


@dataclass(frozen=True)
class Variable:
    """One optimizer variable: its name as written, bounds (SI) and the parameter it sets;
    ``step_of``: for an angle increment, the parameter of the stage before (absolute angle =
    that stage's angle + this value)."""

    name: str
    low: float
    high: float
    param: Parameter
    step_of: Parameter | None = None


@dataclass
class Problem:
    """A validated optimization problem: the wrapped design study, the variables, the optimizer
    settings and the constraints (capacity resolved from the engine)."""

    study: Study
    variables: list[Variable]
    method: str
    budget: int
    batch_size: int
    seed: int
    constraints: Constraints
    initial: list[dict[str, float]] = field(default_factory=list)

    @property
    def names(self) -> list[str]:
        return [v.name for v in self.variables]

    @property
    def objectives(self) -> list[str]:
        return self.study.objectives

    def absolute(self, x) -> list[float]:
        """Optimizer values ``x`` (in :attr:`variables` order) -> the design study's variable
        values (in ``study.params`` order): increments summed onto the stage before."""
        by_key = {v.param.key: float(xi) for v, xi in zip(self.variables, x)}
        fixed = {p.key: val for p, val in self.study.fixed.items()}
        spring = self.study.base.spring
        out: dict[tuple, float] = {}

        def angle(p: Parameter) -> float:
            if p.key in out:
                return out[p.key]
            var = next((v for v in self.variables if v.param.key == p.key), None)
            if var is None:
                if p.key in fixed:
                    return fixed[p.key]
                stages = spring.drive if p.side == 'stages' else spring.coast
                return float(stages[p.index].angle_rad)
            value = by_key[p.key]
            if var.step_of is not None:
                value = angle(var.step_of) + value
            out[p.key] = value
            return value

        for v in self.variables:
            if v.param.kind == 'angle_rad':
                angle(v.param)
            else:
                out[v.param.key] = by_key[v.param.key]
        return [out[p.key] for p in self.study.params]

    def as_dict(self) -> dict:
        return {'method': self.method, 'budget': self.budget, 'batch_size': self.batch_size,
                'seed': self.seed,
                'variables': {v.name: {'min': v.low, 'max': v.high} for v in self.variables},
                'constraints': self.constraints.as_dict(), 'initial': self.initial}

    def fingerprint(self) -> str:
        """What a resumed run must share with the stored one: the study's rows (its own
        fingerprint), the variables, method, seed, batch size, constraints and initial designs
        (not the budget: a resume may extend it)."""
        d = self.as_dict()
        d.pop('budget')
        text = json.dumps(d, sort_keys=True) + self.study.fingerprint()
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def with_method(self, method: str, **changes) -> 'Problem':
        """The same problem solved by another method (e.g. the Latin-hypercube baseline)."""
        if method not in METHODS:
            raise ConfigError(f'method {method!r}: allowed {", ".join(METHODS)}')
        p = copy.copy(self)
        p.method = method
        for k, v in changes.items():
            setattr(p, k, v)
        return p


def read_problem(source, *, budget: int | None = None) -> Problem:
    """A :class:`Problem` from a study file (config name or path), a mapping or a Problem;
    ``budget`` overrides the file's."""
    if isinstance(source, Problem):
        return source if budget is None else source.with_method(source.method, budget=budget)
    from dmf_sim.core.paths import read_yaml_mapping
    if isinstance(source, dict):
        prob = problem_from_dict(source, 'study', base_dir=Path.cwd())
    else:
        path, data = read_yaml_mapping(source, 'optimization study')
        prob = problem_from_dict(data, str(path), base_dir=path.parent, default_name=path.stem)
    if budget is not None:
        if isinstance(budget, bool) or not isinstance(budget, int) or \
                not 1 <= budget <= MAX_BUDGET:
            raise ConfigError(f'--budget {budget!r}: must be an integer in [1, {MAX_BUDGET}]')
        prob.budget = budget
    return prob


def problem_from_dict(data: dict, source: str = 'study', *, base_dir: Path | None = None,
                      default_name: str = 'study') -> Problem:
    """Validate a parsed optimization study; one-line ConfigErrors naming the field."""
    def error(field_name: str, msg: str) -> ConfigError:
        return ConfigError(f'{source}: {field_name}: {msg}')

    if not isinstance(data, dict):
        raise error('study', 'must be a mapping')
    if 'optimizer' not in data:
        raise error('study', "missing key 'optimizer' (method, budget, batch_size, seed, "
                    'constraints; see config/optimize_example.yaml)')
    opt = data['optimizer']
    if not isinstance(opt, dict):
        raise error('optimizer', f'must be a mapping, got {opt!r}')
    for key in OPTIMIZER_REQUIRED:
        if key not in opt:
            raise error('optimizer', f'missing key {key!r}')
    for key in opt:
        if key not in OPTIMIZER_REQUIRED + OPTIMIZER_OPTIONAL:
            raise error('optimizer', f'unknown key {key!r} (allowed: '
                        f'{", ".join(sorted(OPTIMIZER_REQUIRED + OPTIMIZER_OPTIONAL))})')
    method = opt['method']
    if not isinstance(method, str) or method not in METHODS:
        raise error('optimizer.method', f'unknown method {method!r} (allowed: '
                    f'{", ".join(METHODS)})')
    budget = _integer(error, opt['budget'], 'optimizer.budget', 1, MAX_BUDGET)
    batch = _integer(error, opt.get('batch_size', DEFAULT_BATCH_SIZE), 'optimizer.batch_size',
                     1, MAX_BUDGET)
    seed = _integer(error, opt.get('seed', 0), 'optimizer.seed', 0, 2**32 - 1)

    raw_vars = data.get('variables')
    if not isinstance(raw_vars, dict) or not raw_vars:
        raise error('variables', f'must be a non-empty mapping of design parameters, '
                    f'got {raw_vars!r}')
    study_vars, specs = {}, []
    for name, spec in raw_vars.items():
        if not isinstance(spec, dict) or set(spec) != {'min', 'max'}:
            raise error(f'variables.{name}', f'give the bounds as {{min: ..., max: ...}}, '
                        f'got {spec!r}')
        m = _STEP_RE.match(str(name).replace(' ', ''))
        if m:
            side, index = m.group(1), int(m.group(2))
            if index == 0:
                raise error(f'variables.{name}', f'the first stage has no stage before it; give '
                            f'{side}[0].angle_rad' + (' (or theta)' if side == 'stages' else ''))
            param = parse_parameter(f'{side}[{index}].angle_rad', f'{source}: variables')
            step_of = Parameter(f'{side}[{index - 1}].angle_rad', 'angle_rad', side, index - 1)
            lo = bounded(spec['min'], source, f'variables.{name}.min', 'windup_angle')
            hi = bounded(spec['max'], source, f'variables.{name}.max', 'windup_angle')
        else:
            param = parse_parameter(name, f'{source}: variables')
            if param.kind == 'angle_rad' and param.index:
                raise error(f'variables.{name}', f'give stage angles after the first as '
                            f'increments: {param.side}[{param.index}].angle_step_rad (> 0 rad, '
                            'keeps the knees ascending)')
            lo = param.check_value(spec['min'], f'{source}: variables.{name}.min')
            hi = param.check_value(spec['max'], f'{source}: variables.{name}.max')
            step_of = None
        if not lo < hi:
            raise error(f'variables.{name}', f'empty range: min {lo:g} must be < max {hi:g}')
        specs.append(Variable(str(name), lo, hi, param, step_of))
        study_vars[param.name] = [lo, hi]
    # the absolute ranges the increments reach (for the study's table and plots)
    reach = {v.param.key: (v.low, v.high) for v in specs}
    for v in specs:
        if v.step_of is not None:
            prev = reach.get(v.step_of.key)
            if prev is None:
                prev = _base_angle(data, v.step_of, base_dir, source)
            reach[v.param.key] = (prev[0] + v.low, prev[1] + v.high)
            study_vars[v.param.name] = list(reach[v.param.key])
    study_data = {k: val for k, val in data.items() if k != 'optimizer'}
    study_data['variables'] = {k: {'min': lo, 'max': hi} for k, (lo, hi) in study_vars.items()}
    study_data.setdefault('sampling', {'method': 'lhs', 'n': budget, 'seed': seed})
    study = study_from_dict(study_data, source, base_dir=base_dir, default_name=default_name)
    cons = parse_constraints(opt.get('constraints') or {}, f'{source}: optimizer.constraints',
                             study)
    initial = _initial(error, opt.get('initial') or [], specs)
    return Problem(study, specs, method, budget, batch, seed, cons, initial)


def _integer(error, value, field_name: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise error(field_name, f'must be an integer in [{lo}, {hi}], got {value!r}')
    return int(value)


def _base_angle(data: dict, p: Parameter, base_dir, source: str) -> tuple[float, float]:
    """The angle of a stage that is not a variable: its fixed value or the base spring's."""
    fixed = data.get('fixed') or {}
    for key, value in fixed.items() if isinstance(fixed, dict) else ():
        try:
            if parse_parameter(key, 'fixed').key == p.key:
                return float(value), float(value)
        except ConfigError:
            pass
    from dmf_sim.design.study import _load_driveline
    line = _load_driveline(Where(source), data.get('driveline'), base_dir or Path.cwd())
    stages = line.spring.drive if p.side == 'stages' else line.spring.coast
    if p.index >= len(stages):
        raise ConfigError(f'variables: {p.side}[{p.index + 1}].angle_step_rad needs '
                          f'{p.side}[{p.index}].angle_rad (a variable, fixed, or on the base '
                          'spring)')
    a = float(stages[p.index].angle_rad)
    return a, a


def _initial(error, raw, specs: list[Variable]) -> list[dict[str, float]]:
    if not isinstance(raw, list):
        raise error('optimizer.initial', f'must be a list of designs, got {raw!r}')
    out = []
    names = [v.name for v in specs]
    for i, d in enumerate(raw):
        where = f'optimizer.initial[{i}]'
        if not isinstance(d, dict) or set(d) != set(names):
            raise error(where, f'give every variable ({", ".join(names)}), got {d!r}')
        row = {}
        for v in specs:
            x = d[v.name]
            if isinstance(x, bool) or not isinstance(x, (int, float)) or \
                    not v.low <= x <= v.high:
                raise error(f'{where}.{v.name}', f'must be in [{v.low:g}, {v.high:g}], got {x!r}')
            row[v.name] = float(x)
        out.append(row)
    return out


def unit_to_values(problem: Problem, u: np.ndarray) -> np.ndarray:
    """Points of the unit cube -> optimizer values (the baselines' samples)."""
    lo = np.array([v.low for v in problem.variables])
    hi = np.array([v.high for v in problem.variables])
    return lo + np.asarray(u) * (hi - lo)
