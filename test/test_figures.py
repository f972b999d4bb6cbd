"""Figures a reader can trust: wind-up panels scaled to the vibration with the
green line = theta - static wind-up, stability as line style, legends outside the data, DMF
element names on the mode plot; the sweep tables carry both the green line and the dynamic mean."""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
from matplotlib.figure import Figure

from dmf_sim.cli import main as cli_main
from dmf_sim.figures import (
    WindupCurves,
    legend_below,
    mode_shapes_figure,
    sweep_curves,
    windup_figure,
)
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.modal import modes
from dmf_sim.physics.model import read_model
from dmf_sim.solvers.hbm import CondensedHBM, sweep as run_sweep

REPO = Path(__file__).resolve().parents[1]


def _curves(stable=None) -> WindupCurves:
    s = np.linspace(600.0, 1400.0, 81)
    o3 = 0.015 + 0.005 * np.cos(s / 200.0)
    green = 0.14 - 0.0002 * (s - 600.0)          # far above the vibration at low speed
    return WindupCurves(s, o3, 0.002 + 0 * s, o3 * 1.1, -o3 * 1.2, green, stable)


def test_windup_panel_scaled_to_vibration_and_green_clipped():
    c = _curves()
    fig = windup_figure([('α = 3, θ = 0.24 rad, Load A, load 1', [c])], 'title')
    ax = fig.axes[0]
    lo, hi = ax.get_ylim()
    vib = max(c.max_deviation.max(), c.order_3.max())
    assert vib < hi <= 1.3 * vib and 1.3 * c.min_deviation.min() <= lo < c.min_deviation.min()
    assert c.theta_minus_static.max() > 5 * hi                # the green line leaves the axis ...
    note = ax.get_title(loc='right')                          # ... and the panel says how far
    assert 'green off scale above' in note and '+0.140 rad at 600 rpm' in note
    off = c.speed_rpm[c.theta_minus_static > hi]
    assert f'{off.min():.0f}-{off.max():.0f} rpm' in note
    for key in ('α = 3', 'θ = 0.24 rad', 'Load A', 'load 1'):
        assert key in ax.get_title(loc='left')
    assert ax.get_legend() is None and len(fig.legends) == 1  # legend outside the data
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any('θ − static wind-up' in t for t in labels) and any('unstable' in t for t in labels)
    assert fig.axes[-1].get_xlabel() == 'engine speed [rpm]'
    assert '[rad]' in ax.get_ylabel()


