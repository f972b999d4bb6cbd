"""``dmf-sim analyze BAG``: order analysis of a recorded bag, with the HBM prediction overlaid."""
from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from dmf_sim.commands import _options as opt
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text

__all__ = ['NAME', 'HELP', 'EPILOG', 'BIN_RPM_RANGE', 'MIN_CYCLES_RANGE', 'N_MAX_RANGE',
           'POINTS_PER_CYCLE_MAX', 'add_arguments', 'check_arguments', 'default_output', 'run']

NAME = 'analyze'
HELP = ('Order analysis of a recorded bag (rosbag2 MCAP directory, one of its files, or a bare '
        '.mcap; no ROS needed): resample on the crank angle, half-order amplitudes per engine '
        'cycle or speed bin, Campbell/waterfall and Fig. 13 plots, HBM prediction overlaid.')

EPILOG = """signals (--signal, repeatable; default windup):
  windup              DMF wind-up topic (/driveline/dmf_windup) [rad]
  angle:NAME          JointState position of element NAME (vibratory angle) [rad]
  velocity:NAME       JointState velocity of element NAME [rad/s]
  torque:NAME         JointState effort of element NAME (transmitted torque) [Nm]
  topic:/TOPIC        the 'data' field of any scalar topic (e.g. std_msgs/Float64)
  NAME matches case-insensitively, '_' for ' ' (torque:INPUT_SHAFT).

topics: the node's defaults, under the one driveline namespace the bag holds (/truck1/...,
detected; several: choose with --namespace), or given with --*-topic. Crank angle:
/engine/crank_angle; if the bag lacks it, /engine/speed [rpm] is integrated over time; a bag
with neither is refused.

model settings for the modes, the static wind-up and the HBM: each option given wins; else
what the recording node stored in the bag's metadata.yaml (custom_data: driveline, engine, load
set, the whole DMF spring, and the load at the start of the recording) -- also when BAG is one
of the bag's .mcap files, whose metadata.yaml lies beside it; else the defaults (truck_dmf,
engine_d13, load set A, load 1.0, the YAML's spring).

the engine load: without --load, the load each engine cycle ran at, as the bag records it (the
node's health statuses in /diagnostics, the load setpoint topic if recorded, the load stored at
the start of the recording); rows are then per speed bin AND load, each compared with the HBM
at its own load, and cycles during a load change (or of unknown load) are never steady. A bag
that records only the start load (or none: 1.0) is assumed constant, with a warning. --load L
takes L for the whole recording.

speed bins with fewer than --min-cycles engine cycles are ramp bins: hollow markers / hatched
in the plots, and left out of the comparison with the HBM."""

BIN_RPM_RANGE = (0.0, 500.0)          # [rpm]; 0 = one row per cycle
MIN_CYCLES_RANGE = (1, 100_000)
N_MAX_RANGE = (6, 96)                 # half-order index: 3rd .. 48th engine order
POINTS_PER_CYCLE_MAX = 8192


