"""Running an optimization on Dask with optuna's ask-and-tell interface.

Each generation the sampler is asked for ``batch_size`` designs (optuna trials; the trial number
is the design id); every design is one Dask task on the design study's machinery (the context
installed once per worker by :class:`dmf_sim.design.runner.StudyPlugin`, rows by
:func:`dmf_sim.design.evaluate.evaluate_batch`); finished designs are stored at once as Parquet
parts (:class:`dmf_sim.design.table.ResultStore`, the table of a design study plus the columns
of :data:`EXTRA`), then the whole generation is told to the sampler in trial order (so a seed
gives the same run on 1 or many workers). Objectives are the study's (all minimized), the
constraint values (``dmf_sim.optimize.constraints``) go to the sampler as optuna constraints; a
failed design (or one without an objective value) is told as a failed trial, and it is a row.

Storage and resume: the optuna study lives in ``DIR/optuna.journal`` (optuna's journal file
storage, append-only); ``--resume`` loads it, tells every trial whose rows are already stored,
evaluates the trials an interruption left running, and goes on to the budget.
"""
from __future__ import annotations

import json
import math
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dmf_sim.cluster import start_local, wait_for_workers
from dmf_sim.core.errors import ConfigError, one_line
from dmf_sim.core.json_out import write_json
from dmf_sim.core.optional import require
from dmf_sim.design.evaluate import StudyContext, evaluate_batch
from dmf_sim.design.result import StudyResult
from dmf_sim.design.runner import StudyPlugin, _bar, close_run
from dmf_sim.design.table import ResultStore, sort_rows, to_table
from dmf_sim.optimize.constraints import rank, violation
from dmf_sim.optimize.hypervolume import hypervolume_history
from dmf_sim.optimize.problem import Problem, read_problem, unit_to_values

__all__ = ['JOURNAL', 'PROBLEM_FILE', 'OPTUNA_STUDY', 'MAX_CONSTRAINT', 'EXTRA',
           'OptimizationResult', 'check_budget', 'run_optimization', 'finish', 'reference_point',
           'BASELINE_DIR', 'baseline_problem', 'nearest_infeasible']

pa = require('pyarrow', 'optimize')
distributed = require('distributed', 'optimize')
optuna = require('optuna')
JournalFileBackend = require('optuna.storages.journal').JournalFileBackend

JOURNAL = 'optuna.journal'
PROBLEM_FILE = 'optimizer.json'
OPTUNA_STUDY = 'dmf-optimize'
MAX_CONSTRAINT = 1e12
"""An infinite constraint value (an undefined metric) as the sampler sees it."""
EXTRA = [('method', pa.string()), ('generation', pa.int64()), ('feasible', pa.bool_()),
         ('violation', pa.float64()), ('constraints', pa.string()),
         ('torque_at_travel', pa.float64()), ('rank', pa.int64())]
"""Columns the optimizer adds to a design study's table (summary rows; NaN/None elsewhere)."""


@dataclass
class OptimizationResult(StudyResult):
    """A design study's result (every evaluated design as rows of its table, plus
    :data:`EXTRA`; ``pareto_ids``: the *feasible* non-dominated designs of all the
    objectives; ``best_id``: the compromise among them) with the problem, the hypervolume after
    each evaluation and the time-domain verification (of the harmonic-balance objectives, and
    of the transient ones by step refinement)."""

    problem: Problem | None = None
    hypervolume: np.ndarray = field(default_factory=lambda: np.zeros(0))
    verification: list = field(default_factory=list)
    transient_verification: list = field(default_factory=list)

    def summary(self) -> dict:
        """A design study's summary (counts, front, best, failures, throughput, files) plus
        the optimizer's: method, budget, seed, feasible designs, constraints, final
        hypervolume, verification."""
        p = self.problem
        out = super().summary()
        for key in ('batch_size', 'context_loads_per_worker'):
            out.pop(key)
        out.update({
            'method': p.method, 'budget': p.budget, 'seed': p.seed,
            'batch_size': p.batch_size, 'pareto_objectives': list(p.objectives),
            'n_feasible': sum(bool(r['feasible']) for r in self.rows('design')),
            'nearest_infeasible': nearest_infeasible(self.rows('design')),
            'constraints': p.constraints.as_dict(),
            'hypervolume_final': (float(self.hypervolume[-1]) if len(self.hypervolume)
                                  else None),
            'verification': [v.as_dict() for v in self.verification],
            'transient_verification': [v.as_dict() for v in self.transient_verification]})
        return out


