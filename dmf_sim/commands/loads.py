"""``dmf-sim loads``: engine mean torque over speed for Loads A/B/C (paper Fig. 8 left), the order
content of the engine torque at one speed, and the torque before the flywheel of the
conventional driveline over the engine cycle (Fig. 8 right)."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from dmf_sim.commands.sweep import check_grid
from dmf_sim.core.errors import ConfigError
from dmf_sim.physics.engine import LOAD_SETS, engine_torque_orders, load_engine

NAME = 'loads'
HELP = ('Engine mean torque [Nm] over speed [rpm] for load sets A/B/C (Fig. 8 left), the order '
        'content of the engine torque at a speed, and the torque before the flywheel of the '
        'conventional driveline over the engine cycle (Fig. 8 right).')

FIG8_SPEEDS_RPM = (800.0, 1000.0, 1200.0, 1400.0)   # default speeds of Fig. 8 right [rpm]
FIG8_DRIVELINE = 'truck_conventional'
FIG8_ELEMENT = 'FLYWHEEL'
CYCLE_SAMPLES = 720                                   # samples per 720 deg cycle (1 deg)
MAX_TORQUE_SPEEDS = 12


def add_arguments(p) -> None:
    p.add_argument('--engine', default='engine_d13',
                   help='engine YAML or A_n table (CSV/YAML); default engine_d13 (2800 Nm), '
                        'engine_d13_2500nm the 2500 Nm rating')
    p.add_argument('--load-set', nargs='+', default=list(LOAD_SETS), choices=list(LOAD_SETS),
                   help='load sets (default: all)')
    p.add_argument('--load', type=float, default=1.0, help='load fraction 0..1 (default 1)')
    p.add_argument('--speeds', type=float, nargs=3, default=[600.0, 2000.0, 50.0],
                   metavar=('FROM', 'TO', 'STEP'), help='speed range [rpm] (default 600 2000 50)')
    p.add_argument('--speed', type=float, default=1000.0,
                   help='speed [rpm] for the order table (default 1000)')
    p.add_argument('--torque-speeds', type=float, nargs='+', default=list(FIG8_SPEEDS_RPM),
                   help=f'speeds [rpm] of the torque before the flywheel (conventional driveline, '
                        f'first load set; default {" ".join(f"{s:g}" for s in FIG8_SPEEDS_RPM)}; '
                        f'at most {MAX_TORQUE_SPEEDS})')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    p.add_argument('--out', type=Path,
                   help='directory for loads.csv, loads.json, loads.png (mean torque, orders) and '
                        'fig8.png (mean torque, torque before the flywheel)')


def element_torque_over_cycle(loads, speed_rpm: float, load: float, element: str,
                              n_samples: int = CYCLE_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state torque [Nm] transmitted into ``element`` over one 720 deg cycle of a linear
    driveline (``loads.model`` without DMF): harmonic response per half order (eq. 5), then the
    model's torque read-out (ReducedModel.transmitted_torques). Returns (psi [deg], torque)."""
    from dmf_sim.core.units import CYCLE_RAD, RPM_TO_RAD_S
    from dmf_sim.physics.harmonic import solve_harmonic, solve_static
    from dmf_sim.physics.orders import synthesize
    m = loads.model
    if m.spring is not None:
        raise ConfigError(f'driveline {m.line.name!r}: the torque over the cycle is computed for '
                          'a linear driveline (no dmf section)')
    col = m.line.index(element)
    P = loads.dof_harmonics(speed_rpm, load)
    om = np.arange(P.shape[0]) * (speed_rpm * RPM_TO_RAD_S / 2.0)       # Om_n = n omega / 2
    Q = np.empty_like(P)
    Q[0] = solve_static(m, P[0].real)
    for n in range(1, P.shape[0]):
        Q[n] = solve_harmonic(m, om[n], P[n])
    q, qd, qdd = (synthesize(c.T, n_samples).T for c in (Q, 1j * om[:, None] * Q,
                                                         -(om ** 2)[:, None] * Q))
    psi = CYCLE_RAD * np.arange(n_samples) / n_samples
    torque = m.transmitted_torques(q, qd, qdd, loads.element_loads(psi, speed_rpm, load))
    return np.degrees(psi), torque[:, col]