def add_arguments(p: argparse.ArgumentParser) -> None:
    from dmf_sim.analysis.order_bins import DEFAULT_BIN_RPM, DEFAULT_MIN_CYCLES

    p.epilog = EPILOG + '\n\n' + (p.epilog or '')
    p.add_argument('bag', metavar='BAG', help='rosbag2 bag directory, one of its .mcap files, or '
                                              'a bare .mcap file')
    p.add_argument('--signal', action='append', metavar='SIGNAL',
                   help='signal to analyse (repeatable): windup (default), angle:NAME, '
                        'velocity:NAME, torque:NAME, topic:/TOPIC')
    p.add_argument('--bin-rpm', type=float, default=DEFAULT_BIN_RPM,
                   help=f'speed bin width [rpm] within {BIN_RPM_RANGE} (default %(default)g); '
                        '0 = one row per engine cycle (720 deg)')
    p.add_argument('--min-cycles', type=int, default=DEFAULT_MIN_CYCLES,
                   help='speed bins with fewer engine cycles are ramp bins: marked in the plots, '
                        'not compared with the HBM (default %(default)d)')
    p.add_argument('--start', type=float, metavar='S',
                   help='analyse only cycles after S seconds from the start of the recording '
                        '(e.g. skip a start-up transient; default: after the settle from static '
                        'equilibrium the bag marks, as dmf-sim run does; 0 keeps it)')
    p.add_argument('--end', type=float, metavar='S', help='... and before S seconds')
    p.add_argument('--points-per-cycle', type=int, default=256,
                   help=f'crank-angle grid points per 720 deg cycle, 2 n_max + 2 .. '
                        f'{POINTS_PER_CYCLE_MAX} (default %(default)d)')
    p.add_argument('--n-max', type=int, default=24,
                   help=f'highest half-order index n (order n/2) reported, {N_MAX_RANGE[0]} .. '
                        f'{N_MAX_RANGE[1]} (default %(default)d = 12th order)')
    p.add_argument('--out', type=Path,
                   help='output directory (analysis.json, <signal>_orders.csv, '
                        '<signal>_cycles.csv, <signal>_campbell.png, <signal>_fig13.png), '
                        'checked before anything is computed; default: beside the bag, '
                        '<BAG>_analysis (none with --json)')
    opt.add_overwrite(p)
    p.add_argument('--json', action='store_true',
                   help='print one JSON object (order amplitudes per speed bin, Fig. 13 '
                        'quantities, HBM comparison) on stdout')
    p.add_argument('--no-plots', action='store_true', help='skip the PNG plots')
    p.add_argument('--hbm', action=argparse.BooleanOptionalAction, default=True,
                   help='overlay the harmonic-balance prediction on the wind-up (default on)')
    opt.add_config(p, default=None, help_default='from the bag, else truck_dmf')
    opt.add_engine(p, default=None, help_default='from the bag, else engine_d13')
    opt.add_alpha(p, help_default='from the bag, else the YAML')
    opt.add_theta(p, help_default='from the bag, else the YAML')
    opt.add_load(p, default=None, help_default='the load stored in the bag for each cycle, '
                                              'else 1.0; see below')
    opt.add_load_set(p, default=None, help_default='from the bag, else A')
    p.add_argument('--namespace', help="driveline namespace of the default topics (e.g. truck1; "
                                       "default: detected from the bag's topics)")
    p.add_argument('--windup-topic', help='wind-up topic (default /driveline/dmf_windup under the '
                                          'namespace)')
    p.add_argument('--crank-topic', help='crank angle topic (default /engine/crank_angle)')
    p.add_argument('--speed-topic', help='engine speed topic [rpm] (default /engine/speed)')
    p.add_argument('--joints-topic', help='joint states topic (default /driveline/joint_states)')
    p.add_argument('--stamp', choices=('log', 'publish'), default='log',
                   help='message time stamp used: log (receive) time or publish time '
                        '(default log)')
    p.add_argument('--progress', action='store_true', help='tqdm progress bar while reading')


def _within(name: str, value, lo, hi, unit: str = '') -> None:
    if value is None:
        return
    if not (math.isfinite(value) and lo <= value <= hi):
        raise ConfigError(f'{name} {value:g}: must be within [{lo:g}, {hi:g}]{unit}')


def check_arguments(args) -> None:
    """Refuse out-of-range options with one line each (before reading anything)."""
    opt.check_common(args)
    _within('--bin-rpm', args.bin_rpm, *BIN_RPM_RANGE, ' rpm (0 = per cycle)')
    _within('--min-cycles', args.min_cycles, *MIN_CYCLES_RANGE)
    _within('--n-max', args.n_max, *N_MAX_RANGE)
    _within('--points-per-cycle', args.points_per_cycle, 2 * args.n_max + 2,
            POINTS_PER_CYCLE_MAX)
    _within('--start', args.start, 0.0, math.inf, ' s')
    _within('--end', args.end, 0.0, math.inf, ' s')
    if args.start is not None and args.end is not None and args.end <= args.start:
        raise ConfigError(f'--end {args.end:g} must be after --start {args.start:g}')


def default_output(bag: str | Path) -> Path:
    """Where the analysis goes by default: beside the bag, ``<bag directory>_analysis`` or
    ``<file name without .mcap>_analysis`` next to the file (not the current directory)."""
    p = Path(bag)
    if p.name == 'metadata.yaml':
        p = p.parent
    p = Path(os.path.abspath(p))
    return p.parent / f'{p.name.removesuffix(".mcap")}_analysis'


