"""``dmf-sim sweep``: steady-state DMF wind-up over engine speed by condensed harmonic balance with
continuation and Floquet stability (paper Fig. 13 and 15)."""
from __future__ import annotations

import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from dmf_sim.commands import _options as opt
from dmf_sim.core.csv_out import write_csv
from dmf_sim.core.errors import ConfigError, ConvergenceError, DmfSimError, one_line
from dmf_sim.core.json_out import json_text, write_json

__all__ = ['NAME', 'HELP', 'CSV_FIELDS', 'FAULT_CSV_FIELDS', 'FIG15_ALPHA', 'MAX_SWEEPS',
           'add_arguments', 'run', 'sweep_dict', 'figures']

NAME = 'sweep'
HELP = ('Speed sweep of the DMF wind-up (3rd / 1.5th order amplitude, max/min deviation, theta - '
        'static wind-up; rad) by harmonic balance + continuation, all branches with Floquet '
        'stability (Fig. 13/15).')

CSV_FIELDS = ['alpha', 'load_set', 'load', 'speed_rpm', 'branch', 'kind', 'stable', 'order_3',
              'order_1_5', 'max_deviation', 'min_deviation', 'theta_minus_static', 'static_windup',
              'mean_minus_theta', 'mean', 'max_multiplier', 'forced_order_1_5', 'multiplicity',
              'label', 'instability']
FAULT_CSV_FIELDS = ['order_0_5', 'order_1']   # with --faults: what unlike cylinders excite
FIG15_ALPHA = 2.5

MAX_SWEEPS = 24                  # alpha values x load sets


def add_arguments(p) -> None:
    opt.add_config(p)
    opt.add_engine(p)
    opt.add_alpha(p, many=True)
    opt.add_theta(p)
    opt.add_load_set(p, many=True)
    opt.add_load(p)
    opt.add_speeds(p)
    opt.add_harmonics(p)
    opt.add_steady_faults(p)
    p.add_argument('--no-stability', action='store_true',
                   help='skip Floquet stability (and branch switching)')
    p.add_argument('--no-branch-switching', action='store_true',
                   help='follow the branch from the lowest speed only')
    p.add_argument('--fast', action='store_true',
                   help='continuation, stability and branch switching only: skip the full search '
                        'for every stable state (deflated Newton seeds, Newmark shots, '
                        'non-periodic speeds)')
    p.add_argument('--newmark-seed', action='store_true',
                   help='when Newton seeding fails at a sub-harmonic instability, integrate in '
                        'time (slower)')
    p.add_argument('--time-limit', type=float, metavar='S',
                   help='wall-clock limit of each sweep [s]; a case that reaches it is reported '
                        'as failed (phase and speed reached) and the others go on')
    p.add_argument('--no-progress', action='store_true', help='no progress bar on stderr')
    p.add_argument('--json', action='store_true', help='print one JSON object to stdout')
    p.add_argument('--out', type=Path,
                   help='directory for sweep.csv, sweep.json and the figures, every computed '
                        'case in one: fig13.png (every alpha, first load set), '
                        'fig13_load_<X>.png (each further load set) and, with several load sets, '
                        'fig15.png (every load set at alpha 2.5 or the first --alpha), '
                        'fig15_alpha_<a>.png (each further alpha); the printed summary lists '
                        'which cases each figure holds')
    opt.add_overwrite(p)


