"""User mistakes of `steady`, `sweep` and the number parsers are refused
in one line naming the option or field and its allowed range (exit 2), before any computation."""
from __future__ import annotations

import numpy as np
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
    (['sweep', '--no-progress', '--out', '{file}/below'], ('--out', 'cannot be created')),
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


# ---- item 12: numbers the parsers let through or misread --------------------------------------
def _pure3_table(path, a6: float):
    rows = ['speed_rpm,n,re,im']
    for s in range(600, 1201, 100):
        for n in range(25):
            re = 10.0 if n == 0 else (a6 if n == 6 else 0.0)
            rows.append(f'{s},{n},{re!r},0.0')
    path.write_text('\n'.join(rows) + '\n')
    return path


def test_engine_table_beyond_any_cylinder_pressure_is_refused(tmp_path, capsys, monkeypatch):
    """A_n = 1e308 was accepted (overflow warnings, then 'no branch reached', exit 0)."""
    import warnings

    from dmf_sim.core.errors import ConfigError
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.engine.tables import PEAK_PRESSURE_MAX_PA
    monkeypatch.setattr('dmf_sim.solvers.hbm.sweep', _no_compute)
    table = _pure3_table(tmp_path / 'huge.csv', 1e308)
    with warnings.catch_warnings():
        warnings.simplefilter('error')                 # no overflow warning on the way
        with pytest.raises(ConfigError, match=r'A_6 at 600 rpm: .* must be <= 9\.7\d+e\+04 Nm'
                                              r' .*350 bar, got 1e\+308'):
            read_engine(table)
    assert cli_main(['sweep', '--no-progress', '--engine', str(table)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and "huge.csv: field 'coefficients' A_6" in err
    # the bound is the gas torque of one D13 cylinder at 350 bar, times 2 (|A_n| <= 2 max|P|):
    # p pi/4 D^2 r (1 + r/l), D 131 mm, r 79 mm, l 255 mm
    r = 0.079
    bound = 2 * PEAK_PRESSURE_MAX_PA * 0.25 * np.pi * 0.131 ** 2 * r * (1 + r / 0.255)
    assert bound == pytest.approx(9.76e4, rel=2e-3)
    read_engine(_pure3_table(tmp_path / 'ok.csv', 0.99 * bound))           # just inside: read


def test_yaml_numbers_with_an_exponent_but_no_dot(tmp_path):
    """PyYAML (YAML 1.1) reads `alpha: 1e300` and `25e-1`-like numbers without a dot or sign as
    strings; the one validation (core.validation.number) takes them as the numbers meant, and the
    field's range decides (one line naming field and range)."""
    import yaml

    from dmf_sim.core.errors import ConfigError
    from dmf_sim.core.paths import config_file
    from dmf_sim.physics.model import read_driveline
    d = yaml.safe_load(config_file('truck_dmf').read_text())
    text = yaml.safe_dump(d, sort_keys=False)
    good = text.replace('alpha: 2.5', 'alpha: 25e-1').replace('theta_rad: 0.24',
                                                               'theta_rad: 24e-2')
    assert 'alpha: 25e-1' in good
    (tmp_path / 'good.yaml').write_text(good)
    line = read_driveline(tmp_path / 'good.yaml')
    assert (line.spring.alpha, line.spring.theta) == (2.5, 0.24)
    (tmp_path / 'big.yaml').write_text(text.replace('alpha: 2.5', 'alpha: 1e300'))
    with pytest.raises(ConfigError, match=r"field 'alpha' must be in \[0, 50\], got 1e\+300"):
        read_driveline(tmp_path / 'big.yaml')


def test_engine_and_study_yaml_read_exponent_numbers(tmp_path):
    from dmf_sim.core.paths import config_file
    from dmf_sim.design.study import read_study
    from dmf_sim.physics.engine import read_engine
    eng = config_file('engine_d13').read_text().replace('bore_m: 0.131', 'bore_m: 131e-3')
    assert 'bore_m: 131e-3' in eng
    (tmp_path / 'engine_e.yaml').write_text(eng)
    e = read_engine(tmp_path / 'engine_e.yaml')
    assert e.coefficients(1000.0, 1.0)[6] == pytest.approx(
        read_engine('engine_d13').coefficients(1000.0, 1.0)[6], rel=1e-12)
    study = config_file('study_example').read_text().replace('step: 10}', 'step: 1e1}')
    assert 'step: 1e1}' in study
    (tmp_path / 'study.yaml').write_text(study)
    assert read_study(tmp_path / 'study.yaml').speeds_rpm[2] == 10.0


def test_study_variable_beyond_the_spring_bound_is_refused_when_read(tmp_path):
    """The spring's stiffness-factor bound also bounds a design study's variables (refused when
    the study is read, not design by design)."""
    from dmf_sim.core.errors import ConfigError
    from dmf_sim.core.paths import config_file
    from dmf_sim.design.study import read_study
    text = config_file('study_example').read_text()
    assert 'alpha: {min: 1.0, max: 5.0, n: 9}' in text
    (tmp_path / 'big.yaml').write_text(text.replace('alpha: {min: 1.0, max: 5.0, n: 9}',
                                                    'alpha: {min: 1.0, max: 6e1, n: 9}'))
    with pytest.raises(ConfigError, match=r"'variables.alpha.max' must be in \[0, 50\], got"):
        read_study(tmp_path / 'big.yaml')


# ---- one form for every mistake: argparse's and the package's own ------------------------------
def _exit_code(argv) -> int:
    """dmf-sim in this process: the exit code, whether argparse exits or a command returns."""
    try:
        return cli_main(argv)
    except SystemExit as exc:
        return exc.code


@pytest.mark.parametrize('argv, command, needle', [
    # argparse refuses the command line
    (['sweep', '--harmonics', 'x'], 'sweep', "--harmonics: invalid int value: 'x'"),
    (['sweep', '--bogus'], 'sweep', 'unrecognized arguments: --bogus'),
    (['run'], 'run', 'required: PROFILE'),
    (['bag-recover', 'b', '-o', 'x', '--in-place'], 'bag-recover', 'not allowed with'),
    (['swep'], None, "invalid choice: 'swep'"),                       # before a command is known
    # the package refuses a value (ConfigError)
    (['sweep', '--harmonics', '3', '--no-progress'], 'sweep', '--harmonics=3'),
    (['run', 'ramp:800:2000:0', '--no-write'], 'run', 'rate_rpm_per_s'),
    # run names its own options, not the node's parameters publish_rate and dt
    (['run', 'step:1200:0:1:0.1', '--dt', '0.002', '--no-write', '--no-progress'], 'run',
     '--rate 1000 Hz is faster than the step rate of --dt = 0.002 s (500 Hz): give --rate 500 '
     'Hz or less, or --dt 0.001 s or less'),
    (['run', 'step:1200:0:1:0.1', '--rate', '3000', '--no-write', '--no-progress'], 'run',
     '--rate 3000 Hz is not a whole number of steps of --dt = 0.0001 s'),
    # --theta moving the knee past the end stop is blamed on --theta, not on the file's stop
    *[([cmd, *extra, '--config', 'truck_dmf_friction', '--theta', '0.5'], cmd,
       'theta 0.5 rad (--theta 0.5) moves the first drive knee to or past the drive end stop at '
       '0.45 rad (dmf.end_stops.drive_angle_rad): give theta below 0.45 rad')
      for cmd, extra in (('run', ['step:1200:0:1:0.1', '--no-write', '--no-progress']),
                         ('sweep', ['--no-progress']), ('steady', ['--speed', '1000']))],
])
def test_every_mistake_is_one_line_in_one_form(argv, command, needle, capsys, monkeypatch):
    """argparse used to print its usage block and `dmf-sim: error:` without the command (for an
    unknown option); the package's errors printed `dmf-sim <command>: error: ...`. Both are now
    the one line `dmf-sim <command>: error: <message>`, exit 2."""
    monkeypatch.setattr('dmf_sim.solvers.hbm.sweep', _no_compute)
    assert _exit_code(argv) == 2
    captured = capsys.readouterr()
    prog = 'dmf-sim' if command is None else f'dmf-sim {command}'
    assert captured.err.count('\n') == 1, captured.err
    assert captured.err.startswith(f'{prog}: error: ') and needle in captured.err, captured.err
    assert captured.out == ''


def test_the_errors_page_shows_what_dmf_sim_prints(capsys, monkeypatch):
    """doc/errors.md's console examples are run: each prints exactly the line shown."""
    import re
    import shlex
    from pathlib import Path

    monkeypatch.setattr('dmf_sim.solvers.hbm.sweep', _no_compute)
    page = (Path(__file__).resolve().parents[2] / 'doc' / 'errors.md').read_text()
    examples = re.findall(r'^\$ dmf-sim (.*)\n(dmf-sim.*)$', page, re.M)
    assert len(examples) >= 4
    for command, shown in examples:
        assert _exit_code(shlex.split(command)) == 2, command
        assert capsys.readouterr().err == shown + '\n', command
    assert '`dmf-sim <command>: error: <one line>`' in page
