"""A model whose numbers are out of double precision's reach: the sweep names the element field
responsible in one line, not the bare linear-algebra failure.

Before, ``dmf-sim sweep`` with the DMF's damping at 1e300 Nms/rad said "state matrix not
diagonalizable to accuracy (4.8e+299); check for repeated undamped modes", at 1e15 "Singular
matrix"; a tiny inertia also "Singular matrix". The driveline file's own bounds may refuse such
numbers when the file is read; the solvers' error path names them for a model built otherwise
(the API, a study's designs) as well.
"""
from __future__ import annotations

from dataclasses import replace

import pytest
import yaml

from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.paths import config_file
from dmf_sim.physics.engine import read_engine
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_driveline
from dmf_sim.solvers.hbm.sweep import sweep


def _with(element: str, **fields):
    line = read_driveline('truck_dmf')
    els = list(line.elements)
    i = line.index(element)
    els[i] = replace(els[i], **fields)
    return replace(line, elements=tuple(els)), i + 1


@pytest.mark.parametrize('element, field, value', [
    ('SECONDARY FLYWHEEL', 'damping', 1e300),      # "not diagonalizable to accuracy"
    ('SECONDARY FLYWHEEL', 'damping', 1e15),       # "Singular matrix" (the real eigenbasis)
    ('FRONT', 'stiffness', 1e20),
    ('FRONT', 'inertia', 1e-20),
])
def test_sweep_names_the_extreme_field(element, field, value):
    line, number = _with(element, **{field: value})
    loads = DrivelineExcitation(line.reduce(), read_engine('engine_d13'))
    with pytest.raises(ConfigError) as exc:
        sweep(loads, 1.0, (900.0, 1000.0))
    msg = str(exc.value)
    assert '\n' not in msg
    assert msg.startswith(f"element {number} ({element}): field '{field}' {value:g}"), msg


def test_sweep_command_one_line_for_damping_1e300(tmp_path, capsys):
    """The report's case through the command: exit 2, one line naming element and field."""
    data = yaml.safe_load(config_file('truck_dmf').read_text())
    for el in data['elements']:
        if el['name'] == 'SECONDARY FLYWHEEL':
            el['damping'] = 1e300
    path = tmp_path / 'extreme.yaml'
    path.write_text(yaml.safe_dump(data))
    assert cli_main(['sweep', '--config', str(path), '--speeds', '900', '1000', '50',
                     '--no-progress', '--json']) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and 'Traceback' not in '\n'.join(err)
    assert "element 11 (SECONDARY FLYWHEEL)" in err[-1] and "'damping'" in err[-1], err
