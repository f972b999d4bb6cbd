"""Bounded work: a profile too long, too large or too steep is refused in one line; a dense
table is read by numpy and run in merged chunks; a bag larger than the free disk space, or a rate
giving no sample, is refused before integrating; waits and worker counts are bounded."""
from __future__ import annotations

import numpy as np
import pytest

from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.transient.profiles import read_profile


def _csv(path, rows, header='time_s,speed_rpm,load'):
    path.write_text(header + '\n' + '\n'.join(','.join(f'{v!r}' for v in r) for r in rows) + '\n')
    return path


# ---- profiles ----------------------------------------------------------------------------------

@pytest.mark.parametrize('spec, needles', [
    ('{csv_long}', ("'time_s' must end within 86400 s", 'got 1000000000.0')),
    ('ramp:800:2000:0.001', ("'time_s' must end within 86400 s",)),
    ('{csv_jump}', (':4:', "'speed_rpm' changes by", 'at most 10000 rpm/s')),
])
def test_a_profile_beyond_the_limits_is_refused(spec, needles, tmp_path):
    """A 2-row profile to 1e9 s ran until killed; a 10 us jump 800 -> 2000 rpm was taken."""
    files = {'csv_long': _csv(tmp_path / 'long.csv', [(0, 800, 1), (1e9, 800, 1)]),
             'csv_jump': _csv(tmp_path / 'jump.csv', [(0, 800, 1), (1, 800, 1),
                                                      (1.00001, 2000, 1), (2, 2000, 1)])}
    with pytest.raises(ConfigError) as err:
        read_profile(spec.format(**{k: str(v) for k, v in files.items()}))
    for needle in needles:
        assert needle in str(err.value), err.value


def test_the_rate_cap_is_the_ramps_for_every_table(tmp_path):
    fastest = _csv(tmp_path / 'fast.csv', [(0, 800, 1), (0.12, 2000, 1)])    # 10 000 rpm/s
    assert read_profile(fastest).speed_rpm[-1] == 2000
    assert read_profile('ramp:800:2000:10000').duration_s == pytest.approx(2.12)
    with pytest.raises(ConfigError, match='rate_rpm_per_s'):
        read_profile('ramp:800:2000:10001')
    y = tmp_path / 'y.yaml'
    y.write_text('points: [[0, 800, 1], [0.001, 2000, 1]]\n')
    with pytest.raises(ConfigError, match='points row 2: field .speed_rpm. changes by'):
        read_profile(y)


def test_rows_beyond_the_limit_are_refused(tmp_path, monkeypatch):
    monkeypatch.setattr('dmf_sim.transient.profiles.MAX_PROFILE_ROWS', 100)
    rows = [(i * 0.1, 1000.0, 0.5) for i in range(101)]
    with pytest.raises(ConfigError, match='101 rows, a profile has at most 100'):
        read_profile(_csv(tmp_path / 'p.csv', rows))
    assert len(read_profile(_csv(tmp_path / 'q.csv', rows[:100]))) == 100


def test_a_file_larger_than_the_limit_is_refused_before_it_is_read(tmp_path, monkeypatch):
    from dmf_sim.core.limits import MAX_PROFILE_CSV_BYTES, MAX_PROFILE_YAML_BYTES

    def unread(*args, **kwargs):
        raise AssertionError('the file was read')
    monkeypatch.setattr('dmf_sim.transient.profiles.read_text', unread)
    for name, limit in (('big.csv', MAX_PROFILE_CSV_BYTES), ('big.yaml', MAX_PROFILE_YAML_BYTES)):
        path = tmp_path / name
        with path.open('wb') as f:
            f.truncate(limit + 1)                   # sparse: no disk used
        with pytest.raises(ConfigError, match='MiB, a .* profile is at most'):
            read_profile(path)


