"""Benchmark: ``dmf-sim identify`` recovers known DMF parameters from noisy recordings.

Three cases, each a bag written by ``dmf-sim run`` with a DMF that is not the shipped one
(primary stiffness, knee, stage factor, damping and the arc-spring friction's constant and
centrifugal parts all changed), along a profile that drives the wind-up across the knee (a
tip-in to full load and back) and sweeps the speed at part load. The wind-up read
from the bag gets white Gaussian noise of ``noise_rad`` (a wind-up measured from two tooth
wheels) before the fit, which starts from the shipped ``truck_dmf`` values:

* ``identify_param_rel_err``: the largest |fitted / true - 1| over every parameter and case
  (target <= 0.05), per case and parameter in ``cases``;
* ``identify_seconds``: wall time of one identification (median over the cases; each with
  ``starts`` starting points in turn in this process), ``simulations`` per case;
* ``rel_std``: the fit's own (linearized) relative standard deviations, beside the real error.

The fit starts from the shipped spring, which has no friction: the friction starts at
``dmf_sim.identify.fit.FRICTION_START``.

    python benchmarks/bench_identify.py [--small] [--starts 2] [--noise-rad 5e-4]

``--small``: one short case, one start (a smoke test of the chain). Last line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
# (name, true DMF values, profile rows (time_s, speed_rpm, load)). Each profile settles 2 s
# (left out of the fit), crosses the knee in a tip-in to full load and back, and sweeps the speed
# widely at part load: the centrifugal part of the friction grows with the speed squared, the
# constant part does not, and only a speed range tells them apart.
WIDE = [(0, 700, 0.3), (2, 700, 0.3), (4, 1100, 0.3), (4.1, 1100, 1.0), (5.5, 1100, 1.0),
        (5.6, 1100, 0.2), (10, 2100, 0.2), (11, 2100, 0.2)]
WIDE_LOW = [(0, 800, 0.4), (2, 800, 0.4), (3.5, 1000, 0.4), (3.6, 1000, 1.0), (5, 1000, 1.0),
            (5.1, 1000, 0.1), (9, 2000, 0.1), (10, 2000, 0.1)]
CASES = [
    ('soft_early_knee', {'k': 9800.0, 'theta': 0.22, 'alpha': 2.0, 'damping': 42.0,
                         'friction.torque_nm': 40.0, 'friction.speed_coefficient': 3.0e-3}, WIDE),
    ('stiff_high_friction', {'k': 12000.0, 'theta': 0.21, 'alpha': 3.0, 'damping': 30.0,
                             'friction.torque_nm': 80.0, 'friction.speed_coefficient': 6.0e-3},
     WIDE_LOW),
    ('soft_late_knee', {'k': 9000.0, 'theta': 0.25, 'alpha': 1.5, 'damping': 55.0,
                        'friction.torque_nm': 25.0, 'friction.speed_coefficient': 1.5e-3}, WIDE),
]
SMALL = [('small', {'k': 9800.0, 'theta': 0.22, 'alpha': 2.0, 'damping': 42.0,
                    'friction.torque_nm': 40.0, 'friction.speed_coefficient': 3.0e-3},
          [(0, 900, 0.3), (2, 900, 0.3), (2.1, 900, 1.0), (3, 900, 1.0), (3.1, 900, 0.2),
           (5, 1800, 0.2)])]
# a table profile's first 2 s settle from static equilibrium and are left out of the fit
# (dmf_sim.transient.profiles): every case's steps come after them


def make_bag(work: Path, name: str, true: dict, rows) -> tuple[Path, Path]:
    """A ``dmf-sim run`` bag of the case (sensors off) and its profile file."""
    import yaml

    from dmf_sim.transient.profiles import read_profile
    from dmf_sim.transient.run import RunOptions, run_profile
    data = yaml.safe_load((ROOT / 'config' / 'truck_dmf.yaml').read_text())
    dmf_element = data['dmf']['element']
    for el in data['elements']:
        if el['name'] == dmf_element:
            el['stiffness'], el['damping'] = true['k'], true['damping']
    data['dmf']['theta_rad'], data['dmf']['alpha'] = true['theta'], true['alpha']
    if 'friction.torque_nm' in true:
        data['dmf']['friction'] = {'torque_nm': true['friction.torque_nm'],
                                   'speed_coefficient': true['friction.speed_coefficient']}
    line = work / f'{name}.yaml'
    line.write_text(yaml.safe_dump(data, sort_keys=False))
    prof = work / f'{name}.csv'
    prof.write_text('time_s,speed_rpm,load\n' + ''.join(f'{t},{s},{x}\n' for t, s, x in rows))
    bag = work / name
    run_profile(read_profile(str(prof)), bag, RunOptions(driveline=str(line), sensors=False))
    return bag, prof


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--small', action='store_true', help='one short case, one start')
    ap.add_argument('--starts', type=int, default=2, help='starting points per case')
    ap.add_argument('--noise-rad', type=float, default=5e-4, help='wind-up noise (1 sigma)')
    ap.add_argument('--seed', type=int, default=1)
    args = ap.parse_args()
    from dmf_sim.identify.fit import IdentifyOptions, identify, read_measurement

    work = Path(tempfile.mkdtemp(prefix='bench_identify_'))
    out: dict = {'date_utc': time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime()),
                 'load_average_1min': os.getloadavg()[0], 'cpus': os.cpu_count(),
                 'python': platform.python_version(), 'small': args.small,
                 'noise_rad': args.noise_rad, 'start_from': 'truck_dmf'}
    cases = SMALL if args.small else CASES
    starts = 1 if args.small else args.starts
    rng = np.random.default_rng(args.seed)
    results = {}
    try:
        for name, true, rows in cases:
            bag, prof = make_bag(work, name, true, rows)
            options = IdentifyOptions(parameters=tuple(true), driveline='truck_dmf',
                                      profile=str(prof), starts=starts, seed=args.seed)
            meas = read_measurement(bag, options)
            windup_max = float(meas.y[meas.t_s >= meas.settle_s].max())
            meas = replace(meas, y=meas.y + rng.normal(0.0, args.noise_rad, len(meas.y)))
            r = identify(meas, options)
            err = {n: abs(r.values[n] / true[n] - 1.0) for n in true}
            results[name] = {'true': true, 'fitted': r.values, 'rel_err': err,
                             'rel_std': r.rel_std, 'rms': r.rms, 'rms_initial': r.rms_initial,
                             'seconds': r.seconds, 'simulations': r.evaluations,
                             'windup_max_rad': windup_max}
            print(f'{name}: ' + ', '.join(f'{n} {r.values[n]:.5g} (true {true[n]:.5g}, '
                                          f'{100 * err[n]:.2f} %)' for n in true)
                  + f'; {r.seconds:.1f} s, {r.evaluations} simulations')
    finally:
        shutil.rmtree(work, ignore_errors=True)
    out.update(cases=results, starts=starts,
               identify_param_rel_err=max(max(c['rel_err'].values()) for c in results.values()),
               identify_seconds=statistics.median(c['seconds'] for c in results.values()),
               identify_seconds_max=max(c['seconds'] for c in results.values()),
               load_average_1min_end=os.getloadavg()[0])
    print(json.dumps(out))


if __name__ == '__main__':
    main()
