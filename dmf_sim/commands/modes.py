"""``dmf-sim modes``: natural frequencies and mode shapes (paper Fig. 12)."""
from __future__ import annotations

from pathlib import Path

from dmf_sim.commands import _options as opt
from dmf_sim.core.csv_out import write_csv
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text, write_json
from dmf_sim.physics.modal import modes, region_names
from dmf_sim.physics.model import read_model

__all__ = ['NAME', 'HELP', 'VARIANTS', 'add_arguments', 'run', 'fig12']

NAME = 'modes'
HELP = ('Natural frequencies [Hz] and mode shapes (scaled by cumulative gear ratio, Fig. 12) of '
        'the conventional and DMF drivelines.')
VARIANTS = {'dmf': 'truck_dmf', 'conventional': 'truck_conventional'}


def add_arguments(p) -> None:
    p.add_argument('--variant', choices=sorted(VARIANTS), default='dmf',
                   help='default drivelines from config/ (default: dmf)')
    opt.add_config(p, default=None, help_default='the --variant driveline; overrides it')
    opt.add_alpha(p)
    opt.add_theta(p)
    p.add_argument('--region',
                   help="DMF spring stage whose stiffness is used: 'primary' (k), 'secondary' "
                        "(k(1+alpha), the first drive stage), 'drive stage 2', 'coast', ... as "
                        'the spring has them; default secondary when --alpha is given, '
                        'else primary')
    p.add_argument('--modes', type=int, default=8,
                   help='number of modes listed, 1..number of DOFs (default 8)')
    p.add_argument('--json', action='store_true',
                   help='print one JSON object (frequencies_hz ascending)')
    p.add_argument('--out', type=Path, help='directory for modes.json, modes.csv and modes.png')
    opt.add_overwrite(p)


def run(args) -> int:
    opt.check_common(args)
    dest = opt.output(args, NAME) if args.out is not None else None
    source = args.config if args.config is not None else VARIANTS[args.variant]
    model = read_model(source, alpha=args.alpha, theta=args.theta)
    if not 1 <= args.modes <= model.n_dof:
        raise ConfigError(f'--modes={args.modes}: allowed range 1..{model.n_dof} (the DOFs of '
                          f'{model.line.name!r})')
    region = args.region or ('secondary' if args.alpha is not None else 'primary')
    names = region_names(model)
    if model.spring is None:
        if args.region is not None:
            raise ConfigError(f'--region {args.region!r}: driveline {model.line.name!r} has no '
                              'DMF (its modes are linear; leave out --region)')
        region = None
    elif region not in names:
        raise ConfigError(f'--region {region!r}: allowed {", ".join(names)}')
    res = modes(model, region or 'primary')
    n = min(args.modes, len(res.frequencies_hz))
    data = {'driveline': model.line.name, 'region': region,
            'alpha': model.line.dmf.alpha if model.line.dmf else None,
            **res.as_dict(n)}
    if model.spring is not None:
        data['regions'] = {r: [float(f) for f in modes(model, r).frequencies_hz[:n]]
                           for r in names}
    if args.json:
        print(json_text(data))
    else:
        dmf = f'DMF region: {region}' if region else 'no DMF (linear driveline)'
        print(f'{model.line.name}: {model.n_elements} elements, {model.n_dof} DOFs, {dmf}')
        print(f'{"mode":>4}  {"frequency [Hz]":>14}')
        for i, f in enumerate(res.frequencies_hz[:n]):
            print(f'{i:>4}  {f:14.2f}')
    if dest is not None:
        with dest.writing() as out:
            _write(out, data, args)
    return 0


def _write(out: Path, data: dict, args) -> None:
    from dmf_sim.figures import save
    write_json(out / 'modes.json', data, indent=2)
    rows = zip(data['frequencies_hz'], data['mode_shapes_scaled'], strict=True)
    write_csv(out / 'modes.csv', ['mode', 'frequency_hz', *data['elements']],
              ([i, f, *shape] for i, (f, shape) in enumerate(rows)))
    save(fig12(args.alpha, args.theta, 'primary' if args.region is None else args.region),
         out / 'modes.png')


def fig12(alpha: float | None = None, theta: float | None = None, region: str = 'primary'):
    """Paper Fig. 12: the first four modes of the conventional and the DMF driveline (DMF at the
    stiffness of ``region``)."""
    from dmf_sim.figures import mode_shapes_figure
    dmf_model = read_model(VARIANTS['dmf'], alpha=alpha, theta=theta)
    label = f'DMF ({region} stiffness' + (f', α = {dmf_model.spring.alpha:g})'
                                          if region != 'primary' else ')')
    return mode_shapes_figure(modes(read_model(VARIANTS['conventional'])),
                              modes(dmf_model, region), n_modes=4, dmf_label=label)
