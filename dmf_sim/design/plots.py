"""Figures of a study (PNG): objective maps, the Pareto front, Fig. 13 of the best design.

* ``objective_maps.png``: one heat map per objective over the two map variables (default the
  first two design variables). Each cell shows the smallest value of the designs in it, i.e. the
  best that the other variables can do there; grid levels are cells of their own, random and
  Latin-hypercube samples are binned. Dots mark the designs, crosses failed ones.
* ``pareto.png``: every design in the plane of the first two objectives, the non-dominated ones
  joined, the compromise ('best') design and the reference design (the paper's) marked.
* ``fig13_best.png``: the paper's Fig. 13 quantities over speed (every branch, dashed where
  unstable) of the best design beside the reference design, at the study's first condition.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from dmf_sim.design.evaluate import StudyContext, evaluate_design, sweep_condition
from dmf_sim.design.metrics import OBJECTIVES
from dmf_sim.design.parameters import design_driveline

__all__ = ['MAX_CELLS', 'PARETO_IDS_LISTED', 'write_plots', 'reference_row']

MAX_CELLS = 40            # bins per map axis for scattered samples
PARETO_IDS_LISTED = 6     # design ids named in the Pareto legend before 'and n more'


def write_plots(result, out) -> dict[str, str]:
    """Write the three figures of ``result`` (a StudyResult) into ``out``; returns their paths."""
    from dmf_sim.figures import save
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ref = reference_row(result.study)
    files = {}
    for name, draw in (('objective_maps', _maps), ('pareto', _pareto), ('fig13_best', _fig13)):
        fig = draw(result, ref)
        if fig is not None:
            files[name] = str(save(fig, out / f'{name}.png'))
    return files


def reference_row(study) -> dict:
    """Summary row of the study's reference design (the paper's), evaluated here."""
    ctx = StudyContext.from_study(study)
    ctx.params, ctx.fixed = list(study.reference), {}
    ctx.variable_names = [p.name for p in ctx.params]
    return evaluate_design(ctx, -1, list(study.reference.values()))[-1]


def _label(name: str) -> str:
    return OBJECTIVES.get(name, name)


def _axis(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cell edges, cell index of every value): one cell per level for grid levels (values
    repeat, at most MAX_CELLS levels), else about sqrt(n) equal bins (4..MAX_CELLS)."""
    levels = np.unique(values)
    if len(levels) < len(values) and len(levels) <= MAX_CELLS:
        mid = 0.5 * (levels[1:] + levels[:-1])
        pad = (levels[-1] - levels[0]) / (2 * max(len(levels) - 1, 1)) or 0.5 * abs(levels[0]) or 1
        edges = np.concatenate([[levels[0] - pad], mid, [levels[-1] + pad]])
    else:
        n_bins = int(np.clip(np.sqrt(len(values)), 4, MAX_CELLS))
        edges = np.linspace(values.min(), values.max(), n_bins + 1)
    idx = np.clip(np.searchsorted(edges, values, side='right') - 1, 0, len(edges) - 2)
    return edges, idx


def _maps(result, ref):
    study = result.study
    rows = result.rows('design')
    ok = [r for r in rows if r['status'] == 'ok']
    bad = [r for r in rows if r['status'] != 'ok']
    objs = study.objectives
    fig = Figure(figsize=(4.6 * len(objs), 4.0), layout='constrained')
    axes = fig.subplots(1, len(objs), squeeze=False)
    xv = study.map_variables[0]
    yv = study.map_variables[1] if len(study.map_variables) > 1 else None
    x = np.array([r[xv] for r in ok], dtype=float)
    for ax, obj in zip(axes[0], objs):
        v = np.array([r[obj] for r in ok], dtype=float)
        if yv is None:            # one design variable: the objective over it
            order = np.argsort(x)
            ax.plot(x[order], v[order], 'o-', ms=3)
            ax.set_ylabel(obj)
        elif len(ok):
            y = np.array([r[yv] for r in ok], dtype=float)
            ex, ix = _axis(x)
            ey, iy = _axis(y)
            cell = np.full((len(ey) - 1, len(ex) - 1), np.nan)
            for i, j, val in zip(iy, ix, v):
                if np.isfinite(val) and not val >= cell[i, j]:
                    cell[i, j] = val
            mesh = ax.pcolormesh(ex, ey, cell, cmap='viridis', shading='flat')
            fig.colorbar(mesh, ax=ax, shrink=0.85)
            ax.plot(x, y, '.', color='w', ms=2, alpha=0.6)
            ax.plot([r[xv] for r in bad], [r[yv] for r in bad], 'x', color='tab:red', ms=5)
            ax.set_ylabel(yv)
        ax.set_xlabel(xv)
        ax.set_title(f'{obj}\n{_label(obj)}', fontsize=8)
    fig.suptitle(f'{study.name}: objectives over {", ".join(study.map_variables)} '
                 '(each cell: best over the other variables; x = failed design)', fontsize=9)
    return fig


