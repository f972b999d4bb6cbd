"""Plots of the bag analysis: Campbell diagram + order waterfall, and the paper's Fig. 13.

Conventions shared by both: measured speed bins are markers -- filled where the bin holds at
least ``min_cycles`` engine cycles (steady), hollow where it holds fewer (the speed ramped
through it); the harmonic-balance prediction is lines, solid where stable, dashed where
unstable; legends sit outside the data; every axis names its quantity and unit.

Fig. 13 follows the paper's reading rule: the green line is theta minus the static wind-up of
the mean engine torque (drive positive). Green above both black lines (max/min deviation from
the mean): the wind-up stays in the primary region; below both: secondary only; between: it
crosses the knee. The upper panel is scaled to the vibration; the lower one shows the green
line whole (it can lie far below at low speed). The dynamic mean is in the CSV/JSON outputs.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from dmf_sim.analysis.load_timeline import load_text
from dmf_sim.figures import legend_below, legend_beside, save

__all__ = ['fig13_figure', 'plot_campbell', 'plot_fig13']

_ORDER_STYLE = {'order_3': ('3rd order', 'tab:red'), 'order_1_5': ('1.5th order', 'tab:blue'),
                'max_deviation': ('max / min deviation', 'k'), 'min_deviation': (None, 'k')}
_GREEN = 'tab:green'
_MARGIN = 1.25            # the vibration panel spans the measured/HBM extremes x this


def _label(label: str | None, what: str) -> str | None:
    return None if label is None else f'{label} ({what})'


def _measured(ax, speed, y, steady, color, label) -> None:
    """Markers: filled for steady bins, hollow for ramp bins (``label`` None: no legend)."""
    ax.plot(speed[steady], y[steady], 'o', ms=4, color=color, label=_label(label, 'bag'))
    if (~steady).any():
        ax.plot(speed[~steady], y[~steady], 'o', ms=4, mfc='none', mec=color, alpha=0.6,
                label=_label(label, 'bag, not steady: few cycles or load changing'))


def _hbm_lines(ax, curve, key, color, label) -> None:
    """HBM curve of one quantity: solid stable, dashed unstable, per branch."""
    sp = np.asarray(curve['speed_rpm'], float)
    y = np.asarray(curve[key], float)
    stable = list(curve.get('stable') or [None] * len(sp))
    unstable = np.array([v is False for v in stable], bool)
    br = np.asarray(curve.get('branch') or [0] * len(sp))
    first = True
    for b in np.unique(br):
        sel = br == b
        order = np.argsort(sp[sel], kind='stable') if b == 0 else np.arange(sel.sum())
        s, yy, un = sp[sel][order], y[sel][order], unstable[sel][order]
        ax.plot(s, np.where(~un, yy, np.nan), '-', color=color, lw=1.2,
                label=_label(label, 'HBM') if first else None)
        if un.any():
            ax.plot(s, np.where(un, yy, np.nan), '--', color=color, lw=1.0,
                    label=_label(label, 'HBM, unstable') if first else None)
        first = False


def _title(res, sig) -> str:
    s = dict(sig.hbm.settings) if sig.hbm is not None else dict(res.model or {})
    parts = [f'{res.bag.name}: {sig.signal.description}']
    if s:
        theta = s.get('theta_rad')
        parts.append(', '.join(
            x for x in (f'θ = {theta:.3g} rad' if theta is not None else '',
                        f"α = {s['alpha']:g}" if s.get('alpha') is not None else '',
                        f"load set {s['load_set']}" if s.get('load_set') else '',
                        f"load {load_text(s['load'])}" if s.get('load') is not None else '')
                       if x))
    return ' — '.join(parts)


def plot_fig13(res, sig, path: Path) -> Path:
    """Save :func:`fig13_figure` as ``path`` (PNG)."""
    return save(fig13_figure(res, sig), path)


def fig13_figure(res, sig):
    """The paper's Fig. 13 quantities over speed (see the module docstring): a Figure."""
    t = sig.table
    unit = sig.signal.unit
    steady = t.steady
    green = t.theta_minus_static
    two = green is not None and np.isfinite(green).any()
    fig = Figure(figsize=(11, 7.5 if two else 5.5), layout='constrained')
    axes = fig.subplots(2 if two else 1, 1, sharex=True,
                        gridspec_kw={'height_ratios': [3, 1.3]} if two else None, squeeze=False)
    ax = axes[0, 0]
    curve = sig.hbm.curve if sig.hbm is not None else None
    extremes = []
    for key, (label, color) in _ORDER_STYLE.items():
        y = getattr(t, key)
        _measured(ax, t.speed_rpm, y, steady, color, label)
        extremes.append(y[np.isfinite(y)])
        if curve is not None and curve.get(key):
            _hbm_lines(ax, curve, key, color, label)
            extremes.append(np.asarray(curve[key], float))
    vals = np.concatenate([e[np.isfinite(e)] for e in extremes]) if extremes else np.zeros(1)
    top, bottom = float(vals.max(initial=0.0)) * _MARGIN, float(vals.min(initial=0.0)) * _MARGIN
    if two:
        ax.plot(t.speed_rpm, green, '-', color=_GREEN, lw=1.6,
                label='θ − static wind-up of the mean torque')
        ax.set_ylim(bottom if bottom < 0 else -0.05 * top, top if top > 0 else 1.0)
        low = axes[1, 0]
        low.plot(t.speed_rpm, green, '-', color=_GREEN, lw=1.6, label='θ − static wind-up')
        low.plot(t.speed_rpm, t.max_deviation, 'k-', lw=0.8, label='max / min deviation')
        low.plot(t.speed_rpm, t.min_deviation, 'k-', lw=0.8)
        low.axhline(0.0, color='0.6', lw=0.6)
        low.set_ylabel(f'θ − static wind-up [{unit}]\n(whole range, drive positive)')
        low.grid(alpha=0.3)
        legend_beside(low)
    ax.set_ylabel(f'{sig.signal.description} [{unit}]: order amplitudes,\n'
                  'deviations from the cycle mean' + (', θ − static wind-up' if two else ''))
    ax.grid(alpha=0.3)
    legend_beside(ax)
    axes[-1, 0].set_xlabel('engine speed [rpm]')
    fig.suptitle(_title(res, sig) + ' (paper Fig. 13 quantities)', fontsize=10)
    return fig


