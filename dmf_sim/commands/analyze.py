"""``dmf-sim analyze BAG``: order analysis of a recorded bag, with the HBM prediction overlaid."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from dmf_sim.errors import ConfigError

NAME = 'analyze'
HELP = ('Order analysis of a recorded bag (rosbag2 MCAP directory or bare .mcap, no ROS needed): '
        'resample on the crank angle, half-order amplitudes per engine cycle or speed bin, '
        'Campbell/waterfall and Fig. 13 plots, HBM prediction overlaid.')

EPILOG = """signals (--signal, repeatable; default windup):
  windup              DMF wind-up topic (/driveline/dmf_windup) [rad]
  angle:NAME          JointState position of element NAME (vibratory angle) [rad]
  velocity:NAME       JointState velocity of element NAME [rad/s]
  torque:NAME         JointState effort of element NAME (transmitted torque) [Nm]
  topic:/TOPIC        the 'data' field of any scalar topic (e.g. std_msgs/Float64)
  NAME matches case-insensitively, '_' for ' ' (torque:INPUT_SHAFT).

crank angle: /engine/crank_angle; if the bag lacks it, /engine/speed [rpm] is integrated over
time; a bag with neither is refused. Model settings for the modes and the HBM (driveline,
engine, alpha, theta, load set) default to what the recording node stored in the bag's
metadata (custom_data), else to the config defaults; the load is not recorded: --load
(default 1.0)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.epilog = EPILOG + '\n\n' + (p.epilog or '')
    p.add_argument('bag', metavar='BAG', help='rosbag2 bag directory or bare .mcap file')
    p.add_argument('--signal', action='append', metavar='SIGNAL',
                   help="signal to analyse (repeatable): windup (default), angle:NAME, "
                        "velocity:NAME, torque:NAME, topic:/TOPIC")
    p.add_argument('--bin-rpm', type=float, default=20.0,
                   help='speed bin width [rpm] (default 20); 0 = one row per engine cycle (720 deg)')
    p.add_argument('--start', type=float, metavar='S',
                   help='analyse only cycles after S seconds from the start of the recording '
                        '(e.g. skip a start-up transient)')
    p.add_argument('--end', type=float, metavar='S', help='... and before S seconds')
    p.add_argument('--points-per-cycle', type=int, default=256,
                   help='crank-angle grid points per 720 deg cycle (default 256)')
    p.add_argument('--n-max', type=int, default=24,
                   help='highest half-order index n (order n/2) reported (default 24 = 12th order)')
    p.add_argument('--out', type=Path,
                   help='output directory (analysis.json, <signal>_orders.csv, <signal>_cycles.csv, '
                        '<signal>_campbell.png, <signal>_fig13.png); default <BAG name>_analysis '
                        'unless --json')
    p.add_argument('--json', action='store_true',
                   help='print one JSON object (order amplitudes per speed bin, Fig. 13 quantities, '
                        'HBM comparison) on stdout')
    p.add_argument('--no-plots', action='store_true', help='skip the PNG plots')
    p.add_argument('--hbm', action=argparse.BooleanOptionalAction, default=True,
                   help='overlay the harmonic-balance prediction on the wind-up (default on)')
    p.add_argument('--config', help='driveline YAML (name in config/ or path); default: from the bag, '
                                    'else truck_dmf')
    p.add_argument('--engine', help='engine YAML or coefficient table; default: from the bag, else '
                                    'engine_d13')
    p.add_argument('--alpha', type=float, help='DMF secondary stiffness factor k(1+alpha); default: '
                                               'from the bag, else the driveline YAML')
    p.add_argument('--theta', type=float, help='DMF stiffness change angle [rad]; default: from '
                                               'the bag, else the driveline YAML')
    p.add_argument('--load', type=float, help='engine load fraction 0..1 for the HBM (default 1.0; '
                                              'not stored in bags)')
    p.add_argument('--load-set', choices=('A', 'B', 'C'),
                   help='engine load set (default: from the bag, else A)')
    p.add_argument('--windup-topic', default='/driveline/dmf_windup', help='default %(default)s')
    p.add_argument('--crank-topic', default='/engine/crank_angle', help='default %(default)s')
    p.add_argument('--speed-topic', default='/engine/speed', help='default %(default)s [rpm]')
    p.add_argument('--joints-topic', default='/driveline/joint_states', help='default %(default)s')
    p.add_argument('--stamp', choices=('log', 'publish'), default='log',
                   help='message time stamp used: log (receive) time or publish time (default log)')
    p.add_argument('--progress', action='store_true', help='tqdm progress bar while reading')


