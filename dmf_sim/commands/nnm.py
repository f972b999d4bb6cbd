"""``dmf-sim nnm``: non-linear normal modes of the conservative DMF driveline (paper Fig. 14)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from dmf_sim.commands import _options as opt
from dmf_sim.core.csv_out import write_csv
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text, write_json
from dmf_sim.physics.model import read_model
from dmf_sim.solvers.nnm import REGIONS, NNMOptions, nnm_branches, scaling_check

__all__ = ['NAME', 'HELP', 'XI_REPORT', 'XI_MAX_RANGE', 'HARMONICS_RANGE', 'STEP_MAX_RANGE',
           'add_arguments', 'check_options', 'run', 'summary']

NAME = 'nnm'
HELP = ('Non-linear normal modes (no damping, no excitation, about the mean torque\'s static '
        'wind-up): base frequency [Hz] against xi = E/E_nl for the static point in the primary '
        'and in the secondary region (paper Fig. 14).')
XI_REPORT = (1.0, 1.5, 2.0, 3.0, 5.0, 7.0, 10.0)

# Bounds of the size-like options
XI_MAX_RANGE = (1.0, 1000.0)       # xi = E/E_nl shown (1 = the linear limit, excluded)
HARMONICS_RANGE = (1, 64)          # harmonics of the base frequency
STEP_MAX_RANGE = (1e-4, 1.0)       # largest continuation step (scaled units)


def add_arguments(p) -> None:
    opt.add_config(p)
    opt.add_alpha(p, default=2.0, help_default="2.0, as the paper's Fig. 14")
    opt.add_theta(p, help_default="the YAML value; the result does not depend on it, see "
                                  "--check-scaling")
    p.add_argument('--distance', type=float,
                   help='distance of the static wind-up from the knee [rad], up to theta (default '
                        'theta/2; the result does not depend on it either)')
    p.add_argument('--mode', type=int, default=2,
                   help='linear mode the branches start from, modal index with 0 = rigid body '
                        '(default 2: the DMF\'s second driveline mode, 18 Hz at primary '
                        'stiffness)')
    p.add_argument('--xi-max', type=float, default=10.0,
                   help=f'largest xi = E/E_nl shown, up to {XI_MAX_RANGE[1]:g} (default 10)')
    p.add_argument('--harmonics', type=int, default=NNMOptions.n_harmonics,
                   help=f'harmonics of the base frequency kept, {HARMONICS_RANGE[0]}..'
                        f'{HARMONICS_RANGE[1]} (default {NNMOptions.n_harmonics})')
    p.add_argument('--step-max', type=float, default=NNMOptions.step_max,
                   help='largest continuation step (scaled; smaller resolves thinner flat '
                        f'branches, default {NNMOptions.step_max})')
    p.add_argument('--check-scaling', action='store_true',
                   help='also verify that frequency vs xi does not depend on theta or the static '
                        'distance to the knee (HBM for several (theta, distance) and time '
                        'integration of the scaled orbits on the full non-linear driveline; '
                        '~10 s)')
    p.add_argument('--json', action='store_true',
                   help='print one JSON object instead of the table')
    p.add_argument('--out', type=Path, help='directory for nnm.csv, nnm.json and nnm.png')
    opt.add_overwrite(p)


def check_options(args, model) -> None:
    """One-line refusal of every option out of its range."""
    lo, hi = XI_MAX_RANGE
    if not lo < args.xi_max <= hi:
        raise ConfigError(f'--xi-max={args.xi_max}: allowed range ({lo:g}, {hi:g}] (xi = 1 is the '
                          'linear limit)')
    lo, hi = HARMONICS_RANGE
    if not lo <= args.harmonics <= hi:
        raise ConfigError(f'--harmonics={args.harmonics}: allowed range {lo}..{hi}')
    lo, hi = STEP_MAX_RANGE
    if not lo <= args.step_max <= hi:
        raise ConfigError(f'--step-max={args.step_max}: allowed range {lo:g}..{hi:g}')
    if model.spring is None:
        raise ConfigError(f'driveline {model.line.name!r} has no dmf section: no non-linear '
                          'normal modes')
    if not 1 <= args.mode < model.n_dof:
        raise ConfigError(f'--mode={args.mode}: allowed range 1..{model.n_dof - 1} (0 is the '
                          'rigid-body mode)')
    theta = model.spring.theta
    if args.distance is not None and not 0 < args.distance <= theta:
        raise ConfigError(f'--distance={args.distance}: allowed range (0, {theta:g}] rad '
                          '(static wind-up between zero and the knee, or as far beyond it)')


def run(args) -> int:
    opt.check_names(args)
    opt.check_dmf_options([args.alpha], args.theta)
    dest = opt.output(args, NAME) if args.out is not None else None
    model = read_model(args.config, alpha=args.alpha, theta=args.theta)
    check_options(args, model)
    opts = NNMOptions(n_harmonics=args.harmonics, step_max=args.step_max,
                      step=min(NNMOptions.step, args.step_max))
    res = nnm_branches(model, mode=args.mode, distance=args.distance, xi_max=args.xi_max,
                       options=opts)
    data = res.as_dict(xi_max=args.xi_max)
    data['summary'] = summary(res, args.xi_max)
    data['left_out'] = left_out(model.spring)
    if args.check_scaling:
        data['scaling_check'] = scaling_check(model, mode=args.mode, options=opts)
    if args.json:
        print(json_text(data))
    else:
        _print(res, data, args)
    if dest is not None:
        with dest.writing() as out:
            _write(out, res, data, args)
    return 0


def left_out(spring) -> str:
    """What of the spring the NNMs leave out ('' when nothing): a non-linear normal mode is
    a periodic motion of the undamped elastic system, so arc-spring friction is not in it, and
    the end stops' contact is not modelled (the modes hold below the stop angle)."""
    parts = []
    if spring is not None and spring.friction is not None:
        parts.append('arc-spring friction (dissipative: not part of a normal mode)')
    if spring is not None and spring.stops is not None:
        parts.append('the end stops (the modes hold below the stop angles)')
    return '; '.join(parts)


