"""``dmf-sim warm-up``: compile every numerical kernel of the package into numba's cache once, so
that no command and no node start pays for it (``make venv`` runs it; on the colcon route run it
once after ``colcon build``)."""
from __future__ import annotations

import argparse
import time

from dmf_sim.core.json_out import json_text

__all__ = ['NAME', 'HELP', 'add_arguments', 'run']

NAME = 'warm-up'
HELP = ('Compile every numerical kernel of the package into numba\'s cache (once per machine, '
        'numba and dmf_sim version; ~1 min), so that commands and the node start at once')


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('--check', action='store_true',
                   help='only report which kernel groups would compile (nothing is compiled; '
                        'exit 0 either way)')
    p.add_argument('--json', action='store_true', help='print the report as one JSON object')


def run(args: argparse.Namespace) -> int:
    from dmf_sim.core.kernel_cache import cold, warm_up
    from dmf_sim.live.warm import GROUPS

    t0 = time.perf_counter()
    if args.check:
        cold_names = {g.name for g in cold(GROUPS)}
        rows = [{'group': g.name, 'what': g.what, 'cold': g.name in cold_names,
                 'cache': _cache_dir(g)} for g in GROUPS]
    else:
        rows = [{'group': g.name, 'what': g.what, 'compiled': compiled,
                 'seconds': round(seconds, 2), 'cache': _cache_dir(g)}
                for g, seconds, compiled in warm_up(GROUPS, prefix=f'dmf-sim {NAME}')]
    total = time.perf_counter() - t0
    if args.json:
        print(json_text({'groups': rows, 'seconds': round(total, 2)}))
        return 0
    for r in rows:
        if args.check:
            state = 'cold: compiles on first use' if r['cold'] else 'in the cache'
        else:
            state = (f'compiled in {r["seconds"]:.1f} s' if r['compiled']
                     else f'loaded from the cache in {r["seconds"]:.1f} s')
        print(f'{r["group"]:17s} {state}; {r["what"]}')
    if not args.check:
        n = sum(r['compiled'] for r in rows)
        print(f'{n} of {len(rows)} groups compiled, {total:.1f} s in all; numba cache: '
              f'{rows[0]["cache"]} (and beside the other modules)')
    return 0


def _cache_dir(group) -> str:
    return str(group.kernels()[0].stats.cache_path)