def _legend_clear_of_axes(fig) -> None:
    """Drawn (the constrained layout runs at draw time): the figure legend's top lies below every
    axis with its tick labels and axis label [pixels]."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    FigureCanvasAgg(fig).draw()
    renderer = fig.canvas.get_renderer()
    top = fig.legends[0].get_window_extent(renderer).y1
    assert top > 0.0
    for ax in fig.axes:
        assert ax.get_tightbbox(renderer).y0 >= top - 1.0, ax.get_title(loc='left')


def test_figure_legends_below_the_panels_on_this_matplotlib():
    """``loc='outside lower center'`` is matplotlib >= 3.7 only; Ubuntu 24.04 (ROS 2
    Jazzy) has 3.6.3, where every figure path raised. legend_below works on both (make
    test-platform runs this on 3.6.3)."""
    c = _curves()
    _legend_clear_of_axes(windup_figure([('a', [c]), ('b', [c])], 'two panels'))
    fig = Figure(figsize=(6.0, 4.0), layout='constrained')
    ax = fig.subplots()
    for k in range(5):
        ax.plot([0.0, 1.0], [0.0, k], label=f'line {k}')
    ax.set_xlabel('x [m]')
    legend = legend_below(fig, ncols=2, fontsize=8)
    assert [t.get_text() for t in legend.get_texts()] == [f'line {k}' for k in range(5)]
    _legend_clear_of_axes(fig)


def test_unstable_stretches_dashed_and_3rd_order_distinct_from_max_deviation():
    stable = np.ones(81)
    stable[30:40] = 0.0                                       # one unstable stretch
    fig = windup_figure([('p', [_curves(stable)])], 't')
    lines = fig.axes[0].get_lines()
    dashed = [ln for ln in lines if ln.get_linestyle() == '--']
    assert len(dashed) == 5                                   # one per quantity drawn
    for ln in dashed:
        x = ln.get_xdata()
        assert x[0] == pytest.approx(_curves().speed_rpm[30]) and len(x) == 11
    red = [ln for ln in lines if ln.get_color() == 'tab:red']
    black = [ln for ln in lines if ln.get_color() == 'black']
    assert red and black
    assert min(ln.get_linewidth() for ln in red) > 2.5 * max(ln.get_linewidth() for ln in black)
    assert max(ln.get_zorder() for ln in red) < min(ln.get_zorder() for ln in black)


def test_mode_plot_names_the_dmf_elements(truck_dmf):
    conv, dmf = modes(read_model('truck_conventional')), modes(truck_dmf)
    fig = mode_shapes_figure(conv, dmf)
    ticks = [t.get_text() for t in fig.axes[-1].get_xticklabels()]
    assert 'PRIMARY FLYWHEEL\n(conv. FLYWHEEL)' in ticks
    assert 'SECONDARY FLYWHEEL\n(conv. CLUTCH)' in ticks
    assert 'CYL1' in ticks and not any(t == 'FLYWHEEL' for t in ticks)
    for ax in fig.axes:
        assert ax.get_ylabel() and ax.get_legend() is not None
        box = ax.get_legend().get_bbox_to_anchor().transformed(ax.transAxes.inverted())
        assert box.x0 > 1.0                                   # right of the data


def test_sweep_tables_hold_green_line_and_dynamic_mean(tmp_path, capsys, engine_d13):
    assert cli_main(['sweep', '--alpha', '3', '--speeds', '940', '1060', '20', '--no-progress',
                     '--json', '--out', str(tmp_path)]) == 0
    data = json.loads(capsys.readouterr().out)
    with open(tmp_path / 'sweep.csv') as fh:
        rows = list(csv.DictReader(fh))
    assert {'theta_minus_static', 'static_windup', 'mean', 'mean_minus_theta'} <= set(rows[0])
    hbm = CondensedHBM(DrivelineExcitation(read_model('truck_dmf', alpha=3.0), engine_d13), 1.0)
    for r in rows:
        s, theta = float(r['speed_rpm']), data['theta_rad']
        assert float(r['static_windup']) == pytest.approx(hbm.static_windup(s), abs=1e-12)
        assert float(r['theta_minus_static']) == pytest.approx(theta - float(r['static_windup']))
        assert float(r['mean_minus_theta']) == pytest.approx(float(r['mean']) - theta)
    # inside the 1.5th-order resonance the dynamic mean moves off the static wind-up
    peak = max(rows, key=lambda r: float(r['order_1_5']))
    assert abs(float(peak['mean']) - float(peak['static_windup'])) > 1e-3
    assert (tmp_path / 'fig13.png').stat().st_size > 10_000


def test_sweep_starts_inside_the_resonance(engine_d13):
    """Newton from the linear response does not converge at 960-1000 rpm (alpha 3, full Load A);
    the sweep then continues its start solution from the engine's lowest speed and lands on the
    same solution as a sweep from 600 rpm."""
    loads = DrivelineExcitation(read_model('truck_dmf', alpha=3.0), engine_d13)
    inside = run_sweep(loads, 1.0, (980.0, 1020.0))
    assert 'continued from 400 rpm' in inside.main().origin
    full = run_sweep(loads, 1.0, (600.0, 1100.0))
    a, b = inside.solutions_at(1000.0), full.solutions_at(1000.0)
    assert len(a) == len(b) == 1 and a[0].order_1_5 == pytest.approx(b[0].order_1_5, rel=1e-6)
    assert len(sweep_curves(full)) == len(full.branches) + bool(full.non_periodic)


# ---- every text on the canvas, every legend off the data (the shared save / legend rules) -----
class _FakeBranch:
    """A SweepResult branch from WindupCurves (what the figures read of it)."""

    kind, id = 'main', 0

    def __init__(self, curves: WindupCurves):
        self.curves = curves

    def column(self, name):
        if name == 'stable':
            return np.ones(len(self.curves.speed_rpm))
        return np.asarray(getattr(self.curves, name), float)


def _fake_sweep(scale: float = 1.0):
    from types import SimpleNamespace
    c = _curves()
    c = WindupCurves(c.speed_rpm, scale * c.order_3, c.order_1_5, scale * c.max_deviation,
                     scale * c.min_deviation, c.theta_minus_static)
    return SimpleNamespace(branches=[_FakeBranch(c)], non_periodic=[], sharp_resonances=[])


@pytest.mark.slow
def test_sweep_figures_keep_their_titles_on_the_canvas(tmp_path):
    """fig13.png / fig15.png of `sweep --alpha 2 2.5 3 --load-set A B C`: the titles naming the
    other figures were wider than the canvas and cut at both edges."""
    from support.figure_checks import texts_off_canvas

    from dmf_sim.commands.sweep import figures
    from dmf_sim.figures import save
    results = [(a, ls, _fake_sweep(1 + a / 10)) for ls in 'ABC' for a in (2.0, 2.5, 3.0)]
    data = {'theta_rad': 0.24, 'load': 1.0, 'engine': 'engine_d13_2500nm'}
    made = figures(data, results)
    assert set(made) == {'fig13', 'fig13_load_B', 'fig13_load_C', 'fig15', 'fig15_alpha_2',
                         'fig15_alpha_3'}
    for name in ('fig13', 'fig15_alpha_2'):            # the longest titles of both families
        fig = made[name][0]
        save(fig, tmp_path / f'{name}.png')
        assert texts_off_canvas(fig) == [], name
    assert 'fig13_load_C.png' in made['fig13'][0]._suptitle.get_text()
    # the sweep page names every file the command writes (it named fig13 and fig15 only)
    page = (REPO / 'doc' / 'commands' / 'sweep.md').read_text()
    for name in made:
        pattern = name.replace('_load_B', '_load_<X>').replace('_load_C', '_load_<X>')
        pattern = re.sub(r'_alpha_[0-9.]+$', '_alpha_<a>', pattern)
        assert f'`{pattern}.png`' in page, pattern


def test_a_long_title_is_wrapped_not_cut():
    from support.figure_checks import texts_off_canvas

    from dmf_sim.figures import fit_titles
    fig = Figure(figsize=(5.0, 4.0), layout='constrained')
    ax = fig.subplots()
    ax.plot([0, 1], [0, 1])
    words = ' '.join(f'word{k}' for k in range(12))
    fig.suptitle(words)
    ax.set_title('left ' + words, loc='left')
    ax.set_title('right ' + words, loc='right')
    assert texts_off_canvas(fig)                        # cut before fitting
    fit_titles(fig)
    assert texts_off_canvas(fig) == []
    assert ' '.join(fig._suptitle.get_text().split()) == words    # the words kept, wrapped


def _rows(n: int, seed: int = 1):
    """Designs spread over the whole objective plane (a legend inside it would cover some)."""
    rng = np.random.default_rng(seed)
    o1, o2 = 10 ** rng.uniform(-3, -1.5, n), rng.uniform(1300, 4300, n)
    return [{'design_id': i, 'status': 'ok', 'feasible': i % 3 > 0, 'pareto': i < 4,
             'worst_order_1_5': float(a), 'worst_torque_3': float(b)}
            for i, (a, b) in enumerate(zip(o1, o2))]


def test_design_and_optimizer_legends_sit_beside_the_data():
    """pareto.png (design) drew its legend over designs ('best' place in a full plane);
    likewise the optimizer's pareto_vs_lhs.png and hypervolume.png."""
    from types import SimpleNamespace

    from support.figure_checks import points_under_legends, texts_off_canvas

    from dmf_sim.design.plots import _pareto
    from dmf_sim.optimize.report import hypervolume_figure, pareto_figure
    rows = _rows(300)
    from collections import namedtuple
    study = SimpleNamespace(objectives=['worst_order_1_5', 'worst_torque_3'], name='spread',
                            reference={namedtuple('Parameter', 'name')('alpha'): 3.0})
    result = SimpleNamespace(study=study, rows=lambda kind: rows, best_id=2,
                             design=lambda i: rows[i])
    ref = {'status': 'ok', 'feasible': True, 'worst_order_1_5': 0.03, 'worst_torque_3': 1900.0}
    problem = SimpleNamespace(objectives=study.objectives, method='nsga2', study=study)
    opt = SimpleNamespace(problem=problem, rows=lambda kind: rows, best_id=2,
                          design=lambda i: rows[i])
    base = SimpleNamespace(problem=problem, rows=lambda kind: _rows(300, seed=2))
    hv = {'optimizer': list(np.linspace(0, 1, 300) ** 0.3), 'lhs': list(np.linspace(0, 0.9, 300)),
          'reference_point': [0.04, 4400.0], 'ratio': 1.1}
    for fig in (_pareto(result, ref), pareto_figure(opt, base, ref),
                hypervolume_figure(hv, 'nsga2')):
        assert points_under_legends(fig) == []
        assert texts_off_canvas(fig) == []


