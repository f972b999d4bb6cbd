"""Issue 20 items 9 and 12: user mistakes of `steady`, `sweep` and the number parsers are refused
in one line naming the option or field and its allowed range (exit 2), before any computation."""
from __future__ import annotations

import pytest

from dmf_sim.cli import main as cli_main


def _no_compute(*args, **kwargs):
    raise AssertionError('computation started before the options were checked')


@pytest.fixture
def a_file(tmp_path):
    path = tmp_path / 'not_a_dir.txt'
    path.write_text('x')
    return path


@pytest.mark.parametrize('argv, needles', [
    (['steady', '--speed', '1000', '--seed', '-1'], ('--seed -1', '0..4294967295')),
    (['steady', '--speed', '1000', '--seed', str(2 ** 64)], ('--seed', '0..4294967295')),
    (['sweep', '--no-progress', '--out', '{file}'], ('--out', 'not a directory')),
    (['sweep', '--no-progress', '--out', '{file}/below'], ('--out', 'is a file')),
    (['nnm', '--out', '{file}'], ('--out', 'not a directory')),
    (['paper', '--quick', '--no-progress', '--out', '{file}'], ('--out', 'not a directory')),
])
def test_refused_in_one_line_before_computing(argv, needles, a_file, capsys, monkeypatch):
    monkeypatch.setattr('dmf_sim.solvers.hbm.sweep', _no_compute)
    monkeypatch.setattr('dmf_sim.solvers.steady.find_steady_states', _no_compute)
    monkeypatch.setattr('dmf_sim.commands.nnm.nnm_branches', _no_compute)
    monkeypatch.setattr('dmf_sim.commands.paper.PaperStudy', _no_compute)
    argv = [a.replace('{file}', str(a_file)) for a in argv]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith(f'dmf-sim {argv[0]}: error: '), err
    for needle in needles:
        assert needle in err, err


def test_sweep_refuses_a_system_file_as_out(capsys, monkeypatch):
    """The issue's case: `sweep --out /etc/passwd` ran the sweep, then FileExistsError."""
    monkeypatch.setattr('dmf_sim.solvers.hbm.sweep', _no_compute)
    assert cli_main(['sweep', '--no-progress', '--out', '/etc/passwd']) == 2
    assert '--out /etc/passwd: exists and is not a directory' in capsys.readouterr().err
