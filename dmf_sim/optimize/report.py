"""The optimization report: figures (PNG), ``report.md`` and a self-contained ``report.html``.

* ``pareto_vs_lhs.png``: every design of the optimizer and of the Latin-hypercube baseline of the
  same budget in the plane of the first two objectives, feasible fronts joined, the paper's
  design and the compromise ('best') design marked;
* ``hypervolume.png``: hypervolume of the feasible designs after each evaluation, both runs, one
  reference point;
* ``springs.png``: torque-wind-up curves of the Pareto designs beside the paper's two-step
  spring, with the travel and the torque capacity;
* ``fig13_best.png``: the paper's Fig. 13 quantities over speed for the paper's design and the
  best designs, at the condition where the best design's first objective is worst.

Every number in the report is computed in the run (``summary.json`` holds them).
"""
from __future__ import annotations

import base64
import html
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import NullFormatter

from dmf_sim.design.metrics import OBJECTIVES
from dmf_sim.design.parameters import design_driveline
from dmf_sim.figures import legend_beside
from dmf_sim.optimize.hypervolume import hypervolume, hypervolume_history

__all__ = ['FIGURES', 'MAX_SPRINGS', 'MAX_SWEEP_PANELS', 'SPRING_CURVE_POINTS', 'reference_design',
           'ideal_point_search', 'compare_with_reference', 'common_hypervolumes',
           'FRONT_REFERENCE_MARGIN', 'front_reference_point', 'front_hypervolumes', 'spread',
           'pareto_figure', 'hypervolume_figure', 'springs_figure', 'spring_axis',
           'SPRING_AXIS_MARGIN', 'sweeps_figure', 'Block',
           'write_report']

FIGURES = {
    'pareto_vs_lhs.png': 'Designs and feasible Pareto fronts: optimizer vs Latin hypercube of '
                         'the same budget',
    'hypervolume.png': 'Convergence: hypervolume of the feasible designs vs evaluations',
    'springs.png': 'Torque-wind-up curves of the Pareto designs and the paper\'s two-step spring',
    'fig13_best.png': 'Fig. 13-style sweeps: the paper\'s design and the best designs',
}
MAX_SPRINGS = 8              # Pareto designs drawn in springs.png (spread over the front)
MAX_SWEEP_PANELS = 2         # best designs beside the paper's in fig13_best.png
SPRING_CURVE_POINTS = 400
SPRING_AXIS_MARGIN = 1.15    # springs.png: wind-up axis this far beyond the travel and every knee
FRONT_REFERENCE_MARGIN = 0.1  # front reference point: nadir + this x (nadir - ideal) of the fronts


# ------------------------------------------------------------------------------------------------
# numbers
# ------------------------------------------------------------------------------------------------

def reference_design(problem) -> dict:
    """The paper's design (the study's plots.reference) evaluated on the problem's conditions,
    with its constraint values: the summary row plus feasible / violation / constraints."""
    from dmf_sim.design.plots import reference_row
    from dmf_sim.optimize.constraints import violation
    study = problem.study
    row = reference_row(study)
    line = design_driveline(study.base, study.reference)
    cons = problem.constraints
    if row['status'] == 'ok':
        vals = cons.values(line.spring, row)
        row.update(feasible=all(v <= 0 for v in vals), violation=violation(vals),
                   constraints=', '.join(f'{n} {v:+.3g}' for n, v in zip(cons.names, vals)))
    else:
        row.update(feasible=False, violation=math.inf, constraints='failed')
    row['spring'] = line.spring
    return row


