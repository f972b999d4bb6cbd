"""Output and input paths of every command: one rule for ``--out`` / ``-o`` (new or empty, or
``--overwrite`` replacing only the same command's earlier files), checked for real before anything
is computed, and every path the file system refuses (a file on the way, a name too long, a
read-only place) one line with exit 2 -- never a traceback, never after the computation."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.paths import config_dir

MANIFEST = '.dmf-sim-output.json'  # dmf_sim.core.destinations.MANIFEST (checked below)
LONG = 'n' * 300                    # a name component longer than any file system allows
READ_ONLY = Path('/sys/dmf_sim_output_test')   # refused even to root (sysfs)

# what each command computes: must not be reached when its output path is refused
COMPUTE = ['dmf_sim.commands.modes.modes', 'dmf_sim.commands.loads.mean_torques',
           'dmf_sim.solvers.hbm.sweep', 'dmf_sim.commands.nnm.nnm_branches',
           'dmf_sim.commands.paper.PaperStudy', 'dmf_sim.analysis.pipeline.analyze_bag',
           'dmf_sim.design.runner.run_study', 'dmf_sim.design.runner.start_local',
           'dmf_sim.cluster.connect', 'dmf_sim.cluster.start_local',
           'dmf_sim.optimize.runner.run_optimization',
           'dmf_sim.transient.run.run_profile', 'dmf_sim.transient.runup.runup_analysis',
           'dmf_sim.durability.read.bag_durability', 'dmf_sim.bags.recovery.recover_bag']


@pytest.fixture(scope='module')
def bags(tmp_path_factory):
    """A short run-up and run-down bag (dmf-sim run)."""
    from dmf_sim.transient.profiles import read_profile
    from dmf_sim.transient.run import RunOptions, run_profile
    root = tmp_path_factory.mktemp('bags')
    for name, spec in (('up', 'ramp:1000:1100:500:1:0.1'), ('down', 'ramp:1100:1000:500:1:0.1')):
        run_profile(read_profile(spec), root / name, RunOptions(threads=1))
    return root


def commands(bags: Path) -> dict[str, tuple[list[str], str]]:
    """Each command that writes files: (argv without the output, its output option)."""
    up = str(bags / 'up')
    return {
        'modes': (['modes'], '--out'),
        'loads': (['loads'], '--out'),
        'sweep': (['sweep', '--no-progress'], '--out'),
        'nnm': (['nnm'], '--out'),
        'paper': (['paper', '--quick', '--no-progress'], '--out'),
        'analyze': (['analyze', up], '--out'),
        'design': (['design', str(config_dir() / 'study_example.yaml'), '--no-progress'], '--out'),
        'optimize': (['optimize', str(config_dir() / 'optimize_example.yaml'), '--no-progress'],
                     '--out'),
        'run': (['run', 'ramp:1000:1100:500', '--no-progress'], '--out'),
        'runup': (['runup', up, str(bags / 'down')], '--out'),
        'durability': (['durability', up], '--out'),
        'bag-recover': (['bag-recover', up], '-o'),
    }


def _tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob('*')}


def _refused(argv, capsys, forbid, root: Path, *needles) -> str:
    forbid(*COMPUTE)
    before = _tree(root)
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith(f'dmf-sim {argv[0]}: error: '), err
    for needle in needles:
        assert needle in err, err
    assert _tree(root) == before                        # nothing created, nothing removed
    return err


CASES = ['existing file', 'under a file', 'name too long', 'read-only', 'not empty',
         'foreign file with --overwrite']


@pytest.mark.parametrize('case', CASES)
@pytest.mark.parametrize('command', ['modes', 'loads', 'sweep', 'nnm', 'paper', 'analyze',
                                     'design', 'optimize', 'run', 'runup', 'durability',
                                     'bag-recover'])
def test_a_refused_output_is_one_line_before_any_work(command, case, bags, tmp_path, capsys,
                                                      forbid):
    argv, option = commands(bags)[command]
    shown = '--output' if option == '-o' else option
    work = tmp_path / 'work'
    work.mkdir()
    a_file = work / 'a_file'
    a_file.write_text('x')
    full = work / 'full'
    full.mkdir()
    (full / 'notes.txt').write_text('mine')
    out, extra, needles = {
        'existing file': (a_file, [], ('exists and is not a directory',)),
        'under a file': (a_file / 'sub', [], ('cannot be created', 'is not a directory')),
        'name too long': (work / LONG, [], ('cannot be created', 'File name too long')),
        'read-only': (READ_ONLY, [], ('cannot be created',)),
        'not empty': (full, [], ('not empty', 'notes.txt')),
        'foreign file with --overwrite': (full, ['--overwrite'], ('holds notes.txt',
                                                                  'not overwriting')),
    }[case]
    _refused([*argv, option, str(out), *extra], capsys, forbid, work, shown, *needles)


@pytest.mark.parametrize('argv', [
    ['modes', '--config', LONG], ['loads', '--engine', LONG], ['sweep', '--config', LONG],
    ['steady', '--speed', '1000', '--engine', LONG], ['nnm', '--config', LONG],
    ['paper', '--engine', LONG, '--out', '{tmp}/p'], ['analyze', LONG],
    ['design', LONG, '--out', '{tmp}/d'], ['optimize', LONG, '--out', '{tmp}/o'],
    ['run', LONG, '--no-write'], ['run', f'{LONG}.csv', '--no-write'],
    ['runup', LONG], ['durability', LONG], ['durability', '{bag}', '--settings', LONG],
    ['bag-recover', LONG],
])
def test_an_input_path_the_file_system_refuses_is_one_line(argv, bags, tmp_path, capsys, forbid):
    argv = [a.replace('{tmp}', str(tmp_path)).replace('{bag}', str(bags / 'up')) for a in argv]
    err = _refused(argv, capsys, forbid, tmp_path, 'File name too long')
    assert 'Traceback' not in err


# ---- the rule, written once: the same command's earlier output is replaced, nothing else --------

@pytest.mark.slow
def test_overwrite_replaces_only_the_same_commands_earlier_files(tmp_path, capsys):
    out = tmp_path / 'modes'
    assert cli_main(['modes', '--out', str(out)]) == 0
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest['command'] == 'modes'
    assert manifest['files'] == ['modes.csv', 'modes.json', 'modes.png']
    assert cli_main(['modes', '--out', str(out)]) == 2          # the rule: no silent overwrite
    assert 'pass --overwrite' in capsys.readouterr().err
    assert cli_main(['loads', '--out', str(out), '--overwrite']) == 2     # another command's
    assert 'holds the output of dmf-sim modes' in capsys.readouterr().err
    assert cli_main(['modes', '--out', str(out), '--overwrite', '--modes', '3', '--json']) == 0
    assert len(json.loads((out / 'modes.json').read_text())['frequencies_hz']) == 3
    capsys.readouterr()


def test_overwrite_leaves_no_stale_file_of_the_earlier_run(bags, tmp_path, capsys):
    """The report's case: a second run with fewer outputs kept the first run's extra files."""
    out = tmp_path / 'analysis'
    base = ['analyze', str(bags / 'up'), '--no-hbm', '--no-plots', '--bin-rpm', '0', '--load',
            '1', '--out', str(out)]
    assert cli_main([*base, '--signal', 'windup', '--signal', 'torque:INPUT_SHAFT']) == 0
    assert (out / 'torque_INPUT_SHAFT_orders.csv').exists()
    assert cli_main([*base, '--signal', 'windup', '--overwrite']) == 0
    capsys.readouterr()
    assert sorted(p.name for p in out.iterdir()) == [
        MANIFEST, 'analysis.json', 'windup_cycles.csv', 'windup_orders.csv']


def test_a_failed_run_keeps_the_earlier_output_and_leaves_no_new_directory(tmp_path):
    from dmf_sim.core.destinations import MANIFEST as manifest, claim
    assert manifest == MANIFEST
    earlier = claim(tmp_path / 'a', 'x')
    with earlier.writing() as d:
        (d / 'r.txt').write_text('1')
    again = claim(tmp_path / 'a', 'x', overwrite=True)     # checked; nothing removed yet
    assert (tmp_path / 'a' / 'r.txt').read_text() == '1'
    with pytest.raises(RuntimeError), again.writing() as d:
        (d / 'partial.txt').write_text('2')
        raise RuntimeError('the computation failed while writing')
    assert json.loads((tmp_path / 'a' / MANIFEST).read_text())['files'] == ['partial.txt']
    fresh = claim(tmp_path / 'b' / 'c', 'x')
    with pytest.raises(RuntimeError), fresh.writing():
        raise RuntimeError('nothing written')
    assert not (tmp_path / 'b').joinpath('c').exists()


def test_an_empty_directory_is_taken_and_a_bag_goes_the_same_way(tmp_path, capsys):
    empty = tmp_path / 'bag'
    empty.mkdir()
    argv = ['run', 'ramp:1000:1100:500', '--no-progress', '--out', str(empty)]
    assert cli_main(argv) == 0
    assert (empty / 'metadata.yaml').exists()
    assert cli_main(argv) == 2
    assert 'pass --overwrite' in capsys.readouterr().err
    assert cli_main([*argv, '--overwrite']) == 0
    assert json.loads((empty / MANIFEST).read_text())['command'] == 'run'
    capsys.readouterr()


def test_a_bare_mcap_output_is_replaced_only_when_bag_recover_wrote_it(bags, tmp_path, capsys):
    out = tmp_path / 'fixed.mcap'
    mcap = next((bags / 'up').glob('*.mcap'))
    argv = ['bag-recover', str(mcap), '-o', str(out)]
    assert cli_main(argv) == 0
    assert cli_main(argv) == 2
    assert 'pass --overwrite' in capsys.readouterr().err
    assert cli_main([*argv, '--overwrite']) == 0
    capsys.readouterr()
    other = tmp_path / 'other.mcap'
    other.write_bytes(mcap.read_bytes())            # written by dmf-sim run, not bag-recover
    assert cli_main(['bag-recover', str(mcap), '-o', str(other), '--overwrite']) == 2
    assert 'was not written by dmf-sim bag-recover' in capsys.readouterr().err
    assert other.read_bytes() == mcap.read_bytes()


def test_design_resume_and_overwrite_exclude_each_other(tmp_path, capsys):
    study = str(config_dir() / 'study_example.yaml')
    assert cli_main(['design', study, '--out', str(tmp_path), '--resume', '--overwrite']) == 2
    assert 'give one of them' in capsys.readouterr().err


def test_every_command_that_writes_files_has_overwrite_with_the_same_help():
    from dmf_sim.cli import build_parser
    from dmf_sim.commands._options import OVERWRITE_HELP
    sub = next(a for a in build_parser()._actions if a.dest == 'command')
    writers = {}
    for name, p in sub.choices.items():
        opts = {o: a for a in p._actions for o in a.option_strings}
        if '--out' in opts or '--output' in opts:
            writers[name] = opts.get('--overwrite')
    assert set(writers) == {'modes', 'loads', 'sweep', 'nnm', 'paper', 'analyze', 'design',
                            'optimize', 'run', 'runup', 'durability', 'bag-recover', 'identify',
                            'campaign'}
    assert all(a is not None and a.help == OVERWRITE_HELP for a in writers.values()), writers


def test_os_access_is_not_trusted(tmp_path, monkeypatch):
    """Root passes os.access everywhere: the check creates for real."""
    from dmf_sim.core.destinations import claim
    monkeypatch.setattr(os, 'access', lambda *a, **k: True)
    with pytest.raises(ConfigError, match='cannot be created'):
        claim(READ_ONLY, 'x')
