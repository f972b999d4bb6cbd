"""``dmf-sim nnm``: non-linear normal modes of the conservative DMF driveline (paper Fig. 14)."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from dmf_sim.errors import ConfigError
from dmf_sim.model import load_model
from dmf_sim.nnm import REGIONS, NNMOptions, nnm_branches, scaling_check

NAME = 'nnm'
HELP = ('Non-linear normal modes (no damping, no excitation, about the mean torque\'s static wind-up): '
        'base frequency [Hz] against xi = E/E_nl for the static point in the primary and in the '
        'secondary region (paper Fig. 14).')
XI_REPORT = (1.0, 1.5, 2.0, 3.0, 5.0, 7.0, 10.0)


def add_arguments(p) -> None:
    p.add_argument('--config', default='truck_dmf', help='driveline YAML name or path (default truck_dmf)')
    p.add_argument('--alpha', type=float, default=2.0,
                   help='DMF secondary stiffness factor, k(1+alpha) (default 2.0, as the paper\'s Fig. 14)')
    p.add_argument('--theta', type=float,
                   help='DMF stiffness change angle [rad] (default: the YAML\'s; the result does not '
                        'depend on it, see --check-scaling)')
    p.add_argument('--distance', type=float,
                   help='distance of the static wind-up from the knee [rad] (default theta/2; the '
                        'result does not depend on it either)')
    p.add_argument('--mode', type=int, default=2,
                   help='linear mode the branches start from, modal index with 0 = rigid body '
                        '(default 2: the DMF\'s second driveline mode, 18 Hz at primary stiffness)')
    p.add_argument('--xi-max', type=float, default=10.0, help='largest xi = E/E_nl shown (default 10)')
    p.add_argument('--harmonics', type=int, default=NNMOptions.n_harmonics,
                   help=f'harmonics of the base frequency kept (default {NNMOptions.n_harmonics})')
    p.add_argument('--step-max', type=float, default=NNMOptions.step_max,
                   help='largest continuation step (scaled; smaller resolves thinner flat branches, '
                        f'default {NNMOptions.step_max})')
    p.add_argument('--check-scaling', action='store_true',
                   help='also verify that frequency vs xi does not depend on theta or the static '
                        'distance to the knee (HBM for several (theta, distance) and time integration '
                        'of the scaled orbits on the full non-linear driveline; ~10 s)')
    p.add_argument('--json', action='store_true', help='print one JSON object instead of the table')
    p.add_argument('--out', type=Path, help='directory for nnm.csv, nnm.json and nnm.png')


def run(args) -> int:
    if not args.xi_max > 1.0:
        raise ConfigError(f'--xi-max={args.xi_max}: must be > 1 (xi = 1 is the linear limit)')
    if args.harmonics < 1:
        raise ConfigError(f'--harmonics={args.harmonics}: must be >= 1')
    if not args.step_max > 0:
        raise ConfigError(f'--step-max={args.step_max}: must be > 0')
    model = load_model(args.config, alpha=args.alpha, theta=args.theta)
    if model.spring is None:
        raise ConfigError(f'driveline {model.line.name!r} has no dmf section: no non-linear normal modes')
    if args.distance is not None and not args.distance > 0:
        raise ConfigError(f'--distance={args.distance}: must be > 0 rad')
    opts = NNMOptions(n_harmonics=args.harmonics, step_max=args.step_max, step=min(NNMOptions.step, args.step_max))
    res = nnm_branches(model, mode=args.mode, distance=args.distance, xi_max=args.xi_max, options=opts)
    data = res.as_dict(xi_max=args.xi_max)
    xi_rep = [x for x in XI_REPORT if x <= args.xi_max] + ([args.xi_max] if args.xi_max not in XI_REPORT else [])
    data['summary'] = {'xi': xi_rep, **{r: [_num(f) for f in res.branches[r].frequency_at(xi_rep)] for r in REGIONS}}
    if args.check_scaling:
        data['scaling_check'] = scaling_check(model, mode=args.mode, options=opts)
    if args.json:
        print(json.dumps(data))
    else:
        _print(res, data, args)
    if args.out:
        _write(args.out, res, data, args)
    return 0


def _num(v):
    return None if not np.isfinite(v) else float(v)


def _print(res, data, args) -> None:
    print(f'{res.driveline}: NNMs of mode {res.mode}, alpha = {res.alpha:g}, theta = {res.theta:g} rad, '
          f'{res.n_harmonics} harmonics')
    for r in REGIONS:
        br = res.branches[r]
        print(f'  {r:9s} branch: static wind-up {br.windup_static:.4f} rad (knee distance {br.distance:.4f} rad), '
              f'linear {br.linear_frequency_hz:.2f} Hz, E_nl = {br.e_nl:.4g} J')
    s = data['summary']
    print(f'{"xi":>8}  {"primary [Hz]":>13}  {"secondary [Hz]":>14}')
    for i, x in enumerate(s['xi']):
        fp, fs = (float('nan') if v is None else v for v in (s['primary'][i], s['secondary'][i]))
        print(f'{x:8.2f}  {fp:13.3f}  {fs:14.3f}')
    if res.flat_branches:
        print('flat branches (n x base frequency ~ a linear resonance of the part in front of / behind the DMF):')
        for fb in res.flat_branches:
            if fb.xi_min > args.xi_max:
                continue
            print(f'  {fb.region:9s} n = {fb.harmonic:2d}: {fb.frequency_hz:7.3f} Hz (x{fb.harmonic} = '
                  f'{fb.harmonic * fb.frequency_hz:7.2f} Hz; {fb.subsystem} subsystem '
                  f'{fb.subsystem_frequency_hz:.2f} Hz), xi {fb.xi_min:.1f}..{min(fb.xi_max, args.xi_max):.1f}')
    if 'scaling_check' in data:
        for r, v in data['scaling_check'].items():
            msg = f'scaling check {r}: frequency spread over (theta, distance) {v["max_relative_spread"]:.1e}'
            if 'max_time_domain_error' in v:
                msg += (f'; time integration of scaled orbits: periodicity error <= {v["max_time_domain_error"]:.1e} '
                        f'(0.1 % period change: >= {v["min_control_error"]:.1e})')
            print(msg)


def _write(out: Path, res, data: dict, args) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / 'nnm.json').write_text(json.dumps(data, indent=1))
    H = res.n_harmonics
    with open(out / 'nnm.csv', 'w', newline='') as fh:
        w = csv.writer(fh)
        w.writerow(['region', 'segment', 'xi', 'frequency_hz', 'energy_J', 'fundamental_share',
                    'tongue_harmonic', 'windup_static_rad', *[f'a{n}_rad' for n in range(H + 1)]])
        for r in REGIONS:
            br = res.branches[r]
            tn = br.tongue_harmonic
            for i in range(len(br.xi)):
                w.writerow([r, int(br.segment[i]), f'{br.xi[i]:.8g}', f'{br.frequency_hz[i]:.8g}',
                            f'{br.energy[i]:.8g}', f'{br.shares[i, 1]:.4f}', int(tn[i]),
                            f'{br.windup_static:.8g}', *[f'{v:.6e}' for v in br.coefficients[i]]])
    plot(res, out / 'nnm.png', xi_max=args.xi_max)


def plot(res, path: Path, xi_max: float = 10.0) -> None:
    """Frequency [Hz] against xi like the paper's Fig. 14: blue primary-region branch, red
    secondary-region branch, flat branches labelled with their multiple n."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 5.5))
    colors = {'primary': 'tab:blue', 'secondary': 'tab:red'}
    labels = {'primary': 'static wind-up in primary region', 'secondary': 'static wind-up in secondary region'}
    lo, hi = np.inf, -np.inf
    for r in REGIONS:
        br = res.branches[r]
        first = True
        for seg in np.unique(br.segment):
            s = br.segment == seg
            m = s & (br.xi <= xi_max)
            if not m.any():
                continue
            ax.plot(br.xi[s], br.frequency_hz[s], '-', color=colors[r], lw=0.8, alpha=0.6)
            ax.plot(br.xi[m], br.frequency_hz[m], 'o', color=colors[r], ms=2.5,
                    label=labels[r] if first else None)
            first = False
            lo, hi = min(lo, br.frequency_hz[m].min()), max(hi, br.frequency_hz[m].max())
        ax.axhline(br.linear_frequency_hz, color=colors[r], ls=':', lw=0.8)
    for fb in res.flat_branches:
        if fb.xi_min > xi_max:
            continue
        x = min(fb.xi_max, xi_max)
        ax.annotate(str(fb.harmonic), (x, fb.frequency_hz), xytext=(3, 1), textcoords='offset points',
                    fontsize=8, color=colors[fb.region], annotation_clip=False)
    pad = 0.05 * (hi - lo) if np.isfinite(hi - lo) and hi > lo else 1.0
    ax.set_ylim(lo - pad, hi + pad)
    ax.set_xlim(1.0 - 0.02 * (xi_max - 1), xi_max)
    ax.set_xlabel(r'$\xi = E / E_{nl}$')
    ax.set_ylabel('frequency of the fundamental [Hz]')
    ax.set_title(f'Non-linear normal modes, alpha = {res.alpha:g} (mode {res.mode}; dotted: linear; '
                 'numbers: n of flat branches, n x f = subsystem resonance)', fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(loc='best', fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
