"""Benchmark: the DMF spring optimizer against Latin-hypercube sampling of the same budget.

    python benchmarks/bench_optimize.py [--study config/optimize_example.yaml] [--budget 200]
                                         [--seeds 1 2 3 4 5] [--verify 3] [--rate-budget 16]
                                         [--quick]

On the example study (isolation, the worst 3rd-order torque into the gearbox over the map;
the transient, the peak DMF torque in a tip-in and a tip-out into the engine brake; durability,
the arc-spring friction's heat over a window of the packaged road cycle -- every objective of
the study enters the fronts and hypervolumes):

1. ``hypervolume_ratio``: for every seed, the optimizer (the study's method) and a Latin
   hypercube of the same budget (seeded alike) on a LocalCluster of 2 workers; the hypervolume
   of each run's feasible designs against ONE reference point fixed before the runs, the paper
   design's objective values x ``REFERENCE_FACTOR`` (``reference_point`` in the JSON); the
   ratio optimizer / sampling: its median over the seeds and ``hypervolume_ratio_min`` (the
   worst seed). ``hypervolume_ratio_fronts``: the same against the two fronts' own nadir plus
   10 % of their range (``report.front_reference_point``).
2. ``front_size``: distinct designs on the optimizer's final front (first seed; per seed in
   ``front_size_per_seed``); ``best_vs_paper``: the compromise design against the paper's.
3. ``verified_max_rel_diff``: the first seed's Pareto designs (up to ``--verify``, spread along
   the front): the harmonic-balance objectives against Newmark shots at their worst speeds, the
   time-domain objectives (load steps, road cycle) run again with half the Newmark step; the
   largest relative difference of both kinds (each kind's in ``verified_max_rel_diff_hbm`` /
   ``_transient``).
4. ``designs_per_s_1`` / ``designs_per_s_2``: optimizer throughput on 1 and 2 worker processes
   (``--rate-budget`` designs each, cluster start excluded).

``--quick``: a small problem (one condition, 9 speeds, 8 half orders, one load step, 4 s of the
road cycle, the three objectives), small
budgets: the smoke test of the test suite. The machine is shared: the load average before and
after is printed. Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import copy
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

REFERENCE_FACTOR = 1.1
"""The hypervolume's reference point: the paper design's objective values times this."""
QUICK_STUDY = {
    'name': 'bench_optimize_quick', 'driveline': 'truck_dmf_friction', 'engine': 'engine_d13',
    'variables': {'theta': {'min': 0.16, 'max': 0.22}, 'alpha': {'min': 0.5, 'max': 5.0},
                  'stages[1].angle_step_rad': {'min': 0.005, 'max': 0.06},
                  'stages[1].stiffness_factor': {'min': 0.5, 'max': 8.0},
                  'friction.torque_nm': {'min': 0.0, 'max': 150.0}},
    'conditions': {'load_sets': ['A'], 'loads': [1.0],
                   'speeds_rpm': {'from': 1400, 'to': 1800, 'step': 50},
                   'load_steps': [{'speed_rpm': 1400, 'from': 0, 'to': 1, 'rise_s': 0.1,
                                   'hold_s': 0.3, 'settle_s': 0.5}],
                   'road_cycle': {'profile': 'truck_road_cycle', 'from_s': 10, 'to_s': 14,
                                  'settle_s': 0.5}},
    'objectives': ['worst_torque_3', 'transient_dmf_torque', 'cycle_friction_heat'],
    'solver': {'harmonics': 8, 'search': False},
    'optimizer': {'method': 'nsga2', 'budget': 8, 'batch_size': 4, 'seed': 1,
                  'constraints': {'max_travel_rad': 0.29, 'capacity_factor': 1.5}},
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--study', default='config/optimize_example.yaml')
    ap.add_argument('--budget', type=int, default=200)
    ap.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3, 4, 5])
    ap.add_argument('--verify', type=int, default=3)
    ap.add_argument('--rate-budget', type=int, default=16)
    ap.add_argument('--quick', action='store_true')
    args = ap.parse_args(argv)
    from dmf_sim.cluster import close_local, start_local
    from dmf_sim.optimize import read_problem, run_optimization
    from dmf_sim.optimize.report import (
        common_hypervolumes,
        compare_with_reference,
        front_hypervolumes,
        ideal_point_search,
        reference_design,
        spread,
    )
    from dmf_sim.optimize.runner import baseline_problem
    from dmf_sim.optimize.verify import VerifySettings, verify_design, verify_transient

    settings = VerifySettings()
    if args.quick:
        source, budget, seeds, n_verify, rate_budget = QUICK_STUDY, 8, [1, 2], 1, 4
        settings = VerifySettings(dt=1e-4, offsets=(0.0, 1.0), window_rpm=10.0,
                                  max_cycles=150, steady_tol=1e-3)
    else:
        source, budget, seeds = args.study, args.budget, args.seeds
        n_verify, rate_budget = args.verify, args.rate_budget
    base = read_problem(copy.deepcopy(source) if isinstance(source, dict) else source,
                        budget=budget)
    load_before = os.getloadavg()
    t_start = time.strftime('%Y-%m-%d %H:%M:%S %Z')
    ratios, fronts_r, wide, bounds, ideal, sizes, first = [], [], [], [], [], [], None
    ref = reference_design(base)
    objectives = list(base.objectives)
    if ref['status'] != 'ok':
        raise SystemExit(f'the paper design failed on this study: {ref.get("error")}')
    ref_point = tuple(REFERENCE_FACTOR * ref[o] for o in objectives)
    print(f'reference point (paper design x {REFERENCE_FACTOR:g}), fixed before the runs: '
          + ', '.join(f'{o} {v:.6g}' for o, v in zip(objectives, ref_point)),
          file=sys.stderr, flush=True)
    cluster, client = start_local(2)
    try:
        for seed in seeds:
            prob = base.with_method(base.method, seed=seed)
            t0 = time.perf_counter()
            res = run_optimization(prob, client)
            lhs = run_optimization(baseline_problem(prob), client)
            fixed = common_hypervolumes(res, lhs, ref_point)
            hv = common_hypervolumes(res, lhs)
            front = front_hypervolumes(res, lhs, hv)
            ratios.append(fixed['ratio'])
            fronts_r.append(front['ratio'])
            wide.append(hv['ratio'])
            bounds.append(front['wide_bound'])
            ideal.append({'seed': seed, **ideal_point_search(res, lhs)})
            sizes.append(len({tuple(r[v] for v in res.problem.study.variable_names)
                              for r in res.rows('design') if r['pareto']}))
            print(f'seed {seed}: hypervolume (paper x {REFERENCE_FACTOR:g}) optimizer '
                  f'{fixed["optimizer_final"]:.4g}, LHS {fixed["lhs_final"]:.4g}, ratio '
                  f'{fixed["ratio"]:.3f}; fronts\' reference point: ratio {front["ratio"]:.3f};'
                  f' front {sizes[-1]} designs ({time.perf_counter() - t0:.0f} s)',
                  file=sys.stderr, flush=True)
            first = first or (res, lhs)
    finally:
        close_local(cluster, client)
    res, lhs = first
    bvp = compare_with_reference(res, ref)
    bvp_lhs = compare_with_reference(lhs, ref)
    front = [r for r in res.rows('design') if r['pareto']]
    best = [res.design(res.best_id)] if res.best_id is not None else []
    chosen = (best + [r for r in spread(front, res.problem.objectives[0], n_verify)
                      if r not in best])[:n_verify]
    checks = [c for r in chosen for c in verify_design(res.problem, r, settings)]
    transient = [c for r in chosen for c in verify_transient(res.problem, r, settings)]
    for c in transient:
        print(f'design {c.design_id} {c.objective} ({c.condition}): dt {c.dt_s:g} s '
              f'{c.study_value:.5g}, dt {c.refined_dt_s:g} s {c.refined:.5g} '
              f'({100 * c.rel_diff:.2f} %)', file=sys.stderr, flush=True)
    for c in checks:
        print(f'design {c.design_id} {c.objective} at {c.speed_rpm:g} rpm ({c.condition}): HBM '
              f'{c.hbm:.5g}, time domain {c.time_domain:.5g} ({100 * c.rel_diff:.2f} %), run-ups '
              f'{c.run_up:.5g}', file=sys.stderr, flush=True)
    rates = {}
    for workers in (1, 2):
        cluster, client = start_local(workers)
        try:
            with tempfile.TemporaryDirectory() as tmp:
                r = run_optimization(base, client, out=Path(tmp), budget=rate_budget)
            rates[workers] = r.n_computed / r.seconds
        finally:
            close_local(cluster, client)
    # a Latin hypercube without a design better than the reference point has hypervolume 0:
    # the ratio is then infinite (the optimizer found some), NaN only when neither did
    finite = [x for x in ratios if x == x]
    hbm_diff = max((c.rel_diff for c in checks), default=None)
    tr_diff = max((c.rel_diff for c in transient), default=None)
    both = [d for d in (hbm_diff, tr_diff) if d is not None]
    out = {
        'quick': bool(args.quick), 'study': base.study.name, 'method': base.method,
        'objectives': objectives, 'budget': budget, 'seeds': seeds,
        'batch_size': base.batch_size,
        'started': t_start,
        'reference_point': list(ref_point), 'reference_factor': REFERENCE_FACTOR,
        'paper': {**{o: ref[o] for o in objectives}, 'feasible': bool(ref['feasible'])},
        'hypervolume_ratio': statistics.median(finite) if finite else None,
        'hypervolume_ratio_min': min(finite) if finite else None,
        'hypervolume_ratio_per_seed': ratios,
        'hypervolume_ratio_fronts_per_seed': fronts_r,
        'hypervolume_ratio_wide_per_seed': wide,
        'hypervolume_ratio_wide_bound_per_seed': bounds,
        'front_size': sizes[0], 'front_size_per_seed': sizes,
        'ideal_point_search': ideal,
        'best_vs_paper': bvp, 'lhs_vs_paper': {k: bvp_lhs[k] for k in ('n_dominating',
                                                                       'dominates_paper')},
        'n_feasible': sum(bool(r['feasible']) for r in res.rows('design')),
        'verified': [c.as_dict() for c in checks],
        'verified_transient': [c.as_dict() for c in transient],
        'verified_max_rel_diff': max(both) if both else None,
        'verified_max_rel_diff_hbm': hbm_diff, 'verified_max_rel_diff_transient': tr_diff,
        'designs_per_s_1': rates[1], 'designs_per_s_2': rates[2],
        'scaling_2': rates[2] / rates[1],
        'load_before': list(load_before), 'load_after': list(os.getloadavg()),
    }
    print(json.dumps(out, default=float))
    return 0


if __name__ == '__main__':
    sys.exit(main())