def _pareto(result, ref):
    from dmf_sim.figures import legend_beside
    study = result.study
    o1, o2 = study.objectives[:2]
    ok = [r for r in result.rows('design') if r['status'] == 'ok']
    fig = Figure(figsize=(9.0, 5.0), layout='constrained')
    ax = fig.subplots()
    ax.plot([r[o1] for r in ok], [r[o2] for r in ok], '.', color='0.6', label='designs')
    front = sorted((r for r in ok if r['pareto']), key=lambda r: (r[o1], r[o2]))
    ax.plot([r[o1] for r in front], [r[o2] for r in front], 'o-', color='tab:blue', ms=4,
            label=f'non-dominated ({len(front)})')
    same = _coincident(ok, o1, o2)
    for (x, y), ids in same.items():          # designs under one marker: say how many
        if len(ids) > 1:
            ax.annotate(f'×{len(ids)}', (x, y), xytext=(5, 4), textcoords='offset points',
                        fontsize=7, color='0.25')
    if result.best_id is not None:
        b = result.design(result.best_id)
        twins = [i for i in same.get(_key(b, o1, o2), []) if i != b['design_id']]
        also = (f' (same values: design{"s" if len(twins) > 1 else ""} '
                f'{_id_list(twins)})' if twins else '')
        ax.plot(b[o1], b[o2], '*', color='tab:orange', ms=14,
                label=f'best: design {b["design_id"]}{also}')
    if ref['status'] == 'ok':
        ax.plot(ref[o1], ref[o2], 's', color='tab:red', ms=8, label=_ref_text(study))
    ax.set_xlabel(f'{o1}: {_label(o1)}', fontsize=8)
    ax.set_ylabel(f'{o2}: {_label(o2)}', fontsize=8)
    ax.grid(alpha=0.3)
    legend_beside(ax)
    ax.set_title(f'{study.name}: Pareto front (both minimized)', fontsize=10)
    return fig


def _key(row: dict, o1: str, o2: str) -> tuple[float, float]:
    """A design's point in the objective plane, rounded to 12 significant digits (designs that
    differ below that sit under one marker)."""
    return tuple(float(f'{float(row[o]):.12g}') for o in (o1, o2))


def _coincident(rows: list[dict], o1: str, o2: str) -> dict[tuple[float, float], list[int]]:
    """Design ids per point of the objective plane."""
    out: dict[tuple[float, float], list[int]] = {}
    for r in rows:
        out.setdefault(_key(r, o1, o2), []).append(int(r['design_id']))
    return out


def _id_list(ids: list[int], most: int = PARETO_IDS_LISTED) -> str:
    shown = ', '.join(str(i) for i in ids[:most])
    return shown + (f' and {len(ids) - most} more' if len(ids) > most else '')


def _ref_text(study) -> str:
    return 'reference: ' + ', '.join(f'{p.name} = {v:g}' for p, v in study.reference.items())


def _fig13(result, ref):
    from dmf_sim.figures import sweep_panel, windup_figure
    study = result.study
    if result.best_id is None:
        return None
    ctx = StudyContext.from_study(study)
    cond = study.conditions[0]
    best = result.design(result.best_id)
    panels = []
    best_text = ', '.join(f'{v} = {best[v]:.4g}' for v in study.variable_names)
    for values, text in ((study.reference, _ref_text(study)),
                         (ctx.design_values([best[v] for v in study.variable_names]),
                          f'best: design {best["design_id"]} ({best_text})')):
        line = design_driveline(study.base, values)
        res = sweep_condition(line, study.engines[cond.load_set], cond.load, ctx.settings)
        panels.append(sweep_panel(text, res))
    return windup_figure(panels, f'DMF wind-up, Load {cond.load_set}, load {cond.load:g} '
                                 '(paper Fig. 13): reference vs best design')
