"""``dmf-sim identify BAG``: the DMF's spring stages, knee(s), damping and arc-spring friction
fitted to a recorded run (``dmf_sim.identify.fit``), with each parameter's uncertainty and a
plot of measured against fitted."""
from __future__ import annotations

import argparse
import math
from pathlib import Path

from dmf_sim.commands import _options as opt
from dmf_sim.core.json_out import json_text, write_json

__all__ = ['NAME', 'HELP', 'add_arguments', 'run', 'value_line']

NAME = 'identify'
HELP = ("Fit the DMF's spring (stiffness, knees, stage factors), damping and arc-spring "
        'friction (friction.torque_nm, friction.speed_coefficient) to a recorded run-up '
        'or drive cycle (its wind-up, or the two flywheel speeds): fitted values with their '
        'uncertainty, the fit from several starting points (on Dask with --workers or '
        '--scheduler), a plot of measured against fitted')

PARAMETERS_TEXT = ('k, damping, theta, alpha, stages[i].angle_rad, stages[i].stiffness_factor, '
                   'coast_stages[j].angle_rad, coast_stages[j].stiffness_factor, '
                   'friction.torque_nm, friction.speed_coefficient')
"""The parameters --parameters takes, as dmf_sim.design.parameters.ALLOWED_TEXT lists them
(written out: importing the design package would load Dask for every ``dmf-sim --help``; a test
keeps the two the same)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    from dmf_sim.identify.fit import DEFAULT_PARAMETERS, SIGNALS, IdentifyOptions
    d = IdentifyOptions()
    p.add_argument('bag', metavar='BAG', help='rosbag2 bag directory, one of its .mcap files, '
                   'or a bare .mcap file')
    p.add_argument('--parameters', default=','.join(DEFAULT_PARAMETERS), metavar='NAMES',
                   help=f'comma-separated DMF parameters to fit, among {PARAMETERS_TEXT} '
                        f'(default {",".join(DEFAULT_PARAMETERS)})')
    p.add_argument('--signal', default=d.signal, choices=SIGNALS,
                   help='what to fit: the wind-up, or the speeds of the two flywheels '
                        f'(default {d.signal})')
    p.add_argument('--config', help="driveline YAML to start from (default: the bag's)")
    p.add_argument('--engine', help="engine YAML (default: the bag's; another than the bag's "
                   "is refused)")
    p.add_argument('--load-set', help="load set A/B/C (default: the bag's; another than the "
                   "bag's is refused)")
    p.add_argument('--profile', help="the profile the bag was recorded along (default: the "
                   "one the bag names, else rebuilt from its recorded speed and load)")
    p.add_argument('--starts', type=int, default=d.starts,
                   help=f'starting points (default {d.starts})')
    p.add_argument('--max-evaluations', type=int, default=d.max_evaluations,
                   help=f'simulations per start at most (default {d.max_evaluations})')
    p.add_argument('--seed', type=int, default=d.seed, help='seed of the starting points')
    p.add_argument('--local', action='store_true',
                   help='run the starts in this process, in turn (default without --workers '
                        'or --scheduler)')
    opt.add_cluster(p)
    p.add_argument('--out', type=Path, help='output directory (identify.json, identify.png)')
    opt.add_overwrite(p)
    p.add_argument('--json', action='store_true', help='print one JSON object to stdout')


def value_line(result, name: str) -> str:
    """The summary's line of one fitted parameter: value, start and relative uncertainty (or
    why there is none: the fit's sensitivities singular at the optimum, ``rel_std`` NaN)."""
    sd = result.rel_std[name]
    spread = (f'± {100 * sd:.2g} %' if math.isfinite(sd) else
              "uncertainty undetermined: the fit's sensitivities are singular there")
    return (f'  {name:>22} = {result.values[name]:.6g}   (start {result.initial[name]:.6g}, '
            f'{spread})')


def _run_text(meas, result) -> str:
    """The run a summary names: the bag's profile, or the one rebuilt and what of it is read,
    and where the samples read end (an injected fault, the node's spring set)."""
    text = (f'profile {result.profile}' if not meas.rebuilt else
            'profile rebuilt from its speed and health statuses; read where the load is known')
    if meas.model_until_s is not None:
        text += f'; read before {meas.model_until_why} at {meas.model_until_s:.4g} s'
    return text


def run(args: argparse.Namespace) -> int:
    from dmf_sim.identify.fit import (
        TIED_MAX,
        IdentifyOptions,
        fitted_signals,
        identify,
        read_measurement,
    )
    from dmf_sim.live.warm import warm_up

    names = tuple(n.strip() for n in args.parameters.split(',') if n.strip())
    options = IdentifyOptions(parameters=names, signal=args.signal, starts=args.starts,
                              max_evaluations=args.max_evaluations, driveline=args.config,
                              engine=args.engine, load_set=args.load_set,
                              profile=args.profile, seed=args.seed)
    opt.check_cluster(args)
    dest = opt.output(args, NAME) if args.out is not None else None
    dask = args.workers is not None or args.scheduler
    if dask:
        from dmf_sim.core.optional import require_extra
        require_extra('design')             # dask, distributed: one line if missing
    meas = read_measurement(args.bag, options)
    warm_up(NAME, 'bag reading', 'time integration')
    cluster = client = None
    if dask:
        from dmf_sim.cluster import close_local, connect, start_local
        if args.scheduler:
            client = connect(args.scheduler, args.connect_timeout)
        else:
            cluster, client = start_local(args.workers)
    try:
        result = identify(meas, options, client=client)
    finally:
        if cluster is not None:
            close_local(cluster, client)
        elif client is not None:
            client.close()
    written = []
    if dest is not None:
        from dmf_sim.identify.plots import plot_identification
        with dest.writing() as out:
            path = out / 'identify.json'
            write_json(path, result.as_dict(), indent=2)
            written.append(path)
            written.append(plot_identification(result, *fitted_signals(result, meas),
                                               out / 'identify.png'))
    if args.json:
        print(json_text(result.as_dict()))
        return 0
    print(f'{result.bag}: {result.samples} samples of the {result.signal} '
          f'({_run_text(meas, result)}), '
          f'{result.evaluations} simulations from {len(result.starts)} starts, '
          f'{result.seconds:.1f} s')
    for n in result.parameters:
        print(value_line(result, n))
    print(f'  rms residual {result.rms:.3g} {result.unit} (at the start {result.rms_initial:.3g})')
    print(f'  identifiability {result.identifiability:.2g} (the smallest over the largest '
          f'singular value of the parameters\' effects; below {TIED_MAX:g} they are refused as '
          'tied)')
    for path in written:
        print(f'wrote {path}')
    return 0