@pytest.mark.slow
def test_a_large_csv_table_is_read_whole_and_its_errors_name_the_line(tmp_path):
    n = 200_000
    t = np.arange(n) * 1e-3
    rows = np.c_[t, 1000 + 100 * np.sin(t), np.full(n, 0.5)]
    path = tmp_path / 'big.csv'
    path.write_text('# measured\ntime_s,speed_rpm,load\n'
                    + '\n'.join(f'{a:.3f},{b:.6f},{c}' for a, b, c in rows) + '\n')
    prof = read_profile(path)
    assert len(prof) == n and prof.speed_rpm[-1] == pytest.approx(rows[-1, 1], abs=1e-6)
    text = path.read_text().splitlines()
    text[50_002] = text[50_002].replace(',0.5', ',1.5')   # data row 50 001, file line 50 003
    path.write_text('\n'.join(text) + '\n')
    with pytest.raises(ConfigError, match=r'big.csv:50003: field .load. must be in \[-1, 1\]'):
        read_profile(path)


def test_a_ramp_is_named_by_its_whole_spec():
    assert read_profile('ramp:800:1000:100:0:0').name == 'ramp:800:1000:100:0:0'
    assert read_profile('ramp:800:1000:100:1:2').name == 'ramp:800:1000:100'    # defaults
    assert read_profile('ramp:800:1000:100:1:5').name == 'ramp:800:1000:100:1:5'
    for spec in ('ramp:800:1000:100:0:0', 'ramp:800:1000:100:0.5'):
        a = read_profile(spec)
        b = read_profile(a.name)
        assert a.name == b.name and np.array_equal(a.t_s, b.t_s) \
            and np.array_equal(a.load, b.load)


# ---- the run -----------------------------------------------------------------------------------

def _run_counting(profile, monkeypatch, **options):
    """Run ``profile`` without writing; (integrator calls, engine speed of every sample)."""
    from dmf_sim.live.simulation import LiveSimulation
    from dmf_sim.transient.run import RunOptions, run_profile
    calls, speeds = [0], []
    integrate, read_out = LiveSimulation.integrate, LiveSimulation.read_out

    def counting(self, *args, **kwargs):
        calls[0] += 1
        return integrate(self, *args, **kwargs)

    def keeping(self, *args, **kwargs):
        s = read_out(self, *args, **kwargs)
        if calls[0]:                    # not the read-out the simulation warms up with
            speeds.append(np.array(s.speed_rpm))
        return s
    monkeypatch.setattr(LiveSimulation, 'integrate', counting)
    monkeypatch.setattr(LiveSimulation, 'read_out', keeping)
    run_profile(profile, None, RunOptions(threads=1, write=False, **options))
    return calls[0], np.concatenate(speeds)


def test_dense_rows_are_merged_into_chunks_and_followed_exactly(monkeypatch):
    """A 1 kHz table of a ramp ran one 1 ms chunk per row (12x slower than the kernel): now it
    runs in the ramp's chunks, with the ramp's speeds."""
    from dmf_sim.transient.profiles import make_profile
    t = np.arange(2001) * 1e-3
    table = make_profile(np.c_[t, 1000 + 50 * t, np.ones_like(t)], name='table')
    n_table, v_table = _run_counting(table, monkeypatch)
    n_ramp, v_ramp = _run_counting(read_profile('ramp:1000:1100:50:1:0'), monkeypatch)
    assert n_table <= 2 * n_ramp and n_table < 100, (n_table, n_ramp)
    assert np.allclose(v_table, v_ramp, rtol=0, atol=1e-6)


def test_noisy_dense_rows_still_run_in_bounded_chunks(monkeypatch):
    from dmf_sim.transient.profiles import make_profile
    from dmf_sim.transient.run import MERGE_ROWS_S
    t = np.arange(1001) * 1e-3
    noisy = make_profile(np.c_[t, 1000 + 8 * (np.arange(1001) % 2), np.ones_like(t)])
    n, speeds = _run_counting(noisy, monkeypatch)
    assert n <= 2 * 1.0 / MERGE_ROWS_S + 2, n
    assert len(speeds) == 1000 and speeds.min() >= 1000 - 1e-9 and speeds.max() <= 1008 + 1e-9


