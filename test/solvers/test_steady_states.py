"""Every steady state, found and trusted: deflated Newton, twins and multiplicity,
stable 1.5th-order states continuation alone missed, non-periodic speeds, no lost work, the
`dmf-sim steady` basins."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.physics.engine import read_engine
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_driveline
from dmf_sim.solvers.hbm import CondensedHBM, SweepOptions, sweep
from dmf_sim.solvers.hbm.deflation import DeflatedNewton
from dmf_sim.solvers.hbm.unknowns import amplitudes, shift, to_real
from dmf_sim.solvers.newmark import SimulationOptions, simulate
from dmf_sim.solvers.nonperiodic import NonPeriodicOptions, classify_section
from dmf_sim.solvers.steady import BasinOptions, find_steady_states, wilson_interval


@pytest.fixture(scope='module')
def pure3(tmp_path_factory):
    """The issue's user A_n table: pure 3rd-order excitation, per cylinder A_0 = 2650/6 and
    A_6 = 2500/6 Nm, 600-1200 rpm every 20 rpm, no load column."""
    rows = ['speed_rpm,n,re,im']
    for s in range(600, 1201, 20):
        for n in range(25):
            re = 2650 / 6 if n == 0 else (2500 / 6 if n == 6 else 0.0)
            rows.append(f'{s},{n},{re!r},0.0')
    path = tmp_path_factory.mktemp('pure3') / 'pure3.csv'
    path.write_text('\n'.join(rows) + '\n')
    return path


def loads_for(engine, alpha, **dmf):
    line = read_driveline('truck_dmf', alpha=alpha).with_dmf(**dmf)
    return DrivelineExcitation(line.reduce(), engine)


@pytest.mark.slow
def test_stable_subharmonic_at_950_rpm_agrees_with_newmark(pure3):
    """Continuation and branch switching alone stop the 1.5th-order branch at its fold (910 rpm);
    the full search finds the stable 1.5th-order state at 950 rpm (7.1 mrad), reported once with
    multiplicity 2, and Newmark from a perturbed static start lands on it."""
    L = loads_for(read_engine(pure3), 3.0)
    fast = sweep(L, 1.0, (600.0, 1200.0), options=SweepOptions(search=None))
    assert not any(q.stable and q.order_1_5 > 1e-3 for q in fast.solutions_at(950.0))
    res = sweep(L, 1.0, (600.0, 1200.0))
    subs = [q for q in res.solutions_at(950.0) if q.stable and q.order_1_5 > 1e-3]
    assert len(subs) == 1                                   # twins reported once
    hb_amp = subs[0].order_1_5
    assert hb_amp == pytest.approx(7.1e-3, rel=0.05)
    branch = next(b for b in res.branches if b.id == subs[0].branch)
    assert branch.multiplicity == 2
    st = L.static_state(950.0, 1.0)
    nm = simulate(L, 950.0, 1.0, initial=(st.q + 2e-3 * L.model.e / (L.model.e @ L.model.e),
                                          np.zeros_like(st.q)),
                  options=SimulationOptions(max_cycles=300))
    assert nm.steady
    assert abs(nm.windup_orders[3]) == pytest.approx(hb_amp, rel=0.02)


def test_deflation_avoids_known_roots_and_shift_is_a_symmetry(pure3):
    L = loads_for(read_engine(pure3), 3.0)
    hb = CondensedHBM(L, 1.0)
    lp = hb.linear_parts(950.0)
    main = hb.solve(950.0)
    # a plain Newton from near the main solution returns it; the deflated one does not
    x0 = main.x + 1e-4
    assert np.abs(hb.solve(950.0, x0).x - main.x).max() < 1e-9
    sol = DeflatedNewton(hb).solve(lp, x0, main.x[None])
    assert sol is None or np.abs(sol[0] - main.x).max() > 1e-4
    # pure 3rd order excitation is 120 deg periodic (exactly at the table's speeds; between
    # them the exact inertia torque adds a little of other orders): every shift of a solution
    # solves it too
    lp = hb.linear_parts(960.0)
    main = hb.solve(960.0)
    c = np.zeros(hb.H + 1, dtype=complex)
    found = None
    for a in (2e-3, 5e-3, 1e-2):
        for ph in (0.0, 0.5 * np.pi):
            c[3] = a * np.exp(1j * ph)
            found = found or DeflatedNewton(hb).solve(lp, main.x + to_real(c, hb.H), main.x[None])
    assert found is not None
    q = hb.make_point(960.0, found[0])
    assert q.order_1_5 > 1e-3 and np.abs(hb.residual(q.x, lp)).max() < 1e-9
    # (to the AFT's sampling: 120 deg is not a whole number of its 256 samples per cycle)
    for k in range(1, 6):
        sx = shift(q.x, k, hb.H)
        assert np.abs(hb.residual(sx, lp)).max() < 1e-2 * np.abs(q.x[1:]).max()
        twin = hb.solve(960.0, sx)
        assert np.abs(amplitudes(twin.x, hb.H) - amplitudes(q.x, hb.H)).max() < 1e-6
    assert np.abs(shift(q.x, 1, hb.H) - q.x).max() > 1e-3           # a distinct twin


@pytest.mark.slow
def test_torus_speed_is_non_periodic_with_newmark_envelope(pure3):
    """At 620 rpm (alpha 2.5) the periodic solution has lost stability through a complex
    multiplier pair; the sweep reports the speed non-periodic with the envelope of a long time
    integration, which an independent long Newmark run confirms (+63/-56 mrad)."""
    L = loads_for(read_engine(pure3), 2.5)
    res = sweep(L, 1.0, (600.0, 640.0))
    rows = [r for r in res.rows() if r['kind'] == 'non_periodic' and r['speed_rpm'] == 620.0]
    assert len(rows) == 1
    row = rows[0]
    assert row['instability'] == 'torus' and row['label'] in ('quasi-periodic', 'chaotic')
    assert not any(q.stable for q in res.solutions_at(620.0))
    # independent check: from the static equilibrium, 250 cycles, the last 150 kept
    T = 4 * np.pi / (620.0 * np.pi / 30)
    nm = simulate(L, 620.0, 1.0, t_end=250 * T, options=SimulationOptions(record_stride=2))
    keep = nm.psi >= 100 * 4 * np.pi
    w = nm.windup[keep]
    assert w.max() - w.mean() == pytest.approx(row['max_deviation'], rel=0.1)
    assert w.min() - w.mean() == pytest.approx(row['min_deviation'], rel=0.1)
    assert row['max_deviation'] == pytest.approx(0.063, rel=0.1)


def test_poincare_labels():
    rng = np.random.default_rng(1)
    scale = np.array([1.0, 1.0])
    k = np.arange(150)
    period3 = np.column_stack([np.cos(2 * np.pi * k / 3), np.sin(2 * np.pi * k / 3)])
    assert (classify_section(period3 + 1e-7 * rng.standard_normal(period3.shape), scale)
            == ('periodic', 3))
    rot = 2 * np.pi * (np.sqrt(5) - 1) / 2
    circle = np.column_stack([np.cos(rot * k), 0.5 * np.sin(rot * k)])
    assert classify_section(circle, scale)[0] == 'quasi-periodic'
    assert classify_section(rng.standard_normal((150, 2)), scale)[0] == 'chaotic'
    spiral = np.column_stack([np.cos(2.1 * k), np.sin(2.1 * k)]) * np.exp(-k / 20.0)[:, None]
    assert classify_section(spiral, scale)[0] == 'long transient'
    assert NonPeriodicOptions().transient < NonPeriodicOptions().cycles


def test_low_damping_sweep_completes_and_covers_the_range():
    """DMF damping 49.5 -> 5 Nms/rad (the issue's case): the sweep completes without error and
    covers 600-1200 rpm; a stable periodic state exists at 1050 rpm."""
    L = DrivelineExcitation(read_driveline('truck_dmf', alpha=3.0).with_dmf(damping=5.0).reduce(),
                       read_engine('engine_d13'))
    res = sweep(L, 1.0, (600.0, 1200.0), options=SweepOptions(step_rpm=10.0))
    assert res.uncovered == []
    grid = np.arange(600.0, 1201.0, 10.0)
    covered = [any(min(p.speed_rpm, q.speed_rpm) <= s <= max(p.speed_rpm, q.speed_rpm)
                   for b in res.branches for p, q in zip(b.points[:-1], b.points[1:]))
               for s in grid]
    assert all(covered)
    assert res.stable_states_at(1050.0) >= 1


def test_a_failing_case_does_not_lose_the_others(monkeypatch, capsys, tmp_path):
    import dmf_sim.solvers.hbm as hbm
    from dmf_sim.core.errors import ConvergenceError

    real = hbm.sweep

    def flaky(loads, load, speed_range, **kw):
        if loads.model.spring.alpha == 2.0:
            raise ConvergenceError('HBM Newton: residual 1e-3 after 40 iterations')
        return real(loads, load, speed_range, **kw)
    monkeypatch.setattr(hbm, 'sweep', flaky)
    assert cli_main(['sweep', '--alpha', '2', '3', '--speeds', '900', '960', '20', '--fast',
                     '--no-progress', '--json']) == 0
    out = capsys.readouterr()
    data = json.loads(out.out)
    assert [s['alpha'] for s in data['sweeps']] == [3.0]
    assert data['failed'][0]['alpha'] == 2.0 and 'residual' in data['failed'][0]['error']
    assert 'alpha=2, Load A failed' in out.err


def test_corrector_leaving_the_engine_data_ends_the_branch_with_an_event():
    from dmf_sim.core.errors import OperatingRangeError
    from dmf_sim.solvers.continuation import (
        BranchHooks,
        BranchStart,
        ContinuationOptions,
        continue_branch,
    )

    class Problem:                       # r = x - s^2 / 1e4, but no data above 1000
        def residual_and_jacobians(self, x, s):
            if s > 1000.0:
                raise OperatingRangeError(f'speed_rpm: must be in [0, 1000] rpm (got {s:g})')
            return x - np.array([s * s / 1e4]), np.eye(1), np.array([-2 * s / 1e4])

    ends = []
    pts = continue_branch(Problem(), BranchStart(np.array([81.0]), 900.0, (0.0, 2000.0), 1.0),
                          ContinuationOptions(s_scale=10.0, x_scale=1.0, grid=10.0),
                          BranchHooks(on_end=lambda reason, p: ends.append((reason, p.s))))
    assert ends and ends[0][0] == 'left_range'
    assert 990.0 <= pts[-1].s <= 1000.0


def test_steady_lists_states_with_basins_and_confidence(pure3, capsys):
    L = loads_for(read_engine(pure3), 3.0)
    res = find_steady_states(L, 950.0, 1.0, basin=BasinOptions(samples=12, seed=3))
    stable = res.stable
    assert len(stable) == 1 and stable[0].kind == '1.5th order' and stable[0].multiplicity == 2
    assert sum(s.hits for s in res.states) + res.unsettled == 12
    assert stable[0].hits == 12
    lo, hi = wilson_interval(12, 12)
    assert lo > 0.7 and hi == 1.0
    assert cli_main(['steady', '--speed', '950', '--alpha', '3', '--engine', str(pure3),
                     '--samples', '6', '--json', '--no-progress']) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['n_stable'] == 1
    st = data['states'][0]
    assert st['kind'] == '1.5th order' and st['basin']['ci95'][0] <= st['basin']['share'] <= 1.0
    assert data['basin_sampling']['windup_offset_range_rad'][1] > 0


def test_finder_states_are_what_newmark_reaches_from_random_starts(pure3):
    """Every state Newmark reaches from random starts is one of the finder's states, and every
    stable state the finder lists stays put when Newmark starts on it (dt = 5e-5 s: this small
    1.5th order couples to the lightly damped 125 Hz crank mode, where dt = 1e-4 s is 4 % off)."""
    L = loads_for(read_engine(pure3), 3.0)
    res = find_steady_states(L, 920.0, 1.0, basin=BasinOptions(samples=10, seed=5))
    assert res.unsettled == 0
    found_by_newmark = [s for s in res.states if s.found_by.startswith('time integration')]
    assert found_by_newmark == []
    hb = CondensedHBM(L, 1.0)
    for st in res.stable:
        nm = hb.newmark_from(st.point, max_cycles=200, dt=5e-5)
        assert nm.steady
        assert abs(nm.windup_orders[3]) == pytest.approx(st.point.order_1_5, rel=0.02, abs=1e-5)
        assert abs(nm.windup_orders[6]) == pytest.approx(st.point.order_3, rel=0.02)


def test_steady_cli_rejects_bad_options(capsys):
    assert cli_main(['steady', '--speed', '950', '--samples', '100000']) == 2
    assert '--samples' in capsys.readouterr().err
    assert cli_main(['steady', '--speed', '30', '--samples', '0']) == 2
    assert 'engine data covers' in capsys.readouterr().err


def test_a_branch_that_closes_on_itself_ends_instead_of_circling():
    """alpha 3.626, theta 0.2343 (default engine, Load A): continuation from 600 rpm runs onto a
    closed loop between two folds (919 and 1064 rpm). It used to go round it until max_steps
    (about 3,900 points, 9 s); now the branch ends with a closed_loop event, the rest of the range
    is re-seeded, and every grid speed is covered."""
    L = loads_for(read_engine('engine_d13'), 3.626, theta=0.2343)
    res = sweep(L, 1.0, (600.0, 2000.0), options=SweepOptions(search=None))
    assert any(e.kind == 'closed_loop' for e in res.events)
    assert res.n_points < 600 and not res.uncovered


def _paper_loads():
    return loads_for(read_engine('engine_d13'), 3.0, theta=0.24)


def test_a_sweep_stops_at_its_time_limit_naming_phase_and_speed():
    """SweepOptions.time_limit_s bounds the wall time: reached during continuation it raises
    TimeLimitError at once (one point late at most), naming the limit, the phase and the speed;
    a generous limit changes nothing."""
    import time

    from dmf_sim.core.errors import TimeLimitError
    L = _paper_loads()
    t0 = time.process_time()          # CPU time: "at once" also when both cores are busy
    with pytest.raises(TimeLimitError, match=r'time limit 0.001 s reached during continuation '
                                             r'at \d+ rpm'):
        sweep(L, 1.0, (600.0, 2000.0), options=SweepOptions(search=None, time_limit_s=1e-3))
    assert time.process_time() - t0 < 1.0
    free = sweep(L, 1.0, (600.0, 2000.0), options=SweepOptions(search=None))
    bound = sweep(L, 1.0, (600.0, 2000.0), options=SweepOptions(search=None, time_limit_s=600.0))
    assert bound.n_points == free.n_points
    assert np.allclose([p.order_1_5 for b in bound.branches for p in b.points],
                       [p.order_1_5 for b in free.branches for p in b.points])
    for bad in (0.0, -1.0, float('nan'), True, '5'):
        with pytest.raises(ConfigError, match=r'time_limit_s: must be a number in \[0.001, '):
            sweep(L, 1.0, (600.0, 2000.0), options=SweepOptions(time_limit_s=bad))


def test_the_time_limit_also_stops_the_full_search():
    """Past the continuation and branch switching, every search step checks the limit too: a
    sweep whose time runs out as the deflated search starts stops there, with that phase named."""
    from dmf_sim.core.errors import TimeLimitError
    from dmf_sim.solvers.hbm import CondensedHBM
    from dmf_sim.solvers.hbm.sweep import SpeedSweep

    class RunsOutAtTheSearch(SpeedSweep):
        def full_search(self, bar):
            self._deadline = -math.inf
            return super().full_search(bar)

    sw = RunsOutAtTheSearch(CondensedHBM(_paper_loads(), 1.0),
                            SweepOptions(step_rpm=50.0, time_limit_s=600.0))
    with pytest.raises(TimeLimitError, match='during the deflated Newton search at'):
        sw.run((800.0, 1200.0))


def test_sweep_cli_time_limit(capsys):
    """`dmf-sim sweep --time-limit`: a case that reaches it is reported and the run goes on;
    out of range, one line and exit code 2."""
    assert cli_main(['sweep', '--time-limit', '0', '--no-progress']) == 2
    assert '--time-limit: must be a number in [0.001, 86400] s' in capsys.readouterr().err
    code = cli_main(['sweep', '--alpha', '3', '--speeds', '600', '2000', '10', '--fast',
                     '--time-limit', '0.001', '--no-progress', '--json'])
    err = capsys.readouterr().err
    assert code == 2 and 'sweep time limit 0.001 s reached during continuation' in err
    assert 'Traceback' not in err


@pytest.mark.slow
def test_a_state_newton_reaches_from_several_runs_is_listed_once(tmp_path, capsys):
    """Friction DMF with its drive stop moved to 0.25 rad (in contact every cycle at 1200 rpm,
    full load): basin runs settle within the steady tolerance but off the harmonic balance
    state by more than the match tolerance, and each one's Newton polish reached the same
    state. It was listed five times (identical rows, basins 25/15/5/5/5 %) and the output then
    said 'no stable periodic state'. One row now carries every run that reached it, and the
    search's chaotic motion is reported beside it."""
    import yaml

    from dmf_sim.core.paths import config_file
    from dmf_sim.solvers.steady import _fingerprint
    doc = yaml.safe_load(config_file('truck_dmf_friction').read_text())
    doc['dmf']['end_stops']['drive_angle_rad'] = 0.25
    cfg = tmp_path / 'stop_close.yaml'
    cfg.write_text(yaml.safe_dump(doc))
    loads = DrivelineExcitation(read_driveline(cfg).reduce(), read_engine('engine_d13'))
    res = find_steady_states(loads, 1200.0, 1.0, basin=BasinOptions(samples=20, seed=0))
    prints = [_fingerprint(st.point.windup_orders) for st in res.states]
    for i in range(len(prints)):
        for j in range(i):
            assert np.abs(prints[i] - prints[j]).max() > 1e-4 * np.abs(prints[j]).max()
    assert sum(st.hits for st in res.states) + res.unsettled == 20
    assert cli_main(['steady', '--speed', '1200', '--config', str(cfg), '--samples', '20',
                     '--no-progress']) == 0
    out = capsys.readouterr().out
    if res.stable and res.non_periodic:
        assert 'beside them a non-periodic motion' in out and 'no stable periodic' not in out
