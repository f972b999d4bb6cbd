"""Plots of run-ups: order tracks of run-up / run-down over the HBM branches (stable solid,
unstable dashed) with the sweep's events and the jumps found, and the run-up's waterfall (half
orders over speed). Drawn with :mod:`dmf_sim.figures`' rules: the legend below the panels,
outside the data; written by :func:`dmf_sim.figures.save`."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from dmf_sim.figures import legend_below, save
from dmf_sim.transient.runup import ORDERS, RunupResult

__all__ = ['runup_figure', 'plot_runup']

_LABEL = {'order_3': '3rd order', 'order_1_5': '1.5th order'}
_RUN_COLOR = {1: 'tab:red', -1: 'tab:blue'}
_EVENT_STYLE = {'fold': ('k', ':'), 'stability_loss': ('tab:purple', '--'),
                'stability_gain': ('tab:green', '--')}
_WATERFALL_ORDERS = 12.0     # highest engine order shown in the waterfall
_MRAD = 1e3                  # rad -> mrad


def _hbm_branches(ax, curve: dict, key: str, scale: float) -> None:
    """Every branch of the sweep: stable parts solid, unstable dashed."""
    sp = np.asarray(curve['speed_rpm'], float)
    br = np.asarray(curve['branch'])
    val = np.asarray(curve[key], float) * scale
    st = np.array([s is not False for s in curve['stable']])
    labelled = set()
    for b in np.unique(br):
        sel = np.flatnonzero(br == b)
        for stable in (True, False):
            y = np.where(st[sel] == stable, val[sel], np.nan)
            lab = 'HBM stable' if stable else 'HBM unstable'
            if not np.isfinite(y).any():
                continue
            ax.plot(sp[sel], y, color='k' if stable else '0.5', lw=1.2 if stable else 1.0,
                    ls='-' if stable else '--', label=None if lab in labelled else lab)
            labelled.add(lab)


def plot_runup(result: RunupResult, path: Path) -> Path:
    """Save :func:`runup_figure` as ``path`` (PNG)."""
    return save(runup_figure(result), path)


def runup_figure(result: RunupResult) -> Figure:
    """Order tracks (3rd, 1.5th) over speed with the HBM branches, events and jumps, and the
    first run's waterfall; one legend below the panels."""
    fig = Figure(figsize=(15, 5.2), layout='constrained')
    axes = fig.subplots(1, 3, gridspec_kw={'width_ratios': [1, 1, 0.9]})
    curve = next((r.signal('windup').hbm.curve for r in result.runs
                  if r.signal('windup').hbm is not None and r.signal('windup').hbm.curve), None)
    for ax, key in zip(axes[:2], ORDERS):
        if curve is not None:
            _hbm_branches(ax, curve, key, _MRAD)
        for res, d in zip(result.runs, result.directions):
            cyc = res.signal('windup').cycles
            ax.plot(cyc.speed_rpm, getattr(cyc, key) * _MRAD, '.', ms=2, color=_RUN_COLOR[d],
                    alpha=0.6)
        for e in result.events:
            color, ls = _EVENT_STYLE.get(e['kind'], ('0.7', ':'))
            ax.axvline(e['speed_rpm'], color=color, ls=ls, lw=0.8)
        for j in (j for j in result.jumps if j.order == key):
            ax.annotate('', xy=(j.speed_rpm, j.after * _MRAD),
                        xytext=(j.speed_rpm, j.before * _MRAD),
                        arrowprops={'arrowstyle': '->', 'color': _RUN_COLOR[j.direction]})
        ax.set_xlabel('engine speed [rpm]')
        ax.set_ylabel(f'{_LABEL[key]} wind-up amplitude [mrad]')
        ax.set_title(f'{_LABEL[key]}: ramps over the HBM branches', fontsize=10)
    drawn = [ln for ax in axes[:2] for ln in ax.get_lines() if ln.get_label().startswith('HBM')]
    handles = [next(ln for ln in drawn if ln.get_label() == label)      # each kind drawn, once
               for label in dict.fromkeys(ln.get_label() for ln in drawn)]
    handles += [Line2D([], [], ls='none', marker='.', ms=8, color=_RUN_COLOR[d],
                       label=f'run-{"up" if d > 0 else "down"} (a dot per engine cycle)')
                for d in dict.fromkeys(result.directions)]
    for k in sorted({e['kind'] for e in result.events}):
        color, ls = _EVENT_STYLE.get(k, ('0.7', ':'))
        handles.append(Line2D([], [], color=color, ls=ls, lw=0.8, label=f'sweep event: {k}'))
    if result.jumps:
        handles.append(Line2D([], [], color='0.3', marker=r'$\downarrow$', ls='none', ms=9,
                              label='jump found in the record (arrow: before to after)'))
    legend_below(fig, handles, ncols=4, fontsize=8, frameon=False)
    ax = axes[2]
    res = result.runs[0]
    cyc = res.signal('windup').cycles
    n = cyc.coeffs.shape[1]
    orders = np.arange(n) / 2
    keep = orders <= _WATERFALL_ORDERS
    amp = np.abs(cyc.coeffs[:, keep]) * _MRAD
    amp[:, 0] = np.nan                      # the mean is not a vibration
    im = ax.pcolormesh(orders[keep], cyc.speed_rpm, np.log10(np.maximum(amp, 1e-4)),
                       shading='nearest', cmap='magma')
    fig.colorbar(im, ax=ax, label='log10 amplitude [mrad]')
    ax.set_xlabel('engine order')
    ax.set_ylabel('engine speed [rpm]')
    ax.set_title(f'waterfall of the run-{"up" if result.directions[0] > 0 else "down"} '
                 '(DMF wind-up)', fontsize=10)
    return fig