def test_springs_figure_shows_every_coast_knee():
    """springs.png drew the wind-up from -0.5 x 1.15 x travel = -0.167 rad: a coast knee at
    -0.224 rad was off the axis."""
    from types import SimpleNamespace

    from support.figure_checks import points_under_legends, texts_off_canvas

    from dmf_sim.design.parameters import design_driveline
    from dmf_sim.optimize import read_problem
    from dmf_sim.optimize.report import springs_figure
    problem = read_problem('config/optimize_example.yaml')
    names = problem.study.variable_names
    design = dict(zip(names, (0.254, 1.16, 0.276, 4.3, 0.279, 9.7, 0.224, 2.0, 40.0, 3e-3)))
    assert len(design) == len(names)
    rows = [{**design, 'design_id': 155}, {**design, 'design_id': 157,
                                           'coast_stages[0].angle_rad': 0.12}]
    ref = {'spring': design_driveline(problem.study.base, problem.study.reference).spring}
    fig = springs_figure(SimpleNamespace(problem=problem, best_id=155), ref, rows)
    lo, hi = fig.axes[0].get_xlim()
    assert lo < -0.224 and hi > problem.constraints.max_travel_rad
    best = next(ln for ln in fig.axes[0].get_lines() if ln.get_label() == 'design 155 (best)')
    w, torque = best.get_xdata(), best.get_ydata()
    slope = np.gradient(torque, w)
    k = 10890.0                                 # the coast stage's slope k (1 + 2) is drawn
    assert slope[w < -0.23].mean() == pytest.approx(3 * k, rel=1e-3)
    assert points_under_legends(fig) == [] and texts_off_canvas(fig) == []