def run(args) -> int:
    from dmf_sim.analysis.outputs import write_outputs
    from dmf_sim.analysis.pipeline import (
        AnalysisOptions,
        analysis_dict,
        analyze_bag,
        model_settings,
        overlay_all,
    )
    from dmf_sim.bags.layout import resolve_bag
    from dmf_sim.live.warm import warm_up

    check_arguments(args)
    dest = None if args.out is None and args.json else opt.output(
        args, NAME, args.out if args.out is not None else default_output(args.bag))
    topics = {key: value for key, value in (('windup', args.windup_topic),
                                            ('crank', args.crank_topic),
                                            ('speed', args.speed_topic),
                                            ('joints', args.joints_topic)) if value}
    bag = resolve_bag(args.bag)
    settings = model_settings(bag.metadata, config=args.config, engine=args.engine,
                              alpha=args.alpha, theta=args.theta, load=args.load,
                              load_set=args.load_set)
    warm_up(NAME, 'bag reading', *(['sweep'] if args.hbm else []))
    options = AnalysisOptions(bin_rpm=args.bin_rpm, min_cycles=args.min_cycles,
                              points_per_cycle=args.points_per_cycle, n_max=args.n_max,
                              theta=settings['theta_rad'], topics=topics,
                              namespace=args.namespace, stamp=args.stamp, start_s=args.start,
                              end_s=args.end, load=args.load)
    res = analyze_bag(bag, args.signal or ['windup'], options=options, progress=args.progress)
    natural = overlay_all(res, settings, hbm=args.hbm)
    model = {k: v for k, v in settings.items() if k != 'sources'}
    sources = dict(settings['sources'])
    if res.load_timeline is not None:      # each row at the load the bag recorded for it
        model['load'], sources['load'] = res.model['load'], 'bag (per engine cycle)'
    extra = {'model': model, 'model_sources': sources, 'natural_frequencies_hz': natural}
    written = []
    if dest is not None:
        with dest.writing() as out:
            written = write_outputs(res, out, natural=natural, plots=not args.no_plots,
                                    extra=extra)
    if args.json:
        print(json_text(analysis_dict(res, extra)))
        return 0
    _report(res, written)
    return 0


def _fmt(v, scale=1.0, spec='9.5f') -> str:
    return f'{v * scale:{spec}}' if v is not None and math.isfinite(v) else ' ' * 6 + 'n/a'


def _report(res, written) -> None:
    """Human-readable summary on stdout."""
    print(f'{res.bag}: {res.duration_s:.1f} s, {res.sample_rate_hz:.0f} Hz, crank angle from the '
          f'{res.crank_source}; reader {res.reader} ({res.read_seconds:.2f} s)'
          + (f'; namespace /{res.namespace}' if res.namespace else ''))
    for w in res.warnings:
        print(f'warning: {w}')
    for sig in res.signals:
        _report_signal(res, sig)
    if written:
        print('\nwritten: ' + ', '.join(str(p) for p in written))
    sys.stdout.flush()


def _report_signal(res, sig) -> None:
    from dmf_sim.analysis.load_timeline import load_text

    t = sig.table
    unit = sig.signal.unit
    mode = f'{res.bin_rpm:g} rpm bins' if res.bin_rpm > 0 else 'per cycle'
    steady = t.steady
    print(f'\n{sig.signal.description} [{unit}]: {len(sig.cycles)} engine cycles, {len(t)} rows '
          f'({mode}; {int(steady.sum())} steady, ~ marks ramp rows with < {t.min_cycles} cycles'
          + (' or of unknown load' if t.load is not None else '') + ')')
    green = t.theta_minus_static
    last = 'th-static' if green is not None else 'mean'
    head = (f'{"rpm":>8}' + (f' {"load":>6}' if t.load is not None else '')
            + f' {"cycles":>6} {"3rd":>9} {"1.5th":>9} {"max dev":>9} {"min dev":>9} '
            f'{last:>9}')
    if sig.hbm is not None:
        head += f' {"HBM 3rd":>9} {"HBM 1.5":>9}'
    print(head)
    step = max(1, math.ceil(len(t) / 40))
    col = green if green is not None else t.mean
    for i in range(0, len(t), step):
        mark = ' ' if steady[i] else '~'
        line = (f'{mark}{t.speed_rpm[i]:7.0f}'
                + (f' {_fmt(t.load[i], 1, "6.3f").strip():>6}' if t.load is not None else '')
                + f' {t.n_cycles[i]:6d} {_fmt(t.order_3[i])} '
                f'{_fmt(t.order_1_5[i])} {_fmt(t.max_deviation[i])} {_fmt(t.min_deviation[i])} '
                f'{_fmt(col[i])}')
        if sig.hbm is not None:
            line += (f' {_fmt(sig.hbm.values["order_3"][i])} '
                     f'{_fmt(sig.hbm.values["order_1_5"][i])}')
        print(line)
    if sig.hbm is None:
        return
    s = sig.hbm.settings
    if not sig.hbm.difference:
        print(f'HBM: no steady speed bin (>= {t.min_cycles} cycles) to compare with -- the '
              'recording ramps through every bin; lower --min-cycles or widen --bin-rpm')
        return
    print(f'HBM ({sig.hbm.method}; alpha={s["alpha"]:g}, load={load_text(s["load"])}, load set '
          f'{s["load_set"]}, {sig.hbm.seconds:.2f} s): measured - HBM over the steady rows')
    for k, d in sig.hbm.difference.items():
        print(f'  {k:17s} max |diff| {_fmt(d["max_abs"], 1, ".5f")} {unit} at '
              f'{d["at_speed_rpm"]:.0f} rpm, rms {_fmt(d["rms_abs"], 1, ".5f")}, '
              f'{_fmt(d["rel_to_peak"], 100, ".1f")} % of the HBM peak ({d["n_rows"]} rows)')