def run(args) -> int:
    from dmf_sim.analyze import (analysis_dict, analyze_bag, model_settings, overlay_all,
                                 write_outputs)

    if args.load is not None and not (math.isfinite(args.load) and 0.0 <= args.load <= 1.0):
        raise ConfigError(f'--load {args.load}: must be within [0, 1]')
    if args.bin_rpm < 0 or not math.isfinite(args.bin_rpm):
        raise ConfigError(f'--bin-rpm {args.bin_rpm}: must be >= 0 (0 = per cycle)')
    topics = {'windup': args.windup_topic, 'crank': args.crank_topic, 'speed': args.speed_topic,
              'joints': args.joints_topic}
    signals = args.signal or ['windup']
    # model settings first (theta for 'mean - theta'), from the options, the bag, the YAML
    from dmf_sim.analyze import _bag_files
    _, meta = _bag_files(args.bag)
    settings = model_settings(meta, config=args.config, engine=args.engine, alpha=args.alpha,
                              theta=args.theta, load=args.load, load_set=args.load_set)
    res = analyze_bag(args.bag, signals, bin_rpm=args.bin_rpm,
                      points_per_cycle=args.points_per_cycle, n_max=args.n_max,
                      theta=settings['theta_rad'], topics=topics, stamp=args.stamp,
                      progress=args.progress, start_s=args.start, end_s=args.end)
    natural = overlay_all(res, settings, hbm=args.hbm)
    extra = {'model': {k: v for k, v in settings.items() if k != 'sources'},
             'model_sources': settings['sources'], 'natural_frequencies_hz': natural}
    out = args.out
    if out is None and not args.json:
        out = Path(f'{Path(args.bag).name.removesuffix(".mcap")}_analysis')
    written = write_outputs(res, out, natural=natural, plots=not args.no_plots,
                            extra=extra) if out is not None else []
    if args.json:
        print(json.dumps(analysis_dict(res, extra)))
        return 0
    _report(res, settings, written)
    return 0


def _fmt(v, scale=1.0, spec='9.5f') -> str:
    return f'{v * scale:{spec}}' if v is not None and math.isfinite(v) else ' ' * 6 + 'n/a'


def _report(res, settings, written) -> None:
    """Human-readable summary on stdout."""
    print(f'{res.bag}: {res.duration_s:.1f} s, {res.sample_rate_hz:.0f} Hz, crank angle from the '
          f'{res.crank_source}; reader {res.reader} ({res.read_seconds:.2f} s)')
    for w in res.warnings:
        print(f'warning: {w}')
    for sig in res.signals:
        t = sig.table
        unit = sig.signal.unit
        mode = f'{res.bin_rpm:g} rpm bins' if res.bin_rpm > 0 else 'per cycle'
        print(f'\n{sig.signal.description} [{unit}]: {len(sig.cycles)} engine cycles, {len(t)} rows ({mode})')
        head = f'{"rpm":>7} {"cycles":>6} {"3rd":>9} {"1.5th":>9} {"max dev":>9} {"min dev":>9} {"mean-th" if t.theta is not None else "mean":>9}'
        if sig.hbm is not None:
            head += f' {"HBM 3rd":>9} {"HBM 1.5":>9}'
        print(head)
        step = max(1, math.ceil(len(t) / 40))
        mm = t.mean_minus_theta if t.theta is not None else t.mean
        for i in range(0, len(t), step):
            line = (f'{t.speed_rpm[i]:7.0f} {t.n_cycles[i]:6d} {_fmt(t.order_3[i])} {_fmt(t.order_1_5[i])} '
                    f'{_fmt(t.max_deviation[i])} {_fmt(t.min_deviation[i])} {_fmt(mm[i])}')
            if sig.hbm is not None:
                line += f' {_fmt(sig.hbm.values["order_3"][i])} {_fmt(sig.hbm.values["order_1_5"][i])}'
            print(line)
        if sig.hbm is not None:
            s = sig.hbm.settings
            print(f'HBM ({sig.hbm.method}; alpha={s["alpha"]:g}, load={s["load"]:g}, load set '
                  f'{s["load_set"]}, {sig.hbm.seconds:.2f} s): measured - HBM per quantity')
            for k, d in sig.hbm.difference.items():
                print(f'  {k:17s} max |diff| {_fmt(d["max_abs"], 1, ".5f")} {unit} at '
                      f'{d["at_speed_rpm"]:.0f} rpm, rms {_fmt(d["rms_abs"], 1, ".5f")}, '
                      f'{_fmt(d["rel_to_peak"], 100, ".1f")} % of the HBM peak')
    if written:
        print('\nwritten: ' + ', '.join(str(p) for p in written))
    sys.stdout.flush()