def run(args) -> int:
    from dmf_sim.live.warm import warm_up
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_driveline
    from dmf_sim.solvers.hbm import HBMOptions, SweepOptions, sweep
    from dmf_sim.solvers.hbm.sweep import check_time_limit

    opt.check_common(args)
    lo, hi, step = args.speeds
    time_limit = check_time_limit(args.time_limit, '--time-limit')
    if len(args.alpha or [None]) * len(args.load_set) > MAX_SWEEPS:
        raise ConfigError(f'--alpha x --load-set: {len(args.alpha) * len(args.load_set)} sweeps, '
                          f'allowed at most {MAX_SWEEPS}')
    dest = opt.output(args, NAME) if args.out is not None else None
    line = read_driveline(args.config, theta=args.theta)
    if line.dmf is None:
        raise ConfigError(f'driveline {line.name!r} has no dmf section: nothing to sweep')
    alphas = args.alpha if args.alpha else [line.dmf.alpha]
    faults = opt.steady_faults(args.faults, line)
    engines = {}
    for ls in dict.fromkeys(args.load_set):
        engines[ls] = read_engine(args.engine, load_set=ls)
        opt.check_load(engines[ls], args.load)
        opt.check_grid(lo, hi, step, engines[ls])

    hopt = HBMOptions(n_harmonics=args.harmonics)
    sopt = SweepOptions(step_rpm=step, stability=not args.no_stability,
                        branch_switching=not args.no_branch_switching,
                        newmark_seed=args.newmark_seed, time_limit_s=time_limit)
    if args.fast:
        sopt = replace(sopt, search=None)
    warm_up(NAME, 'sweep')       # before the bars: their rate without a first compile
    results, failures = [], []
    for ls, eng in engines.items():
        for a in alphas:
            model = line.with_dmf(alpha=a).reduce()
            try:
                res = sweep(DrivelineExcitation(model, eng), args.load, (lo, hi), hbm_options=hopt,
                            options=sopt, progress=not args.no_progress,
                            label=f'alpha={a:g}, Load {ls}', faults=faults)
            except (DmfSimError, np.linalg.LinAlgError) as exc:     # one case lost, not the run
                failures.append({'alpha': a, 'load_set': ls, 'error': one_line(exc)})
                print(f'dmf-sim sweep: alpha={a:g}, Load {ls} failed: {one_line(exc)}',
                      file=sys.stderr)
                continue
            results.append((a, ls, res))
    if not results:
        raise ConvergenceError('every case failed: ' + '; '.join(
            f'alpha={f["alpha"]:g} Load {f["load_set"]}: {f["error"]}' for f in failures))

    data = {
        'driveline': line.name, 'engine': str(args.engine), 'load': args.load,
        'theta_rad': line.dmf.theta, 'speeds_rpm': [lo, hi, step], 'n_harmonics': args.harmonics,
        'faults': faults.text() if faults else None,
        'units': 'wind-up quantities in rad (positive when the engine drives); speed in rpm; '
                 'theta_minus_static = theta - static wind-up of the mean torque (the paper\'s '
                 'green line), mean = dynamic mean wind-up',
        'sweeps': [sweep_dict(a, ls, r) for a, ls, r in results],
        'failed': failures,
    }
    if dest is not None:
        with dest.writing() as out:
            data['files'] = _write(out, data, results)
    if args.json:
        print(json_text(data))
    else:
        _print_summary(data, results)
    return 0


def sweep_dict(alpha: float, load_set: str, res) -> dict:
    """``SweepResult.as_dict`` with alpha and load set on the sweep and on every point."""
    d = res.as_dict()
    d['alpha'] = alpha
    d['load_set'] = load_set
    for row in d['points']:
        row['alpha'], row['load_set'] = alpha, load_set
    return d


def _print_summary(data: dict, results) -> None:
    from dmf_sim.solvers.hbm.results import instability_text
    lo, hi, step = data['speeds_rpm']
    print(f'{data["driveline"]}: harmonic balance sweep {lo:g}-{hi:g} rpm (grid {step:g} rpm), '
          f'engine {data["engine"]}, load {data["load"]:g}, theta {data["theta_rad"]:g} rad, '
          f'H = {data["n_harmonics"]}; wind-up in rad')
    if data.get('faults'):
        print(f'faults (every cycle, held over the sweep): {data["faults"]}')
    print(f'{"alpha":>6} {"load":>4} {"points":>6} {"branches":>8} {"time [s]":>8} '
          f'{"max 3rd order @ rpm":>22}   1.5th-order resonance (branch: rpm range, peak @ rpm)')
    for a, ls, r in results:
        main = r.main()
        o3 = main.column('order_3')
        k = int(np.argmax(o3))
        subs = r.subharmonic_summary()
        txt = '; '.join(f'{s["branch"]}: {s["speed_min_rpm"]:.0f}-{s["speed_max_rpm"]:.0f}, '
                        f'{s["peak_order_1_5_rad"]:.4f} @ {s["peak_speed_rpm"]:.0f}'
                        for s in subs) or 'none'
        peak = f'{o3[k]:.4f} @ {main.points[k].speed_rpm:.0f}'
        print(f'{a:6g} {ls:>4} {r.n_points:6d} {len(r.branches):8d} {r.seconds:8.2f} {peak:>22}'
              f'   {txt}')
        if data.get('faults'):
            half = [abs(p.windup_orders[1]) for p in main.points]
            j = int(np.argmax(half))
            print(f'{"":>6} {"":>4} max 0.5th order {half[j]:.4f} @ '
                  f'{main.points[j].speed_rpm:.0f} rpm (branch 0)')
    for a, ls, r in results:
        for e in r.events:
            print(f'  alpha={a:g} Load {ls}: {e.kind} on branch {e.branch} at {e.speed_rpm:.1f} '
                  f'rpm  {e.detail}')
        for b in r.non_periodic:
            speeds = ', '.join(f'{x.speed_rpm:g}' for x in b.results)
            env = max(b.results, key=lambda x: x.max_deviation - x.min_deviation)
            print(f'  alpha={a:g} Load {ls}: no stable periodic state at {speeds} rpm '
                  f'({instability_text(b.instability)}); time integration: '
                  f'{b.results[0].describe()}; '
                  f'wind-up swings up to {env.max_deviation:+.4f}/{env.min_deviation:+.4f} rad '
                  f'at {env.speed_rpm:g} rpm (envelope per speed in the CSV/JSON)')
        for m in r.sharp_resonances:
            print(f'  alpha={a:g} Load {ls}: sharp resonance at {m["speed_rpm"]:.1f} rpm: order '
                  f'{m["order"]:g} meets the {m["frequency_hz"]:.1f} Hz mode (damping ratio '
                  f'{m["damping_ratio"]:.2%}; {m["share"]:.0%} of the linear wind-up there), '
                  'labelled in the figures')
        for nc in r.not_computed:
            at = 'every speed' if nc['speed_rpm'] is None else f'{nc["speed_rpm"]:g} rpm'
            print(f'  alpha={a:g} Load {ls}: not computed at {at}: {nc["reason"]}')
        if r.uncovered:
            print(f'  alpha={a:g} Load {ls}: no branch reached '
                  f'{", ".join(f"{s:g}" for s in r.uncovered)} rpm')
    for f in data.get('failed', []):
        print(f'  alpha={f["alpha"]:g} Load {f["load_set"]}: FAILED: {f["error"]}')
    for name, cases in data.get('figures', {}).items():
        print(f'  {name}: {", ".join(cases)}')


