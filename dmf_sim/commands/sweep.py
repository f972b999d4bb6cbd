"""``dmf-sim sweep``: steady-state DMF wind-up over engine speed by condensed harmonic balance with
continuation and Floquet stability (paper Fig. 13 and 15)."""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np

from dmf_sim.errors import ConfigError, ConvergenceError, DmfSimError, one_line

NAME = 'sweep'
HELP = ('Speed sweep of the DMF wind-up (3rd / 1.5th order amplitude, max/min deviation, mean - theta; '
        'rad) by harmonic balance + continuation, all branches with Floquet stability (Fig. 13/15).')

CSV_FIELDS = ['alpha', 'load_set', 'load', 'speed_rpm', 'branch', 'kind', 'stable', 'order_3', 'order_1_5',
              'max_deviation', 'min_deviation', 'mean_minus_theta', 'mean', 'static_windup',
              'theta_minus_static', 'max_multiplier', 'forced_order_1_5', 'multiplicity', 'label']
FIG15_ALPHA = 2.5


def add_arguments(p) -> None:
    p.add_argument('--config', default='truck_dmf', help='driveline YAML name or path (default truck_dmf)')
    p.add_argument('--engine', default='engine_d13',
                   help='engine YAML or A_n table (CSV/YAML), as for `dmf-sim loads` (default engine_d13)')
    p.add_argument('--alpha', type=float, nargs='+',
                   help='DMF secondary stiffness factors, k(1+alpha) (default: the YAML value)')
    p.add_argument('--theta', type=float, help='DMF stiffness change angle [rad] (default: the YAML value)')
    p.add_argument('--load-set', nargs='+', default=['A'], help='load sets A/B/C (default A)')
    p.add_argument('--load', type=float, default=1.0, help='load fraction 0..1 (default 1)')
    p.add_argument('--speeds', type=float, nargs=3, default=[600.0, 2000.0, 10.0], metavar=('FROM', 'TO', 'STEP'),
                   help='speed range and output grid step [rpm] (default 600 2000 10)')
    p.add_argument('--harmonics', type=int, default=24,
                   help='highest half-order index H kept (default 24 = 12th engine order)')
    p.add_argument('--no-stability', action='store_true', help='skip Floquet stability (and branch switching)')
    p.add_argument('--no-branch-switching', action='store_true',
                   help='follow the branch from the lowest speed only')
    p.add_argument('--fast', action='store_true',
                   help='continuation, stability and branch switching only: skip the full search for '
                        'every stable state (deflated Newton seeds, Newmark shots, non-periodic speeds)')
    p.add_argument('--newmark-seed', action='store_true',
                   help='when Newton seeding fails at a sub-harmonic instability, integrate in time (slower)')
    p.add_argument('--no-progress', action='store_true', help='no progress bar on stderr')
    p.add_argument('--json', action='store_true', help='print one JSON object to stdout')
    p.add_argument('--out', type=Path,
                   help='directory for sweep.csv, sweep.json, fig13.png (one panel per alpha, first load set) '
                        'and, with several load sets, fig15.png (alpha 2.5 or the first --alpha, one panel per '
                        'load set)')