def nearest_infeasible(rows) -> dict | None:
    """Where no design row is feasible: the one nearest to it (the least violation, the sum of
    its relative constraint values > 0), as design_id, violation and its constraint values'
    text; None where one is feasible or none has constraint values (every one failed)."""
    if any(bool(r.get('feasible')) for r in rows):
        return None
    scored = [r for r in rows if r.get('violation') is not None and math.isfinite(r['violation'])]
    if not scored:
        return None
    near = min(scored, key=lambda r: r['violation'])
    return {'design_id': int(near['design_id']), 'violation': float(near['violation']),
            'constraints': str(near['constraints'])}


def _sampler(problem: Problem):
    """optuna's sampler of the method; constraints reach it through ``Trial.set_constraint``."""
    seed = problem.seed
    if problem.method == 'nsga2':
        return optuna.samplers.NSGAIISampler(population_size=max(problem.batch_size, 2),
                                             seed=seed)
    if problem.method == 'tpe':
        return optuna.samplers.TPESampler(seed=seed, multivariate=True,
                                          n_startup_trials=problem.batch_size,
                                          constant_liar=True)
    return optuna.samplers.RandomSampler(seed=seed)       # lhs: every trial is enqueued


def _open_study(problem: Problem, out: Path | None, resume: bool):
    """The optuna study in ``out``'s journal (or in memory); new ones get their enqueued
    designs (the initial designs; for 'lhs' the whole Latin hypercube)."""
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = None
    existed = resume and out is not None and (out / JOURNAL).exists()   # before opening it
    if out is not None:
        storage = optuna.storages.JournalStorage(JournalFileBackend(str(out / JOURNAL)))
    study = optuna.create_study(storage=storage, study_name=OPTUNA_STUDY,
                                directions=['minimize'] * len(problem.objectives),
                                sampler=_sampler(problem), load_if_exists=existed)
    if not existed:
        for d in problem.initial:
            study.enqueue_trial(d)
        if problem.method == 'lhs':
            from scipy.stats import qmc
            u = qmc.LatinHypercube(d=len(problem.variables),
                                   seed=np.random.default_rng(problem.seed)).random(
                max(problem.budget - len(problem.initial), 0))
            for x in unit_to_values(problem, u):
                study.enqueue_trial(dict(zip(problem.names, map(float, x))))
    return study


def _check_problem_file(problem: Problem, out: Path, resume: bool) -> None:
    meta = out / PROBLEM_FILE
    if meta.exists() and resume:
        stored = json.loads(meta.read_text())
        if stored.get('fingerprint') != problem.fingerprint():
            raise ConfigError(f'--resume: {out} holds another optimization (other method, seed, '
                              'batch size, variables or constraints); choose another --out')
    out.mkdir(parents=True, exist_ok=True)
    write_json(meta, {**problem.as_dict(), 'fingerprint': problem.fingerprint()}, default=float)


def check_budget(problem: Problem, store: ResultStore | None) -> None:
    """A resumed run keeps every design stored in its directory: a budget below their number
    is a one-line ConfigError (nothing is computed, nothing stored is changed)."""
    if store is None:
        return
    stored = len(store.finished())
    if problem.budget < stored:
        raise ConfigError(f'budget {problem.budget}: {store.dir} holds {stored} designs '
                          f'already, and a resumed run keeps every one of them; pass --budget '
                          f'{stored} or more (or choose another --out)')


def run_optimization(problem, client=None, *, out=None, resume: bool = False,
                     workers: int | None = None, progress: bool = False, on_batch=None,
                     budget: int | None = None) -> OptimizationResult:
    """Optimize the DMF design of ``problem`` (a study file, mapping or Problem) on Dask.

    Args:
        client: a ``distributed.Client``; None starts a LocalCluster of ``workers`` processes.
        out: directory of the journal, the Parquet parts and the final table (None: in memory).
        resume: continue the optimization stored in ``out``.
        progress: tqdm progress bar with ETA on stderr.
        on_batch: ``on_batch(n_done, n_total)`` after every stored design.
        budget: overrides the problem's budget (e.g. to extend a finished run with resume;
            never below the designs stored in ``out``: :func:`check_budget`).
    """
    problem = read_problem(problem, budget=budget)
    study = problem.study
    out = Path(out) if out is not None else None
    store = ResultStore(out, study, resume, extra=EXTRA) if out is not None else None
    if store:
        store.lock()
    own = client is None
    cluster = None
    t0 = time.perf_counter()
    try:
        check_budget(problem, store)
        if out is not None:
            _check_problem_file(problem, out, resume)
            store.start()
        ostudy = _open_study(problem, out, resume)
        run = _Run(problem, ostudy, store, on_batch)
        todo = run.reconcile()
        n_workers = 0
        if run.n_finished < problem.budget:      # (left-over running trials wait for it)
            if own:
                cluster, client = start_local(workers)
            n_workers = wait_for_workers(client)
            run.compute(client, todo, _bar(progress, problem.budget, run.n_finished))
        rows = (store.rows if store else []) + run.rows
        result = finish(problem, rows,
                        n_computed=run.n_computed, seconds=time.perf_counter() - t0,
                        workers=n_workers)
        if store:
            result.files.update(store.finalize(result.table))
            result.files['journal'] = str(out / JOURNAL)
        return result
    finally:
        close_run(cluster if own else None, client if own else None, store)


