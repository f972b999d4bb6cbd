"""Figures a reader can trust (issue 11 §3): wind-up panels scaled to the vibration with the
green line = theta - static wind-up, stability as line style, legends outside the data, DMF
element names on the mode plot; the sweep tables carry both the green line and the dynamic mean."""
from __future__ import annotations

import csv
import json

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
from dmf_sim.physics.loads import DrivelineLoads
from dmf_sim.physics.modal import modes
from dmf_sim.physics.model import load_model
from dmf_sim.solvers.hbm import CondensedHBM
from dmf_sim.solvers.hbm import sweep as run_sweep


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
    """Issue 20.15: loc='outside lower center' is matplotlib >= 3.7 only; Ubuntu 24.04 (ROS 2
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
    conv, dmf = modes(load_model('truck_conventional')), modes(truck_dmf)
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
    hbm = CondensedHBM(DrivelineLoads(load_model('truck_dmf', alpha=3.0), engine_d13), 1.0)
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
    loads = DrivelineLoads(load_model('truck_dmf', alpha=3.0), engine_d13)
    inside = run_sweep(loads, 1.0, (980.0, 1020.0))
    assert 'continued from 400 rpm' in inside.main().origin
    full = run_sweep(loads, 1.0, (600.0, 1100.0))
    a, b = inside.solutions_at(1000.0), full.solutions_at(1000.0)
    assert len(a) == len(b) == 1 and a[0].order_1_5 == pytest.approx(b[0].order_1_5, rel=1e-6)
    assert len(sweep_curves(full)) == len(full.branches) + bool(full.non_periodic)
