"""Benchmark: the DMF spring optimizer against Latin-hypercube sampling.

    python benchmarks/bench_optimize.py [--study config/optimize_example.yaml] [--budget 200]
                                         [--seeds 1 2 3] [--verify 3] [--rate-budget 16]
                                         [--quick]

1. ``hypervolume_ratio``: for every seed, the optimizer (the study's method) and a Latin
   hypercube of the same budget (seeded alike) on a LocalCluster of 2 workers; hypervolume of
   each run's feasible designs against one reference point per seed, the fronts' own: the nadir
   of both final fronts plus 10 % of their range (``report.front_reference_point``, the usual
   choice for comparing fronts); ratio optimizer / sampling, its median and spread.
   ``hypervolume_ratio_wide``: the same against 1.1 x the largest feasible value of each
   objective over both runs (the report's convergence plot), and ``hypervolume_ratio_wide_bound``
   the largest ratio any front could reach against that point (a design at the ideal point of
   both runs): where the bound is near 1, that reference point cannot separate the fronts.
   ``hypervolume_ratio_vs_paper``: the same with the paper's design (alpha 3, theta 0.24) as
   the reference point, so only the area of designs better than the paper's in both objectives
   counts (the default reference point makes the box so large that fronts which differ near
   the best designs have nearly the same hypervolume).
   ``ideal_point_search`` per seed: the evaluations each run needs to find a design within 1 %
   of the ideal point (the best feasible value of each objective over both runs), how many such
   designs it finds and the size of its final front -- the figures that still separate the
   methods when the objectives do not conflict and both fronts shrink to that point.
2. ``best_vs_paper``: the first seed's compromise design relative to the paper's design (alpha 3,
   theta 0.24) under the same constraints, and whether a feasible design dominates it.
3. ``verified_max_rel_diff``: the first seed's Pareto designs (up to ``--verify``, spread along
   the front) in the time domain (Newmark shots and run-ups at their worst speeds) vs the
   harmonic-balance worst values.
4. ``designs_per_s_1`` / ``designs_per_s_2``: optimizer throughput on 1 and 2 worker processes
   (``--rate-budget`` designs each, cluster start excluded).

``--quick``: a small problem (one condition, 9 speeds, 8 half orders), small budgets: the smoke
test of the test suite. The machine is shared: the load average before and after is printed.
Last line: one JSON object.
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

QUICK_STUDY = {
    'name': 'bench_optimize_quick', 'driveline': 'truck_dmf', 'engine': 'engine_d13',
    'variables': {'theta': {'min': 0.16, 'max': 0.22}, 'alpha': {'min': 0.5, 'max': 5.0},
                  'stages[1].angle_step_rad': {'min': 0.005, 'max': 0.06},
                  'stages[1].stiffness_factor': {'min': 0.5, 'max': 8.0}},
    'conditions': {'load_sets': ['A'], 'loads': [1.0],
                   'speeds_rpm': {'from': 1400, 'to': 1800, 'step': 50}},
    'objectives': ['worst_order_3', 'worst_torque_3'],
    'solver': {'harmonics': 8, 'search': False},
    'optimizer': {'method': 'nsga2', 'budget': 8, 'batch_size': 4, 'seed': 1,
                  'constraints': {'max_travel_rad': 0.29, 'capacity_factor': 1.5}},
}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--study', default='config/optimize_example.yaml')
    ap.add_argument('--budget', type=int, default=200)
    ap.add_argument('--seeds', type=int, nargs='+', default=[1, 2, 3])
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
    from dmf_sim.optimize.verify import VerifySettings, verify_design

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
    ratios, wide, bounds, paper_ratios, ideal, first = [], [], [], [], [], None
    ref = reference_design(base)
    o1, o2 = base.objectives[:2]
    paper_point = ((ref[o1], ref[o2]) if ref['status'] == 'ok' and ref['feasible'] else None)
    cluster, client = start_local(2)
    try:
        for seed in seeds:
            prob = base.with_method(base.method, seed=seed)
            t0 = time.perf_counter()
            res = run_optimization(prob, client)
            lhs = run_optimization(baseline_problem(prob), client)
            hv = common_hypervolumes(res, lhs)
            front = front_hypervolumes(res, lhs, hv)
            ratios.append(front['ratio'])
            wide.append(hv['ratio'])
            bounds.append(front['wide_bound'])
            if paper_point is not None:
                paper_ratios.append(common_hypervolumes(res, lhs, paper_point)['ratio'])
            ideal.append({'seed': seed, **ideal_point_search(res, lhs)})
            print(f'seed {seed}: hypervolume (fronts\' reference point) optimizer '
                  f'{front["optimizer_final"]:.4g}, LHS {front["lhs_final"]:.4g}, ratio '
                  f'{front["ratio"]:.3f}; wide reference point: ratio {hv["ratio"]:.3f} '
                  f'(at most {front["wide_bound"]:.3f}) ({time.perf_counter() - t0:.0f} s)',
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
    finite = [x for x in ratios if x == x and x != float('inf')]
    out = {
        'quick': bool(args.quick), 'study': base.study.name, 'method': base.method,
        'budget': budget, 'seeds': seeds, 'started': t_start,
        'hypervolume_ratio': statistics.median(finite) if finite else None,
        'hypervolume_ratio_per_seed': ratios,
        'hypervolume_ratio_spread': [min(finite), max(finite)] if finite else None,
        'hypervolume_ratio_wide': statistics.median(wide) if wide else None,
        'hypervolume_ratio_wide_per_seed': wide,
        'hypervolume_ratio_wide_bound_per_seed': bounds,
        'hypervolume_ratio_vs_paper': (statistics.median(paper_ratios) if paper_ratios
                                       else None),
        'hypervolume_ratio_vs_paper_per_seed': paper_ratios,
        'ideal_point_search': ideal,
        'best_vs_paper': bvp, 'lhs_vs_paper': {k: bvp_lhs[k] for k in ('n_dominating',
                                                                       'dominates_paper')},
        'n_feasible': sum(bool(r['feasible']) for r in res.rows('design')),
        'verified': [c.as_dict() for c in checks],
        'verified_max_rel_diff': max((c.rel_diff for c in checks), default=None),
        'designs_per_s_1': rates[1], 'designs_per_s_2': rates[2],
        'scaling_2': rates[2] / rates[1],
        'load_before': list(load_before), 'load_after': list(os.getloadavg()),
    }
    print(json.dumps(out, default=float))
    return 0


if __name__ == '__main__':
    sys.exit(main())
