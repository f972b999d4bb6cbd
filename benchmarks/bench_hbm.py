"""Benchmark: harmonic balance speed sweep vs Newmark time integration to steady state.

    python benchmarks/bench_hbm.py [--alpha 3] [--load-set A] [--load 1] [--speeds 600 2000 10]
                                   [--newmark-every 10] [--quick]

1. HBM: the whole sweep timed end to end after the warm-up (``warm.warm_up``, as a design-study
   worker does when it starts, and one solve), in its two modes:
   ``fast`` (condensed HBM + pseudo-arc-length continuation landing on the speed grid, Floquet
   stability of every point, branch switching: ``dmf-sim sweep --fast``) and ``full`` (plus the
   search for every stable state: deflated Newton seeds, Newmark shots, non-periodic speeds;
   the default). Repeated ``--repeat`` times: min and median.
2. Newmark (newmark.simulate, dt = 1e-4 s, average acceleration, from the static equilibrium until
   the cycle-to-cycle change is below its default tolerance): timed on a subset of the grid speeds
   (every ``--newmark-every``-th) only; the per-point mean is extrapolated to the whole grid and
   the output says so. The Newmark runs are interleaved with the sweeps' repetitions (after each
   repetition, the next share of the subset), so that on a shared machine both are timed in the
   same spells and their ratio is not the ratio of two different moments.
3. Agreement on the subset: relative difference of the wind-up's 3rd-order amplitude |c_6|, of the
   1.5th-order amplitude |c_3| where it is significant (> 20 % of |c_6|), and of the mean, between
   Newmark and the HBM solution it settled on (the nearest one where solutions coexist).

The last line of the output is one JSON object: sweep_seconds,
speedup_vs_newmark, max_rel_diff, ...
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
from sweep_args import check_sweep_args  # beside this script


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--alpha', type=float, default=3.0)
    p.add_argument('--load-set', default='A')
    p.add_argument('--load', type=float, default=1.0)
    p.add_argument('--theta', type=float,
                   help='DMF knee angle [rad] (default: the YAML value, 0.24)')
    p.add_argument('--speeds', type=float, nargs=3, default=[600.0, 2000.0, 10.0],
                   metavar=('FROM', 'TO', 'STEP'))
    p.add_argument('--newmark-every', type=int, default=10,
                   help='time Newmark on every k-th grid speed')
    p.add_argument('--dt', type=float, default=1e-4, help='Newmark time step [s]')
    p.add_argument('--engine', default='engine_d13',
                   help='engine YAML or A_n table (default engine_d13)')
    p.add_argument('--repeat', type=int, default=5, help='timed repetitions of each sweep mode')
    p.add_argument('--quick', action='store_true',
                   help='small run (900-1100 rpm, Newmark on 3 points) for tests')
    args = p.parse_args(argv)
    check_sweep_args(p, args)
    if args.quick:
        args.speeds = [900.0, 1100.0, 10.0]
        args.newmark_every = 10
        args.repeat = 1
    from dmf_sim.core.errors import DmfSimError
    try:
        return _measure(args)
    except DmfSimError as exc:          # a bad model, engine or range: one line, exit 2
        p.error(str(exc))


def _measure(args) -> int:
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_model
    from dmf_sim.solvers.hbm import CondensedHBM, SweepOptions, sweep
    from dmf_sim.solvers.hbm.warm import warm_up
    from dmf_sim.solvers.newmark import SimulationOptions, simulate

    lo, hi, step = args.speeds
    model = read_model('truck_dmf', alpha=args.alpha, theta=args.theta)
    engine = read_engine(args.engine, load_set=args.load_set)
    engine.warm_up()  # engine gas-pressure grid: computed once, not timed
    loads = DrivelineExcitation(model, engine)
    grid = np.arange(lo, hi + 0.5 * step, step)

    # warm-up, not timed: every compiled kernel of a sweep point loaded (or compiled) as a
    # design-study worker does when it starts, the Newmark kernel, first-call overheads
    warm_up()
    CondensedHBM(loads, args.load).solve(lo)
    simulate(loads, lo, args.load, options=SimulationOptions(dt=args.dt, max_cycles=2))

    # the sweeps and the Newmark runs interleaved: after each repetition's two sweeps, the next
    # share of the Newmark speeds, so both sample the same spells of a shared machine
    subset = grid[::max(args.newmark_every, 1)]
    repeat = args.repeat
    shares = np.array_split(np.arange(len(subset)), repeat)
    times = {'fast': [], 'full': []}
    nm_results, nm_times = [None] * len(subset), [0.0] * len(subset)
    for r in range(repeat):
        for mode in ('fast', 'full'):
            opts = (SweepOptions(step_rpm=step, search=None) if mode == 'fast'
                    else SweepOptions(step_rpm=step))
            t0 = time.perf_counter()
            res = sweep(loads, args.load, (lo, hi), options=opts)
            times[mode].append(time.perf_counter() - t0)
            if mode == 'fast':
                res_fast = res
        for i in shares[r].tolist():
            t1 = time.perf_counter()
            nm_results[i] = simulate(loads, float(subset[i]), args.load,
                                     options=SimulationOptions(dt=args.dt))
            nm_times[i] = time.perf_counter() - t1
    sweep_s = float(np.median(times['full']))
    fast_s = float(np.median(times['fast']))
    n_grid_hbm = sum(1 for b in res.branches for q in b.points
                     if abs(q.speed_rpm / step - round(q.speed_rpm / step)) < 1e-9)
    print(f'HBM sweep {lo:g}-{hi:g} rpm, grid {step:g} rpm, alpha {args.alpha:g}, '
          f'theta {model.spring.theta:g} rad, Load {args.load_set}, load {args.load:g}:')
    print(f'  --fast (continuation, stability, branch switching): '
          f'min {min(times["fast"]):.3f} s, median '
          f'{fast_s:.3f} s; {res_fast.n_points} points on {len(res_fast.branches)} branch(es)')
    print(f'  full search (default): min {min(times["full"]):.3f} s, median {sweep_s:.3f} s; '
          f'{res.n_points} points on {len(res.branches)} branch(es) ({n_grid_hbm} on the grid), '
          f'{len(res.non_periodic)} non-periodic band(s), uncovered {res.uncovered}')

    rows, rel = [], []
    for s, nm, nm_s in zip(subset, nm_results, nm_times):
        c = nm.windup_orders
        sols = res.solutions_at(float(s))
        hb = min(sols, key=lambda q: abs(q.order_3 - abs(c[6])) + abs(q.order_1_5 - abs(c[3])))
        d6 = abs(abs(c[6]) - hb.order_3) / hb.order_3
        d0 = abs(c[0].real - hb.summary.mean) / abs(hb.summary.mean)
        sig3 = hb.order_1_5 > 0.2 * hb.order_3
        d3 = abs(abs(c[3]) - hb.order_1_5) / hb.order_1_5 if sig3 else float('nan')
        worst = max(d6, d0, d3 if sig3 else 0.0)
        rel.append(worst)
        rows.append((s, nm_s, nm.cycles, nm.steady, hb.order_3, abs(c[6]), hb.order_1_5,
                     abs(c[3]), d6, d3, d0, len(sols)))
    per_point = float(np.mean(nm_times))
    nm_total = per_point * len(grid)
    speedup = nm_total / sweep_s
    print(f'\nNewmark (dt {args.dt:g} s) timed on {len(subset)} of the {len(grid)} grid speeds '
          f'(every {args.newmark_every}th); mean {per_point:.3f} s per point, extrapolated to the '
          f'grid: {nm_total:.2f} s')
    print(f'{"rpm":>6} {"NM s":>6} {"cyc":>4} {"steady":>6} {"HBM |c6|":>9} {"NM |c6|":>9} '
          f'{"HBM |c3|":>9} {"NM |c3|":>9} {"d|c6|":>8} {"d|c3|":>8} {"d mean":>8} {"sols":>4}')
    for r in rows:
        d3 = f'{r[9]:8.1e}' if np.isfinite(r[9]) else f'{"-":>8}'
        print(f'{r[0]:6.0f} {r[1]:6.3f} {r[2]:4d} {str(r[3]):>6} {r[4]:9.5f} {r[5]:9.5f} '
              f'{r[6]:9.5f} {r[7]:9.5f} {r[8]:8.1e} {d3} {r[10]:8.1e} {r[11]:4d}')
    print(f'\nspeed-up HBM sweep vs Newmark (extrapolated): full search {speedup:.0f}x, --fast '
          f'{nm_total / fast_s:.0f}x; max relative difference {max(rel):.2e} '
          f'(|c6| always, |c3| where > 20 % of |c6|, mean)')
    out = {'sweep_seconds': round(sweep_s, 4), 'sweep_seconds_min': round(min(times['full']), 4),
           'sweep_seconds_fast': round(fast_s, 4),
           'sweep_seconds_fast_min': round(min(times['fast']), 4),
           'speedup_vs_newmark': round(speedup, 1),
           'speedup_vs_newmark_fast': round(nm_total / fast_s, 1),
           'max_rel_diff': float(max(rel)),
           'hbm_points': res.n_points, 'hbm_branches': len(res.branches),
           'grid_points': int(len(grid)),
           'newmark_points_timed': int(len(subset)),
           'newmark_seconds_per_point': round(per_point, 4),
           'newmark_seconds_extrapolated': round(nm_total, 3), 'newmark_dt': args.dt,
           'alpha': args.alpha, 'theta_rad': model.spring.theta, 'load_set': args.load_set,
           'load': args.load,
           'speeds_rpm': [lo, hi, step], 'engine': args.engine, 'repeat': int(args.repeat),
           'non_periodic_bands': len(res.non_periodic), 'quick': bool(args.quick)}
    print(json.dumps(out))
    return 0


if __name__ == '__main__':
    sys.exit(main())
