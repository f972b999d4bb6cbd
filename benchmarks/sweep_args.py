"""The command-line checks the sweep benchmarks share (``bench_hbm.py``, ``bench_eigen.py``):
a bad value is refused with argparse's one line naming the option and its range, exit 2."""
from __future__ import annotations

import argparse


def check_sweep_args(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``--repeat`` at least 1; ``--speeds FROM TO STEP`` with FROM < TO and STEP > 0 [rpm]."""
    if args.repeat < 1:
        p.error(f'--repeat {args.repeat}: must be an integer >= 1')
    if not (args.speeds[2] > 0 and args.speeds[1] > args.speeds[0]):
        p.error(f'--speeds {" ".join(f"{v:g}" for v in args.speeds)}: need FROM < TO and '
                f'STEP > 0 [rpm]')
