"""Benchmark: the cost of arc-spring friction in a harmonic-balance speed sweep, and the HBM's
agreement with Newmark where the DMF slips.

    python benchmarks/bench_friction_hbm.py [--speeds 600 2000] [--repeat 5] [--small]

1. ``friction_sweep_time_ratio``: a sweep of truck_dmf_friction (friction and end stops) over
   the speed range, divided by the same sweep of truck_dmf (the same driveline without them),
   full load, both after the warm-up. Each repetition times the two back to back (so the ratio
   is of one moment on a shared machine); min and median over the repetitions. Measured in
   both modes: ``fast`` (continuation, Floquet stability of every point, branch switching:
   ``dmf-sim sweep --fast``) and ``full`` (plus the search for every stable state).
   ``floquet_over_baseline_fast``: the Floquet stage of the friction sweep alone (the compiled
   monodromies and their eigenvalues, :meth:`FloquetAnalyzer.analyze_many` on the sweep's
   points, timed right after each repetition's pair) divided by the whole sweep without
   friction: the share of the 2x budget that stability takes before any Newton step.
2. ``max_rel_diff``: HBM vs Newmark (dt 5e-5 s, from the HBM state, to steady state) at speeds
   where the DMF slips: the largest relative difference of the 3rd- and 1.5th-order wind-up
   amplitudes; the 0.5th and 1st orders (about 1 % of the 3rd) as an absolute difference
   relative to the 3rd order (``max_small_order_diff``).

The last line of the output is one JSON object.
"""
from __future__ import annotations

import argparse
import json
import statistics
import time

import numpy as np


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--speeds', type=float, nargs=2, default=[600.0, 2000.0],
                   metavar=('FROM', 'TO'))
    p.add_argument('--repeat', type=int, default=5, help='timed repetitions of each pair')
    p.add_argument('--engine', default='engine_d13')
    p.add_argument('--small', action='store_true',
                   help='900-1300 rpm, 2 repetitions, Newmark at 2 speeds (for tests)')
    args = p.parse_args(argv)
    check = [1000.0, 1200.0, 1500.0, 1800.0]
    if args.small:
        args.speeds, args.repeat, check = [900.0, 1300.0], 2, [1000.0, 1200.0]
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_model
    from dmf_sim.physics.orders import synthesize
    from dmf_sim.solvers.hbm import CondensedHBM, SweepOptions, sweep
    from dmf_sim.solvers.hbm.warm import warm_up
    from dmf_sim.solvers.stability import FloquetAnalyzer

    warm_up()
    engine = read_engine(args.engine)
    engine.warm_up()
    loads = {name: DrivelineExcitation(read_model(name), engine)
             for name in ('truck_dmf', 'truck_dmf_friction')}
    rng = tuple(args.speeds)
    modes = {'fast': SweepOptions(search=None), 'full': SweepOptions()}
    for name, ld in loads.items():                  # one untimed sweep each (first-call costs)
        sweep(ld, 1.0, rng, options=modes['fast'])
    out = {'speeds_rpm': list(rng), 'repeat': args.repeat, 'small': args.small}
    model = loads['truck_dmf_friction'].model
    floquet = FloquetAnalyzer(model, modes=CondensedHBM(loads['truck_dmf_friction'], 1.0).modes)
    for mode, opts in modes.items():
        ratios, shares, secs = [], [], {'truck_dmf': [], 'truck_dmf_friction': []}
        for _ in range(args.repeat):
            t = {}
            for name, ld in loads.items():
                t0 = time.perf_counter()
                res = sweep(ld, 1.0, rng, options=opts)
                t[name] = time.perf_counter() - t0
                secs[name].append(t[name])
            ratios.append(t['truck_dmf_friction'] / t['truck_dmf'])
            points = [p for b in res.branches for p in b.points]
            C = np.array([p.windup_orders for p in points])
            W = synthesize(C, floquet.n_fine)
            t0 = time.perf_counter()
            floquet.analyze_many(C, [p.speed_rpm for p in points], W)
            shares.append((time.perf_counter() - t0) / t['truck_dmf'])
        print(f'{mode}: without friction {statistics.median(secs["truck_dmf"]):.3f} s, with '
              f'{statistics.median(secs["truck_dmf_friction"]):.3f} s ({len(points)} points); '
              f'ratio min {min(ratios):.2f} median {statistics.median(ratios):.2f}; its '
              f'Floquet stage alone {statistics.median(shares):.2f}x the sweep without '
              f'friction (min {min(shares):.2f})')
        out[f'friction_sweep_time_ratio_{mode}'] = statistics.median(ratios)
        out[f'friction_sweep_time_ratio_{mode}_min'] = min(ratios)
        out[f'floquet_over_baseline_{mode}'] = statistics.median(shares)
        out[f'floquet_over_baseline_{mode}_min'] = min(shares)
        out[f'sweep_seconds_{mode}'] = {k: statistics.median(v) for k, v in secs.items()}
    out['friction_sweep_time_ratio'] = out['friction_sweep_time_ratio_fast']
    hb = CondensedHBM(loads['truck_dmf_friction'], 1.0)
    rows, main_diff, small_diff = [], 0.0, 0.0
    for s in check:
        pt = hb.solve(s)
        c = hb.newmark_from(pt, dt=5e-5, steady_tol=1e-7, max_cycles=200).windup_orders
        h = np.abs(pt.windup_orders)
        n = np.abs(c)
        rel = {k: abs(h[k] - n[k]) / n[k] for k in (3, 6)}
        small = {k: abs(h[k] - n[k]) / n[6] for k in (1, 2)}
        main_diff = max(main_diff, *rel.values())
        small_diff = max(small_diff, *small.values())
        rows.append({'speed_rpm': s, 'order_3_hbm': h[6], 'order_3_newmark': n[6],
                     'rel_diff_3': rel[6], 'rel_diff_1_5': rel[3],
                     'diff_0_5': small[1], 'diff_1': small[2]})
        print(f'{s:.0f} rpm: order 3 HBM {h[6]:.4e} Newmark {n[6]:.4e} ({rel[6]:.2%}), '
              f'order 1.5 {rel[3]:.2%}, orders 0.5 / 1 {small[1]:.2%} / {small[2]:.2%} of the 3rd')
    out.update(max_rel_diff=main_diff, max_small_order_diff=small_diff, check=rows,
               target_ratio=2.0)
    print(json.dumps(out, default=float))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