def compare_with_reference(result, ref: dict) -> dict:
    """best_vs_paper: the compromise design's objectives relative to the paper's, and whether a
    feasible design dominates the paper's (<= in every objective, < in one); the dominating
    design with the largest smallest improvement."""
    objs = result.problem.objectives
    out = {'paper': {**{o: ref.get(o) for o in objs}, 'feasible': bool(ref['feasible']),
                     'constraints': ref['constraints']}}
    if result.best_id is not None and ref['status'] == 'ok':
        b = result.design(result.best_id)
        out['best'] = {'design_id': b['design_id'], **{o: b[o] for o in objs},
                       **{f'{o}_ratio': _ratio(b[o], ref[o]) for o in objs}}
    dom = []
    if ref['status'] == 'ok':
        for r in result.rows('design'):
            if not _counts(r):
                continue
            if all(r[o] <= ref[o] for o in objs) and any(r[o] < ref[o] for o in objs):
                dom.append(r)
    out['n_dominating'] = len(dom)
    out['dominates_paper'] = bool(dom)
    if dom:
        top = min(dom, key=lambda r: max(_ratio(r[o], ref[o]) for o in objs))
        out['dominating'] = {'design_id': top['design_id'],
                             **{f'{o}_ratio': _ratio(top[o], ref[o]) for o in objs}}
    return out


def _ratio(value: float, paper: float) -> float:
    """A design's objective over the paper design's (NaN when the paper's is 0)."""
    return value / paper if paper else math.nan


def _objective_points(rows: list[dict], objs) -> np.ndarray:
    return np.array([[_f(r.get(o)) for o in objs] for r in rows], dtype=float).reshape(
        len(rows), len(objs))


def common_hypervolumes(result, baseline, reference_point=None) -> dict:
    """Hypervolume histories of both runs against one reference point (default 1.1 x the
    largest feasible value of each objective over both runs; e.g. the paper's design's
    objectives to count only the volume that improves on it), and their final ratio."""
    objs = result.problem.objectives
    cols = {}
    for name, res in (('optimizer', result), ('lhs', baseline)):
        rows = sorted(res.rows('design'), key=lambda r: r['design_id'])
        cols[name] = (_objective_points(rows, objs), np.array([_counts(r) for r in rows],
                                                               dtype=bool))
    f = np.concatenate([c[0][c[1]] for c in cols.values()])
    if not len(f):
        return {'reference_point': None, 'optimizer': [], 'lhs': [], 'optimizer_final': 0.0,
                'lhs_final': 0.0, 'ratio': math.nan}
    ref = (tuple(float(v) for v in reference_point) if reference_point is not None
           else tuple(1.1 * float(v) for v in f.max(axis=0)))
    hv = {k: hypervolume_history(*c, ref) for k, c in cols.items()}
    last = {k: float(v[-1]) if len(v) else 0.0 for k, v in hv.items()}
    return {'reference_point': list(ref), 'optimizer': hv['optimizer'].tolist(),
            'lhs': hv['lhs'].tolist(), 'optimizer_final': last['optimizer'],
            'lhs_final': last['lhs'],
            'ratio': last['optimizer'] / last['lhs'] if last['lhs'] > 0 else math.inf}


def front_reference_point(result, baseline, margin: float = FRONT_REFERENCE_MARGIN
                          ) -> tuple[float, ...] | None:
    """The reference point of the fronts themselves: the nadir of both runs' final feasible
    Pareto fronts (the worst value of each objective over their points) plus ``margin`` times
    the fronts' range (nadir - ideal) in each objective, so every point of either front counts.

    The default reference point (1.1 x the worst feasible design) spans the volume of designs
    many times worse than either front, which neither run's front changes: two fronts that differ
    near the best designs then have nearly the same hypervolume (their ratio is bounded by that
    of the ideal point, see :func:`front_hypervolumes`). A reference just beyond the nadir of the
    fronts compared is the usual choice for comparing fronts (H. Ishibuchi et al., "How to
    specify a reference point in hypervolume calculation for fair performance comparison",
    Evolutionary Computation 26(3), 2018). None when a run has no feasible design."""
    objs = result.problem.objectives
    pts = []
    for res in (result, baseline):
        rows = [r for r in res.rows('design') if _counts(r) and r.get('pareto')]
        if not rows:
            return None
        pts.append(_objective_points(rows, objs))
    p = np.concatenate(pts)
    lo, hi = p.min(axis=0), p.max(axis=0)
    span = np.where(hi > lo, hi - lo, np.abs(hi))    # a front of one point: its own size
    return tuple(float(v) for v in hi + margin * span)


