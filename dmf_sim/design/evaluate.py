"""Evaluating designs: one design over all its operating conditions -> result rows.

:func:`solve_condition` is the one place that decides how the steady states of a design are
found. Today it is continuation (``dmf_sim.solvers.hbm.sweep``: the branch from the lowest speed,
turning points, Floquet stability, branch switching to 1.5th-order branches); when another
finder is wanted, its body changes and nothing else does.

A design that cannot be built (e.g. stage angles out of order) or whose solver fails is recorded
with its reason and never stops the study. :class:`StudyContext` is what a worker needs (base
driveline, engines per load set, conditions, solver settings). The runner installs it once in
every worker process (a Dask WorkerPlugin calls :func:`install_context`); tasks name it by key
and carry only their designs. :func:`context_loads` counts the installs per process, so a test
and the summary can show that a worker loads the model once, not once per task.
"""
from __future__ import annotations

import os
import time
from dataclasses import dataclass, field, replace

from dmf_sim.core.errors import one_line
from dmf_sim.design.metrics import condition_metrics, design_summary
from dmf_sim.design.parameters import Parameter, design_driveline
from dmf_sim.design.transient import (
    cycle_metrics,
    cycle_summary,
    step_metrics,
    transient_summary,
)

__all__ = ['install_context', 'drop_context', 'context_loads', 'SolverSettings', 'StudyContext',
           'solve_condition', 'sweep_condition', 'evaluate_design', 'BatchResult',
           'evaluate_batch']

_CONTEXTS: dict[str, 'StudyContext'] = {}     # key -> context installed in this process
_CONTEXT_LOADS = [0]                           # contexts installed in this process so far


def install_context(key: str, ctx: 'StudyContext') -> None:
    """Make ``ctx`` available to :func:`evaluate_batch` in this process under ``key``."""
    _CONTEXTS[key] = ctx
    _CONTEXT_LOADS[0] += 1


def drop_context(key: str) -> None:
    _CONTEXTS.pop(key, None)


def context_loads() -> int:
    """How many study contexts this process has installed."""
    return _CONTEXT_LOADS[0]


@dataclass(frozen=True)
class SolverSettings:
    """Speed grid [rpm] (from, to, step), harmonics H, branch switching, torque element index,
    and the full steady-state search (``dmf_sim.solvers.hbm.search``; off: continuation, stability
    and branch switching only, as ``dmf-sim sweep --fast``); ``time_limit_s``: wall-clock limit of
    one design x condition sweep (None: none), past which the condition is recorded as failed."""

    speeds_rpm: tuple[float, float, float]
    harmonics: int
    branch_switching: bool
    torque_element: int
    search: bool = True
    time_limit_s: float | None = None


@dataclass
class StudyContext:
    """Everything a worker needs to evaluate designs of one study."""

    base: object                      # dmf_sim.physics.model.Driveline
    engines: dict                     # load set -> engine
    conditions: list                  # dmf_sim.design.study.Condition
    params: list[Parameter]
    fixed: dict[Parameter, float]
    settings: SolverSettings
    variable_names: list[str] = field(default_factory=list)
    load_steps: list = field(default_factory=list)     # dmf_sim.design.transient.LoadStep
    road_cycle: object = None                          # dmf_sim.design.transient.RoadCycle

    @classmethod
    def from_study(cls, study) -> 'StudyContext':
        settings = SolverSettings(study.speeds_rpm, study.harmonics, study.branch_switching,
                                  study.base.index(study.torque_element), study.search,
                                  study.time_limit_s)
        return cls(study.base, study.engines, study.conditions, study.params, study.fixed,
                   settings, study.variable_names, list(study.load_steps), study.road_cycle)

    def design_values(self, row) -> dict[Parameter, float]:
        """Parameter -> value of one design: its variables plus the fixed parameters."""
        values = dict(self.fixed)
        values.update({p: float(v) for p, v in zip(self.params, row)})
        return values


def solve_condition(line, engine, load: float, settings: SolverSettings):
    """Every steady state of driveline ``line`` under ``engine`` at load fraction ``load``, on
    the speed grid, as :class:`~dmf_sim.design.states.GridStates` (the sweep's solution finder,
    or continuation alone with ``settings.search`` off)."""
    from dmf_sim.design.states import grid_states
    res = sweep_condition(line, engine, load, settings)
    return grid_states(res, settings.speeds_rpm, settings.torque_element)


