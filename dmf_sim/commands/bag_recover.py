"""``dmf-sim bag-recover BAG [--output OUT | --in-place]``: make a crashed bag complete again."""
from __future__ import annotations

import argparse

from dmf_sim.commands import _options as opt

__all__ = ['NAME', 'HELP', 'add_arguments', 'run']

NAME = 'bag-recover'
HELP = ('Complete a bag a crash left behind (recorder killed) or repair a damaged one: every '
        'complete, intact split is kept as it is; each truncated file, or file with corrupt '
        'chunks (CRC mismatch), is rewritten with every complete, intact chunk plus summary and '
        'index (what was dropped is listed: topic, time range, messages), and metadata.yaml '
        'lists them all. A file that is not MCAP, or holds no complete message, is refused.')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments: the bag, and where the repaired bag goes."""
    parser.add_argument('bag', metavar='BAG', help='rosbag2 bag directory or bare .mcap file')
    where = parser.add_mutually_exclusive_group()
    where.add_argument('-o', '--output', metavar='OUT',
                       help='output bag: a name ending in .mcap gives a bare MCAP file, '
                            'anything else a bag directory. Default: BAG_recovered')
    where.add_argument('--in-place', action='store_true',
                       help='replace the truncated files of BAG (and its metadata.yaml) once '
                            'the rewrite succeeded')
    opt.add_overwrite(parser)


def run(args: argparse.Namespace) -> int:
    """Recover the bag and print what was kept."""
    from dmf_sim.bags.layout import resolve_bag
    from dmf_sim.bags.recovery import recover_bag, recovery_output, written_by_recovery
    from dmf_sim.core.errors import ConfigError

    bag = resolve_bag(args.bag)
    if args.in_place:
        if args.overwrite:
            raise ConfigError('--overwrite is for an output path; --in-place replaces the '
                              "bag's own incomplete files")
        report = recover_bag(bag.path, in_place=True)
    else:
        out, as_dir = recovery_output(bag, args.output)
        dest = opt.output(args, NAME, out, option='--output', kind='bag' if as_dir else 'file',
                          owned=written_by_recovery)
        with dest.writing():
            report = recover_bag(bag.path, out)
    print(report)
    for topic, count in sorted(report.topics.items()):
        print(f'  {topic}: {count}')
    if report.rewritten:
        print(f'  rewritten: {", ".join(report.rewritten)}')
    for error in report.errors:
        print(f'  reading stopped at: {error}')
    for line in report.corrupt:
        print(f'  {line}')
    return 0
