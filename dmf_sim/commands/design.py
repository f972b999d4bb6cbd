"""``dmf-sim design``: a DMF design study (many designs x operating conditions) on Dask."""
from __future__ import annotations

import sys
from pathlib import Path

from dmf_sim.commands import _options as opt
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text, write_json
from dmf_sim.core.optional import require_extra

__all__ = ['NAME', 'HELP', 'add_arguments', 'run']

NAME = 'design'
HELP = ('DMF design study: every design of a study file (k, theta, alpha, damping, spring stages) '
        'swept over its operating conditions on Dask; table, Pareto front and plots.')


def add_arguments(p) -> None:
    p.add_argument('study', help='study YAML (see config/study_example.yaml)')
    p.add_argument('--out', type=Path, required=True,
                   help='directory for results.parquet, results.csv, summary.json and the plots; '
                        'finished designs are stored there as they arrive')
    p.add_argument('--resume', action='store_true',
                   help='continue the study stored in --out (finished designs are not recomputed)')
    opt.add_overwrite(p)
    opt.add_cluster(p)
    p.add_argument('--batch-size', type=int, help='designs per Dask task (default: measured, '
                   'see doc/performance.md)')
    p.add_argument('--no-plots', action='store_true', help='skip the PNG figures')
    p.add_argument('--no-progress', action='store_true', help='no progress bar on stderr')
    p.add_argument('--json', action='store_true', help='print the summary as one JSON object')


def run(args) -> int:
    require_extra('design')                 # dask, distributed, pyarrow: one line if missing
    from dmf_sim.cluster import connect
    from dmf_sim.design.runner import run_study
    from dmf_sim.design.study import read_study
    from dmf_sim.design.table import ResultStore
    from dmf_sim.live.warm import warm_up

    opt.check_cluster(args)
    if args.batch_size is not None and args.batch_size < 1:
        raise ConfigError(f'--batch-size {args.batch_size}: must be >= 1')
    dest = opt.resumable_output(args, NAME)
    study = read_study(args.study)
    if args.resume:
        ResultStore(args.out, study, args.resume)      # --resume problems, before work
    warm_up(NAME, 'sweep')     # compiled once here, then every worker loads them
    client = connect(args.scheduler, args.connect_timeout) if args.scheduler else None
    done = [0, study.n_designs]
    with dest.writing() as out:
        try:
            result = run_study(study, client, out=out, resume=args.resume,
                               workers=args.workers, batch_size=args.batch_size,
                               progress=not args.no_progress,
                               on_batch=lambda n, total: done.__setitem__(0, n),
                               on_worker_event=_say)
        except KeyboardInterrupt:
            print(f'dmf-sim design: interrupted; {done[0]} of {done[1]} designs are stored in '
                  f'{out}; continue with --resume', file=sys.stderr)
            return 130
        finally:
            if client is not None:
                client.close()
        if not args.no_plots:
            from dmf_sim.design.plots import write_plots
            result.files.update(write_plots(result, out))
        summary = result.summary()
        write_json(out / 'summary.json', summary)
    if args.json:
        print(json_text(summary))
    else:
        _print(summary)
    return 0


def _say(line: str) -> None:
    """A cluster event on stderr, one line, without breaking the progress bar."""
    from tqdm import tqdm
    tqdm.write(f'dmf-sim design: {line}', file=sys.stderr)


def _print(s: dict) -> None:
    rate = f'{s["designs_per_s"]:.1f} designs/s' if s['designs_per_s'] else 'nothing computed'
    print(f'study {s["study"]}: {s["n_designs"]} designs ({s["n_ok"]} ok, {s["n_failed"]} failed, '
          f'{s["n_resumed"]} resumed) x conditions {", ".join(s["conditions"])}; '
          f'{s["seconds"]:.1f} s on {s["workers"]} worker(s), {rate}')
    o1, o2 = s['pareto_objectives']
    print(f'Pareto front of {o1} and {o2} (both minimized): {len(s["pareto"])} designs')
    for d in s['pareto'][:20]:
        print('  ' + ', '.join(f'{k} = {v:.5g}' if isinstance(v, float) else f'{k} = {v}'
                               for k, v in d.items()))
    if s['best']:
        print('best (compromise): ' + ', '.join(f'{k} = {v:.5g}' if isinstance(v, float)
                                                else f'{k} = {v}' for k, v in s['best'].items()))
    for f in s['failed'][:10]:
        print(f'  design {f["design_id"]} failed: {f["error"]}')
    for k, v in s['files'].items():
        print(f'{k}: {v}')