def test_a_bag_larger_than_the_free_disk_space_is_refused_before_running(tmp_path, capsys,
                                                                        monkeypatch):
    monkeypatch.setattr('dmf_sim.core.destinations.free_bytes', lambda path: 10**6)
    out = tmp_path / 'bag'
    assert cli_main(['run', 'ramp:1000:1100:500', '--out', str(out), '--no-progress']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'the bag (2200 samples at 1000 Hz) would take about' in err
    assert '1 MB free' in err and not out.exists()


def test_a_refused_run_keeps_the_bag_it_would_replace(tmp_path, capsys, monkeypatch):
    out = tmp_path / 'bag'
    argv = ['run', 'ramp:1000:1100:500', '--out', str(out), '--no-progress']
    assert cli_main(argv) == 0
    before = {p.name: p.stat().st_size for p in out.iterdir()}
    monkeypatch.setattr('dmf_sim.core.destinations.free_bytes', lambda path: 10**6)
    assert cli_main([*argv, '--overwrite']) == 2
    assert {p.name: p.stat().st_size for p in out.iterdir()} == before     # kept
    err = capsys.readouterr().err
    assert 'MB of the output it replaces' in err and err.count('\n') == 1


def test_a_rate_giving_no_sample_is_refused(capsys):
    """`run --rate 1e-3` integrated the whole profile and wrote 0 samples, exit 0."""
    assert cli_main(['run', 'ramp:1000:1100:500', '--no-write', '--rate', '1e-3']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and '--rate' in err and '0.001 Hz gives 0 samples' in err


def test_the_bag_size_estimate_is_close(tmp_path):
    from dmf_sim.transient.run import RunOptions, bag_bytes, build_simulation, run_profile
    prof = read_profile('ramp:1000:1100:500:1:0.5')
    summary = run_profile(prof, tmp_path / 'bag', RunOptions(threads=1))
    size = sum(f.stat().st_size for f in (tmp_path / 'bag').iterdir())
    estimate = bag_bytes(build_simulation(prof, RunOptions()), summary.samples, prof)
    assert 0.9 * size <= estimate <= size, (estimate, size)


# ---- waits and workers -------------------------------------------------------------------------

@pytest.mark.parametrize('argv, needles', [
    (['design', '{config}/study_example.yaml', '--out', '{tmp}', '--workers', '100000'],
     ('--workers 100000', 'per usable CPU')),
    (['optimize', '{config}/optimize_example.yaml', '--out', '{tmp}', '--workers', '100000'],
     ('--workers 100000',)),
    (['design', '{config}/study_example.yaml', '--out', '{tmp}', '--scheduler', 'tcp://h:1',
      '--connect-timeout', '1e12'], ('--connect-timeout', 'at most 3600 s')),
    (['setpoint', '--speed', '900', '--timeout', '1e12'], ('--timeout', 'at most 3600 s')),
    (['setpoint', '--profile', 'ramp:800:900:10', '--timeout', '1e12'], ('--timeout',)),
    (['monitor', '--once', '--timeout', '1e12'], ('--timeout', 'at most 3600 s')),
])
def test_waits_and_workers_are_bounded(argv, needles, tmp_path, capsys, forbid):
    forbid('dmf_sim.commands._ros.ros_session', 'dmf_sim.design.runner.start_local',
           'dmf_sim.design.runner.run_study', 'dmf_sim.cluster.connect',
           'dmf_sim.cluster.start_local')
    from dmf_sim.core.paths import config_dir
    argv = [a.replace('{tmp}', str(tmp_path / 'out')).replace('{config}', str(config_dir()))
            for a in argv]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1, err
    for needle in needles:
        assert needle in err, err
    assert not (tmp_path / 'out').exists()
