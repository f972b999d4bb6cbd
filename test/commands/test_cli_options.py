"""Every size-like option of sweep / loads / modes / nnm / paper is bounded and refused
with one line naming the option and the allowed range (exit 2), before any computation; an
option that was silently accepted (an empty --config, --torque-speeds without --out) is refused
the same way."""
from __future__ import annotations

import pytest

from dmf_sim.cli import main as cli_main


@pytest.mark.parametrize('argv, needles', [
    (['sweep', '--harmonics', '100000'], ('--harmonics=100000', '6..64')),
    (['sweep', '--harmonics', '3'], ('--harmonics=3', '6..64')),
    (['sweep', '--speeds', '600', '2000', '0.001'], ('--speeds', 'STEP >= 0.5')),
    (['sweep', '--speeds', '600', '2000', '0.5'], ('--speeds', '2801 grid points', '2000')),
    (['sweep', '--speeds', '600', '1e9', '10'], ('--speeds', 'grid points', '2000')),
    (['sweep', '--speeds', '300', '1000', '10'], ('--speeds', '400..2200')),
    (['sweep', '--speeds', '1000', '900', '10'], ('--speeds', 'TO > FROM')),
    (['sweep', '--speeds', 'nan', '900', '10'], ('--speeds', 'finite')),
    (['sweep', '--alpha', '1e6'], ('--alpha', '0..50')),
    (['sweep', '--theta', '0'], ('--theta', '(0, 2]')),
    (['sweep', '--alpha', *['2'] * 13, '--load-set', 'A', 'B'], ('26 sweeps', '24')),
    (['sweep', '--load-set', 'D'], ('--load-set', 'A, B, C')),
    (['loads', '--speeds', '600', '2000', '0.01'], ('--speeds', 'STEP >= 0.5')),
    (['loads', '--speeds', '0', '1e7', '100'], ('--speeds', '100001 grid points')),
    (['loads', '--speeds', '100', '1000', '100'], ('--speeds', '400..2200')),
    (['loads', '--speed', '5000'], ('--speed 5000', '400..2200')),
    (['loads', '--torque-speeds', *['1000'] * 13], ('--torque-speeds', '12')),
    (['modes', '--modes', '100'], ('--modes=100', '1..17')),
    (['modes', '--alpha', '-1'], ('--alpha', '0..50')),
    (['nnm', '--xi-max', '1e9'], ('--xi-max', '1000')),
    (['nnm', '--harmonics', '100000'], ('--harmonics=100000', '1..64')),
    (['nnm', '--step-max', '50'], ('--step-max', '1')),
    (['nnm', '--mode', '40'], ('--mode=40', '1..16')),
    (['nnm', '--distance', '5'], ('--distance', '0.24')),
])
def test_size_like_options_refused_in_one_line(argv, needles, capsys, monkeypatch):
    def no_compute(*args, **kwargs):
        raise AssertionError('computation started before the options were checked')
    monkeypatch.setattr('dmf_sim.solvers.hbm.sweep', no_compute)
    monkeypatch.setattr('dmf_sim.commands.nnm.nnm_branches', no_compute)
    assert cli_main([*argv, '--no-progress'] if argv[0] == 'sweep' else argv) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith(f'dmf-sim {argv[0]}: error: '), err
    for needle in needles:
        assert needle in err, err


@pytest.mark.parametrize('argv, needles', [
    (['--frames', '0'], ('--frames', '>= 1')),
    (['--timeout', '0'], ('--timeout', '> 0 s')),
    (['--timeout', 'inf'], ('--timeout', 'finite', '> 0 s', 'inf')),
    (['--duration', 'nan'], ('--duration', 'finite', '> 0 s')),
    (['--rate', '100'], ('--rate', '[0.1, 50] Hz')),
])
def test_monitor_options_refused_in_one_line(argv, needles, capsys, monkeypatch):
    """Checked before any ROS participant starts (no node needed, no rclpy session)."""
    def no_session(*args, **kwargs):
        raise AssertionError('ROS session started before the options were checked')
    monkeypatch.setattr('dmf_sim.commands._ros.ros_session', no_session)
    assert cli_main(['monitor', *argv]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('dmf-sim monitor: error: '), err
    for needle in needles:
        assert needle in err, err


@pytest.mark.parametrize('argv, needles', [
    (['modes', '--config', ''], ('--config: empty name',)),
    (['loads', '--engine', ''], ('--engine: empty name',)),
    (['sweep', '--config', ' '], ('--config: empty name',)),
    (['nnm', '--config', ''], ('--config: empty name',)),
    (['paper', '--engine', '', '--out', '{tmp}'], ('--engine: empty name',)),
    (['run', 'ramp:800:900:100', '--no-write', '--config', ''], ('--config: empty name',)),
    (['loads', '--torque-speeds', '800', '-5'], ('--torque-speeds', 'give --out too')),
    (['loads', '--torque-speeds', '800', '-5', '--out', '{tmp}'],
     ('--torque-speeds -5', '400..2200 rpm')),
])
def test_options_no_longer_accepted_silently(argv, needles, tmp_path, capsys, forbid):
    """`--config ''` ran the default driveline, `--torque-speeds ... -5` without --out was
    ignored (with --out refused after computing)."""
    forbid('dmf_sim.commands.modes.modes', 'dmf_sim.commands.loads.mean_torques',
           'dmf_sim.solvers.hbm.sweep', 'dmf_sim.commands.nnm.nnm_branches',
           'dmf_sim.commands.paper.PaperStudy')
    out = tmp_path / 'out'
    assert cli_main([a.replace('{tmp}', str(out)) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith(f'dmf-sim {argv[0]}: error: '), err
    for needle in needles:
        assert needle in err, err
    assert not out.exists()