def finish(problem: Problem, rows: list[dict], **run) -> OptimizationResult:
    """The final table: rows sorted, ranks (feasible by layer, infeasible, failed), the
    feasible Pareto front of all the objectives, the compromise, hypervolume history."""
    from dmf_sim.design.pareto import compromise
    study = problem.study
    rows = sort_rows(rows, [c.label for c in study.conditions])
    summ = [r for r in rows if r['kind'] == 'design']
    f = np.array([[_num(r.get(o)) for o in study.objectives] for r in summ]).reshape(
        len(summ), len(study.objectives))
    feas = np.array([bool(r.get('feasible')) for r in summ], dtype=bool)
    failed = np.array([r['status'] != 'ok' for r in summ], dtype=bool)
    viol = np.array([_num(r.get('violation'), math.inf) for r in summ])
    ranks = rank(feas, viol, f, failed) if summ else np.zeros(0, int)
    front = {r['design_id'] for r, k in zip(summ, ranks) if k == 1 and r['feasible']}
    for r, k in zip(summ, ranks):
        r['rank'] = int(k)
    mask = np.array([r['design_id'] in front for r in summ], dtype=bool)
    best = summ[compromise(f.T, mask)]['design_id'] if mask.any() else None
    for r in rows:
        r['pareto'] = (r['design_id'] in front) if r['kind'] == 'design' else None
    table = to_table(rows, study.variable_names, final=True, extra=EXTRA)
    order = np.argsort([r['design_id'] for r in summ], kind='stable')
    hv = hypervolume_history(f[order], feas[order] & ~failed[order],
                             reference_point(problem, f[feas]))
    return OptimizationResult(study, table, sorted(front), best, problem=problem,
                              hypervolume=hv, **run)


def reference_point(problem: Problem, f) -> tuple[float, ...]:
    """The hypervolume reference point: 1.1 x the largest feasible value of each objective
    (``f``: (n_designs, n_objectives) of the feasible designs; comparisons of runs pass one
    common point, :func:`hypervolume_history`)."""
    f = np.asarray(f, float).reshape(-1, len(problem.objectives))
    ok = np.all(np.isfinite(f), axis=1)
    if not ok.any():
        return tuple(math.nan for _ in problem.objectives)
    return tuple(1.1 * float(v) for v in f[ok].max(axis=0))


def _num(v, default=math.nan) -> float:
    return default if v is None else float(v)


