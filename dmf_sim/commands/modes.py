"""``dmf-sim modes``: natural frequencies and mode shapes (paper Fig. 12)."""
from __future__ import annotations

import csv
import json
from pathlib import Path

from dmf_sim.errors import ConfigError
from dmf_sim.modal import modes, region_names
from dmf_sim.model import load_model

NAME = 'modes'
HELP = ('Natural frequencies [Hz] and mode shapes (scaled by cumulative gear ratio, Fig. 12) of the '
        'conventional and DMF drivelines.')
VARIANTS = {'dmf': 'truck_dmf', 'conventional': 'truck_conventional'}


def add_arguments(p) -> None:
    p.add_argument('--variant', choices=sorted(VARIANTS), default='dmf',
                   help='default drivelines from config/ (default: dmf)')
    p.add_argument('--config', help='driveline YAML path (overrides --variant)')
    p.add_argument('--alpha', type=float, help='DMF secondary stiffness factor: k(1+alpha)')
    p.add_argument('--theta', type=float, help='DMF stiffness change angle [rad]')
    p.add_argument('--region',
                   help="DMF spring stage whose stiffness is used: 'primary' (k), 'secondary' "
                        "(k(1+alpha), the first drive stage), 'drive stage 2', 'coast', ... as the "
                        'spring has them; default secondary when --alpha is given, else primary')
    p.add_argument('--modes', type=int, default=8, help='number of modes listed (default 8)')
    p.add_argument('--json', action='store_true', help='print one JSON object (frequencies_hz ascending)')
    p.add_argument('--out', type=Path, help='directory for modes.json, modes.csv and modes.png')


def run(args) -> int:
    source = args.config or VARIANTS[args.variant]
    model = load_model(source, alpha=args.alpha, theta=args.theta)
    region = args.region or ('secondary' if args.alpha is not None else 'primary')
    names = region_names(model)
    if model.spring is None:
        region = 'primary'
    elif region not in names:
        raise ConfigError(f'--region {region!r}: allowed {", ".join(names)}')
    res = modes(model, region)
    n = min(args.modes, len(res.frequencies_hz))
    data = {'driveline': model.line.name, 'region': region,
            'alpha': model.line.dmf.alpha if model.line.dmf else None,
            **res.as_dict(n)}
    if model.spring is not None:
        data['regions'] = {r: [float(f) for f in modes(model, r).frequencies_hz[:n]] for r in names}
    if args.json:
        print(json.dumps(data))
    else:
        print(f'{model.line.name}: {model.n_elements} elements, {model.n_dof} DOFs, DMF region: {region}')
        print(f'{"mode":>4}  {"frequency [Hz]":>14}')
        for i, f in enumerate(res.frequencies_hz[:n]):
            print(f'{i:>4}  {f:14.2f}')
    if args.out:
        _write(args.out, data, source, args)
    return 0


def _write(out: Path, data: dict, source: str, args) -> None:
    out.mkdir(parents=True, exist_ok=True)
    (out / 'modes.json').write_text(json.dumps(data, indent=2))
    with open(out / 'modes.csv', 'w', newline='') as fh:
        w = csv.writer(fh)
        w.writerow(['mode', 'frequency_hz', *data['elements']])
        for i, (f, shape) in enumerate(zip(data['frequencies_hz'], data['mode_shapes_scaled'])):
            w.writerow([i, f, *shape])
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    conv = modes(load_model('truck_conventional'))
    dmf = modes(load_model('truck_dmf', alpha=args.alpha, theta=args.theta))
    fig, axes = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    x = range(len(conv.names))
    for k, ax in enumerate(axes, start=1):
        ax.plot(x, conv.element_shapes[:, k], 'b-o', ms=3, label=f'conventional {conv.frequencies_hz[k]:.1f} Hz')
        ax.plot(x, dmf.element_shapes[:, k], 'r--s', ms=3, label=f'DMF {dmf.frequencies_hz[k]:.1f} Hz')
        ax.set_ylabel(f'mode {k}')
        ax.legend(loc='best', fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xticks(list(x))
    axes[-1].set_xticklabels(conv.names, rotation=70, fontsize=7)
    fig.suptitle('Mode shapes x cumulative gear ratio (paper Fig. 12)')
    fig.tight_layout()
    fig.savefig(out / 'modes.png', dpi=120)
    plt.close(fig)
