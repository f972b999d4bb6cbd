"""The paper reproduction's outputs: its figures (Figs. 8, 12, 13, 14, 15) and the claims report
as Markdown and as one HTML file with the figures embedded."""
from __future__ import annotations

import base64
import datetime
import html
from pathlib import Path

from dmf_sim.paper.claims import NO, PARTLY, YES

__all__ = ['FIGURES', 'STATUS_MARK', 'COLUMNS', 'STATUS_COLUMN', 'write_figures',
           'report_markdown', 'report_html']

FIGURES = {
    'fig8.png': 'Fig. 8: engine mean torque of Loads A/B/C and the torque into the flywheel of '
                'the conventional driveline (Load A, full load)',
    'fig12.png': 'Fig. 12: mode shapes x cumulative gear ratio, conventional vs DMF',
    'fig13.png': 'Fig. 13: DMF wind-up over speed for several α, Load A, full load',
    'fig13_damping.png': 'The 720 rpm remark: Table 1 DMF damping vs a lower one (α = 3, Load A)',
    'fig14.png': 'Fig. 14: non-linear normal modes, frequency against ξ',
    'fig15.png': 'Fig. 15: DMF wind-up over speed, α = 2.5, Loads A, B and C',
}
STATUS_MARK = {YES: 'yes', PARTLY: 'partly', NO: 'no'}
COLUMNS = ('#', 'claim', 'the paper', 'the package (computed)', 'reproduced', 'why / notes')
STATUS_COLUMN = 4


def write_figures(r, out: Path) -> dict[str, str]:
    from dmf_sim.figures import (
        fig8,
        mode_shapes_figure,
        nnm_figure,
        panel_title,
        save,
        sweep_panel,
        windup_figure,
    )
    s = r.settings
    files = {}
    files['fig8.png'] = save(fig8(r.mean_torque_speeds, r.mean_torque, 1.0, r.fig8_psi_deg,
                                  r.fig8_torque, 'A', s.engine), out / 'fig8.png')
    files['fig12.png'] = save(mode_shapes_figure(r.modes_conventional, r.modes_dmf,
                                                 dmf_label='DMF (primary stiffness)'),
                              out / 'fig12.png')
    panels = [sweep_panel(panel_title(a, r.theta, 'A', 1.0), r.sweeps[(a, 'A')])
              for a in s.alphas]
    files['fig13.png'] = save(windup_figure(panels, f'DMF wind-up over engine speed, Load A, full '
                                                    f'load, engine {s.engine} (paper Fig. 13)'),
                              out / 'fig13.png')
    panels = [sweep_panel(panel_title(s.band_alpha, r.theta, 'A', 1.0)
                          + f', DMF damping {r.dmf_damping[k]:g} Nms/rad', r.low_damping[k])
              for k in ('table', 'lower')]
    files['fig13_damping.png'] = save(windup_figure(
        panels, 'DMF wind-up with the Table 1 DMF damping and a lower one (paper: "a resonance '
                'peak at 720 rpm ... for lower damping")'), out / 'fig13_damping.png')
    files['fig14.png'] = save(nnm_figure(r.nnm, xi_max=s.nnm_xi_max), out / 'fig14.png')
    panels = [sweep_panel(panel_title(s.fig15_alpha, r.theta, ls, 1.0),
                          r.sweeps[(s.fig15_alpha, ls)]) for ls in s.load_sets]
    files['fig15.png'] = save(windup_figure(panels, f'DMF wind-up over engine speed, α = '
                                                    f'{s.fig15_alpha:g}, Loads '
                                                    f'{", ".join(s.load_sets)}, full load '
                                                    '(paper Fig. 15)'), out / 'fig15.png')
    return {k: str(v) for k, v in files.items()}


def _settings_text(r, summary: dict) -> str:
    s = r.settings
    lo, hi, step = s.speeds
    return (f'dmf_sim {summary["version"]}, {datetime.date.today().isoformat()}; engine '
            f'`{s.engine}`, driveline `{s.driveline}` (Table 1, θ = {r.theta:g} rad); sweeps '
            f'{lo:g}-{hi:g} rpm every {step:g} rpm with H = {s.n_harmonics} half orders, Floquet '
            f'stability and branch switching; load scan at loads '
            f'{", ".join(f"{v:g}" for v in s.scan_loads)}; NNMs (α = {s.nnm_alpha:g}) to ξ = '
            f'{s.nnm_xi_max:g} with {s.nnm_harmonics} harmonics'
            + (' (reduced study, --quick)' if summary['quick'] else '')
            + f'. Computed in {summary["seconds"]:.0f} s.')


