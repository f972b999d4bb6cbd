"""`dmf-sim paper` on the reduced study, run through its benchmark
(benchmarks/bench_paper.py --quick: the last line is JSON): figures, report.md / report.html,
claims.json, and claim rows that are computed from the study (they follow the data), with the
physics verdicts the package reaches for the default engine."""
from __future__ import annotations

import contextlib
import copy
import dataclasses
import importlib.util
import io
import json
import math
import re
from pathlib import Path

import pytest

import dmf_sim.commands.paper as paper_cmd
from dmf_sim.cli import main as cli_main
from dmf_sim.paper.claims import NO, PARTLY, YES, claims

pytestmark = pytest.mark.slow     # the reduced paper study (bench_paper --quick) runs once

FIGS = ('fig8.png', 'fig12.png', 'fig13.png', 'fig13_damping.png', 'fig14.png', 'fig15.png')
BENCH = Path(__file__).resolve().parents[2] / 'benchmarks' / 'bench_paper.py'


@pytest.fixture(scope='module')
def run(tmp_path_factory):
    """One reduced run of the command through its benchmark; the StudyResults the report was
    made of are kept as well."""
    out = tmp_path_factory.mktemp('paper')
    spec = importlib.util.spec_from_file_location('bench_paper', BENCH)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    seen = {}

    def keep(results):
        seen['results'] = results
        return claims(results)

    so, se = io.StringIO(), io.StringIO()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(paper_cmd, 'claims', keep)
        with contextlib.redirect_stdout(so), contextlib.redirect_stderr(se):
            rc = bench.main(['--quick', '--out', str(out)])
    assert rc == 0, se.getvalue()
    return {'out': out, 'bench': json.loads(so.getvalue().strip().splitlines()[-1]),
            'summary': json.loads((out / 'claims.json').read_text()), 'stderr': se.getvalue(),
            'results': seen['results']}


def test_benchmark_json(run):
    b = run['bench']
    assert b['quick'] is True and b['budget_seconds'] == 120.0
    for key in ('seconds', 'cpu_seconds', 'peak_rss_mib'):
        assert math.isfinite(b[key]) and b[key] > 0
    assert set(b['step_seconds']) >= {'sweeps (Figs. 13, 15)', 'non-linear normal modes (Fig. 14)'}
    assert sum(b['counts'].values()) == 14


def _rows(run) -> dict:
    return {c.key: c for c in claims(run['results'])}


def test_files_reports_and_progress(run):
    out, summary = run['out'], run['summary']
    for name in FIGS:
        assert (out / name).stat().st_size > 10_000, name
    md = (out / 'report.md').read_text()
    table = [ln for ln in md.splitlines() if re.match(r'^\| \d+ \|', ln)]
    assert len(table) == len(summary['claims']) == 14
    for name in FIGS:
        assert f']({name})' in md
    page = (out / 'report.html').read_text()
    assert page.count('src="data:image/png;base64,') == len(FIGS)       # self-contained
    assert not re.search(r'src="(?!data:)', page)
    assert page.count('<tr>') == len(summary['claims']) + 1
    assert all(c['package'] and c['status'] in (YES, PARTLY, NO) for c in summary['claims'])
    assert sum(summary['counts'].values()) == len(summary['claims'])
    assert summary['quick'] and summary['seconds'] > 0
    lines = run['stderr'].strip().splitlines()
    assert len(lines) >= 10 and all(ln.startswith('dmf-sim paper [') for ln in lines)
    assert any('non-linear normal modes' in ln for ln in lines) and 'done:' in lines[-1]


def test_verdicts_for_the_default_engine(run):
    """The package reproduces the paper's headline results with the default engine; it disagrees
    with the text on the primary NNM branch (it stiffens) and shows 'worst amplitude not at the
    highest load' only with a higher full-load plateau."""
    rows = _rows(run)
    for key in ('frequency_shift', 'frequencies', 'band_720_1080', 'growth_with_alpha',
                'pure_third_order', 'peak_720_lower_damping', 'nnm_secondary_branch',
                'flat_branches', 'theta_independence', 'fig15_ordering', 'coexisting_solutions'):
        assert rows[key].status == YES, (key, rows[key].package, rows[key].why)
    assert rows['nnm_primary_branch'].status == NO and 'rise' in rows['nnm_primary_branch'].why
    worst = rows['worst_not_at_highest_load']
    assert worst.status == PARTLY and not worst.values['cases'] and worst.values['what_if_cases']
    assert rows['nnm_convergence'].status in (YES, PARTLY)      # xi only to 10 when quick
    for c in rows.values():
        assert c.status in (YES, PARTLY, NO) and c.paper.startswith('"') and c.package
        assert c.status == YES or c.why, c.key


def test_rows_print_the_computed_numbers(run):
    rows = _rows(run)
    v = rows['frequencies'].values
    assert f'{v["primary_hz"]:.2f} Hz' in rows['frequencies'].package
    assert f'{v["secondary_hz"]:.2f} Hz' in rows['frequencies'].package
    for a, p in rows['growth_with_alpha'].values['peaks'].items():
        assert f'α {a}: {1e3 * p["order_1_5"]:.1f} mrad at {p["speed_rpm"]:.0f} rpm' in \
            rows['growth_with_alpha'].package
    r = run['results']
    assert rows['frequencies'].values['primary_hz'] == r.modes_dmf.frequencies_hz[2]
    assert f'{r.knee_torque_nm:.0f} Nm' in rows['worst_not_at_highest_load'].why


def test_rows_follow_the_data(run):
    """Feed the claims other data: the verdicts and numbers change with it (nothing typed in)."""
    r = copy.copy(run['results'])
    r.sweeps = dict(r.sweeps)
    r.sweeps[(3.0, 'A')] = r.sweeps[(2.0, 'A')]                  # no growth with alpha any more
    r.sweeps[(2.5, 'C')] = r.sweeps[(2.5, 'A')]                  # Load C no lower than Load A
    m = r.modes_dmf_band
    r.modes_dmf_band = dataclasses.replace(m, frequencies_hz=m.frequencies_hz * 1.1)
    rows = {c.key: c for c in claims(r)}
    assert rows['growth_with_alpha'].status != YES
    assert rows['fig15_ordering'].status == NO
    assert rows['frequencies'].status == NO
    f2 = 1.1 * m.frequencies_hz[2]
    assert f'{f2:.2f} Hz' in rows['frequencies'].package
    assert f'{f2 / 0.025:.0f} rpm' in rows['band_720_1080'].package


def test_bad_out_refused(tmp_path, capsys):
    f = tmp_path / 'file'
    f.write_text('x')
    assert cli_main(['paper', '--out', str(f), '--quick']) == 2
    assert 'not a directory' in capsys.readouterr().err
    assert cli_main(['paper', '--out', str(tmp_path / 'o'), '--engine', '/etc/passwd']) == 2
