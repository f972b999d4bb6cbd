"""Benchmark: the Floquet multipliers' eigenvalue call against LAPACK's ``dgeev``.

    python benchmarks/bench_eigen.py [--alpha 3] [--speeds 600 2000 10] [--repeat 40] [--quick]

The package computes the eigenvalues of a monodromy with LAPACK's balancing (``dgebal``) and
Hessenberg reduction (``dgehrd``) followed by its own compiled double-shift QR iteration
(``dmf_sim.solvers.francis_qr``) instead of ``dgeev``'s ``dlahqr``: written because the QR stage
is most of a sweep's Floquet time. This script says whether that is worth it, on the matrices a
sweep really meets: the monodromies of every point of a ``--fast`` sweep of the paper case
(alpha 3, Load A, full load, default engine) that crosses a knee, 32 x 32.

Both calls run inside compiled loops over all the matrices (no Python in between), in alternating
repetitions so both sample the same spells of a shared machine: microseconds per matrix (min and
median) and the median of the per-repetition ratios. Accuracy: the largest distance from an
eigenvalue of ``numpy.linalg.eigvals`` to the nearest one of each call, relative to the
largest modulus.

Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from sweep_args import check_sweep_args  # beside this script

from dmf_sim.core.compiled import jit
from dmf_sim.solvers.lapack_kernel import dgeev_into, eigenvalues_into


def _all_dgeev(Xs, wr, wi, info):
    for k in range(Xs.shape[0]):
        info[k] = dgeev_into(Xs[k], wr[k], wi[k])


def _all_package(Xs, wr, wi, info):
    for k in range(Xs.shape[0]):
        info[k] = eigenvalues_into(Xs[k], wr[k], wi[k])


_all_dgeev = jit(_all_dgeev)
_all_package = jit(_all_package)


def monodromies(alpha: float, speeds: tuple[float, float, float]) -> np.ndarray:
    """(K, n, n) monodromies (up to similarity, as the Floquet kernel forms them) of the points of
    a --fast sweep that cross a knee."""
    from dmf_sim.core.units import RPM_TO_RAD_S
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_model
    from dmf_sim.physics.orders import synthesize
    from dmf_sim.solvers.hbm import SweepOptions, sweep
    from dmf_sim.solvers.stability import FloquetAnalyzer
    from dmf_sim.solvers.stability_kernel import floquet

    lo, hi, step = speeds
    model = read_model('truck_dmf', alpha=alpha)
    engine = read_engine('engine_d13', load_set='A')
    loads = DrivelineExcitation(model, engine)
    res = sweep(loads, 1.0, (lo, hi), options=SweepOptions(step_rpm=step, search=None))
    fa = FloquetAnalyzer(loads.model)
    out = []
    for b in res.branches:
        for p in b.points:
            c = np.ascontiguousarray(p.windup_orders, dtype=complex)
            X, count, _, _ = floquet(c, synthesize(c, fa.n_fine), p.speed_rpm * RPM_TO_RAD_S,
                                     *fa._kernel_args)
            if count > 1:
                out.append(X.copy())
    return np.array(out)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--alpha', type=float, default=3.0)
    p.add_argument('--speeds', type=float, nargs=3, default=[600.0, 2000.0, 10.0],
                   metavar=('FROM', 'TO', 'STEP'))
    p.add_argument('--repeat', type=int, default=40, help='alternating timed repetitions')
    p.add_argument('--quick', action='store_true', help='small run (900-1100 rpm) for tests')
    args = p.parse_args(argv)
    check_sweep_args(p, args)
    if args.quick:
        args.speeds = [900.0, 1100.0, 10.0]
        args.repeat = 3

    from dmf_sim.core.errors import DmfSimError
    try:
        Xs = monodromies(args.alpha, tuple(args.speeds))
    except DmfSimError as exc:          # a bad model or range: one line, exit 2
        p.error(str(exc))
    if len(Xs) == 0:
        print(f'no point of the sweep {args.speeds} crosses a knee: nothing to time',
              file=sys.stderr)
        return 1
    K, n = Xs.shape[0], Xs.shape[1]

    calls = {'dgeev': _all_dgeev, 'package': _all_package}
    wr = {name: np.empty((K, n)) for name in calls}
    wi = {name: np.empty((K, n)) for name in calls}
    info = {name: np.empty(K, dtype=np.int64) for name in calls}
    for name, f in calls.items():          # compile, not timed
        f(Xs, wr[name], wi[name], info[name])
    times = {name: [] for name in calls}
    for r in range(args.repeat):
        order = list(calls) if r % 2 == 0 else list(calls)[::-1]
        for name in order:
            t0 = time.perf_counter()
            calls[name](Xs, wr[name], wi[name], info[name])
            times[name].append((time.perf_counter() - t0) / K)
    ratio = np.array(times['package']) / np.array(times['dgeev'])

    worst = {}
    for name in calls:
        if info[name].any():
            print(f'{name}: {int((info[name] != 0).sum())} matrices did not converge',
                  file=sys.stderr)
            return 1
        gap = 0.0
        for k in range(K):
            ref = np.linalg.eigvals(Xs[k])
            got = wr[name][k] + 1j * wi[name][k]
            d = np.abs(ref[:, None] - got[None, :]).min(axis=1).max()
            gap = max(gap, float(d / np.abs(ref).max()))
        worst[name] = gap

    us = {name: (1e6 * min(t), 1e6 * float(np.median(t))) for name, t in times.items()}
    print(f'{K} monodromies of {n} x {n} (the points of a --fast sweep of the paper case, '
          f'{args.speeds[0]:g}-{args.speeds[1]:g} rpm, that cross a knee), {args.repeat} '
          f'alternating repetitions:')
    for name, label in (('dgeev', "LAPACK dgeev (dgebal, dgehrd, dlahqr)"),
                        ('package', 'dgebal, dgehrd, francis_qr (the package)')):
        print(f'  {label:45s} min {us[name][0]:7.1f} us, median {us[name][1]:7.1f} us per '
              f'matrix; largest difference to numpy.linalg.eigvals {worst[name]:.1e} '
              f'(relative to the largest modulus)')
    print(f'  per-repetition ratio package / dgeev: median {np.median(ratio):.3f} '
          f'(min {ratio.min():.3f}, max {ratio.max():.3f})')
    out = {'matrices': int(K), 'size': int(n), 'repeat': int(args.repeat),
           'us_per_matrix_dgeev_min': round(us['dgeev'][0], 2),
           'us_per_matrix_dgeev_median': round(us['dgeev'][1], 2),
           'us_per_matrix_package_min': round(us['package'][0], 2),
           'us_per_matrix_package_median': round(us['package'][1], 2),
           'ratio_median': round(float(np.median(ratio)), 4),
           'max_rel_diff_package': worst['package'], 'max_rel_diff_dgeev': worst['dgeev'],
           'speeds_rpm': list(args.speeds), 'alpha': args.alpha, 'quick': bool(args.quick)}
    print(json.dumps(out))
    return 0


if __name__ == '__main__':
    sys.exit(main())
