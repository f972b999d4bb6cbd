"""``dmf-sim optimize``: design the DMF spring (multi-objective, robust, constrained) on Dask."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from dmf_sim.commands import _options as opt
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text, write_json
from dmf_sim.core.optional import require_extra

__all__ = ['NAME', 'HELP', 'DEFAULT_VERIFY', 'add_arguments', 'run']

NAME = 'optimize'
HELP = ('Optimize the DMF spring of a study file with an optimizer section (NSGA-II or TPE, '
        'optuna) on Dask: constraints, resumable journal, Latin-hypercube baseline, time-domain '
        'verification of the Pareto designs, report and a driveline YAML per Pareto design.')
DEFAULT_VERIFY = 4
"""Pareto designs verified in the time domain by default (spread along the front, best first)."""


def add_arguments(p) -> None:
    p.add_argument('study', help='study YAML with an optimizer section (see '
                   'config/optimize_example.yaml)')
    p.add_argument('--out', type=Path, required=True,
                   help='directory for the journal, results.parquet/csv, designs/*.yaml, the '
                        'figures, report.md/html and summary.json')
    p.add_argument('--resume', action='store_true',
                   help='continue the optimization stored in --out (finished designs are not '
                        'recomputed; a larger --budget extends it, a budget below the designs '
                        'stored is refused)')
    opt.add_overwrite(p)
    p.add_argument('--budget', type=int, help='designs in all (default: the study file\'s)')
    opt.add_cluster(p)
    p.add_argument('--no-baseline', action='store_true',
                   help='skip the Latin-hypercube run of the same budget (in --out/baseline)')
    p.add_argument('--verify', type=int, default=DEFAULT_VERIFY, metavar='N',
                   help=f'Pareto designs to verify in the time domain (default {DEFAULT_VERIFY}; '
                        '0: none)')
    p.add_argument('--no-report', action='store_true', help='skip the figures and the report')
    p.add_argument('--no-progress', action='store_true', help='no progress output on stderr')
    p.add_argument('--json', action='store_true', help='print the summary as one JSON object')


def run(args) -> int:
    require_extra('optimize')               # optuna, dask, pyarrow: one line if missing
    from dmf_sim.cluster import close_local, connect, start_local
    from dmf_sim.design.table import ResultStore
    from dmf_sim.live.warm import warm_up
    from dmf_sim.optimize.problem import read_problem
    from dmf_sim.optimize.runner import BASELINE_DIR, EXTRA, check_budget

    opt.check_cluster(args)
    if args.verify < 0:
        raise ConfigError(f'--verify {args.verify}: must be >= 0')
    dest = opt.resumable_output(args, NAME)
    problem = read_problem(args.study, budget=args.budget)
    if args.resume:     # the budget against what is stored there, before any work
        check_budget(problem, ResultStore(args.out, problem.study, args.resume, extra=EXTRA))
        if not args.no_baseline:
            check_budget(problem, ResultStore(args.out / BASELINE_DIR, problem.study,
                                              args.resume, extra=EXTRA))
    warm_up(NAME, 'sweep', *(['time integration'] if args.verify else []))
    t0 = time.perf_counter()
    say = _say(args.no_progress, t0)
    if args.scheduler:
        client, cluster = connect(args.scheduler, args.connect_timeout), None
    else:
        cluster, client = start_local(args.workers)
    done = {'run': 'optimizer', 'n': 0}
    with dest.writing():
        try:
            result, baseline = _optimize(problem, client, args, done, say)
        except KeyboardInterrupt:
            print(f'dmf-sim optimize: interrupted in the {done["run"]} run; {done["n"]} designs '
                  f'are stored in {args.out}; continue with --resume', file=sys.stderr)
            return 130
        finally:
            close_local(cluster, client)
        summary = _finish(problem, result, baseline, args, say, time.perf_counter() - t0)
        if baseline is not None:
            summary['baseline_dir'] = str(args.out / BASELINE_DIR)
        write_json(args.out / 'summary.json', summary, default=_json)
    if args.json:
        print(json_text(summary, default=_json))
    else:
        _print(summary)
    return 0


def _optimize(problem, client, args, done, say):
    from dmf_sim.optimize.runner import BASELINE_DIR, baseline_problem, run_optimization

    def track(n, total):
        done['n'] = n

    say(f'{problem.method}: {problem.budget} designs, {problem.batch_size} per generation')
    result = run_optimization(problem, client, out=args.out, resume=args.resume,
                              progress=not args.no_progress, on_batch=track)
    baseline = None
    if not args.no_baseline:
        done.update(run='baseline', n=0)
        say(f'Latin-hypercube baseline: {problem.budget} designs')
        baseline = run_optimization(baseline_problem(problem), client,
                                    out=args.out / BASELINE_DIR, resume=args.resume,
                                    progress=not args.no_progress, on_batch=track)
    return result, baseline


def _finish(problem, result, baseline, args, say, seconds_so_far: float) -> dict:
    from dmf_sim.optimize.export import write_designs
    from dmf_sim.optimize.report import (
        common_hypervolumes,
        compare_with_reference,
        front_hypervolumes,
        reference_design,
        spread,
        write_report,
    )
    from dmf_sim.optimize.verify import verification_extremes, verify_design, verify_transient
    t0 = time.perf_counter()
    front = [r for r in result.rows('design') if r['pareto']]
    exported = write_designs(problem, front, args.out)
    result.files['designs'] = exported
    o1 = problem.objectives[0]
    if args.verify:
        best = [result.design(result.best_id)] if result.best_id is not None else []
        chosen = best + [r for r in spread(front, o1, args.verify) if r not in best]
        for r in chosen[:args.verify]:
            say(f'verifying design {r["design_id"]} in the time domain')
            result.verification += verify_design(problem, r)
            result.transient_verification += verify_transient(problem, r)
    say('the paper\'s design')
    ref = reference_design(problem)
    bvp = compare_with_reference(result, ref)
    hv = common_hypervolumes(result, baseline) if baseline is not None else {}
    summary = result.summary()
    summary['best_vs_paper'] = bvp
    if hv:
        keys = ('reference_point', 'optimizer_final', 'lhs_final', 'ratio')
        front = front_hypervolumes(result, baseline, hv)
        hv['front'] = {k: front[k] for k in (*keys, 'wide_bound') if k in front}
        summary['hypervolume'] = {**{k: hv[k] for k in keys}, 'front': hv['front']}
        summary['baseline'] = {k: v for k, v in baseline.summary().items()
                               if k in ('n_designs', 'n_feasible', 'n_failed', 'pareto',
                                        'best', 'seconds', 'designs_per_s')}
    summary.update(verification_extremes(summary['verification']))
    if not args.no_report:
        say('figures and report')
        summary['files'].update(write_report(
            result, baseline, args.out, ref=ref, hv=hv or {'reference_point': None, 'ratio':
                                                            float('nan')},
            best_vs_paper=bvp, exported=exported,
            seconds=seconds_so_far + time.perf_counter() - t0))
    summary['seconds_total'] = seconds_so_far + time.perf_counter() - t0
    return summary


def _say(quiet: bool, t0: float):
    def say(text: str) -> None:
        if not quiet:
            print(f'dmf-sim optimize [{time.perf_counter() - t0:6.1f} s] {text}',
                  file=sys.stderr, flush=True)
    return say


def _json(v):
    return float(v) if hasattr(v, '__float__') else str(v)


def _print(s: dict) -> None:
    from dmf_sim.optimize.verify import verification_lines
    rate = f'{s["designs_per_s"]:.2f} designs/s' if s['designs_per_s'] else 'nothing computed'
    print(f'{s["study"]} ({s["method"]}): {s["n_designs"]} designs ({s["n_feasible"]} feasible, '
          f'{s["n_failed"]} failed, {s["n_resumed"]} resumed); {s["seconds"]:.1f} s on '
          f'{s["workers"]} worker(s), {rate}')
    print(f'feasible Pareto front of {", ".join(s["objectives"])}: {len(s["pareto"])} designs')
    near = s.get('nearest_infeasible')
    if near:
        print(f'no design meets the constraints; the nearest, design {near["design_id"]}: '
              f'{near["constraints"]} (values > 0 violated, relative to the bound: relax those '
              f'in optimizer.constraints or widen the variables)')
    for d in s['pareto'][:20]:
        print('  ' + ', '.join(f'{k} = {v:.5g}' if isinstance(v, float) else f'{k} = {v}'
                               for k, v in d.items()))
    if 'hypervolume' in s:
        h = s['hypervolume']
        print(f'hypervolume: optimizer {h["optimizer_final"]:.4g}, Latin hypercube '
              f'{h["lhs_final"]:.4g}, ratio {h["ratio"]:.3g}')
    bvp = s.get('best_vs_paper', {})
    print(f'designs dominating the paper\'s: {bvp.get("n_dominating", 0)}')
    for line in verification_lines(s):
        print(line)
    for k in ('report.md', 'report.html', 'parquet'):
        if k in s['files']:
            print(f'{k}: {s["files"][k]}')