def front_hypervolumes(result, baseline, wide: dict | None = None,
                       margin: float = FRONT_REFERENCE_MARGIN) -> dict:
    """Both runs' hypervolumes with :func:`front_reference_point` (``common_hypervolumes`` with
    that point), and ``wide_bound``: the largest ratio any optimizer could reach against this
    baseline with the default reference point (a front at the ideal point of both runs, the
    best feasible value of each objective, over the baseline's hypervolume) -- when it is close to
    1 that reference point cannot tell fronts apart. ``wide``: ``common_hypervolumes(result,
    baseline)`` when the caller has it already (computed here otherwise)."""
    ref = front_reference_point(result, baseline, margin)
    if ref is None:
        return {'reference_point': None, 'optimizer': [], 'lhs': [], 'optimizer_final': 0.0,
                'lhs_final': 0.0, 'ratio': math.nan, 'wide_bound': math.nan}
    out = common_hypervolumes(result, baseline, ref)
    wide = wide if wide is not None else common_hypervolumes(result, baseline)
    ideal = ideal_point_search(result, baseline)['ideal']
    best = hypervolume([[ideal[o] for o in result.problem.objectives]],
                       tuple(wide['reference_point']))
    out['wide_bound'] = best / wide['lhs_final'] if wide['lhs_final'] > 0 else math.inf
    return out


def ideal_point_search(result, baseline, rel: float = 0.01) -> dict:
    """How each run reaches the ideal point of the objectives (the smallest feasible value of
    each over both runs): the evaluations until one feasible design lies within ``rel`` of it in
    every objective (None: never), how many designs do, and the size of each run's final
    front. Where one design is (nearly) best in every objective -- objectives that do not
    conflict -- both fronts shrink to that point and their hypervolumes agree whatever the
    method; these figures still tell how fast and how often a method finds it."""
    objs = result.problem.objectives
    runs = {}
    for name, res in (('optimizer', result), ('lhs', baseline)):
        rows = sorted(filter(_counts, res.rows('design')), key=lambda r: r['design_id'])
        runs[name] = (rows, sum(bool(r.get('pareto')) for r in res.rows('design')))
    every = [r for rows, _ in runs.values() for r in rows]
    if not every:
        return {'ideal': None}
    ideal = {o: min(r[o] for r in every) for o in objs}
    out: dict = {'ideal': ideal, 'rel': rel}
    for name, (rows, front) in runs.items():
        near = [r for r in rows if all(r[o] <= (1 + rel) * ideal[o] for o in objs)]
        out[name] = {'front_size': front, 'n_near_ideal': len(near),
                     'evaluations_to_ideal': (near[0]['design_id'] + 1 if near else None)}
    return out


def _counts(r: dict) -> bool:
    """A design row that enters the fronts and hypervolumes: evaluated and feasible."""
    return bool(r['feasible']) and r['status'] == 'ok'


def _f(v) -> float:
    return math.nan if v is None else float(v)


def spread(rows: list[dict], objective: str, n: int) -> list[dict]:
    """Up to ``n`` rows spread evenly along the front (sorted by ``objective``)."""
    rows = sorted(rows, key=lambda r: r[objective])
    if len(rows) <= n:
        return rows
    idx = np.unique(np.round(np.linspace(0, len(rows) - 1, n)).astype(int))
    return [rows[i] for i in idx]


# ------------------------------------------------------------------------------------------------
# figures
# ------------------------------------------------------------------------------------------------

def _label(name: str) -> str:
    return f'{name}: {OBJECTIVES.get(name, name)}'


