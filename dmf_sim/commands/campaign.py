"""``dmf-sim campaign``: a fault campaign (speed x load x fault x sensor noise) on Dask, scored
by the reference misfire detector."""
from __future__ import annotations

import argparse
from pathlib import Path

from dmf_sim.commands import _options as opt
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text

__all__ = ['NAME', 'HELP', 'add_arguments', 'run']

NAME = 'campaign'
HELP = ('fault campaign: a grid of (speed, load, fault, sensor noise) offline runs on Dask, each '
        'scored by the reference misfire detector; detection and false-alarm rates as a table '
        'and a plot')


def _numbers(text: str, option: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(',') if v.strip()]
    except ValueError:
        raise ConfigError(f'{option}: {text!r} is not a comma-separated list of numbers') from None
    if not values:
        raise ConfigError(f'{option}: give at least one value')
    return values


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('--out', type=Path, required=True,
                   help='directory for scores.csv, summary.json, campaign.png (and bags/ with '
                        '--keep-bags)')
    p.add_argument('--speeds', default='800,1400,2000',
                   help='engine speeds [rpm], comma-separated')
    p.add_argument('--loads', default='0.3,1', help='loads in [0, 1], comma-separated')
    p.add_argument('--faults', default='none,misfire',
                   help='faults: none (healthy) and/or misfire (single misfires every 0.5 s on '
                        'the cylinders in turn)')
    p.add_argument('--noise', default='1',
                   help="factors on the driveline's default sensor noise (timer jitter, bus "
                        'noise), comma-separated')
    p.add_argument('--duration', type=float, default=3.0,
                   help='scored seconds of each run (after 0.5 s of settling; default 3)')
    p.add_argument('--keep-bags', action='store_true', help='keep every run\'s bag in OUT/bags')
    p.add_argument('--local', action='store_true',
                   help='run the cases in this process, without Dask')
    opt.add_overwrite(p)
    opt.add_cluster(p)
    p.add_argument('--no-plots', action='store_true', help='skip campaign.png')
    p.add_argument('--json', action='store_true', help='print the summary as one JSON object')


def run(args: argparse.Namespace) -> int:
    from dmf_sim.campaign.runner import cases, run_campaign, write_outputs
    from dmf_sim.live.warm import warm_up

    grid = cases(_numbers(args.speeds, '--speeds'), _numbers(args.loads, '--loads'),
                 [f.strip() for f in args.faults.split(',') if f.strip()],
                 _numbers(args.noise, '--noise'))
    if not 0.5 <= args.duration <= 600:
        raise ConfigError(f'--duration {args.duration!r}: must be in [0.5, 600] s')
    opt.check_cluster(args)
    dest = opt.output(args, NAME)
    if not args.local:
        from dmf_sim.core.optional import require_extra
        require_extra('design')             # dask, distributed: one line if missing
    warm_up(NAME, 'bag reading', 'time integration')
    with dest.writing() as out:
        cluster = client = None
        if not args.local:
            from dmf_sim.cluster import close_local, connect, start_local
            if args.scheduler:
                client = connect(args.scheduler, args.connect_timeout)
            else:
                cluster, client = start_local(args.workers)
        try:
            rows, summary = run_campaign(grid, client, duration_s=args.duration,
                                         keep_dir=out / 'bags' if args.keep_bags else None)
        finally:
            if cluster is not None:
                close_local(cluster, client)
            elif client is not None:
                client.close()
        files = write_outputs(rows, summary, out, plots=not args.no_plots)
    if args.json:
        print(json_text(summary))
        return 0
    print(f'{"speed_rpm":>9} {"load":>5} {"fault":>8} {"noise":>5} {"misfires":>8} '
          f'{"detected":>8} {"false_alarms":>12} {"cycles":>7}')
    for r in rows:
        print(f'{r["speed_rpm"]:9g} {r["load"]:5g} {r["fault"]:>8} {r["noise"]:5g} '
              f'{r["misfires"]:8d} {r["detected"]:8d} {r["false_alarms"]:12d} {r["cycles"]:7.1f}')
    dr, fa = summary['detection_rate'], summary['false_alarm_rate']
    print(f'{summary["runs"]} runs in {summary["seconds"]:.1f} s on {summary["workers"]} '
          f'worker(s) ({summary["runs_per_s"]:.2f} runs/s): detection rate '
          f'{"n/a" if dr is None else f"{dr:.4f}"}, false alarms per engine cycle '
          f'{"n/a" if fa is None else f"{fa:.2e}"}')
    for k, v in files.items():
        print(f'{k}: {v}')
    return 0