def test_runup_legend_below_the_panels():
    """runup.png drew its legend inside the 3rd-order panel (upper left), over the tracks."""
    from types import SimpleNamespace

    from support.figure_checks import points_under_legends, texts_off_canvas

    from dmf_sim.transient.plots import runup_figure
    from dmf_sim.transient.runup import Jump
    speed = np.linspace(330.0, 420.0, 200)
    coeffs = np.zeros((200, 25), complex)
    coeffs[:, 6] = np.linspace(0.12, 0.01, 200)          # high where the legend used to be
    coeffs[:, 3] = 0.004 * np.abs(np.sin(speed / 7.0))
    cycles = SimpleNamespace(speed_rpm=speed, order_3=np.abs(coeffs[:, 6]),
                             order_1_5=np.abs(coeffs[:, 3]), coeffs=coeffs)
    curve = {'speed_rpm': list(speed), 'branch': [0] * 200, 'order_3': list(cycles.order_3),
             'order_1_5': list(cycles.order_1_5), 'stable': [True] * 200}
    sig = SimpleNamespace(cycles=cycles, hbm=SimpleNamespace(curve=curve))
    run = SimpleNamespace(signal=lambda name: sig)
    result = SimpleNamespace(runs=[run, run], directions=[1, -1],
                             jumps=[Jump(1, 'order_3', 381.0, 0.1, 0.02, 12.0)],
                             events=[{'kind': 'fold', 'speed_rpm': 372.6}])
    fig = runup_figure(result)
    assert len(fig.legends) == 1 and not any(ax.get_legend() for ax in fig.axes)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert 'sweep event: fold' in labels and any('run-down' in t for t in labels)
    assert points_under_legends(fig) == [] and texts_off_canvas(fig) == []
