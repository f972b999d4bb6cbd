"""``dmf-sim foxglove-layout [--node /truck1/driveline_node]``: the Foxglove layout for a node.

The shipped ``config/foxglove_layout.json`` is written for a node named ``/driveline_node``
(no namespace). For another name or namespace this prints (or writes, ``--out``) the same
layout with that node's topics and its health status selected by its hardware id (the node's
full name), ready for Foxglove's "Import layout".
"""
from __future__ import annotations

import json
from pathlib import Path

from dmf_sim.core.errors import ConfigError

NAME = 'foxglove-layout'
HELP = ('Print (or write) the Foxglove layout for a node by its full name, e.g. '
        '/truck1/driveline_node: its namespaced topics and its health status')


def add_arguments(p) -> None:
    p.add_argument('--node', default='/driveline_node',
                   help="the node's fully qualified name (default /driveline_node)")
    p.add_argument('--out', type=Path, help='write the layout to this new file (default: print)')


def run(args) -> int:
    from dmf_sim.live.foxglove_bridge import foxglove_layout

    if args.out is not None and (args.out.exists() or args.out.is_symlink()):
        raise ConfigError(f'--out {args.out} exists already; not overwriting it')
    text = json.dumps(foxglove_layout(args.node), indent=2) + '\n'
    if args.out is None:
        print(text, end='')
        return 0
    try:
        args.out.write_text(text, encoding='utf-8')
    except OSError as exc:
        raise ConfigError(f'--out {args.out}: {exc.strerror or exc}') from None
    print(f'wrote {args.out} (layout for {json.loads(text)["globalVariables"]["node"]})')
    return 0