def _case(a: float, ls: str) -> str:
    return f'α {a:g} Load {ls}'


def figures(data: dict, results) -> dict[str, tuple]:
    """Every computed case in a figure (paper Figs. 13 and 15): ``fig13`` holds every alpha of
    the first load set, ``fig13_load_<X>`` those of each further load set; with several load
    sets ``fig15`` holds every load set at alpha 2.5 (or the first alpha), ``fig15_alpha_<a>``
    those at each further alpha. Returns {name: (Figure, cases drawn)}; each figure's title
    names the figures holding the other cases."""
    from dmf_sim.figures import panel_title, sweep_panel, windup_figure
    theta, load = data['theta_rad'], data['load']
    load_sets = list(dict.fromkeys(ls for _, ls, _ in results))
    alphas = list(dict.fromkeys(a for a, _, _ in results))
    groups = {}                     # name -> (title, [(alpha, load set, result)])
    for i, ls in enumerate(load_sets):
        groups['fig13' if i == 0 else f'fig13_load_{ls}'] = (
            f'DMF wind-up over engine speed, Load {ls}, load {load:g}, engine {data["engine"]} '
            '(paper Fig. 13)', [c for c in results if c[1] == ls])
    if len(load_sets) > 1:
        a15 = FIG15_ALPHA if FIG15_ALPHA in alphas else alphas[0]
        for a in [a15] + [x for x in alphas if x != a15]:
            groups['fig15' if a == a15 else f'fig15_alpha_{a:g}'] = (
                f'DMF wind-up over engine speed, α = {a:g}, Loads '
                f'{", ".join(load_sets)}, load {load:g} (paper Fig. 15)',
                [c for c in results if c[0] == a])
    out = {}
    for name, (title, cases) in groups.items():
        family = [n for n in groups if n.split('_')[0] == name.split('_')[0] and n != name]
        if family:
            title += f'; other cases: {", ".join(f + ".png" for f in family)}'
        panels = [sweep_panel(panel_title(a, theta, ls, load), r) for a, ls, r in cases]
        out[name] = (windup_figure(panels, title), [_case(a, ls) for a, ls, _ in cases])
    return out


def _write(out: Path, data: dict, results) -> dict:
    from dmf_sim.figures import save
    files = {'csv': str(out / 'sweep.csv'), 'json': str(out / 'sweep.json')}
    data['figures'] = {}
    for name, (fig, cases) in figures(data, results).items():
        files[name] = str(save(fig, out / f'{name}.png'))
        data['figures'][f'{name}.png'] = cases
    fields = CSV_FIELDS + (FAULT_CSV_FIELDS if data.get('faults') else [])
    write_csv(out / 'sweep.csv', fields, ({**row, 'load': data['load']}
                                          for sw in data['sweeps'] for row in sw['points']))
    write_json(out / 'sweep.json', {**data, 'files': files})
    return files