def pareto_figure(result, baseline, ref: dict) -> Figure:
    o1, o2 = result.problem.objectives[:2]
    n_obj = len(result.problem.objectives)
    fig = Figure(figsize=(10.0, 5.2), layout='constrained')
    ax = fig.subplots()
    for res, color, name in ((baseline, 'tab:gray', 'Latin hypercube'),
                             (result, 'tab:blue', f'optimizer ({result.problem.method})')):
        if res is None:
            continue
        rows = [r for r in res.rows('design') if r['status'] == 'ok']
        feas = [r for r in rows if r['feasible']]
        bad = [r for r in rows if not r['feasible']]
        ax.plot([r[o1] for r in bad], [r[o2] for r in bad], 'x', color=color, alpha=0.35, ms=4,
                label=f'{name}: infeasible ({len(bad)})')
        ax.plot([r[o1] for r in feas], [r[o2] for r in feas], '.', color=color, alpha=0.6,
                label=f'{name}: feasible ({len(feas)})')
        front = sorted((r for r in rows if r['pareto']), key=lambda r: r[o1])
        # with more than two objectives the front is drawn as points: its projection on the
        # plane of the first two is no staircase
        style = ('o-' if res is result else 'o--') if n_obj == 2 else 'o'
        ax.plot([r[o1] for r in front], [r[o2] for r in front], style, color=color, ms=4,
                mfc='none' if n_obj > 2 else color, label=f'{name}: Pareto front ({len(front)})')
    if result.best_id is not None:
        b = result.design(result.best_id)
        ax.plot(b[o1], b[o2], '*', color='tab:orange', ms=15,
                label=f'best: design {b["design_id"]}')
    if ref['status'] == 'ok':
        ax.plot(ref[o1], ref[o2], 's', color='tab:red', ms=8,
                label='paper (α 3, θ 0.24)' + ('' if ref['feasible'] else ', infeasible'))
    ax.set_xscale('log')
    ax.xaxis.set_minor_formatter(NullFormatter())   # minor labels of a short decade overlap
    ax.set_xlabel(_label(o1), fontsize=8)
    ax.set_ylabel(_label(o2), fontsize=8)
    ax.grid(alpha=0.3, which='both')
    legend_beside(ax, fontsize=7)
    what = ('both objectives' if n_obj == 2 else
            f'the first two of {n_obj} objectives (front: non-dominated in all {n_obj})')
    ax.set_title(f'{result.problem.study.name}: {what} minimized, worst over conditions '
                 'and states', fontsize=9)
    return fig


def hypervolume_figure(hv: dict, method: str) -> Figure:
    fig = Figure(figsize=(8.5, 4.0), layout='constrained')
    ax = fig.subplots()
    for key, color, name in (('optimizer', 'tab:blue', f'optimizer ({method})'),
                             ('lhs', 'tab:gray', 'Latin hypercube')):
        v = np.asarray(hv.get(key) or [])
        ax.plot(np.arange(1, len(v) + 1), v, color=color, label=name)
    ax.set_xlabel('designs evaluated')
    ax.set_ylabel('hypervolume of the feasible designs')
    ax.grid(alpha=0.3)
    legend_beside(ax)
    ref = hv.get('reference_point')
    if ref:
        ax.set_title(f'reference point ({", ".join(f"{v:.4g}" for v in ref)}); final ratio '
                     f'{hv["ratio"]:.3g}', fontsize=9)
    return fig