def run(args) -> int:
    from dmf_sim.engine import load_engine
    from dmf_sim.hbm import HBMOptions, SweepOptions, sweep
    from dmf_sim.loads import DrivelineLoads
    from dmf_sim.model import load_driveline

    lo, hi, step = args.speeds
    if not (step > 0 and hi > lo):
        raise ConfigError('--speeds FROM TO STEP: need TO > FROM and STEP > 0 rpm')
    if not 0.0 <= args.load <= 1.0:
        raise ConfigError(f'--load={args.load}: allowed range 0..1')
    if args.harmonics < 6:
        raise ConfigError(f'--harmonics={args.harmonics}: need >= 6 (the 3rd order is n = 6)')
    line = load_driveline(args.config, theta=args.theta)
    if line.dmf is None:
        raise ConfigError(f'driveline {line.name!r} has no dmf section: nothing to sweep')
    alphas = args.alpha if args.alpha else [line.dmf.alpha]
    for a in alphas:
        if not a >= 0:
            raise ConfigError(f'--alpha {a}: must be >= 0')
    engines = {}
    for ls in args.load_set:
        eng = load_engine(args.engine, load_set=ls)
        rng = getattr(eng, 'speed_range_rpm', None)
        if rng is not None and not (rng[0] <= lo and hi <= rng[1]):
            raise ConfigError(f'--speeds {lo:g} {hi:g}: engine data covers {rng[0]:g}..{rng[1]:g} rpm')
        engines[ls] = eng

    hopt = HBMOptions(n_harmonics=args.harmonics)
    sopt = SweepOptions(step_rpm=step, stability=not args.no_stability,
                        branch_switching=not args.no_branch_switching, newmark_seed=args.newmark_seed)
    if args.fast:
        sopt = SweepOptions(**{**sopt.__dict__, 'search': None})
    results, failures = [], []
    for ls, eng in engines.items():
        for a in alphas:
            model = line.with_dmf(alpha=a).reduce()
            try:
                res = sweep(DrivelineLoads(model, eng), args.load, (lo, hi), hbm_options=hopt,
                            options=sopt, progress=not args.no_progress, label=f'alpha={a:g}, Load {ls}')
            except (DmfSimError, np.linalg.LinAlgError) as exc:     # one case lost, not the run
                failures.append({'alpha': a, 'load_set': ls, 'error': one_line(exc)})
                print(f'dmf-sim sweep: alpha={a:g}, Load {ls} failed: {one_line(exc)}', file=sys.stderr)
                continue
            results.append((a, ls, res))
    if not results:
        raise ConvergenceError('every case failed: ' + '; '.join(
            f'alpha={f["alpha"]:g} Load {f["load_set"]}: {f["error"]}' for f in failures))

    data = {
        'driveline': line.name, 'engine': str(args.engine), 'load': args.load, 'theta_rad': line.dmf.theta,
        'speeds_rpm': [lo, hi, step], 'n_harmonics': args.harmonics,
        'units': 'wind-up quantities in rad (positive when the engine drives); speed in rpm',
        'sweeps': [_sweep_dict(a, ls, r) for a, ls, r in results],
        'failed': failures,
    }
    if args.out:
        data['files'] = _write(args.out, data, results, args)
    if args.json:
        print(json.dumps(data))
    else:
        _print_summary(data, results)
    return 0


def _sweep_dict(alpha: float, load_set: str, res) -> dict:
    d = res.as_dict()
    d['alpha'] = alpha
    d['load_set'] = load_set
    for row in d['points']:
        row['alpha'], row['load_set'] = alpha, load_set
    return d


def _print_summary(data: dict, results) -> None:
    print(f'{data["driveline"]}: harmonic balance sweep {data["speeds_rpm"][0]:g}-{data["speeds_rpm"][1]:g} rpm '
          f'(grid {data["speeds_rpm"][2]:g} rpm), load {data["load"]:g}, theta {data["theta_rad"]:g} rad, '
          f'H = {data["n_harmonics"]}; wind-up in rad')
    print(f'{"alpha":>6} {"load":>4} {"points":>6} {"branches":>8} {"time [s]":>8} {"max 3rd order @ rpm":>22}'
          '   1.5th-order resonance (branch: rpm range, peak @ rpm)')
    for a, ls, r in results:
        main = r.main()
        o3 = main.column('order_3')
        k = int(np.argmax(o3))
        subs = r.subharmonic_summary()
        txt = '; '.join(f'{s["branch"]}: {s["speed_min_rpm"]:.0f}-{s["speed_max_rpm"]:.0f}, '
                        f'{s["peak_order_1_5_rad"]:.4f} @ {s["peak_speed_rpm"]:.0f}' for s in subs) or 'none'
        peak = f'{o3[k]:.4f} @ {main.points[k].speed_rpm:.0f}'
        print(f'{a:6g} {ls:>4} {r.n_points:6d} {len(r.branches):8d} {r.seconds:8.2f} {peak:>22}   {txt}')
    for a, ls, r in results:
        for e in r.events:
            print(f'  alpha={a:g} Load {ls}: {e.kind} on branch {e.branch} at {e.speed_rpm:.1f} rpm  {e.detail}')
        for b in r.non_periodic:
            env = max(b.results, key=lambda x: x.max_deviation - x.min_deviation)
            print(f'  alpha={a:g} Load {ls}: no stable periodic state at {b.speed_min_rpm:.0f}-'
                  f'{b.speed_max_rpm:.0f} rpm ({b.label}, after a {b.instability} instability): '
                  f'wind-up swings {env.max_deviation:+.4f}/{env.min_deviation:+.4f} rad (time integration)')
        if r.uncovered:
            print(f'  alpha={a:g} Load {ls}: no branch reached {", ".join(f"{s:g}" for s in r.uncovered)} rpm')
    for f in data.get('failed', []):
        print(f'  alpha={f["alpha"]:g} Load {f["load_set"]}: FAILED: {f["error"]}')


