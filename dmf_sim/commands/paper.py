"""``dmf-sim paper --out DIR``: the whole reference paper in one command.

Regenerates the paper's Figs. 8, 12, 13, 14 and 15 (plus the lower-damping comparison behind its
720 rpm remark) and writes ``report.md`` and a self-contained ``report.html`` (figures embedded)
with one row per claim of the paper: its words, the package's numbers, reproduced yes / partly /
no, and why where the package disagrees. The computations are in :mod:`dmf_sim.paper.study`, the
claims in :mod:`dmf_sim.paper.claims`, the figures and report in :mod:`dmf_sim.paper.report`;
nothing in the report is typed in. This module parses the options and prints.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

from dmf_sim import __version__
from dmf_sim.commands import _options as opt
from dmf_sim.core.json_out import json_text, write_json
from dmf_sim.paper.claims import NO, PARTLY, YES, claims
from dmf_sim.paper.report import STATUS_MARK, report_html, report_markdown, write_figures
from dmf_sim.paper.study import PaperStudy, StudySettings

__all__ = ['NAME', 'HELP', 'add_arguments', 'run']

NAME = 'paper'
HELP = ('Reproduce the reference paper: Figs. 8, 12, 13, 14, 15 and a report (report.md, '
        'report.html) with one computed row per claim of the paper (about a minute).')


def add_arguments(p) -> None:
    p.add_argument('--out', type=Path, required=True,
                   help='directory for the figures, report.md, report.html and claims.json')
    opt.add_overwrite(p)
    opt.add_engine(p)
    p.add_argument('--quick', action='store_true',
                   help='reduced study (coarser sweeps, smaller load scan, NNMs to xi = 10; '
                        'about 20 s): the same claims computed on less')
    p.add_argument('--no-progress', action='store_true', help='no progress lines on stderr')
    p.add_argument('--json', action='store_true', help='print a JSON summary to stdout')


def run(args) -> int:
    from dmf_sim.live.warm import warm_up
    from dmf_sim.physics.engine import read_engine
    opt.check_names(args)
    dest = opt.output(args, NAME)
    read_engine(args.engine)                       # a bad engine file: one line before any work
    settings = (StudySettings.quick if args.quick else StudySettings)(engine=args.engine)
    t0 = time.perf_counter()

    def say(text: str) -> None:
        if not args.no_progress:
            print(f'dmf-sim paper [{time.perf_counter() - t0:5.1f} s] {text}', file=sys.stderr,
                  flush=True)

    warm_up(NAME, 'sweep', 'time integration')
    results = PaperStudy(settings, progress=say).run()
    rows = claims(results)
    say('figures')
    with dest.writing() as out:
        files = write_figures(results, out)
        seconds = time.perf_counter() - t0
        summary = {
            'out': str(out), 'seconds': round(seconds, 1), 'quick': bool(args.quick),
            'engine': args.engine, 'version': __version__,
            'counts': {k: sum(c.status == k for c in rows) for k in (YES, PARTLY, NO)},
            'claims': [{'key': c.key, 'status': c.status, 'package': c.package} for c in rows],
            'figures': files, 'solver_notes': results.notes, 'step_seconds': results.seconds,
        }
        write_json(out / 'claims.json', {**summary, 'claims': [c.as_dict() for c in rows]},
                   default=float)
        (out / 'report.md').write_text(report_markdown(results, rows, summary))
        (out / 'report.html').write_text(report_html(results, rows, summary, out))
    summary['files'] = [str(out / n) for n in ('report.md', 'report.html', 'claims.json')]
    say(f'done: {summary["counts"][YES]} yes, {summary["counts"][PARTLY]} partly, '
        f'{summary["counts"][NO]} no; {args.out / "report.html"}')
    if args.json:
        print(json_text(summary, default=float))
    else:
        for c in rows:
            print(f'{STATUS_MARK[c.status]:>6}  {c.topic}')
        print(f'report: {args.out / "report.md"}, {args.out / "report.html"} ({seconds:.0f} s)')
    return 0