def _num(v):
    return None if not np.isfinite(v) else float(v)


def summary(res, xi_max: float) -> dict:
    """Frequency [Hz] of both branches at the report's xi values up to ``xi_max``."""
    xi = [x for x in XI_REPORT if x <= xi_max] + ([xi_max] if xi_max not in XI_REPORT else [])
    return {'xi': xi, **{r: [_num(f) for f in res.branches[r].frequency_at(xi)] for r in REGIONS}}


def _print(res, data, args) -> None:
    print(f'{res.driveline}: NNMs of mode {res.mode}, alpha = {res.alpha:g}, '
          f'theta = {res.theta:g} rad, {res.n_harmonics} harmonics')
    for r in REGIONS:
        br = res.branches[r]
        print(f'  {r:9s} branch: static wind-up {br.windup_static:.4f} rad (knee distance '
              f'{br.distance:.4f} rad), linear {br.linear_frequency_hz:.2f} Hz, '
              f'E_nl = {br.e_nl:.4g} J')
    if data['left_out']:
        print(f'  left out: {data["left_out"]}')
    s = data['summary']
    print(f'{"xi":>8}  {"primary [Hz]":>13}  {"secondary [Hz]":>14}')
    for i, x in enumerate(s['xi']):
        fp, fs = (float('nan') if v is None else v for v in (s['primary'][i], s['secondary'][i]))
        print(f'{x:8.2f}  {fp:13.3f}  {fs:14.3f}')
    if res.flat_branches:
        print('flat branches (n x base frequency ~ a linear resonance of the part in front of / '
              'behind the DMF):')
        for fb in res.flat_branches:
            if fb.xi_min > args.xi_max:
                continue
            print(f'  {fb.region:9s} n = {fb.harmonic:2d}: {fb.frequency_hz:7.3f} Hz '
                  f'(x{fb.harmonic} = {fb.harmonic * fb.frequency_hz:7.2f} Hz; {fb.subsystem} '
                  f'subsystem {fb.subsystem_frequency_hz:.2f} Hz), '
                  f'xi {fb.xi_min:.1f}..{min(fb.xi_max, args.xi_max):.1f}')
    for r, v in data.get('scaling_check', {}).items():
        msg = (f'scaling check {r}: frequency spread over (theta, distance) '
               f'{v["max_relative_spread"]:.1e}')
        if 'max_time_domain_error' in v:
            msg += (f'; time integration of scaled orbits: periodicity error <= '
                    f'{v["max_time_domain_error"]:.1e} (0.1 % period change: >= '
                    f'{v["min_control_error"]:.1e})')
        print(msg)


def _write(out: Path, res, data: dict, args) -> None:
    write_json(out / 'nnm.json', data)
    H = res.n_harmonics
    rows = [[r, int(br.segment[i]), br.xi[i], br.frequency_hz[i], br.energy[i],
             br.shares[i, 1], int(br.tongue_harmonic[i]), br.windup_static, *br.coefficients[i]]
            for r in REGIONS for br in (res.branches[r],) for i in range(len(br.xi))]
    write_csv(out / 'nnm.csv', ['region', 'segment', 'xi', 'frequency_hz', 'energy_J',
                                'fundamental_share', 'tongue_harmonic', 'windup_static_rad',
                                *[f'a{n}_rad' for n in range(H + 1)]], rows)
    from dmf_sim.figures import nnm_figure, save
    save(nnm_figure(res, xi_max=args.xi_max), out / 'nnm.png')