class _Run:
    """One run: asking, evaluating on Dask, storing and telling, generation by generation."""

    def __init__(self, problem: Problem, ostudy, store, on_batch):
        self.problem, self.ostudy, self.store, self.on_batch = problem, ostudy, store, on_batch
        self.ctx = StudyContext.from_study(problem.study)
        self.rows: list[dict] = []
        self.n_computed = 0
        self.n_finished = 0

    # ---- resume ---------------------------------------------------------------------------
    def reconcile(self) -> list:
        """Tell stored designs an interruption left untold; return trials to evaluate again."""
        Trial, TrialState = optuna.trial.Trial, optuna.trial.TrialState
        stored = {}
        if self.store:
            for r in self.store.rows:
                stored.setdefault(r['design_id'], []).append(r)
        todo = []
        for ft in self.ostudy.get_trials(deepcopy=False):
            if ft.state == TrialState.RUNNING:
                rows = stored.get(ft.number)
                trial = Trial(self.ostudy, ft._trial_id)
                if rows and any(r['kind'] == 'design' for r in rows):
                    self._tell(trial, next(r for r in rows if r['kind'] == 'design'))
                else:
                    todo.append(trial)
        self.n_finished = sum(t.state in (TrialState.COMPLETE, TrialState.FAIL)
                              for t in self.ostudy.get_trials(deepcopy=False))
        return todo

    # ---- the loop -----------------------------------------------------------------------------
    def compute(self, client, todo: list, bar) -> None:
        p = self.problem
        key = f'dmf-optimize-{p.study.fingerprint()}-{uuid.uuid4().hex[:8]}'
        client.register_plugin(StudyPlugin(key, self.ctx), name=key)
        dists = {v.name: optuna.distributions.FloatDistribution(v.low, v.high)
                 for v in p.variables}
        futures: dict = {}
        generation = self.n_finished // max(p.batch_size, 1)
        try:
            while self.n_finished < p.budget:
                n = min(p.batch_size, p.budget - self.n_finished)
                trials = todo[:n]
                todo = todo[n:]
                while len(trials) < n:
                    trials.append(self.ostudy.ask(dists))
                for t in trials:
                    x = [t.params[name] for name in p.names]
                    item = [(t.number, p.absolute(x))]
                    fut = client.submit(evaluate_batch, key, item, pure=False,
                                        key=f'dmf-opt-{t.number}-{uuid.uuid4().hex[:8]}')
                    futures[fut] = t
                summaries = {}
                for fut in distributed.as_completed(list(futures)):
                    t = futures.pop(fut)
                    rows = self._rows_of(fut, t, generation)
                    fut.release()
                    if self.store:
                        self.store.append(rows)
                    self.rows += rows
                    self.n_computed += 1
                    summaries[t.number] = rows[-1]
                    if bar is not None:
                        bar.update(1)
                    if self.on_batch is not None:
                        self.on_batch(self.n_finished + len(summaries), p.budget)
                for t in sorted(trials, key=lambda t: t.number):
                    self._tell(t, summaries[t.number])
                self.n_finished += len(trials)
                generation += 1
        finally:
            if bar is not None:
                bar.close()
            if futures and client.status == 'running':
                client.cancel(list(futures))
            if client.status == 'running':
                client.unregister_worker_plugin(key)

    def _rows_of(self, fut, trial, generation: int) -> list[dict]:
        p = self.problem
        x = [trial.params[name] for name in p.names]
        try:
            rows = fut.result().rows
        except Exception as exc:      # noqa: BLE001 - a lost task is a failed row, never fatal
            rows = [{'design_id': trial.number, 'kind': 'design', 'status': 'failed',
                     'error': f'task lost: {type(exc).__name__}: {one_line(exc)}',
                     'condition': 'all', **dict(zip(p.study.variable_names, p.absolute(x)))}]
        for r in rows:
            r['method'] = p.method
            r['generation'] = generation
        summary = rows[-1]
        summary.update(self._feasibility(summary))
        return rows

    def _feasibility(self, summary: dict) -> dict:
        """feasible, violation, constraint text and the spring's torque at the travel."""
        p = self.problem
        from dmf_sim.design.parameters import design_driveline
        cons = p.constraints
        try:
            line = design_driveline(p.study.base, self.ctx.design_values(
                [summary[n] for n in p.study.variable_names]))
            spring = line.spring
            t_travel = (float(spring.torque(cons.max_travel_rad))
                        if cons.max_travel_rad is not None else math.nan)
        except Exception:             # noqa: BLE001 - the design itself failed to build
            spring, t_travel = None, math.nan
        if summary['status'] != 'ok' or spring is None:
            return {'feasible': False, 'violation': math.inf, 'constraints': 'failed',
                    'torque_at_travel': t_travel}
        values = cons.values(spring, summary)
        return {'feasible': all(v <= 0 for v in values), 'violation': violation(values),
                'constraints': ', '.join(f'{n} {v:+.3g}' for n, v in zip(cons.names, values)),
                'torque_at_travel': t_travel, '_constraint_values': values}

    def _tell(self, trial, summary: dict) -> None:
        TrialState = optuna.trial.TrialState
        p = self.problem
        values = summary.pop('_constraint_values', None)
        if values is None and summary.get('status') == 'ok':
            values = self._feasibility(summary).get('_constraint_values')
        objs = [_num(summary.get(o)) for o in p.objectives]
        if summary.get('status') != 'ok' or values is None or not np.all(np.isfinite(objs)):
            self.ostudy.tell(trial, state=TrialState.FAIL)
            return
        for name, v in zip(p.constraints.names, values):
            trial.set_constraint(name, min(v, MAX_CONSTRAINT))
        self.ostudy.tell(trial, objs)


BASELINE_DIR = 'baseline'


def baseline_problem(problem: Problem) -> Problem:
    """The same problem sampled by a Latin hypercube of the same budget (no initial designs):
    what the optimizer's front is compared with."""
    return problem.with_method('lhs', initial=[])