def _cells(i: int, cl) -> list[str]:
    """The report's columns (COLUMNS) for claim ``cl``, row number ``i``."""
    fig = f' ({cl.figure})' if cl.figure else ''
    return [str(i), cl.topic + fig, cl.paper, cl.package, STATUS_MARK[cl.status], cl.why]


def _md_cell(text: str) -> str:
    return ' '.join(str(text).split()).replace('|', '\\|')


def report_markdown(r, rows, summary: dict) -> str:
    c = summary['counts']
    out = ['# The reference paper, reproduced by dmf_sim', '',
           _settings_text(r, summary), '',
           f'**Claims reproduced: {c[YES]} yes, {c[PARTLY]} partly, {c[NO]} no.** Every number '
           'below is computed by the package in this run (`claims.json` holds them all).', '',
           '## Claims', '', '| ' + ' | '.join(COLUMNS) + ' |', '|---' * len(COLUMNS) + '|']
    for i, cl in enumerate(rows, start=1):
        cells = [_md_cell(c) for c in _cells(i, cl)]
        cells[STATUS_COLUMN] = f'**{cells[STATUS_COLUMN]}**'
        out.append('| ' + ' | '.join(cells) + ' |')
    out += ['', '## Figures', '']
    for name, caption in FIGURES.items():
        out += [f'### {caption}', '', f'![{caption}]({name})', '']
    if r.notes:
        out += ['## Solver notes', ''] + [f'- {n}' for n in r.notes] + ['']
    out += ['## Time per step', '', '| step | s |', '|---|---|']
    out += [f'| {k} | {v:.1f} |' for k, v in r.seconds.items()]
    return '\n'.join(out) + '\n'


_CSS = """body{font-family:sans-serif;max-width:1250px;margin:2em auto;color:#222}
table{border-collapse:collapse;font-size:0.9em}td,th{border:1px solid #bbb;padding:4px 6px;
vertical-align:top}th{background:#eee}td.yes{background:#dff0d8}td.partly{background:#fcf8e3}
td.no{background:#f2dede}img{max-width:100%}figure{margin:1.5em 0}"""


def report_html(r, rows, summary: dict, out: Path) -> str:
    """The report as one HTML file with the PNGs embedded (base64)."""
    e = html.escape
    c = summary['counts']
    parts = ['<!DOCTYPE html><html><head><meta charset="utf-8">',
             '<title>dmf_sim: the reference paper, reproduced</title>',
             f'<style>{_CSS}</style></head><body>',
             '<h1>The reference paper, reproduced by dmf_sim</h1>',
             f'<p>{e(_settings_text(r, summary))}</p>',
             f'<p><b>Claims reproduced: {c[YES]} yes, {c[PARTLY]} partly, {c[NO]} no.</b> Every '
             'number below is computed by the package in this run.</p>', '<h2>Claims</h2>',
             '<table><tr>' + ''.join(f'<th>{e(c)}</th>' for c in COLUMNS) + '</tr>']
    for i, cl in enumerate(rows, start=1):
        cells = [f'<td>{e(c)}</td>' for c in _cells(i, cl)]
        cells[STATUS_COLUMN] = f'<td class="{cl.status}"><b>{e(STATUS_MARK[cl.status])}</b></td>'
        parts.append('<tr>' + ''.join(cells) + '</tr>')
    parts += ['</table>', '<h2>Figures</h2>']
    for name, caption in FIGURES.items():
        data = base64.b64encode((out / name).read_bytes()).decode('ascii')
        parts.append(f'<figure><img alt="{e(caption)}" src="data:image/png;base64,{data}">'
                     f'<figcaption>{e(caption)}</figcaption></figure>')
    if r.notes:
        parts += ['<h2>Solver notes</h2><ul>'] + [f'<li>{e(n)}</li>' for n in r.notes] + ['</ul>']
    parts.append('</body></html>')
    return '\n'.join(parts) + '\n'
