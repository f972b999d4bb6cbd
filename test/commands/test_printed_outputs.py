"""Figures and printed output say what was computed and nothing else: CSV
numbers as people write them (one writer), `modes` of a driveline without DMF, no basin share for
an unstable state, every computed sweep case in a figure."""
from __future__ import annotations

import ast
import csv
import json
from pathlib import Path

import numpy as np
import pytest

import dmf_sim
from dmf_sim.cli import main as cli_main
from dmf_sim.core.csv_out import csv_value, write_csv


def test_csv_floats_read_as_written(tmp_path):
    theta = 0.2 + 0.04                                 # 0.24000000000000002
    assert repr(theta) != '0.24'
    path = write_csv(tmp_path / 'x.csv', ['theta', 'n', 'name', 'missing', 'small', 'np'],
                     [[theta, 3, 'a', None, 1e-5 + 1e-21, np.float64(0.1) * 3],
                      {'theta': float('nan'), 'n': np.int64(4)}])
    rows = list(csv.reader(path.open()))
    assert rows[1] == ['0.24', '3', 'a', '', '1e-05', '0.3']
    assert rows[2] == ['nan', '4', '', '', '', '']
    x = 0.1234567890123456
    assert abs(float(csv_value(x)) - x) <= 5e-12 * abs(x)       # 12 significant digits kept


@pytest.mark.slow
def test_every_csv_of_the_package_goes_through_the_one_writer():
    """No CSV writer outside dmf_sim/core/csv_out.py (csv.writer, DictWriter, pyarrow's)."""
    root = Path(dmf_sim.__file__).parent
    offenders = []
    for path in root.rglob('*.py'):
        if path.name == 'csv_out.py':
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr in ('writer', 'DictWriter') \
                    and isinstance(node.value, ast.Name) and node.value.id == 'csv':
                offenders.append(f'{path.relative_to(root)}:{node.lineno}')
            if isinstance(node, ast.Attribute) and node.attr == 'write_csv' \
                    and isinstance(node.value, ast.Name) and node.value.id != 'self':
                offenders.append(f'{path.relative_to(root)}:{node.lineno}')
    assert offenders == []


def test_design_results_csv_prints_grid_values_as_written(tmp_path):
    import pyarrow as pa

    from dmf_sim.design.table import ResultStore
    store = ResultStore.__new__(ResultStore)
    store.dir = tmp_path
    table = pa.table({'theta': [0.2 + 0.04, 0.3], 'ok': [True, False], 'x': [None, 1.5]})
    files = store.finalize(table)
    lines = Path(files['csv']).read_text().splitlines()
    assert lines == ['theta,ok,x', '0.24,True,', '0.3,False,1.5']


