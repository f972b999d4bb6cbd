"""A demonstration case with coexisting steady states, as files ``dmf-sim run`` takes.

The hardening DMF resonance of the test suite's fold case: the paper driveline (``truck_dmf``)
with the DMF damping divided by :data:`DAMPING_DIVISOR`, the knee at :data:`THETA_RAD`,
alpha :data:`ALPHA`, excited by pure 3rd-order cylinder torques of :data:`A6_NM` each (no mean
torque) from an engine table over :data:`SPEEDS_RPM`. Its resonance bends to higher speeds
and folds twice near 360-380 rpm: a slow run-up stays on the upper branch up to the upper
fold and drops, a run-down stays on the lower one down to the lower fold and jumps up.
"""
from __future__ import annotations

from pathlib import Path

import yaml

from dmf_sim.core.paths import config_file

__all__ = ['DAMPING_DIVISOR', 'THETA_RAD', 'ALPHA', 'A6_NM', 'SPEEDS_RPM', 'N_MAX',
           'write_fold_case']

DAMPING_DIVISOR = 10.0
THETA_RAD = 0.05
ALPHA = 1.0
A6_NM = 40.0                         # 3rd-order torque amplitude per cylinder [Nm]
SPEEDS_RPM = range(300, 501, 10)     # engine table speeds [rpm]
N_MAX = 24


def write_fold_case(directory: str | Path) -> tuple[Path, Path]:
    """Write the case's driveline YAML and engine table into ``directory``; returns their
    paths (for ``--driveline`` and ``--engine``)."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    data = yaml.safe_load(config_file('truck_dmf').read_text())
    for el in data['elements']:
        if el['name'] == data['dmf']['element']:
            el['damping'] /= DAMPING_DIVISOR
    data['dmf'].update(alpha=ALPHA, theta_rad=THETA_RAD)
    data['name'] = 'truck_dmf_fold_case'
    line = d / 'truck_dmf_fold_case.yaml'
    line.write_text(yaml.safe_dump(data, sort_keys=False))
    rows = ['# pure 3rd-order excitation (dmf_sim.transient.cases), full load, no mean torque',
            'speed_rpm,n,re,im']
    for s in SPEEDS_RPM:
        rows += [f'{s},{n},{A6_NM if n == 6 else 0.0!r},0.0' for n in range(N_MAX + 1)]
    engine = d / 'engine_pure3_fold_case.csv'
    engine.write_text('\n'.join(rows) + '\n')
    return line, engine