def _write(out: Path, data: dict, results, args) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    files = {'csv': str(out / 'sweep.csv'), 'json': str(out / 'sweep.json')}
    with open(out / 'sweep.csv', 'w', newline='') as fh:
        w = csv.DictWriter(fh, fieldnames=CSV_FIELDS, extrasaction='ignore')
        w.writeheader()
        for sw in data['sweeps']:
            for row in sw['points']:
                w.writerow({**row, 'load': data['load']})
    (out / 'sweep.json').write_text(json.dumps(data, indent=1))
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    first_ls = results[0][1]
    panel = [(f'alpha = {a:g}', r) for a, ls, r in results if ls == first_ls]
    fig = figure(panel, f'DMF wind-up, Load {first_ls}, load {data["load"]:g} (paper Fig. 13)', plt)
    fig.savefig(out / 'fig13.png', dpi=110)
    plt.close(fig)
    files['fig13'] = str(out / 'fig13.png')
    load_sets = list(dict.fromkeys(ls for _, ls, _ in results))
    if len(load_sets) > 1:
        alphas = [a for a, _, _ in results]
        a15 = FIG15_ALPHA if FIG15_ALPHA in alphas else alphas[0]
        panel = [(f'Load {ls}', r) for a, ls, r in results if a == a15]
        fig = figure(panel, f'DMF wind-up, alpha = {a15:g}, Loads {", ".join(load_sets)} (paper Fig. 15)', plt)
        fig.savefig(out / 'fig15.png', dpi=110)
        plt.close(fig)
        files['fig15'] = str(out / 'fig15.png')
    return files


STYLE = {'order_3': ('tab:red', '3rd order'), 'order_1_5': ('tab:blue', '1.5th order'),
         'max_deviation': ('black', 'max deviation'), 'min_deviation': ('black', 'min deviation'),
         'mean_minus_theta': ('tab:green', 'mean - theta')}


def figure(panels, title: str, plt):
    """One panel per (label, SweepResult): the Fig. 13 quantities of every branch over speed;
    solid = stable, dashed = unstable (Floquet)."""
    n = len(panels)
    fig, axes = plt.subplots(n, 1, figsize=(9, 2.9 * n + 0.6), sharex=True, squeeze=False)
    for ax, (label, res) in zip(axes[:, 0], panels):
        for band in res.non_periodic:
            ax.axvspan(band.speed_min_rpm - band.half_width_rpm, band.speed_max_rpm + band.half_width_rpm,
                       color='0.88', lw=0)
        for b in res.branches:
            s = b.column('speed_rpm')
            stable = b.column('stable')
            lw = 1.6 if b.kind == 'main' else 1.1
            for key, (color, _) in STYLE.items():
                y = b.column(key)
                _plot_stability(ax, s, y, stable, color, lw)
        ax.axhline(0.0, color='0.6', lw=0.6)
        ax.set_ylabel('wind-up [rad]')
        ax.set_title(label, fontsize=10, loc='left')
        ax.grid(alpha=0.3)
    handles = [plt.Line2D([], [], color=c, label=t) for c, t in
               [STYLE['order_3'], STYLE['order_1_5'], ('black', 'max / min deviation'), STYLE['mean_minus_theta']]]
    handles.append(plt.Line2D([], [], color='0.3', ls='--', label='unstable (Floquet)'))
    handles.append(plt.Rectangle((0, 0), 1, 1, color='0.88', label='no stable periodic state'))
    axes[0, 0].legend(handles=handles, fontsize=8, ncol=5, loc='upper right')
    axes[-1, 0].set_xlabel('engine speed [rpm]')
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return fig


def _plot_stability(ax, s, y, stable, color, lw) -> None:
    """Solid where stable (or unknown), dashed where unstable; segments share their end points."""
    st = np.where(np.isnan(stable), 1.0, stable) > 0.5
    start = 0
    for i in range(1, len(s) + 1):
        if i == len(s) or st[i] != st[start]:
            j = min(i + 1, len(s))
            ax.plot(s[start:j], y[start:j], color=color, lw=lw, ls='-' if st[start] else '--')
            start = i


if __name__ == '__main__':  # pragma: no cover
    from dmf_sim.cli import main
    sys.exit(main([NAME, *sys.argv[1:]]))
