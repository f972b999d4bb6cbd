"""``dmf-sim durability BAG``: rainflow, Palmgren-Miner damage, time per spring stage, largest
torques and the DMF damping's dissipated power of a recorded or ``dmf-sim run`` bag, read in
batches (``dmf_sim.durability``)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from dmf_sim.commands import _options as opt
from dmf_sim.core.json_out import json_text
from dmf_sim.core.optional import require_extra

__all__ = ['NAME', 'HELP', 'add_arguments', 'run']

NAME = 'durability'
HELP = ('DMF durability of a bag: rainflow counts of the spring torque, damage per hour with an '
        'S-N curve (placeholder defaults in config/durability.yaml), time per spring stage, '
        'largest torques, dissipated power; a one-page report')


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', metavar='BAG', help='rosbag2 bag directory, one of its .mcap files, '
                   'or a bare .mcap file')
    p.add_argument('--settings', default='durability', metavar='YAML',
                   help='durability settings (S-N curve, bins; default config/durability.yaml)')
    p.add_argument('--exponent', type=float, metavar='B', help='Basquin exponent b')
    p.add_argument('--reference-range', type=float, metavar='NM',
                   help='S-N reference torque range S_ref [Nm]')
    p.add_argument('--reference-cycles', type=float, metavar='N',
                   help='S-N cycles to failure N_ref at S_ref')
    p.add_argument('--out', type=Path, help='output directory (durability.json, '
                   'durability.png); default <BAG name>_durability unless --json')
    opt.add_overwrite(p)
    p.add_argument('--json', action='store_true', help='print the JSON report to stdout')
    p.add_argument('--no-plots', action='store_true', help='skip the PNG report')
    opt.add_config(p, default=None, help_default="the bag's driveline, else truck_dmf")
    p.add_argument('--namespace', help="driveline namespace of the node's topics (default: "
                   'found in the bag)')
    p.add_argument('--progress', action='store_true', help='progress bar over the bytes read')


def run(args: argparse.Namespace) -> int:
    require_extra('durability')             # fatpack: one line if missing
    from dmf_sim.bags.layout import resolve_bag
    from dmf_sim.durability.read import bag_durability
    from dmf_sim.durability.report import plot_report, report_dict, write_json
    from dmf_sim.durability.settings import read_settings
    from dmf_sim.live.warm import warm_up

    opt.check_common(args)
    settings = read_settings(args.settings, exponent=args.exponent,
                             reference_range_nm=args.reference_range,
                             reference_cycles=args.reference_cycles)
    bag = resolve_bag(args.bag)
    out = args.out
    if out is None and not args.json:
        out = Path(f'{bag.path.resolve().name}_durability')
    dest = opt.output(args, NAME, out) if out is not None else None
    warm_up(NAME, 'bag reading')
    result = bag_durability(bag, settings, namespace=args.namespace, config=args.config,
                            progress=args.progress and sys.stderr.isatty())
    written = []
    if dest is not None:
        with dest.writing() as out:
            written.append(write_json(result, out / 'durability.json'))
            if not args.no_plots:
                written.append(plot_report(result, out / 'durability.png'))
    if args.json:
        print(json_text(report_dict(result)))
    else:
        r = result.result
        print(f'{result.bag}: {r.duration_s:.1f} s, damage {r.damage:.3g} ({r.damage_per_hour:.3g}'
              f' per hour{", placeholder S-N curve" if settings.sn.placeholder else ""}), torque '
              f'{r.torque_min_nm:.0f}..{r.torque_max_nm:.0f} Nm, DMF damping power mean '
              f'{r.power_mean_w:.0f} W')
        for note in r.notes:
            print(f'note: {note}')
        for path in written:
            print(f'wrote {path}')
    return 0