def springs_figure(result, ref: dict, rows: list[dict]) -> Figure:
    """Torque over wind-up of the Pareto designs ``rows`` and the paper's spring; the wind-up
    axis holds every knee of every spring drawn (coast knees at -angle) and the travel."""
    p = result.problem
    study, cons = p.study, p.constraints
    from dmf_sim.design.evaluate import StudyContext
    ctx = StudyContext.from_study(study)
    springs = []
    for r in rows:
        line = design_driveline(study.base, ctx.design_values([r[v] for v in
                                                               study.variable_names]))
        springs.append((r, line.spring))
    w_lo, w_hi = spring_axis(cons.max_travel_rad or max(r.get('max_windup') or 0.3
                                                        for r in rows),
                             [sp for _, sp in springs] + [ref['spring']])
    w = np.linspace(w_lo, w_hi, SPRING_CURVE_POINTS)
    fig = Figure(figsize=(8.5, 4.8), layout='constrained')
    ax = fig.subplots()
    for r, spring in springs:
        best = r['design_id'] == result.best_id
        ax.plot(w, spring.torque(w), lw=2.2 if best else 1.0,
                color='tab:orange' if best else 'tab:blue', alpha=1.0 if best else 0.6,
                label=f'design {r["design_id"]}' + (' (best)' if best else ''))
    ax.plot(w, ref['spring'].torque(w), color='tab:red', lw=2.0, ls='--',
            label='paper: α 3, θ 0.24 rad')
    ax.set_xlim(w_lo, w_hi)
    ax.axhline(cons.capacity_nm, color='k', lw=0.8, ls=':')
    ax.text(w[0], cons.capacity_nm, f' capacity {cons.capacity_nm:.0f} Nm', fontsize=7,
            va='bottom')
    ax.axhline(cons.engine_max_torque_nm, color='0.5', lw=0.8, ls=':')
    ax.text(w[0], cons.engine_max_torque_nm, f' engine max. mean torque '
            f'{cons.engine_max_torque_nm:.0f} Nm', fontsize=7, va='bottom', color='0.4')
    if cons.max_travel_rad is not None:
        ax.axvline(cons.max_travel_rad, color='k', lw=0.8)
        ax.text(cons.max_travel_rad, ax.get_ylim()[0], ' travel', fontsize=7, rotation=90,
                va='bottom')
    ax.set_xlabel('wind-up w [rad] (positive: engine drives)')
    ax.set_ylabel('DMF spring torque T(w) [Nm]')
    ax.grid(alpha=0.3)
    legend_beside(ax, fontsize=7)
    ax.set_title('Torque-wind-up curves of the Pareto designs', fontsize=9)
    return fig


def spring_axis(travel_rad: float, springs) -> tuple[float, float]:
    """Wind-up range [rad] of the springs figure: :data:`SPRING_AXIS_MARGIN` beyond the travel
    on the drive side and beyond every knee of ``springs`` (drive knees at +angle, coast knees at
    -angle), and at least half the drive side on the coast side."""
    drive = max([travel_rad] + [st.angle_rad for sp in springs for st in sp.drive])
    coast = max([0.5 * drive] + [st.angle_rad for sp in springs for st in sp.coast])
    return -SPRING_AXIS_MARGIN * coast, SPRING_AXIS_MARGIN * drive


def sweeps_figure(result, ref: dict, rows: list[dict]) -> Figure:
    from dmf_sim.design.evaluate import StudyContext, sweep_condition
    from dmf_sim.figures import sweep_bands, sweep_curves, windup_figure
    p = result.problem
    study = p.study
    o1 = p.objectives[0]
    ctx = StudyContext.from_study(study)
    label = rows[0].get(f'{o1}_condition') if rows else None
    cond = next((c for c in study.conditions if c.label == label), study.conditions[0])
    panels = []
    designs = [('paper: α 3, θ 0.24 rad', study.reference)]
    for r in rows:
        designs.append((f'design {r["design_id"]}: ' + _spring_text(r, study),
                        ctx.design_values([r[v] for v in study.variable_names])))
    for text, values in designs:
        line = design_driveline(study.base, values)
        res = sweep_condition(line, study.engines[cond.load_set], cond.load, ctx.settings)
        panels.append((text, sweep_curves(res), sweep_bands(res)))
    return windup_figure(panels, f'DMF wind-up over speed, Load {cond.load_set}, load '
                                 f'{cond.load:g} (paper Fig. 13): the paper\'s design vs the best')


