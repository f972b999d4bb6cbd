"""``dmf-sim runup UP_BAG [DOWN_BAG]``: order tracks of run-up / run-down bags over the HBM
sweep's branches, the jump speeds in the records and the sweep events that explain them
(``dmf_sim.transient.runup``)."""
from __future__ import annotations

import argparse
from pathlib import Path

from dmf_sim.analysis.outputs import to_jsonable
from dmf_sim.commands import _options as opt
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text, write_json
from dmf_sim.transient.defaults import DEFAULT_BIN_RPM, JUMP_WINDOW_CYCLES

__all__ = ['NAME', 'HELP', 'MAX_BAGS', 'add_arguments', 'run']

NAME = 'runup'
HELP = ('Run-up analysis: order tracks of run-up/run-down bags (e.g. from dmf-sim run '
        'ramp:...) over the HBM branches, jump speeds vs the sweep\'s fold/stability events')
MAX_BAGS = 2                    # a run-up and a run-down


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('bags', nargs='+', metavar='BAG',
                   help='a run-up bag, a run-down bag, or one of each')
    p.add_argument('--bin-rpm', type=float, default=DEFAULT_BIN_RPM,
                   help=f'speed bin for the quasi-static comparison [rpm] (default '
                        f'{DEFAULT_BIN_RPM:g})')
    p.add_argument('--window', type=int, default=JUMP_WINDOW_CYCLES,
                   help=f'engine cycles before/after a jump (default {JUMP_WINDOW_CYCLES})')
    p.add_argument('--no-hbm', action='store_true', help='no HBM sweep (jumps unmatched)')
    p.add_argument('--out', type=Path, help='output directory (runup.json, runup.png); '
                   'default <first BAG name>_runup unless --json')
    opt.add_overwrite(p)
    p.add_argument('--json', action='store_true', help='print the JSON to stdout')
    opt.add_config(p, default=None, help_default="the bag's driveline, else truck_dmf")


def run(args: argparse.Namespace) -> int:
    from dmf_sim.bags.layout import resolve_bag
    from dmf_sim.live.warm import warm_up
    from dmf_sim.transient.plots import plot_runup
    from dmf_sim.transient.runup import runup_analysis

    opt.check_common(args)
    if not 0 < args.bin_rpm <= 500:
        raise ConfigError(f'--bin-rpm must be within (0, 500] rpm, got {args.bin_rpm!r}')
    if not 2 <= args.window <= 200:
        raise ConfigError(f'--window must be within [2, 200] cycles, got {args.window!r}')
    if len(args.bags) > MAX_BAGS:
        raise ConfigError(f'BAG: {len(args.bags)} bags given; give a run-up bag, a run-down bag '
                          'or one of each')
    bags = [resolve_bag(b) for b in args.bags]
    out = args.out
    if out is None and not args.json:
        out = Path(f'{bags[0].path.resolve().name}_runup')
    dest = opt.output(args, NAME, out) if out is not None else None
    warm_up(NAME, 'bag reading', *([] if args.no_hbm else ['sweep']))
    res = runup_analysis(args.bags, bin_rpm=args.bin_rpm, hbm=not args.no_hbm,
                         window=args.window, config=args.config)
    data = to_jsonable(res.as_dict())
    if dest is not None:
        with dest.writing() as out:
            write_json(out / 'runup.json', data)
            plot_runup(res, out / 'runup.png')
    if args.json:
        print(json_text(data))
    else:
        for r in res.runs:               # what the reading had to leave out, as analyze says
            for line in r.damage:
                print(f'warning: {r.bag}: {line}')
        for j in res.jumps:
            ev = (f'; sweep {j.event["kind"]} at {j.event["speed_rpm"]:.1f} rpm '
                  f'({j.error_rpm:.1f} rpm away)' if j.event else '')
            way = 'up' if j.direction > 0 else 'down'
            print(f'run-{way}: {j.order} jumps {j.before * 1e3:.1f} -> {j.after * 1e3:.1f} mrad '
                  f'at {j.speed_rpm:.1f} rpm{ev}')
        if not res.jumps:
            print('no jumps found')
        print(f'wrote {out}/runup.json, {out}/runup.png')
    return 0
