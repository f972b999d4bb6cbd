"""Benchmark: ``dmf-sim paper`` end to end (study, figures, reports), against its 2-minute budget.

Runs the command in this process (as ``dmf-sim paper --out DIR --json``) and prints the time of
each study step, the wall-clock and CPU time of the whole run and the peak memory. Last line: one
JSON object (seconds, cpu_seconds, within_budget, counts of reproduced claims, ...).

    python benchmarks/bench_paper.py [--quick] [--out DIR]
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

BUDGET_S = 120.0       # the full run finishes in under 2 minutes on the 2-core machine


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--quick', action='store_true', help='the reduced study (as in the test suite)')
    p.add_argument('--out', type=Path, help='output directory (default: a temporary one)')
    args = p.parse_args(argv)

    from dmf_sim.cli import main as cli_main
    with contextlib.ExitStack() as stack:
        out = args.out or Path(stack.enter_context(tempfile.TemporaryDirectory()))
        argv_cmd = ['paper', '--out', str(out), '--json']          # progress on stderr
        if args.quick:
            argv_cmd.append('--quick')
        buf = io.StringIO()
        t0, c0 = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(buf):
            rc = cli_main(argv_cmd)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        if rc != 0:
            print(f'dmf-sim paper failed (exit {rc})', file=sys.stderr)
            return rc
        summary = json.loads(buf.getvalue())
    rss_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(f'dmf-sim paper{" --quick" if args.quick else ""}: {wall:.1f} s wall, {cpu:.1f} s CPU '
          f'(this process), peak RSS {rss_mib:.0f} MiB; budget {BUDGET_S:.0f} s')
    for step, s in summary['step_seconds'].items():
        print(f'  {step:<40s} {s:7.1f} s')
    c = summary['counts']
    print(f'claims: {c["yes"]} yes, {c["partly"]} partly, {c["no"]} no')
    print(json.dumps({'seconds': round(wall, 2), 'cpu_seconds': round(cpu, 2),
                      'budget_seconds': BUDGET_S, 'within_budget': wall < BUDGET_S,
                      'peak_rss_mib': round(rss_mib, 1), 'quick': bool(args.quick),
                      'step_seconds': summary['step_seconds'], 'counts': c,
                      'out': str(args.out) if args.out else None}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