def _spring_text(r: dict, study) -> str:
    return ', '.join(f'{v} {r[v]:.3g}' for v in study.variable_names)


# ------------------------------------------------------------------------------------------------
# the report: blocks rendered as Markdown and as HTML
# ------------------------------------------------------------------------------------------------

@dataclass
class Block:
    kind: str                 # 'h1' 'h2' 'p' 'table' 'figure' 'list'
    content: object


def write_report(result, baseline, out, *, ref: dict, hv: dict, best_vs_paper: dict,
                 exported: dict, seconds: float) -> dict[str, str]:
    """Figures, report.md and report.html in ``out``; returns name -> path."""
    from dmf_sim.figures import save
    out = Path(out)
    p = result.problem
    o1 = p.objectives[0]
    front = [r for r in result.rows('design') if r['pareto']]
    files = {}
    files['pareto_vs_lhs.png'] = save(pareto_figure(result, baseline, ref),
                                      out / 'pareto_vs_lhs.png')
    files['hypervolume.png'] = save(hypervolume_figure(hv, p.method), out / 'hypervolume.png')
    files['springs.png'] = save(springs_figure(result, ref, spread(front, o1, MAX_SPRINGS)),
                                out / 'springs.png')
    best = ([result.design(result.best_id)] if result.best_id is not None else [])
    others = [r for r in spread(front, o1, MAX_SWEEP_PANELS + 1) if r not in best]
    files['fig13_best.png'] = save(sweeps_figure(result, ref,
                                                 (best + others)[:MAX_SWEEP_PANELS]),
                                   out / 'fig13_best.png')
    blocks = _blocks(result, baseline, ref, hv, best_vs_paper, exported, seconds, front)
    (out / 'report.md').write_text(_markdown(blocks))
    (out / 'report.html').write_text(_html(blocks, out, p.study.name))
    files.update({'report.md': out / 'report.md', 'report.html': out / 'report.html'})
    return {k: str(v) for k, v in files.items()}


