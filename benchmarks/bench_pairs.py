"""Benchmark: this tree's sweeps against another tree's, in alternating pairs.

    python benchmarks/bench_pairs.py [--base HEAD] [--mode fast|full] [--pairs 30] [--quick]

This machine is shared, and its speed drifts by up to 1.6x within minutes: two benchmark runs
one after the other cannot tell a 5 % change. Here two warm worker processes, one importing
``dmf_sim`` from each tree, sweep the paper case (alpha 3, Load A, full load, 600-2000 rpm at
10 rpm, default engine; ``--mode fast``: continuation, stability and branch switching,
``full``: with the full steady-state search) one sweep each in turn, alternating which goes
first, so both sides of a pair run in the same spell. Each worker times its sweep's CPU time
(``time.process_time``). The median of the per-pair ratios (this tree / base) is the figure;
its quartiles say how far to trust it.

``--base``: a git revision of this repository (default HEAD: the working tree against its last
commit; checked out into a temporary worktree for the run and removed after, its numba kernels
compiled there before anything is timed) or a directory holding a ``dmf_sim`` tree. Each worker
also reports its sweep's number of points, so a change that alters what a sweep computes shows.

Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SPEEDS = (600.0, 2000.0)
QUICK_SPEEDS = (900.0, 1100.0)
WARM_SWEEPS = 2                  # untimed sweeps per mode before a worker says it is ready


def worker(lo: float, hi: float) -> int:
    """Run in a subprocess: sweep the paper case once per line read ('fast' or 'full') and
    print 'CPU milliseconds points' for each."""
    from dmf_sim.physics import engine as engines, loads as excitations, model as models
    from dmf_sim.solvers.hbm import SweepOptions, sweep

    def api(module, new: str, old: str):
        """A name of either tree (the base may predate a rename)."""
        return getattr(module, new, None) or getattr(module, old)
    engine = api(engines, 'read_engine', 'load_engine')('engine_d13', load_set='A')
    (getattr(engine, 'warm_up', None) or engine.warm)()   # the gas grid now, not in a sweep
    loads = api(excitations, 'DrivelineExcitation', 'DrivelineLoads')(
        api(models, 'read_model', 'load_model')('truck_dmf', alpha=3.0), engine)
    modes = {'fast': SweepOptions(step_rpm=10.0, search=None),
             'full': SweepOptions(step_rpm=10.0)}
    for options in modes.values():
        for _ in range(WARM_SWEEPS):
            sweep(loads, 1.0, (lo, hi), options=options)
    # every dmf_sim module from this worker's tree (a module the tree lacks would otherwise
    # come from the installed package, and the pair would time a mixture)
    tree = Path(os.environ['PYTHONPATH']).resolve()
    strays = sorted(name for name, mod in list(sys.modules.items())
                    if name.split('.')[0] == 'dmf_sim' and getattr(mod, '__file__', None)
                    and not Path(mod.__file__).resolve().is_relative_to(tree))
    if strays:
        print(f'dmf_sim modules not in {tree}: {", ".join(strays[:3])}', flush=True)
        return 1
    print('ready', flush=True)
    for line in sys.stdin:
        t0 = time.process_time()
        res = sweep(loads, 1.0, (lo, hi), options=modes[line.strip()])
        print(f'{(time.process_time() - t0) * 1e3:.4f} {res.n_points}', flush=True)
    return 0


class Worker:
    """A worker process importing dmf_sim from ``tree``."""

    def __init__(self, tree: Path, lo: float, hi: float):
        self.tree = tree
        env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS='1',
                   OPENBLAS_NUM_THREADS='1')
        self.proc = subprocess.Popen(
            [sys.executable, str(Path(__file__).resolve()), '--worker', str(lo), str(hi)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env,
            cwd=tempfile.gettempdir())           # not the repository: PYTHONPATH decides
        line = self.proc.stdout.readline().strip()
        if line != 'ready':
            self.close()
            raise RuntimeError(f'the worker for {tree} did not start ({line or "no output"})')

    def sweep(self, mode: str) -> tuple[float, int]:
        self.proc.stdin.write(mode + '\n')
        self.proc.stdin.flush()
        line = self.proc.stdout.readline().split()
        if len(line) != 2:
            raise RuntimeError(f'the worker for {self.tree} stopped during a {mode} sweep')
        return float(line[0]), int(line[1])

    def close(self) -> None:
        if self.proc.stdin:
            self.proc.stdin.close()
        self.proc.wait(timeout=60)


def base_tree(base: str, scratch: Path) -> tuple[Path, bool]:
    """(the directory of the base tree, whether it is a worktree made here)."""
    path = Path(base)
    if path.is_dir():
        if not (path / 'dmf_sim' / '__init__.py').is_file():
            raise ValueError(f'--base {base}: no dmf_sim package in that directory')
        return path.resolve(), False
    out = subprocess.run(['git', '-C', str(REPO), 'worktree', 'add', '--detach', str(scratch),
                          base], capture_output=True, text=True)
    if out.returncode != 0:
        raise ValueError(f'--base {base}: neither a directory nor a git revision of this '
                         f'repository ({out.stderr.strip().splitlines()[-1]})')
    return scratch, True


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--base', default='HEAD',
                   help='git revision or directory of the other tree (default HEAD)')
    p.add_argument('--mode', choices=('fast', 'full'), default='fast')
    p.add_argument('--pairs', type=int, default=30)
    p.add_argument('--quick', action='store_true', help='900-1100 rpm, 3 pairs (for tests)')
    args = p.parse_args(argv)
    if args.pairs < 1:
        p.error(f'--pairs {args.pairs}: must be an integer >= 1')
    lo, hi = QUICK_SPEEDS if args.quick else SPEEDS
    if args.quick:
        args.pairs = 3
    with tempfile.TemporaryDirectory(prefix='dmf-bench-pairs-') as tmp:
        try:
            tree, made = base_tree(args.base, Path(tmp) / 'base')
        except ValueError as exc:
            p.error(str(exc))
        try:
            out = compare(tree, made, Path(tmp) / 'base', args, lo, hi)
        except RuntimeError as exc:         # a worker that could not run the sweeps
            print(f'bench_pairs: {exc}', file=sys.stderr)
            return 1
    print(f'{args.mode} sweep, {args.pairs} pairs: base {out["base_ms_min"]:.1f} ms min, '
          f'{out["base_ms_median"]:.1f} median; this tree {out["this_ms_min"]:.1f} / '
          f'{out["this_ms_median"]:.1f} ms (CPU); this / base per pair: median '
          f'{out["ratio_median"]:.3f} (quartiles {out["ratio_q25"]:.3f}-{out["ratio_q75"]:.3f}); '
          f'points {out["points_base"]} / {out["points_this"]}; load '
          f'{out["load_avg"][0]:.1f} -> {out["load_avg"][1]:.1f}')
    print(json.dumps(out))
    return 0


def compare(tree: Path, made: bool, scratch: Path, args, lo: float, hi: float) -> dict:
    """The alternating pairs of sweeps between the base tree and this one; the figures."""
    workers: list[Worker] = []
    try:
        t0 = time.perf_counter()
        workers = [Worker(tree, lo, hi), Worker(REPO, lo, hi)]
        print(f'workers ready in {time.perf_counter() - t0:.1f} s (base: {tree})')
        ms = [[], []]
        points = [set(), set()]
        load0 = os.getloadavg()[0]
        for i in range(args.pairs):
            for k in ((0, 1) if i % 2 == 0 else (1, 0)):
                t, n = workers[k].sweep(args.mode)
                ms[k].append(t)
                points[k].add(n)
        load1 = os.getloadavg()[0]
    finally:
        for w in workers:
            w.close()
        if made:
            subprocess.run(['git', '-C', str(REPO), 'worktree', 'remove', '--force',
                            str(scratch)], capture_output=True)
    base_ms, this_ms = np.array(ms[0]), np.array(ms[1])
    ratio = this_ms / base_ms
    out = {'mode': args.mode, 'pairs': args.pairs, 'speeds_rpm': [lo, hi, 10.0],
           'base': args.base, 'base_ms_min': float(base_ms.min()),
           'base_ms_median': float(np.median(base_ms)), 'this_ms_min': float(this_ms.min()),
           'this_ms_median': float(np.median(this_ms)),
           'ratio_median': float(np.median(ratio)),
           'ratio_q25': float(np.percentile(ratio, 25)),
           'ratio_q75': float(np.percentile(ratio, 75)),
           'ratio_of_minima': float(this_ms.min() / base_ms.min()),
           'points_base': sorted(points[0]), 'points_this': sorted(points[1]),
           'load_avg': [load0, load1]}
    return out


if __name__ == '__main__':
    if len(sys.argv) == 4 and sys.argv[1] == '--worker':
        sys.exit(worker(float(sys.argv[2]), float(sys.argv[3])))
    sys.exit(main())
