"""``dmf-sim loads``: engine mean torque over speed for Loads A/B/C (paper Fig. 8 left) and the
order content of the engine torque at one speed."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from dmf_sim.errors import ConfigError
from dmf_sim.engine import LOAD_SETS, engine_torque_orders, load_engine

NAME = 'loads'
HELP = ('Engine mean torque [Nm] over speed [rpm] for load sets A/B/C (Fig. 8 left) and the order '
        'content of the engine torque at a speed.')


def add_arguments(p) -> None:
    p.add_argument('--engine', default='engine_d13', help='engine YAML or A_n table (CSV/YAML); default engine_d13')
    p.add_argument('--load-set', nargs='+', default=list(LOAD_SETS), choices=list(LOAD_SETS),
                   help='load sets (default: all)')
    p.add_argument('--load', type=float, default=1.0, help='load fraction 0..1 (default 1)')
    p.add_argument('--speeds', type=float, nargs=3, default=[600.0, 2000.0, 50.0],
                   metavar=('FROM', 'TO', 'STEP'), help='speed range [rpm] (default 600 2000 50)')
    p.add_argument('--speed', type=float, default=1000.0, help='speed [rpm] for the order table (default 1000)')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    p.add_argument('--out', type=Path, help='directory for loads.csv, loads.json, loads.png')


def run(args) -> int:
    if not 0.0 <= args.load <= 1.0:
        raise ConfigError(f'--load={args.load}: allowed range 0..1')
    lo, hi, step = args.speeds
    if not (step > 0 and hi >= lo):
        raise ConfigError('--speeds FROM TO STEP: need TO >= FROM and STEP > 0 rpm')
    speeds = np.arange(lo, hi + 0.5 * step, step)
    engines = {s: load_engine(args.engine, load_set=s) for s in args.load_set}
    mean = {s: [float(e.mean_torque(v, args.load)) for v in speeds] for s, e in engines.items()}
    first = engines[args.load_set[0]]
    whole = engine_torque_orders(first, args.speed, args.load)
    cyl = first.coefficients(args.speed, args.load)
    orders = [{'order': n / 2, 'half_order_index': n, 'engine_nm': float(abs(whole[n])),
               'cylinder_nm': float(abs(cyl[n]))} for n in range(len(cyl))]
    data = {'engine': args.engine, 'load': args.load, 'speeds_rpm': speeds.tolist(),
            'mean_torque_nm': mean, 'orders_at_speed': {'speed_rpm': args.speed,
                                                        'load_set': args.load_set[0], 'orders': orders}}
    if args.json:
        print(json.dumps(data))
    else:
        print(f'engine mean torque [Nm] at load {args.load:g}')
        print('speed_rpm ' + ' '.join(f'{s:>9}' for s in args.load_set))
        for i, v in enumerate(speeds):
            print(f'{v:9.0f} ' + ' '.join(f'{mean[s][i]:9.1f}' for s in args.load_set))
        print(f'\norders at {args.speed:g} rpm (load set {args.load_set[0]}), amplitudes [Nm]')
        print(f'{"order":>6} {"engine (rigid crank)":>21} {"one cylinder":>13}')
        for o in orders:
            print(f'{o["order"]:6.1f} {o["engine_nm"]:21.1f} {o["cylinder_nm"]:13.1f}')
    if args.out:
        args.out.mkdir(parents=True, exist_ok=True)
        (args.out / 'loads.json').write_text(json.dumps(data, indent=2))
        with open(args.out / 'loads.csv', 'w', newline='') as fh:
            w = csv.writer(fh)
            w.writerow(['speed_rpm', *[f'mean_torque_{s}_nm' for s in args.load_set]])
            for i, v in enumerate(speeds):
                w.writerow([v, *[mean[s][i] for s in args.load_set]])
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4))
        for s in args.load_set:
            a1.plot(speeds, mean[s], label=f'Load {s}')
        a1.set_xlabel('engine speed [rpm]')
        a1.set_ylabel('mean torque [Nm]')
        a1.set_title('Engine mean torque (Fig. 8 left)')
        a1.legend()
        a1.grid(alpha=0.3)
        a2.bar([o['order'] for o in orders], [o['engine_nm'] for o in orders], width=0.35, label='engine')
        a2.bar([o['order'] + 0.2 for o in orders], [o['cylinder_nm'] for o in orders], width=0.2,
               label='one cylinder')
        a2.set_xlabel('engine order')
        a2.set_ylabel('torque amplitude [Nm]')
        a2.set_title(f'Order content at {args.speed:g} rpm')
        a2.legend()
        a2.grid(alpha=0.3)
        fig.tight_layout()
        fig.savefig(args.out / 'loads.png', dpi=120)
        plt.close(fig)
    return 0
