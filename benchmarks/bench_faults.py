"""Benchmark: the sensors carry what a controller uses (misfire detection, DMF wind-up).

Bags written by ``dmf-sim run`` (Python API) with the shipped ``truck_dmf`` and its default
sensors (60-2 crank and secondary-flywheel wheels with pitch errors, timer resolution and
jitter), read back through the analysis layer:

* ``misfire_detection_rate``: detected / injected single misfires of the reference detector
  (:mod:`dmf_sim.analysis.misfire_detector`) over a grid of steady speeds (800-2000 rpm) x
  loads (0.3-1), misfires ``MISFIRE_SPACING_S`` apart on every cylinder in turn (target
  >= 0.99);
* ``false_alarm_rate``: false alarms per engine cycle over every run of the grid and the healthy
  runs (run-ups and run-downs at part and full load, fast and slow, tip-in and tip-out load
  steps) (target <= 1e-3; ``engine_cycles`` says how many cycles it rests on);
* ``windup_from_sensors_rel_err``: peak-to-peak of the wind-up from the two tooth wheels against
  the true one, 1200 rpm, full load (target <= 0.03);
* ``campaign_runs_per_s``: ``dmf-sim campaign`` throughput (:mod:`dmf_sim.campaign.runner`,
  scores only) on a local Dask cluster of 1 and 2 workers, ``CAMPAIGN_CASES`` steady runs of
  ``CAMPAIGN_DURATION_S`` (no target; the cluster's start and one warm-up case per worker are
  not counted);
* ``table``: detections, misses and false alarms per (speed, load) and per healthy run.

    python benchmarks/bench_faults.py [--small]

``--small``: a 2 x 2 grid, shorter runs and one healthy run-up. Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path

SPEEDS_RPM = (800, 1100, 1400, 1700, 2000)
LOADS = (0.3, 0.65, 1.0)
SMALL_SPEEDS_RPM = (800, 2000)
SMALL_LOADS = (0.3, 1.0)
SETTLE_S = 0.5                 # from static equilibrium; not scored (the run's settle_s)
MISFIRE_SPACING_S = 0.5        # between single misfires: the DMF swing has decayed
MISFIRES_PER_RUN = 6           # one on each cylinder
SMALL_MISFIRES_PER_RUN = 3
HEALTHY = ('ramp:800:2000:600:1.0:0.5', 'ramp:2000:800:600:0.3:0.5',
           'ramp:800:2000:100:0.3:0.5', 'ramp:2000:800:100:1.0:0.5',
           'step:800:0.3:1:0.1:0.8:0.5', 'step:1200:0.3:1:0.1:0.8:0.5',
           'step:1600:1:0.3:0.1:0.8:0.5', 'step:2000:1:0.3:0.1:0.8:0.5')
SMALL_HEALTHY = ('ramp:800:2000:1200:1.0:0.5',)
WINDUP_POINT = (1200.0, 1.0)
CAMPAIGN_CASES = 8
SMALL_CAMPAIGN_CASES = 2
CAMPAIGN_DURATION_S = 1.0


def campaign_rate(n_cases: int, workers: int) -> float:
    """Runs per second of a campaign of ``n_cases`` on a local cluster of ``workers``."""
    from dmf_sim.campaign.runner import Case, run_campaign
    from dmf_sim.cluster import close_local, start_local

    grid = [Case(800.0 + 1200.0 * i / max(n_cases - 1, 1), 0.3 + 0.7 * (i % 2), 'misfire', 1.0)
            for i in range(n_cases)]
    cluster, client = start_local(workers)
    try:
        # one untimed case per worker first: each worker process imports and loads the
        # compiled kernels once
        run_campaign(grid[:workers], client, duration_s=CAMPAIGN_DURATION_S)
        _, summary = run_campaign(grid, client, duration_s=CAMPAIGN_DURATION_S)
    finally:
        close_local(cluster, client)
    return summary['runs_per_s']


def _steady(speed: float, load: float, duration_s: float):
    from dmf_sim.transient.profiles import make_profile

    prof = make_profile([(0.0, speed, load), (duration_s, speed, load)],
                        name=f'steady_{speed:g}_{load:g}')
    return replace(prof, settle_s=SETTLE_S)


def _schedule(path: Path, n: int) -> Path:
    lines = ['faults:']
    for i in range(n):
        lines.append(f'  - {{kind: misfire, cylinders: [{i % 6 + 1}], '
                     f'at_s: {SETTLE_S + MISFIRE_SPACING_S * (i + 0.5):g}}}')
    path.write_text('\n'.join(lines) + '\n')
    return path


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('--small', action='store_true', help='a small grid (smoke test)')
    args = ap.parse_args(argv)
    from dmf_sim.analysis.misfire_detector import detect_bag
    from dmf_sim.analysis.windup_estimate import windup_from_bag
    from dmf_sim.transient.profiles import read_profile
    from dmf_sim.transient.run import RunOptions, run_profile

    speeds = SMALL_SPEEDS_RPM if args.small else SPEEDS_RPM
    loads = SMALL_LOADS if args.small else LOADS
    n_mis = SMALL_MISFIRES_PER_RUN if args.small else MISFIRES_PER_RUN
    healthy = SMALL_HEALTHY if args.small else HEALTHY
    work = Path(tempfile.mkdtemp(prefix='bench_faults_'))
    table, totals = [], {'misfires': 0, 'detected': 0, 'false_alarms': 0, 'cycles': 0.0}
    t0 = time.perf_counter()
    sim_s = 0.0
    try:
        schedule = _schedule(work / 'faults.yaml', n_mis)
        duration = SETTLE_S + MISFIRE_SPACING_S * (n_mis + 1)
        runs = [(f'{s:g} rpm, load {ld:g}', _steady(s, ld, duration), str(schedule), s, ld)
                for s in speeds for ld in loads]
        runs += [(name, read_profile(name), None, None, None) for name in healthy]
        for k, (name, prof, faults, speed, load) in enumerate(runs):
            bag = work / f'run{k}'
            summary = run_profile(prof, bag, RunOptions(faults=faults))
            sim_s += summary.simulated_s
            _, score = detect_bag(bag)
            row = {'run': name, 'speed_rpm': speed, 'load': load, **score.as_dict()}
            del row['per_cylinder']
            table.append(row)
            for key in totals:
                totals[key] += getattr(score, key)
            print(f'{name:32s} misfires {score.misfires:2d} detected {score.detected:2d} '
                  f'false alarms {score.false_alarms:2d} cycles {score.cycles:7.1f}', flush=True)
            shutil.rmtree(bag)
        wbag = work / 'windup'
        run_profile(_steady(*WINDUP_POINT, 1.5), wbag, RunOptions())
        w = windup_from_bag(wbag)
        print(f'wind-up p2p from sensors {w.p2p_est_rad:.5f} rad, true {w.p2p_true_rad:.5f} '
              f'rad, rel. error {w.rel_err:.4f}')
    finally:
        shutil.rmtree(work, ignore_errors=True)
    n_camp = SMALL_CAMPAIGN_CASES if args.small else CAMPAIGN_CASES
    rates = {str(w): campaign_rate(n_camp, w) for w in (1, 2)}
    print('campaign runs/s: ' + ', '.join(f'{r:.2f} on {w} worker(s)' for w, r in rates.items()))
    wall = time.perf_counter() - t0
    result = {
        'small': args.small,
        'misfire_detection_rate': totals['detected'] / totals['misfires'],
        'false_alarm_rate': totals['false_alarms'] / totals['cycles'],
        'misfires': totals['misfires'], 'detected': totals['detected'],
        'false_alarms': totals['false_alarms'], 'engine_cycles': totals['cycles'],
        'windup_from_sensors_rel_err': w.rel_err,
        'windup_p2p_rad': {'sensors': w.p2p_est_rad, 'true': w.p2p_true_rad},
        'campaign_runs_per_s': rates, 'campaign_cases': n_camp,
        'campaign_run_s': SETTLE_S + CAMPAIGN_DURATION_S,
        'speeds_rpm': list(speeds), 'loads': list(loads), 'healthy_runs': list(healthy),
        'simulated_s': sim_s, 'wall_s': wall, 'table': table,
    }
    print(json.dumps(result))
    return result


if __name__ == '__main__':
    main()