def torque_before_flywheel(engine, speeds_rpm, load: float) -> tuple[np.ndarray, dict]:
    """Paper Fig. 8 right: torque into the flywheel of the conventional driveline [Nm] over the
    crank angle [deg], per speed [rpm]."""
    from dmf_sim.physics.loads import DrivelineLoads
    from dmf_sim.physics.model import load_model
    loads = DrivelineLoads(load_model(FIG8_DRIVELINE), engine)
    out = {}
    psi = None
    for s in speeds_rpm:
        psi, out[float(s)] = element_torque_over_cycle(loads, float(s), load, FIG8_ELEMENT)
    return psi, out


def mean_torques(engines: dict, speeds: np.ndarray, load: float) -> dict[str, list[float]]:
    """Whole-engine mean torque [Nm] over ``speeds`` per load set."""
    return {s: [float(e.mean_torque(v, load)) for v in speeds] for s, e in engines.items()}


def run(args) -> int:
    if not 0.0 <= args.load <= 1.0:
        raise ConfigError(f'--load={args.load}: allowed range 0..1')
    lo, hi, step = args.speeds
    engines = {s: load_engine(args.engine, load_set=s) for s in dict.fromkeys(args.load_set)}
    first = engines[args.load_set[0]]
    check_grid(lo, hi, step, first)
    if len(args.torque_speeds) > MAX_TORQUE_SPEEDS:
        raise ConfigError(f'--torque-speeds: {len(args.torque_speeds)} speeds, allowed at most '
                          f'{MAX_TORQUE_SPEEDS}')
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
    if args.out:
        psi, tq = torque_before_flywheel(first, args.torque_speeds, args.load)
        data['torque_before_flywheel'] = {
            'driveline': FIG8_DRIVELINE, 'element': FIG8_ELEMENT, 'load_set': args.load_set[0],
            'crank_angle_deg': psi.tolist(),
            'torque_nm': {f'{s:g}': v.tolist() for s, v in tq.items()}}
        _write(args.out, data, speeds, mean, orders, args, psi, tq)
    if args.json:
        print(json.dumps(data))
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


def fig8(mean_speeds, mean, load: float, psi_deg, torque: dict, load_set: str, engine: str):
    """Paper Fig. 8: mean torque of the load sets (left), torque before the flywheel of the
    conventional driveline over the engine cycle (right)."""
    from dmf_sim.figures import mean_torque_panel, torque_over_angle_panel, two_panel_figure
    fig, left, right = two_panel_figure(f'Engine loads, engine {engine} (paper Fig. 8)')
    mean_torque_panel(left, mean_speeds, mean, load)
    torque_over_angle_panel(right, psi_deg, torque,
                            f'Torque into the flywheel, conventional driveline, Load {load_set}, '
                            f'load {load:g} (Fig. 8 right)')
    return fig


def _write(out: Path, data: dict, speeds, mean, orders, args, psi, tq) -> None:
    from dmf_sim.figures import mean_torque_panel, order_bars_panel, save, two_panel_figure
    out.mkdir(parents=True, exist_ok=True)
    (out / 'loads.json').write_text(json.dumps(data, indent=2))
    with open(out / 'loads.csv', 'w', newline='') as fh:
        w = csv.writer(fh)
        w.writerow(['speed_rpm', *[f'mean_torque_{s}_nm' for s in mean]])
        for i, v in enumerate(speeds):
            w.writerow([v, *[mean[s][i] for s in mean]])
    fig, left, right = two_panel_figure(f'Engine loads, engine {args.engine}', width=11.0)
    mean_torque_panel(left, speeds, mean, args.load)
    order_bars_panel(right, orders, args.speed, args.load_set[0], args.load)
    save(fig, out / 'loads.png')
    save(fig8(speeds, mean, args.load, psi, tq, args.load_set[0], args.engine), out / 'fig8.png')
