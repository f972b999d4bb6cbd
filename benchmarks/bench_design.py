"""Benchmark: design-study throughput on Dask.

    python benchmarks/bench_design.py [--designs 300] [--repeats 3] [--rss-designs 2000]
                                       [--engine engine_d13] [--search] [--quick]

The paper case: every design is the paper's DMF (alpha 3, theta 0.24 rad) with its damping
varied within +-1 % (so each design costs what the paper case costs), evaluated at Load A, full
load, 600-2000 rpm at 10 rpm (141 speeds), continuation + Floquet stability + branch switching
(`--search`: and the full steady-state search; its serial cost is printed either way),
plus the study's metrics (3rd-order torque at the input shaft, 1.5th-order and non-periodic
speeds, coexisting states).

1. Serial, no Dask: seconds per design, split into the sweep (dmf_sim.solvers.hbm.sweep) and what
the
   study adds (grid states, torque at the element, metrics).
2. ``designs_per_s_1`` / ``designs_per_s_2``: the study on a LocalCluster of 1 and 2 worker
   processes (127.0.0.1), cluster start excluded; min and median of ``--repeats`` runs;
   ``scaling_2`` = median 2 workers / median 1 worker.
3. Dask task overhead: tasks that evaluate no design (pure round trip) and the paper-case study
   at batch sizes 1, 2, 4, 8 on 2 workers; the default batch size is the smallest whose task
   overhead is below 2 % of the designs it carries.
4. Memory: peak RSS of each worker process over a ``--rss-designs`` study (sampled every 0.5 s),
   and its growth from the first 10 % of the study to the end.
5. A mixed study (alpha 2-4, theta 0.2-0.26 rad, Latin hypercube): throughput on 2 workers, for
   comparison (designs that cross the knee cost more: branch switching, 1.5th-order branches).

The machine is shared: the load average before and after is printed. Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import threading
import time

import numpy as np

OVERHEAD_BUDGET = 0.02          # task overhead allowed per batch, relative to its designs' time
BATCH_SIZES = (1, 2, 4, 8)


# what the benchmark's studies run on: set from the command line (--engine, --search)
CASE = {'engine': 'engine_d13', 'search': False}


def paper_study(n: int, speeds=(600.0, 2000.0, 10.0), seed: int = 1) -> dict:
    lo, hi, step = speeds
    return {'name': 'bench_paper_case', 'driveline': 'truck_dmf', 'engine': CASE['engine'],
            'sampling': {'method': 'lhs', 'n': n, 'seed': seed},
            'variables': {'damping': {'min': 49.0, 'max': 50.0}},
            'fixed': {'alpha': 3.0, 'theta': 0.24},
            'conditions': {'load_sets': ['A'], 'loads': [1.0],
                           'speeds_rpm': {'from': lo, 'to': hi, 'step': step}},
            'objectives': ['worst_order_1_5', 'worst_torque_3'],
            'solver': {'search': CASE['search']}}


def mixed_study(n: int, speeds=(600.0, 2000.0, 10.0)) -> dict:
    d = paper_study(n, speeds)
    d.update(name='bench_mixed', fixed={},
             variables={'alpha': {'min': 2.0, 'max': 4.0}, 'theta': {'min': 0.2, 'max': 0.26}})
    return d


def serial(study, n: int) -> dict:
    """Seconds per design without Dask: the whole evaluation and the sweep alone."""
    from dmf_sim.design.evaluate import StudyContext, evaluate_design, sweep_condition
    from dmf_sim.design.parameters import design_driveline
    ctx = StudyContext.from_study(study)
    designs = study.designs()[:n]
    cond = study.conditions[0]
    evaluate_design(ctx, -1, designs[0])                    # first-call costs, not timed
    t_eval, t_sweep = [], []
    for row in designs:
        t0 = time.perf_counter()
        evaluate_design(ctx, 0, row)
        t1 = time.perf_counter()
        line = design_driveline(study.base, ctx.design_values(row))
        sweep_condition(line, study.engines[cond.load_set], cond.load, ctx.settings)
        t2 = time.perf_counter()
        t_eval.append(t1 - t0)
        t_sweep.append(t2 - t1)
    med_e, med_s = statistics.median(t_eval), statistics.median(t_sweep)
    return {'serial_s_per_design_median': med_e, 'serial_s_per_design_min': min(t_eval),
            'sweep_s_per_design_median': med_s, 'sweep_s_per_design_min': min(t_sweep),
            'study_overhead_s_per_design': med_e - med_s,
            'serial_designs_per_s': 1.0 / med_e}


def throughput(client, study, repeats: int, batch_size=None, failures_ok=False) -> list[float]:
    """Designs per second of ``repeats`` runs; also keeps the workers' CPU use of the last run
    (``throughput.cpu_use``: worker CPU time / (wall time x workers), below 1 when the workers
    wait or the machine's cores are taken by other jobs)."""
    import psutil

    from dmf_sim.design import run_study
    procs = [psutil.Process(pid) for pid in client.run(os.getpid).values()]
    rates = []
    for _ in range(repeats):
        cpu0 = sum(p.cpu_times().user + p.cpu_times().system for p in procs)
        t0 = time.perf_counter()
        res = run_study(study, client, batch_size=batch_size)
        dt = time.perf_counter() - t0
        cpu = sum(p.cpu_times().user + p.cpu_times().system for p in procs) - cpu0
        assert failures_ok or not res.failed(), res.failed()[:3]
        rates.append(res.n_designs / dt)
        throughput.failed = len(res.failed())
        throughput.cpu_use = cpu / (dt * len(procs))
        throughput.cpu_s_per_design = cpu / res.n_designs
    return rates


def study_fixed_cost(client, speeds, design_s: float) -> float:
    """Seconds a study costs on an already running cluster beyond computing its designs: one
    design per worker (they run in parallel), minus one design's time."""
    from dmf_sim.design import run_study
    from dmf_sim.design.study import read_study
    n = len(client.scheduler_info()['workers'])
    times = []
    for seed in range(3):
        study = read_study(paper_study(n, speeds, seed=20 + seed))
        t0 = time.perf_counter()
        run_study(study, client)
        times.append(time.perf_counter() - t0 - design_s)
    return statistics.median(times)


def task_overhead(client, n_tasks: int) -> float:
    """Seconds of Dask overhead per task: round trips of tasks that evaluate no design."""
    from distributed import wait

    from dmf_sim.design.evaluate import StudyContext, evaluate_batch
    from dmf_sim.design.runner import StudyPlugin
    from dmf_sim.design.study import read_study
    study = read_study(paper_study(2))
    client.register_plugin(StudyPlugin('bench-empty', StudyContext.from_study(study)),
                           name='bench-empty')
    n_workers = len(client.scheduler_info()['workers'])
    wait([client.submit(evaluate_batch, 'bench-empty', [], pure=False) for _ in range(20)])
    t0 = time.perf_counter()
    wait([client.submit(evaluate_batch, 'bench-empty', [], pure=False) for _ in range(n_tasks)])
    dt = time.perf_counter() - t0
    client.unregister_worker_plugin('bench-empty')
    return dt * n_workers / n_tasks           # per task, per worker (tasks run in parallel)


class RssSampler:
    """Samples the RSS of the worker processes every ``period`` s in a thread."""

    def __init__(self, pids: list[int], period: float = 0.5):
        import psutil
        self.procs = {pid: psutil.Process(pid) for pid in pids}
        self.samples: dict[int, list[tuple[float, float]]] = {pid: [] for pid in pids}
        self.period = period
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        t0 = time.perf_counter()
        while not self._stop.is_set():
            for pid, p in self.procs.items():
                try:
                    rss_mb = p.memory_info().rss / 2**20
                    self.samples[pid].append((time.perf_counter() - t0, rss_mb))
                except Exception:   # noqa: BLE001 - a worker that went away has no sample
                    pass
            self._stop.wait(self.period)

    def __enter__(self):
        self._t.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()


def memory(client, study) -> dict:
    from dmf_sim.design import run_study
    pids = list(client.run(os.getpid).values())
    with RssSampler(pids) as s:
        t0 = time.perf_counter()
        res = run_study(study, client)
        dt = time.perf_counter() - t0
    peak, growth = {}, {}
    for pid, series in s.samples.items():
        rss = np.array([v for _, v in series])
        k = max(1, len(rss) // 10)
        peak[pid] = float(rss.max())
        growth[pid] = float(rss[-k:].mean() - rss[:k].mean())
    return {'rss_designs': res.n_designs, 'rss_failed': len(res.failed()),
            'rss_study_designs_per_s': res.n_designs / dt,
            'peak_rss_mb_per_worker': sorted(peak.values()),
            'rss_growth_mb_first_to_last_10pct': sorted(growth.values())}


def choose_batch(overhead_s: float, design_s: float) -> int:
    for b in BATCH_SIZES:
        if overhead_s <= OVERHEAD_BUDGET * b * design_s:
            return b
    return BATCH_SIZES[-1]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    p.add_argument('--designs', type=int, default=300, help='designs per throughput run')
    p.add_argument('--repeats', type=int, default=3)
    p.add_argument('--rss-designs', type=int, default=2000)
    p.add_argument('--quick', action='store_true', help='small run for the test suite')
    p.add_argument('--engine', default='engine_d13',
                   help='engine of the paper case (default engine_d13, 2800 Nm: the paper\'s '
                        'regime, crossing the knee; engine_d13_2500nm stays below it)')
    p.add_argument('--search', action='store_true',
                   help='the full steady-state search in every sweep (default: continuation, '
                        'stability and branch switching, the issue\'s throughput definition)')
    args = p.parse_args(argv)
    CASE.update(engine=args.engine, search=args.search)
    speeds = (600.0, 2000.0, 10.0)
    if args.quick:
        args.designs, args.repeats, args.rss_designs = 8, 1, 16
        speeds = (900.0, 1100.0, 10.0)
    os.environ.setdefault('OMP_NUM_THREADS', '1')       # the driver's own numpy, as the workers
    from distributed import Client

    from dmf_sim.cluster import local_cluster
    from dmf_sim.design.study import read_study

    load0 = os.getloadavg()
    out: dict = {'quick': args.quick, 'speeds_rpm': list(speeds), 'designs': args.designs,
                 'repeats': args.repeats, 'cores': os.cpu_count(), 'load_avg_before': load0,
                 'engine': args.engine, 'search': args.search}
    study = read_study(paper_study(args.designs, speeds))
    out.update(serial(study, min(args.designs, 20)))
    if not args.search:               # what the solution finder costs on top, per design
        CASE['search'] = True
        full = serial(read_study(paper_study(args.designs, speeds)), min(args.designs, 5))
        CASE['search'] = False
        out['serial_s_per_design_full_search_median'] = full['serial_s_per_design_median']
        print(f'serial with the full steady-state search: '
              f'{full["serial_s_per_design_median"] * 1e3:.1f} ms per design (median)')
    print(f'serial (no Dask): {out["serial_s_per_design_median"] * 1e3:.1f} ms per design '
          f'(median; sweep {out["sweep_s_per_design_median"] * 1e3:.1f} ms, study metrics '
          f'{out["study_overhead_s_per_design"] * 1e3:.1f} ms) = '
          f'{out["serial_designs_per_s"]:.1f} designs/s')
    rates = {}
    for n_workers in (1, 2):
        t_start = time.perf_counter()
        with local_cluster(n_workers) as cluster, Client(cluster) as client:
            client.wait_for_workers(n_workers)
            out[f'local_cluster_start_s_{n_workers}'] = time.perf_counter() - t_start
            throughput(client, read_study(paper_study(4, speeds, seed=9)), 1)    # warm-up
            r = throughput(client, study, args.repeats)
            rates[n_workers] = r
            out[f'designs_per_s_{n_workers}'] = statistics.median(r)
            out[f'designs_per_s_{n_workers}_min'] = min(r)
            out[f'designs_per_s_{n_workers}_max'] = max(r)
            out[f'worker_cpu_use_{n_workers}'] = throughput.cpu_use
            out[f'worker_cpu_s_per_design_{n_workers}'] = throughput.cpu_s_per_design
            print(f'{n_workers} worker(s): {statistics.median(r):.1f} designs/s (median of '
                  f'{len(r)}; min {min(r):.1f}, max {max(r):.1f}), {args.designs} designs; '
                  f'workers busy {throughput.cpu_use:.0%} of the wall time, '
                  f'{throughput.cpu_s_per_design * 1e3:.0f} ms CPU per design')
            if n_workers == 2:
                oh = task_overhead(client, 100 if args.quick else 400)
                out['task_overhead_ms'] = oh * 1e3
                by_batch = {}
                for b in BATCH_SIZES:
                    by_batch[b] = statistics.median(throughput(client, study, 1, batch_size=b))
                out['designs_per_s_2_by_batch'] = by_batch
                out['chosen_batch_size'] = choose_batch(oh, out['serial_s_per_design_median'])
                print(f'Dask overhead per task: {oh * 1e3:.2f} ms; 2 workers by batch size: '
                      + ', '.join(f'{b}: {v:.1f}/s' for b, v in by_batch.items())
                      + f'; batch size for < {OVERHEAD_BUDGET:.0%} overhead: '
                      f'{out["chosen_batch_size"]}')
                out.update(memory(client, read_study(paper_study(args.rss_designs, speeds,
                                                                 seed=5))))
                print(f'memory over {out["rss_designs"]} designs: peak RSS per worker '
                      f'{out["peak_rss_mb_per_worker"]} MB, growth first -> last 10 % '
                      f'{[round(g, 1) for g in out["rss_growth_mb_first_to_last_10pct"]]} MB')
                out['study_fixed_s'] = study_fixed_cost(client, speeds,
                                                        out['serial_s_per_design_median'])
                print(f'local cluster start: {out["local_cluster_start_s_2"]:.1f} s; a study '
                      f'on a running cluster costs {out["study_fixed_s"]:.2f} s beyond its '
                      'designs')
                mixed = read_study(mixed_study(args.designs, speeds))
                out['mixed_designs_per_s_2'] = statistics.median(
                    throughput(client, mixed, 1, failures_ok=True))
                out['mixed_failed'] = throughput.failed
                print(f'mixed study (alpha 2-4, theta 0.2-0.26): '
                      f'{out["mixed_designs_per_s_2"]:.1f} designs/s on 2 workers, '
                      f'{out["mixed_failed"]} of {args.designs} designs failed in the sweep')
    out['scaling_2'] = out['designs_per_s_2'] / out['designs_per_s_1']
    out['per_worker_target_met'] = out['designs_per_s_1'] >= 15.0
    out['scaling_target_met'] = out['scaling_2'] >= 1.7
    out['load_avg_after'] = os.getloadavg()
    print(f'scaling 2 workers / 1: {out["scaling_2"]:.2f} (target >= 1.7); load average '
          f'before {load0[0]:.1f}, after {out["load_avg_after"][0]:.1f} on {os.cpu_count()} cores')
    print(json.dumps(out))
    return 0


if __name__ == '__main__':
    sys.exit(main())