def _blocks(result, baseline, ref, hv, bvp, exported, seconds, front) -> list[Block]:
    p = result.problem
    s = p.study
    objs = p.objectives
    o1 = objs[0]
    c = p.constraints
    n_feas = sum(bool(r['feasible']) for r in result.rows('design'))
    b: list[Block] = [Block('h1', f'DMF spring optimization: {s.name}')]
    travel = (f'reach {c.capacity_nm:.0f} Nm (capacity) before {c.max_travel_rad:g} rad travel'
              if c.max_travel_rad is not None else 'no travel constraint')
    b.append(Block('p', f'{p.method} ({p.budget} designs, {p.batch_size} per generation, seed '
                        f'{p.seed}) on {len(p.variables)} variables '
                        f'({", ".join(p.names)}); objectives {", ".join(p.objectives)} '
                        '(minimized, '
                        f'worst over conditions {", ".join(x.label for x in s.conditions)}, every '
                        f'stable state and the non-periodic envelopes); constraints: {travel}'
                        + (f', largest DMF torque in operation <= {c.capacity_nm:.0f} Nm'
                           if c.max_dmf_torque else '')
                        + ''.join(f', {m} in [{lo:g}, {hi:g}]' for m, (lo, hi) in c.bounds.items())
                        + (f'. The capacity is {c.capacity_factor:g} x the engine\'s largest '
                           f'mean torque {c.engine_max_torque_nm:.0f} Nm.'
                           if c.capacity_factor else '.')))
    b.append(Block('p', f'{result.n_designs} designs, {n_feas} feasible, '
                        f'{sum(r["status"] != "ok" for r in result.rows("design"))} failed; '
                        f'{len(front)} on the feasible Pareto front. Computed in '
                        f'{seconds:.0f} s.'))
    b.append(Block('h2', 'Optimizer vs Latin hypercube (same budget)'))
    if baseline is not None:
        b.append(Block('p', f'Hypervolume of the feasible designs (reference point '
                            f'{_pt(hv["reference_point"])}): optimizer '
                            f'{hv.get("optimizer_final", math.nan):.4g}, Latin hypercube '
                            f'{hv.get("lhs_final", math.nan):.4g}, ratio {hv["ratio"]:.4g}.'))
        fhv = hv.get('front') or {}
        if fhv.get('reference_point') is not None:
            b.append(Block('p', f'With the fronts\' own reference point (their nadir + '
                                f'{FRONT_REFERENCE_MARGIN:g} x their range: '
                                f'{_pt(fhv["reference_point"])}): optimizer '
                                f'{fhv["optimizer_final"]:.4g}, Latin hypercube '
                                f'{fhv["lhs_final"]:.4g}, ratio {fhv["ratio"]:.3g}. With '
                                f'the reference point above, no front could have a ratio above '
                                f'{fhv["wide_bound"]:.4g} (a design at the ideal point).'))
    else:
        b.append(Block('p', 'No baseline run (--no-baseline).'))
    b.append(Block('h2', 'Best design vs the paper\'s'))
    rows = [['paper (α 3, θ 0.24)', *[_g(ref.get(o)) for o in objs],
             'yes' if ref['feasible'] else 'no', ref['constraints']]]
    if result.best_id is not None:
        r = result.design(result.best_id)
        rows.append([f'best: design {r["design_id"]}', *[_g(r[o]) for o in objs], 'yes',
                     r['constraints']])
    b.append(Block('table', (['design', *objs, 'feasible', 'constraint values (> 0 violated)'],
                             rows)))
    if bvp.get('dominates_paper'):
        d = bvp['dominating']
        b.append(Block('p', f'{bvp["n_dominating"]} feasible designs dominate the paper\'s; '
                            f'design {d["design_id"]}: '
                            + ', '.join(f'{o} x {d[f"{o}_ratio"]:.3g}' for o in objs)
                            + ' of the paper\'s.'))
    else:
        b.append(Block('p', 'No feasible design dominates the paper\'s within the bounds.'))
    b.append(Block('h2', 'Pareto designs'))
    head = ['design', *s.variable_names, *objs, 'max DMF torque [Nm]', 'T(travel) [Nm]',
            'driveline YAML']
    b.append(Block('table', (head, [[str(r['design_id']), *[_g(r[v]) for v in
                                                              s.variable_names],
                                     *[_g(r[o]) for o in objs], _g(r['max_dmf_torque']),
                                     _g(r['torque_at_travel']),
                                     Path(exported.get(str(r['design_id']), '')).name]
                                    for r in sorted(front, key=lambda r: r[o1])])))
    if result.verification:
        from dmf_sim.optimize.verify import verification_extremes, verification_lines
        checks = [v.as_dict() for v in result.verification]
        b.append(Block('h2', 'Verification in the time domain (Newmark)'))
        b.append(Block('p', 'At the speed and condition of each worst value: shots from several '
                            'initial states (their largest value: "Newmark shots"), compared '
                            'with the harmonic-balance worst value ("shots vs HBM"), and slow '
                            'run-ups up and down through the speed (their largest value within '
                            'half a grid step of it: "run-ups"), compared with the same HBM '
                            'value ("run-ups vs HBM"; a ramp passes between the grid speeds and '
                            'is not steady).'))
        for line in verification_lines({'verification': checks,
                                         **verification_extremes(checks)}):
            if line.startswith('  '):           # the comparisons, not their heading
                b.append(Block('p', line.strip()[0].upper() + line.strip()[1:] + '.'))
        b.append(Block('table', (['design', 'objective', 'condition', 'speed [rpm]', 'HBM',
                                  'Newmark shots', 'shots vs HBM', 'run-ups', 'run-ups vs HBM',
                                  'shots settled'],
                                 [[str(v.design_id), v.objective, v.condition,
                                   f'{v.speed_rpm:g}', _g(v.hbm), _g(v.time_domain),
                                   f'{100 * v.rel_diff:.2f} %', _g(v.run_up),
                                   _pct(v.run_up_rel_diff), f'{v.settled}/{len(v.shots)}']
                                  for v in result.verification])))
    if result.transient_verification:
        b.append(Block('h2', 'Verification of the transient objectives (step refinement)'))
        b.append(Block('p', "The load steps of each verified design run again with the "
                            "verification's finer Newmark step: the transient objectives at "
                            "both steps."))
        b.append(Block('table', (['design', 'objective', 'load step', 'study', 'dt [s]',
                                  'refined', 'refined dt [s]', 'difference'],
                                 [[str(v.design_id), v.objective, v.condition,
                                   _g(v.study_value), f'{v.dt_s:g}', _g(v.refined),
                                   f'{v.refined_dt_s:g}', f'{100 * v.rel_diff:.2f} %']
                                  for v in result.transient_verification])))
    b.append(Block('h2', 'Figures'))
    for name, caption in FIGURES.items():
        b.append(Block('figure', (name, caption)))
    return b


