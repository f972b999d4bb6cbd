"""``dmf-sim loads``: engine mean torque over speed for Loads A/B/C (paper Fig. 8 left), the order
content of the engine torque at one speed, and the torque before the flywheel of the
conventional driveline over the engine cycle (Fig. 8 right)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from dmf_sim.commands import _options as opt
from dmf_sim.core.csv_out import write_csv
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text, write_json
from dmf_sim.physics.cycle_torque import (
    FIG8_DRIVELINE,
    FIG8_ELEMENT,
    FIG8_SPEEDS_RPM,
    mean_torques,
    torque_before_flywheel,
)
from dmf_sim.physics.engine import LOAD_SETS, engine_torque_orders, read_engine

__all__ = ['NAME', 'HELP', 'MAX_TORQUE_SPEEDS', 'add_arguments', 'run']

NAME = 'loads'
HELP = ('Engine mean torque [Nm] over speed [rpm] for load sets A/B/C (Fig. 8 left), the order '
        'content of the engine torque at a speed, and the torque before the flywheel of the '
        'conventional driveline over the engine cycle (Fig. 8 right).')

MAX_TORQUE_SPEEDS = 12


def add_arguments(p) -> None:
    opt.add_engine(p)
    opt.add_load_set(p, many=True, default=LOAD_SETS, help_default='all')
    opt.add_load(p)
    opt.add_speeds(p, default=(600.0, 2000.0, 50.0), what='speed range')
    p.add_argument('--speed', type=float, default=1000.0,
                   help='speed [rpm] for the order table (default 1000)')
    p.add_argument('--torque-speeds', type=float, nargs='+',
                   help=f'speeds [rpm] of the torque before the flywheel in fig8.png and '
                        f'loads.json (conventional driveline, first load set; with --out; '
                        f'default {" ".join(f"{s:g}" for s in FIG8_SPEEDS_RPM)}; at most '
                        f'{MAX_TORQUE_SPEEDS})')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    p.add_argument('--out', type=Path,
                   help='directory for loads.csv, loads.json, loads.png (mean torque, orders) and '
                        'fig8.png (mean torque, torque before the flywheel)')
    opt.add_overwrite(p)


def run(args) -> int:
    opt.check_common(args)
    torque_speeds = list(FIG8_SPEEDS_RPM) if args.torque_speeds is None else args.torque_speeds
    if len(torque_speeds) > MAX_TORQUE_SPEEDS:
        raise ConfigError(f'--torque-speeds: {len(torque_speeds)} speeds, allowed at most '
                          f'{MAX_TORQUE_SPEEDS}')
    if args.torque_speeds is not None and args.out is None:
        raise ConfigError('--torque-speeds: the torque before the flywheel goes to fig8.png and '
                          'loads.json in --out DIR; give --out too')
    dest = opt.output(args, NAME) if args.out is not None else None
    lo, hi, step = args.speeds
    engines = {s: read_engine(args.engine, load_set=s) for s in dict.fromkeys(args.load_set)}
    first = engines[args.load_set[0]]
    opt.check_load(first, args.load)
    opt.check_grid(lo, hi, step, first)
    _check_speeds(first, [('--speed', args.speed)]
                  + [('--torque-speeds', s) for s in torque_speeds])
    speeds = np.arange(lo, hi + 0.5 * step, step)
    mean = mean_torques(engines, speeds, args.load)
    whole = engine_torque_orders(first, args.speed, args.load)
    cyl = first.coefficients(args.speed, args.load)
    orders = [{'order': n / 2, 'half_order_index': n, 'engine_nm': float(abs(whole[n])),
               'cylinder_nm': float(abs(cyl[n]))} for n in range(len(cyl))]
    data = {'engine': args.engine, 'load': args.load, 'speeds_rpm': speeds.tolist(),
            'mean_torque_nm': mean,
            'orders_at_speed': {'speed_rpm': args.speed, 'load_set': args.load_set[0],
                                'orders': orders}}
    if dest is not None:
        psi, tq = torque_before_flywheel(first, torque_speeds, args.load)
        data['torque_before_flywheel'] = {
            'driveline': FIG8_DRIVELINE, 'element': FIG8_ELEMENT, 'load_set': args.load_set[0],
            'crank_angle_deg': psi.tolist(),
            'torque_nm': {f'{s:g}': v.tolist() for s, v in tq.items()}}
        with dest.writing() as out:
            _write(out, data, speeds, mean, orders, args, psi, tq)
    if args.json:
        print(json_text(data))
    else:
        print(f'engine mean torque [Nm] at load {args.load:g}')
        print('speed_rpm ' + ' '.join(f'{s:>9}' for s in mean))
        for i, v in enumerate(speeds):
            print(f'{v:9.0f} ' + ' '.join(f'{mean[s][i]:9.1f}' for s in mean))
        print(f'\norders at {args.speed:g} rpm (load set {args.load_set[0]}), amplitudes [Nm]')
        print(f'{"order":>6} {"engine (rigid crank)":>21} {"one cylinder":>13}')
        for o in orders:
            print(f'{o["order"]:6.1f} {o["engine_nm"]:21.1f} {o["cylinder_nm"]:13.1f}')
    return 0


def _check_speeds(engine, speeds) -> None:
    """Each (option, speed [rpm]) finite and within the engine's data."""
    lo, hi = getattr(engine, 'speed_range_rpm', None) or (0.0, math.inf)
    for option, s in speeds:
        if not (math.isfinite(s) and s > 0 and lo <= s <= hi):
            raise ConfigError(f'{option} {s:g}: allowed {lo:g}..{hi:g} rpm (the engine data)')


def _write(out: Path, data: dict, speeds, mean, orders, args, psi, tq) -> None:
    from dmf_sim.figures import fig8, mean_torque_panel, order_bars_panel, save, two_panel_figure
    write_json(out / 'loads.json', data, indent=2)
    write_csv(out / 'loads.csv', ['speed_rpm', *[f'mean_torque_{s}_nm' for s in mean]],
              ([v, *[mean[s][i] for s in mean]] for i, v in enumerate(speeds)))
    fig, left, right = two_panel_figure(f'Engine loads, engine {args.engine}', width=11.0)
    mean_torque_panel(left, speeds, mean, args.load)
    order_bars_panel(right, orders, args.speed, args.load_set[0], args.load)
    save(fig, out / 'loads.png')
    save(fig8(speeds, mean, args.load, psi, tq, args.load_set[0], args.engine), out / 'fig8.png')
