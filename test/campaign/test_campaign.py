"""``dmf-sim campaign``: a small grid run and scored (in the process, and on a 2-worker Dask
cluster), its table, summary and plot; a bad grid value is one line and exit 2."""
from __future__ import annotations

import csv
import json

import pytest

from dmf_sim.campaign.runner import Case, run_campaign
from dmf_sim.cli import main as cli_main


def test_campaign_local_scores_the_grid(tmp_path, capsys):
    out = tmp_path / 'camp'
    assert cli_main(['campaign', '--out', str(out), '--speeds', '1300', '--loads', '0.5',
                     '--faults', 'none,misfire', '--noise', '1', '--duration', '1.5',
                     '--local', '--keep-bags']) == 0
    rows = list(csv.DictReader(open(out / 'scores.csv')))
    assert [(r['fault'], int(r['misfires'])) for r in rows] == [('none', 0), ('misfire', 2)]
    assert all(int(r['false_alarms']) == 0 for r in rows)
    assert int(rows[1]['detected']) == 2
    assert abs(float(rows[0]['mean_speed_rpm']) - 1300) < 5
    summary = json.loads((out / 'summary.json').read_text())
    assert summary['detection_rate'] == 1.0 and summary['false_alarm_rate'] == 0.0
    assert summary['runs'] == 2 and summary['runs_per_s'] > 0
    assert (out / 'campaign.png').stat().st_size > 1000
    assert all((out / 'bags' / r['case'] / 'metadata.yaml').exists() for r in rows)
    assert 'detection rate 1.0000' in capsys.readouterr().out


@pytest.mark.slow
def test_campaign_on_two_dask_workers_gives_the_same_scores(tmp_path):
    from dmf_sim.cluster import close_local, start_local

    grid = [Case(1300.0, 0.5, 'misfire', 1.0), Case(1700.0, 1.0, 'misfire', 3.0)]
    here, _ = run_campaign(grid, None, duration_s=1.5)
    cluster, client = start_local(2)
    try:
        there, summary = run_campaign(grid, client, duration_s=1.5)
    finally:
        close_local(cluster, client)
    assert summary['workers'] == 2 and summary['runs'] == 2
    key = ('misfires', 'detected', 'false_alarms', 'cycles')
    assert [[r[k] for k in key] for r in here] == [[r[k] for k in key] for r in there]
    assert all(r['detected'] == r['misfires'] == 2 for r in there)


@pytest.mark.parametrize('option, value, message', [
    ('--faults', 'misfire,leak', "--faults: 'leak' is not one of none, misfire"),
    ('--noise', '-1', '--noise: -1.0 must be in [0, 100]'),
    ('--loads', '1.5', '--loads: 1.5 must be in [0, 1]'),
    ('--speeds', 'fast', "--speeds: 'fast' is not a comma-separated list of numbers"),
    ('--duration', '0.1', '--duration 0.1: must be in [0.5, 600] s'),
])
def test_a_bad_grid_is_one_line(tmp_path, capsys, option, value, message):
    out = tmp_path / 'camp'
    assert cli_main(['campaign', '--out', str(out), '--local', option, value]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()