def _edges(values: np.ndarray, half_width: float) -> np.ndarray:
    if len(values) > 1:
        mids = (values[1:] + values[:-1]) / 2
        return np.concatenate(([values[0] - (mids[0] - values[0])], mids,
                               [values[-1] + (values[-1] - mids[-1])]))
    return np.array([values[0] - half_width, values[0] + half_width])


def plot_campbell(res, sig, path: Path, natural: Mapping[str, Sequence[float]] | None = None,
                  engine_orders: Sequence[float] = (1.5, 3.0, 4.5, 6.0, 9.0)) -> Path:
    """Campbell diagram (frequency over speed, half orders as dots sized by amplitude, engine
    orders and linear natural frequencies as lines) beside an order waterfall (colour map);
    ramp bins hollow / hatched."""
    from matplotlib.colors import LogNorm

    t = sig.table
    amp, orders, speeds, steady = t.amplitudes[:, 1:], t.orders[1:], t.speed_rpm, t.steady
    unit = sig.signal.unit
    fig = Figure(figsize=(14, 6), layout='constrained')
    ax, ax2 = fig.subplots(1, 2, gridspec_kw={'width_ratios': [1.25, 1]})
    finite = amp[np.isfinite(amp)]
    top = float(finite.max()) if finite.size else 1.0
    norm = LogNorm(vmin=max(1e-3 * top, 1e-300), vmax=top)
    fmax = min(res.sample_rate_hz / 2 if math.isfinite(res.sample_rate_hz) else np.inf,
               orders[-1] * speeds.max() / 60.0 * 1.05)
    S, Ord = np.meshgrid(speeds, orders, indexing='ij')
    ok = np.isfinite(amp) & (amp > 1e-4 * top)
    ramp = ok & ~steady[:, None]
    ok &= steady[:, None]
    sizes = 4 + 120 * (amp / top)
    sc = ax.scatter(S[ok], (Ord * S / 60.0)[ok], s=sizes[ok], c=amp[ok], cmap='viridis',
                    norm=norm, alpha=0.85, lw=0)
    if ramp.any():
        ax.scatter(S[ramp], (Ord * S / 60.0)[ramp], s=sizes[ramp], facecolors='none',
                   edgecolors=colormaps['viridis'](norm(amp[ramp])), lw=0.6,
                   label='not steady (few cycles or load changing)')
    fig.colorbar(sc, ax=ax, label=f'half-order amplitude [{unit}]')
    rpm = np.array([speeds.min(), speeds.max()])
    for o in engine_orders:
        ax.plot(rpm, o * rpm / 60.0, 'k--', lw=0.7)
        ax.annotate(f'{o:g}', (rpm[-1], o * rpm[-1] / 60.0), fontsize=8, xytext=(2, 0),
                    textcoords='offset points', va='center')
    styles = {'primary': ('tab:blue', '-'), 'secondary': ('tab:red', ':')}
    for region, freqs in (natural or {}).items():
        color, ls = styles.get(region, ('gray', '-.'))
        shown = [f for f in freqs if f <= fmax]
        for j, f in enumerate(shown):
            ax.axhline(f, color=color, ls=ls, lw=1,
                       label=f'natural frequency, DMF {region} stiffness' if j == 0 else None)
    ax.set_xlim(speeds.min() - 10, speeds.max() + 10)
    ax.set_ylim(0, fmax)
    ax.set_xlabel('engine speed [rpm]')
    ax.set_ylabel('frequency [Hz]')
    ax.set_title(f'Campbell diagram ({res.crank_source})', fontsize=10)
    if ax.get_legend_handles_labels()[0]:         # below: a legend beside would push the
        legend_below(fig, ncols=3, fontsize=8)       # colorbar away from its panel
    ax.grid(alpha=0.3)
    edges_s = _edges(speeds, 1.0)
    edges_o = np.concatenate(([orders[0] - 0.25], orders + 0.25))
    a2 = np.where(np.isfinite(amp) & (amp > 0), amp, np.nan)
    m = ax2.pcolormesh(edges_o, edges_s, a2, cmap='magma', norm=norm, shading='flat')
    for i in np.flatnonzero(~steady):
        ax2.axhspan(edges_s[i], edges_s[i + 1], facecolor='none', edgecolor='0.8', hatch='//',
                    lw=0)
    fig.colorbar(m, ax=ax2, label=f'amplitude [{unit}]')
    ax2.set_xlabel('engine order [-]')
    ax2.set_ylabel('engine speed [rpm]')
    ax2.set_title('order waterfall (hatched: not steady)', fontsize=10)
    fig.suptitle(_title(res, sig), fontsize=10)
    return save(fig, path)