def sweep_condition(line, engine, load: float, settings: SolverSettings):
    """The harmonic-balance sweep (``dmf_sim.solvers.hbm.sweep``) of one design at one condition:
    the
    solution finder (every stable state, non-periodic speeds) unless ``settings.search`` is off."""
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.solvers.hbm import HBMOptions, SweepOptions, sweep
    lo, hi, step = settings.speeds_rpm
    options = SweepOptions(step_rpm=step, branch_switching=settings.branch_switching,
                           time_limit_s=settings.time_limit_s)
    if not settings.search:
        options = replace(options, search=None)
    return sweep(DrivelineExcitation(line.reduce(), engine), load, (lo, hi),
                 hbm_options=HBMOptions(n_harmonics=settings.harmonics), options=options)


def _failure(exc: BaseException) -> str:
    return f'{type(exc).__name__}: {one_line(exc)}'


def evaluate_design(ctx: StudyContext, design_id: int, row) -> list[dict]:
    """Rows of one design: one per condition, then its summary row (kind 'design')."""
    values = dict(zip(ctx.variable_names, (float(v) for v in row)))
    head = {'design_id': int(design_id), **values}
    t0 = time.perf_counter()
    try:
        line = design_driveline(ctx.base, ctx.design_values(row))
        build_error = None
    except Exception as exc:          # noqa: BLE001 - any failure is recorded, never fatal
        line, build_error = None, _failure(exc)
    rows = []
    for cond in ctx.conditions:
        r = {**head, 'kind': 'condition', 'load_set': cond.load_set, 'load': cond.load,
             'condition': cond.label}
        t1 = time.perf_counter()
        if build_error:
            r.update(status='failed', error=build_error)
        else:
            try:
                states = solve_condition(line, ctx.engines[cond.load_set], cond.load, ctx.settings)
                r.update(condition_metrics(states, line.spring, ctx.settings.speeds_rpm[2]))
                r.update(status='ok', error='')
            except Exception as exc:  # noqa: BLE001 - the design failed, the study goes on
                r.update(status='failed', error=_failure(exc))
        r['seconds'] = time.perf_counter() - t1
        rows.append(r)
    summary = {**head, 'kind': 'design', 'condition': 'all'}
    failed = [r for r in rows if r['status'] != 'ok']
    if failed:
        summary.update(status='failed', error=f'{failed[0]["condition"]}: {failed[0]["error"]}')
    else:
        summary.update(design_summary(rows), status='ok', error='')
        _load_steps(ctx, line, summary)
        if summary['status'] == 'ok':
            _road_cycle(ctx, line, summary)
    summary['seconds'] = time.perf_counter() - t0
    return rows + [summary]


def _load_steps(ctx: StudyContext, line, summary: dict) -> None:
    """The design's load steps (:mod:`dmf_sim.design.transient`) into its summary row; a
    step that fails fails the design, naming the step."""
    results = []
    for step in ctx.load_steps:
        try:
            results.append(step_metrics(line, ctx.engines[step.load_set], step))
        except Exception as exc:      # noqa: BLE001 - the design failed, the study goes on
            summary.update(status='failed', error=f'{step.label}: {_failure(exc)}')
            return
    summary.update(transient_summary(ctx.load_steps, results))


def _road_cycle(ctx: StudyContext, line, summary: dict) -> None:
    """The design's road cycle (:mod:`dmf_sim.design.transient`) into its summary row; a
    cycle that fails fails the design, naming the cycle."""
    cycle = ctx.road_cycle
    if cycle is None:
        return
    try:
        result = cycle_metrics(line, ctx.engines[cycle.load_set], cycle)
    except Exception as exc:          # noqa: BLE001 - the design failed, the study goes on
        summary.update(status='failed', error=f'{cycle.label}: {_failure(exc)}')
        return
    summary.update(cycle_summary(cycle, result))


@dataclass
class BatchResult:
    """Rows of a batch of designs, and who computed them."""

    rows: list[dict]
    design_ids: list[int]
    pid: int
    context_loads: int
    seconds: float


def evaluate_batch(key: str, items: list[tuple[int, list[float]]]) -> BatchResult:
    """Evaluate (design_id, values) items one after another with the context installed under
    ``key`` (one Dask task)."""
    t0 = time.perf_counter()
    ctx = _CONTEXTS.get(key)
    if ctx is None:
        raise RuntimeError(f'study context {key!r} is not installed in process {os.getpid()}')
    rows = []
    for design_id, row in items:
        rows += evaluate_design(ctx, design_id, row)
    return BatchResult(rows, [i for i, _ in items], os.getpid(), context_loads(),
                       time.perf_counter() - t0)