def _pct(v: float) -> str:
    return '' if v is None or not math.isfinite(v) else f'{100 * v:+.1f} %'


def _pt(p) -> str:
    return 'none' if not p else '(' + ', '.join(f'{v:.4g}' for v in p) + ')'


def _g(v) -> str:
    if v is None:
        return ''
    if isinstance(v, float):
        return f'{v:.4g}'
    return str(v)


def _md_cell(text) -> str:
    return ' '.join(str(text).split()).replace('|', '\\|')


def _markdown(blocks: list[Block]) -> str:
    out = []
    for bl in blocks:
        if bl.kind == 'h1':
            out += [f'# {bl.content}', '']
        elif bl.kind == 'h2':
            out += [f'## {bl.content}', '']
        elif bl.kind == 'p':
            out += [bl.content, '']
        elif bl.kind == 'table':
            head, rows = bl.content
            out += ['| ' + ' | '.join(_md_cell(h) for h in head) + ' |', '|---' * len(head) + '|']
            out += ['| ' + ' | '.join(_md_cell(c) for c in r) + ' |' for r in rows] + ['']
        elif bl.kind == 'figure':
            name, caption = bl.content
            out += [f'### {caption}', '', f'![{caption}]({name})', '']
    return '\n'.join(out) + '\n'


_CSS = """body{font-family:sans-serif;max-width:1250px;margin:2em auto;color:#222}
table{border-collapse:collapse;font-size:0.85em}td,th{border:1px solid #bbb;padding:3px 6px}
th{background:#eee}img{max-width:100%}figure{margin:1.5em 0}"""


def _html(blocks: list[Block], out: Path, title: str) -> str:
    e = html.escape
    parts = ['<!DOCTYPE html><html><head><meta charset="utf-8">',
             f'<title>dmf_sim optimize: {e(title)}</title><style>{_CSS}</style></head><body>']
    for bl in blocks:
        if bl.kind in ('h1', 'h2'):
            parts.append(f'<{bl.kind}>{e(bl.content)}</{bl.kind}>')
        elif bl.kind == 'p':
            parts.append(f'<p>{e(bl.content)}</p>')
        elif bl.kind == 'table':
            head, rows = bl.content
            parts.append('<table><tr>' + ''.join(f'<th>{e(str(h))}</th>' for h in head) + '</tr>')
            parts += ['<tr>' + ''.join(f'<td>{e(str(c))}</td>' for c in r) + '</tr>'
                      for r in rows]
            parts.append('</table>')
        elif bl.kind == 'figure':
            name, caption = bl.content
            data = base64.b64encode((out / name).read_bytes()).decode('ascii')
            parts.append(f'<figure><img alt="{e(caption)}" src="data:image/png;base64,{data}">'
                         f'<figcaption>{e(caption)}</figcaption></figure>')
    parts.append('</body></html>')
    return '\n'.join(parts) + '\n'
