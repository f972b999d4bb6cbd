"""``dmf-sim steady``: every steady state at one operating point, its stability and basin."""
from __future__ import annotations

from dmf_sim.commands import _options as opt
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text
from dmf_sim.core.validation import SEED_MAX

__all__ = ['NAME', 'HELP', 'SEED_MAX', 'LIMITS', 'add_arguments', 'run']

NAME = 'steady'
HELP = ('Every steady state of the DMF wind-up at one engine speed and load (harmonic balance '
        'search: continuation, deflated Newton, Newmark shots), with orders, Fig. 13 quantities, '
        'Floquet stability and a basin estimate: the share of random initial states that Newmark '
        'carries to each state, with a Wilson 95 per cent confidence interval.')

LIMITS = {'samples': (0, 10000), 'window': (1.0, 300.0),
          'amplitude': (1e-4, 1.0), 'max_cycles': (10, 5000), 'seed': (0, SEED_MAX)}


def add_arguments(p) -> None:
    p.add_argument('--speed', type=float, required=True, help='engine speed [rpm]')
    opt.add_load(p)
    opt.add_config(p)
    opt.add_engine(p)
    opt.add_load_set(p)
    opt.add_alpha(p)
    opt.add_theta(p)
    p.add_argument('--samples', type=int, default=200,
                   help='random initial states for the basin estimate (default 200; 0 = none)')
    p.add_argument('--amplitude', type=float,
                   help='half-range A [rad] of the random wind-up offsets (default: twice the '
                        'largest 3rd-order amplitude, at least 0.02 rad)')
    p.add_argument('--seed', type=int, default=0,
                   help=f'random generator seed 0..{SEED_MAX} (default 0)')
    p.add_argument('--max-cycles', type=int, default=200,
                   help='engine cycles per basin run (default 200)')
    p.add_argument('--window', type=float, default=30.0,
                   help='half-width [rpm] of the speed window the search continues over '
                        '(default 30)')
    opt.add_harmonics(p)
    opt.add_steady_faults(p)
    p.add_argument('--no-progress', action='store_true', help='no progress bar on stderr')
    p.add_argument('--json', action='store_true', help='print one JSON object to stdout')


def _check(args) -> None:
    opt.check_common(args)
    for name, (lo, hi) in LIMITS.items():
        value = getattr(args, name)
        if value is not None and not lo <= value <= hi:
            raise ConfigError(f'--{name.replace("_", "-")} {value!r}: '
                              f'allowed range {lo:.12g}..{hi:.12g}')


def run(args) -> int:
    from dmf_sim.live.warm import warm_up
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_driveline
    from dmf_sim.solvers.hbm import HBMOptions
    from dmf_sim.solvers.steady import BasinOptions, find_steady_states

    _check(args)
    line = read_driveline(args.config, alpha=args.alpha, theta=args.theta)
    if line.dmf is None:
        raise ConfigError(f'driveline {line.name!r} has no dmf section: nothing to search')
    faults = opt.steady_faults(args.faults, line)
    loads = DrivelineExcitation(line.reduce(), read_engine(args.engine, load_set=args.load_set))
    opt.check_load(loads.engine, args.load)
    warm_up(NAME, 'sweep', 'time integration')
    res = find_steady_states(
        loads, args.speed, args.load, window_rpm=args.window,
        hbm_options=HBMOptions(n_harmonics=args.harmonics),
        basin=BasinOptions(samples=args.samples, amplitude_rad=args.amplitude, seed=args.seed,
                           max_cycles=args.max_cycles),
        progress=not args.no_progress, faults=faults)
    data = res.as_dict()
    data.update(driveline=line.name, engine=str(args.engine), load_set=args.load_set,
                alpha=line.spring.alpha, theta_rad=line.spring.theta)
    if args.json:
        print(json_text(data))
        return 0
    print(f'{line.name}, {args.engine} Load {args.load_set}: {args.speed:g} rpm, '
          f'load {args.load:g}, '
          f'alpha {line.spring.alpha:g}, theta {line.spring.theta:g} rad ({res.seconds:.1f} s); '
          'wind-up in mrad')
    if faults:
        print(f'faults (every cycle): {faults.text()}')
    half = (f'{"0.5th":>7} {"1st":>7} ' if faults else '')    # cylinders that differ excite them
    print(f'{"state":>11} {"stable":>6} {"twins":>5} {half}{"3rd":>7} {"1.5th":>7} '
          f'{"max dev":>8} {"min dev":>8} {"mean-th":>8}  basin share [95 % CI]')
    for st in res.states:
        s, p = st.point.summary, st.point
        basin = ''
        if res.samples:
            d = st.as_dict(res.samples)['basin']
            basin = ('-  (unstable: attracts no run)' if d is None else
                     f'{d["share"]:5.1%} [{d["ci95"][0]:.1%}, {d["ci95"][1]:.1%}]')
        c = p.windup_orders
        low = f'{abs(c[1]) * 1e3:7.2f} {abs(c[2]) * 1e3:7.2f} ' if faults else ''
        print(f'{st.kind:>11} {str(p.stable):>6} {st.multiplicity:5d} {low}{s.order_3 * 1e3:7.2f} '
              f'{s.order_1_5 * 1e3:7.2f} {s.max_deviation * 1e3:8.2f} '
              f'{s.min_deviation * 1e3:8.2f} {s.mean_minus_theta * 1e3:8.2f}  {basin}')
    if res.samples:
        print(f'basin: {res.samples} runs from wind-up offsets '
              f'within +-{res.amplitude_rad * 1e3:.1f} mrad '
              f'(rates within +-{res.rate_rad_s:.2f} rad/s); {res.unsettled} did not settle')
    for r in res.non_periodic:       # the search's time integration, before the basin runs
        what = ('no stable periodic state' if not res.stable else    # found by the basin runs
                'beside them a non-periodic motion')
        print(f'{what}: {r.label}; wind-up {r.mean * 1e3:.1f} mrad '
              f'{r.max_deviation * 1e3:+.1f}/{r.min_deviation * 1e3:+.1f} mrad, '
              f'3rd order {r.order_3 * 1e3:.2f}, 1.5th {r.order_1_5 * 1e3:.2f} mrad '
              '(time integration)')
    if not res.stable:
        print('no stable periodic steady state at this operating point')
    return 0