def test_modes_of_a_driveline_without_dmf_names_no_dmf_region(capsys, tmp_path):
    assert cli_main(['modes', '--variant', 'conventional', '--modes', '3']) == 0
    out = capsys.readouterr().out
    assert 'DMF region' not in out and 'no DMF' in out.splitlines()[0]
    assert cli_main(['modes', '--variant', 'conventional', '--modes', '3', '--json']) == 0
    assert json.loads(capsys.readouterr().out)['region'] is None
    assert cli_main(['modes', '--variant', 'conventional', '--region', 'secondary']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and '--region' in err and 'no DMF' in err
    assert cli_main(['modes', '--modes', '3']) == 0
    assert 'DMF region: primary' in capsys.readouterr().out        # the DMF driveline: unchanged


def _states_at_1000_rpm():
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_driveline
    from dmf_sim.solvers.hbm import CondensedHBM
    from dmf_sim.solvers.steady import SteadyState, SteadyStateSet
    L = DrivelineExcitation(read_driveline('truck_dmf').reduce(), read_engine('engine_d13'))
    hb = CondensedHBM(L, 1.0)
    good, bad = hb.solve(1000.0), hb.solve(1000.0)
    good.stable, bad.stable = True, False
    states = [SteadyState(good, 1, 'test', hits=7), SteadyState(bad, 1, 'test', hits=0)]
    return SteadyStateSet(1000.0, 1.0, states, samples=10, amplitude_rad=0.02, unsettled=3)


def test_no_basin_share_for_an_unstable_state(capsys, monkeypatch):
    from dmf_sim.solvers.steady import _Matcher
    res = _states_at_1000_rpm()
    d = res.as_dict()
    assert d['states'][0]['basin']['share'] == pytest.approx(0.7)
    assert d['states'][1]['stable'] is False and d['states'][1]['basin'] is None
    # a run ending on the unstable state's orders is not counted as reaching it
    assert _Matcher(res.states, 0.03).match(res.states[1].point.windup_orders) is res.states[0]
    res.states[0].point.stable = None                  # unknown stability: may match
    assert _Matcher(res.states[1:], 0.03).match(res.states[1].point.windup_orders) is None
    res.states[0].point.stable = True
    monkeypatch.setattr('dmf_sim.solvers.steady.find_steady_states', lambda *a, **k: res)
    assert cli_main(['steady', '--speed', '1000', '--samples', '10', '--no-progress']) == 0
    lines = capsys.readouterr().out.splitlines()
    unstable = [ln for ln in lines if ' False ' in ln]
    stable = [ln for ln in lines if ' True ' in ln]
    assert len(unstable) == 1 and '%' not in unstable[0] and 'unstable' in unstable[0]
    assert len(stable) == 1 and '70.0%' in stable[0]


def test_the_1251_rpm_spike_is_the_6th_order_meeting_the_125_hz_crank_mode():
    """The sharp feature at 1251 rpm in every Fig. 13/15 panel is physical, and not the 11th
    order at 228.7 Hz: the 6th engine order (n = 12) meets the 125.1 Hz mode (damping ratio
    0.05 %); the LINEAR 6th-order wind-up already dips there (harmonic balance with H = 24 and
    36 agree, so it is no aliasing), while the 11th order is 0.002 mrad and flat."""
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_driveline
    from dmf_sim.solvers.hbm import CondensedHBM, HBMOptions
    L = DrivelineExcitation(read_driveline('truck_dmf').reduce(), read_engine('engine_d13'))
    hb = CondensedHBM(L, 1.0)
    marks = hb.sharp_resonances((600.0, 2000.0))
    m = next(r for r in marks if r['half_order'] == 12)
    assert m['speed_rpm'] == pytest.approx(1250.7, abs=0.2)
    assert m['frequency_hz'] == pytest.approx(125.1, abs=0.1) and m['damping_ratio'] < 1e-3
    assert not any(r['half_order'] == 22 for r in marks)
    w6 = {s: abs(hb.linear_parts(s).wlin[12]) for s in (1240.0, 1250.5, 1262.0)}
    assert w6[1250.5] < 0.7 * min(w6[1240.0], w6[1262.0])
    w11 = [abs(hb.linear_parts(s).wlin[22]) for s in np.arange(1240.0, 1262.0, 0.5)]
    assert max(w11) < 1e-5 and np.ptp(w11) < 0.2 * max(w11)
    # the non-linear max deviation jumps there with either number of harmonics (no aliasing)
    jumps = []
    for H in (24, 36):
        h = CondensedHBM(L, 1.0, HBMOptions(n_harmonics=H))
        d = [h.solve(s).summary.max_deviation for s in (1248.0, 1251.0)]
        jumps.append(d[1] - d[0])
    assert min(jumps) > 1e-3 and jumps[0] == pytest.approx(jumps[1], rel=0.02)


@pytest.mark.slow
def test_sweep_figures_hold_every_computed_case_and_label_the_spike(capsys, tmp_path):
    out = tmp_path / 'out'
    assert cli_main(['sweep', '--fast', '--no-progress', '--speeds', '1240', '1260', '20',
                     '--alpha', '2', '3', '--load-set', 'A', 'C', '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    data = json.loads((out / 'sweep.json').read_text())
    drawn = data['figures']
    assert sorted(drawn) == ['fig13.png', 'fig13_load_C.png', 'fig15.png', 'fig15_alpha_3.png']
    every = {f'α {a:g} Load {ls}' for a in (2, 3) for ls in 'AC'}
    assert set(drawn['fig13.png']) | set(drawn['fig13_load_C.png']) == every
    assert set(drawn['fig15.png']) | set(drawn['fig15_alpha_3.png']) == every
    for name, cases in drawn.items():
        assert (out / name).stat().st_size > 0
        assert f'  {name}: {", ".join(cases)}' in printed
    assert 'order 6 meets the 125.1 Hz mode' in printed
    from dmf_sim.commands.sweep import figures
    from dmf_sim.solvers.hbm.results import SweepResult
    res = SweepResult([], [], (1240.0, 1260.0), 1.0, 2.0, 0.24,
                      sharp_resonances=data['sweeps'][0]['sharp_resonances'])
    figs = figures({'theta_rad': 0.24, 'load': 1.0, 'engine': 'e'}, [(2.0, 'A', res)])
    fig, cases = figs['fig13']
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert cases == ['α 2 Load A'] and '6th × 125.1 Hz' in texts


def test_pareto_plot_shows_designs_hidden_under_one_marker():
    """Several designs with identical objective values sat under the 'best' star unseen: the
    star's label names them and every shared marker carries its count."""
    from types import SimpleNamespace

    from dmf_sim.design.plots import _pareto
    rows = [{'design_id': i, 'status': 'ok', 'a': a, 'b': b, 'pareto': p}
            for i, (a, b, p) in enumerate([(1.0, 4.0, True), (2.0, 2.0, True), (2.0, 2.0, True),
                                           (2.0 + 1e-15, 2.0, True), (4.0, 1.0, True),
                                           (3.0, 3.0, False), (3.0, 3.0, False)])]
    study = SimpleNamespace(objectives=['a', 'b'], name='s', reference={})
    result = SimpleNamespace(study=study, rows=lambda what: rows, best_id=1,
                             design=lambda i: rows[i])
    fig = _pareto(result, {'status': 'failed'})
    ax = fig.axes[0]
    counts = sorted(t.get_text() for t in ax.texts)
    assert counts == ['×2', '×3']
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert 'best: design 1 (same values: designs 2, 3)' in labels


def test_worker_watch_says_lost_joined_and_restarted():
    from dmf_sim.cluster import WorkerWatch

    class FakeClient:
        workers = {'tcp://a:1': {'name': 'w0'}, 'tcp://b:1': {'name': 'w1'}}

        def scheduler_info(self, n_workers=-1):
            return {'workers': dict(self.workers)}
    c, said = FakeClient(), []
    watch = WorkerWatch(c, said.append)
    assert watch.check() == []
    c.workers = {'tcp://a:1': {'name': 'w0'}}                          # w1 SIGKILLed
    assert watch.check() == ['worker w1 (tcp://b:1) lost; 1 worker(s) left, its running '
                             'designs are rescheduled']
    c.workers = {'tcp://a:1': {'name': 'w0'}, 'tcp://b:2': {'name': 'w1'}}   # nanny restart
    c.workers['tcp://c:1'] = {'name': 'w2'}                                  # and a new one
    assert watch.check() == ['worker w1 restarted (tcp://b:2); 3 worker(s)',
                             'worker w2 (tcp://c:1) joined; 3 worker(s)']
    assert said == ['worker w1 (tcp://b:1) lost; 1 worker(s) left, its running designs are '
                    'rescheduled', 'worker w1 restarted (tcp://b:2); 3 worker(s)',
                    'worker w2 (tcp://c:1) joined; 3 worker(s)']


def test_worker_watch_on_a_real_cluster():
    """A real (in-process) Dask cluster: a worker that joins and one that leaves are each said
    once, by the watch's own thread (waited on as events, no sleeps)."""
    import threading

    from distributed import Client, LocalCluster

    from dmf_sim.cluster import WorkerWatch
    events, seen = [], threading.Event()

    def say(line):
        events.append(line)
        seen.set()
    with LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client, WorkerWatch(client, say, interval_s=0.1):
        cluster.scale(2)
        client.wait_for_workers(2, timeout=60)
        assert seen.wait(60)
        assert len(events) == 1 and 'joined; 2 worker(s)' in events[0]
        seen.clear()
        cluster.scale(1)
        assert seen.wait(60)
        assert len(events) == 2 and 'lost; 1 worker(s) left' in events[1]
