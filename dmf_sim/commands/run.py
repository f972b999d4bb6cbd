"""``dmf-sim run PROFILE --out BAG``: an offline transient run of a speed/load profile, written as
a bag with the node's topics (``dmf_sim.transient.run``).

PROFILE: a CSV (``time_s,speed_rpm,load``) or YAML file, a packaged profile
(``truck_road_cycle``), ``ramp:FROM:TO:RATE[:LOAD[:SETTLE]]`` (rpm, rpm, rpm/s, -1..1, s) or
a load step ``step:SPEED:FROM:TO:RISE[:HOLD[:SETTLE]]`` (rpm, -1..1, -1..1, s, s, s). The summary
gives the peak wind-up (both signs), the DMF spring torque there and, for a spring with end stops,
the travel margin and the stop contacts (``dmf_sim.live.peaks``).
``--faults FILE``: a fault schedule (YAML ``faults: [...]``, times of the profile) injected
along the run, its ground truth written into the bag (``faults/ground_truth``,
``faults/active``).
"""
from __future__ import annotations

import argparse
import sys

from dmf_sim.commands._options import (
    add_alpha,
    add_config,
    add_engine,
    add_load_set,
    add_overwrite,
    add_theta,
    check_common,
    output,
)
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text
from dmf_sim.core.names import check_namespace
from dmf_sim.live.peaks import peaks_text
from dmf_sim.transient.defaults import CHUNK_RANGE_S, DEFAULT_CHUNK_S, default_threads

__all__ = ['NAME', 'HELP', 'add_arguments', 'run']

NAME = 'run'
HELP = ('Offline transient run of a speed/load profile (run-up, run-down, drive cycle) through '
        "the Newmark kernel, written as a bag with the live node's topics")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('profile', metavar='PROFILE',
                   help='CSV/YAML profile (time_s, speed_rpm, load -1..1), a packaged one '
                        '(truck_road_cycle), ramp:FROM:TO:RATE[:LOAD[:SETTLE]], e.g. '
                        'ramp:800:2000:10 (run-up at 10 rpm/s, load 1), or a load step '
                        'step:SPEED:FROM:TO:RISE[:HOLD[:SETTLE]], e.g. step:1200:0:1:0.1 '
                        '(tip-in 0 -> 1 in 0.1 s and back)')
    p.add_argument('--out', metavar='BAG', help='bag directory to create (new or empty); '
                   'required unless --no-write')
    add_overwrite(p)
    p.add_argument('--rate', type=float, default=1000.0, metavar='HZ',
                   help='samples per simulated second in the bag (default 1000; a whole number '
                        'of Newmark steps per sample)')
    add_config(p)
    add_engine(p)
    add_load_set(p)
    add_alpha(p)
    add_theta(p)
    p.add_argument('--dt', type=float, default=1e-4, help='Newmark step [s] (default 1e-4)')
    p.add_argument('--chunk', type=float, default=DEFAULT_CHUNK_S, metavar='S',
                   help='simulated time per chunk: excitation coefficients and load are held '
                        f'over a chunk, the speed ramp is exact (default {DEFAULT_CHUNK_S:g}, '
                        f'within [{CHUNK_RANGE_S[0]:g}, {CHUNK_RANGE_S[1]:g}])')
    p.add_argument('--faults', metavar='FILE',
                   help='fault schedule (YAML faults: [...]; misfires, weak cylinders, DMF and '
                        'sensor faults with start_s/end_s or at_s in the profile\'s time) '
                        'injected along the run; its ground truth goes into the bag')
    p.add_argument('--namespace', default='', help='write the topics under this ROS 2 namespace '
                   '(e.g. /truck1; checked by ROS 2\'s rules)')
    p.add_argument('--no-write', action='store_true', help='integrate only (timing)')
    p.add_argument('--no-sensors', action='store_true',
                   help="no sensor topics (the driveline YAML's tooth wheels and bus signals; "
                        'default: recorded as the node publishes them)')
    p.add_argument('--threads', type=int, choices=(1, 2), default=None,
                   help='1: integrate and write in turn; 2: integrate the next chunks in a '
                        'thread of their own while the last ones are written (the same bag) '
                        '(default: 2 when this process may use two or more CPUs, else 1)')
    p.add_argument('--json', action='store_true', help='print the summary as JSON')
    p.add_argument('--no-progress', action='store_true', help='no progress bar')


def run(args: argparse.Namespace) -> int:
    from dmf_sim.live.warm import warm_up
    from dmf_sim.transient.profiles import read_profile
    from dmf_sim.transient.run import RunOptions, dt_error, run_profile

    check_common(args)
    namespace = check_namespace(args.namespace, '--namespace')
    if not args.no_write and not args.out:
        raise ConfigError('give --out BAG (the bag directory to create) or --no-write')
    if reason := dt_error(args.dt, '--dt'):
        raise ConfigError(reason)
    dest = None if args.no_write else output(args, NAME, kind='bag')
    profile = read_profile(args.profile)
    opt = RunOptions(driveline=args.config, engine=args.engine, load_set=args.load_set,
                     alpha=args.alpha, theta=args.theta, dt=args.dt, rate_hz=args.rate,
                     chunk_s=args.chunk, write=not args.no_write, namespace=namespace,
                     threads=default_threads() if args.threads is None else args.threads,
                     faults=args.faults, sensors=not args.no_sensors)
    warm_up(NAME, 'time integration')    # before the bar: its rate without a compile
    summary = run_profile(profile, None if args.no_write else args.out, opt,
                          progress=not (args.no_progress or args.json), destination=dest)
    if args.json:
        print(json_text(summary.as_dict()))
    else:
        what = f'bag {summary.bag}: {summary.messages} messages' if summary.bag else 'not written'
        faults = (f'; faults {args.faults}: ground-truth events: {summary.fault_events}, '
                  f'misfires: {summary.misfires}' if args.faults else '')
        print(f'{profile.name}: {summary.simulated_s:.3f} s simulated in {summary.wall_s:.2f} s '
              f'(x{summary.realtime_factor:.0f} real time), {summary.samples} samples at '
              f'{summary.rate_hz:g} Hz; {what}{faults}')
        after = (f' (after the first {summary.peaks_after_s:g} s: the settling from static '
                 'equilibrium)' if summary.peaks_after_s > 0 else '')
        print(f'{profile.name}: {peaks_text(summary.as_dict())}{after}')
    if summary.interrupted:
        print(f'dmf-sim run: interrupted at {summary.simulated_s:.3f} s; the bag holds what was '
              'simulated', file=sys.stderr)
        return 130
    return 0
