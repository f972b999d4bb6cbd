"""``dmf-sim bag-recover BAG [--output OUT | --in-place]``: make a crashed bag complete again."""
from __future__ import annotations

import argparse
import sys

NAME = 'bag-recover'
HELP = ('Rewrite a truncated MCAP bag (recorder crashed or was killed) as a complete rosbag2 bag '
        'with summary, index and metadata.yaml, keeping every complete chunk.')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments: the bag, and where the repaired bag goes."""
    parser.add_argument('bag', metavar='BAG', help='rosbag2 bag directory or bare .mcap file')
    where = parser.add_mutually_exclusive_group()
    where.add_argument('-o', '--output', metavar='OUT',
                       help='output bag (never overwritten); a name ending in .mcap gives a bare '
                            'MCAP file, anything else a bag directory. Default: BAG_recovered')
    where.add_argument('--in-place', action='store_true',
                       help='replace BAG by the repaired bag once the rewrite succeeded')


def run(args: argparse.Namespace) -> int:
    """Recover the bag and print what was kept."""
    from dmf_sim.bag import recover_bag

    try:
        report = recover_bag(args.bag, args.output, in_place=args.in_place)
    except FileExistsError as exc:
        print(f'dmf-sim {NAME}: error: {exc}', file=sys.stderr)
        return 2
    print(report)
    for topic, count in sorted(report.topics.items()):
        print(f'  {topic}: {count}')
    for error in report.errors:
        print(f'  reading stopped at: {error}')
    return 0
