"""The package's figures (paper Figs. 8, 12, 13, 14, 15), one place for how they look.

Used by ``dmf-sim sweep``, ``modes``, ``nnm``, ``loads`` and ``paper``. Drawn with matplotlib's
object API (``matplotlib.figure.Figure``: no pyplot state, no GUI backend needed).

Reading rules kept in every figure:

* every axis names its quantity and unit; titles carry alpha, theta, load set and load;
* every text stays on the canvas: :func:`save` wraps a title that would be cut at the figure's
  edges or run into the title beside it (:func:`fit_titles`), for every figure of the package;
* legends sit outside the data: a figure's legend below its panels (:func:`legend_below`), a
  panel's own legend beside it, right of the axes (:func:`legend_beside`);
* solid = stable, dashed = unstable (Floquet); unknown stability is drawn solid;
* wind-up panels (Figs. 13/15, :func:`windup_panel`): red 3rd order drawn as a wide translucent
  band under the thin black max/min deviation lines (the two nearly coincide where the 3rd order
  dominates), blue 1.5th order, green = theta minus the static wind-up of the mean torque (the
  paper's reading rule: green above both black lines -> primary region only, below both ->
  secondary only, between -> both). The axis is scaled to the vibration; where the green line
  leaves it (far from the knee), the panel says how far it goes.
"""
from __future__ import annotations

import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

__all__ = ['DPI', 'COLORS', 'LOAD_SET_COLORS', 'NO_PERIODIC_SHADE', 'RESONANCE_MARK_COLOR',
           'legend_below', 'legend_beside', 'fit_titles', 'WindupCurves', 'windup_panel',
           'panel_title', 'sweep_curves',
           'order_label', 'sweep_marks', 'sweep_panel', 'sweep_bands', 'windup_legend_handles',
           'windup_figure', 'mode_shapes_figure', 'nnm_figure', 'mean_torque_panel',
           'order_bars_panel', 'torque_over_angle_panel', 'two_panel_figure', 'save', 'fig8']

DPI = 120
"""Resolution of the PNG files [dots per inch]."""

COLORS = {'order_3': 'tab:red', 'order_1_5': 'tab:blue', 'deviation': 'black',
          'green': 'tab:green', 'conventional': 'tab:blue', 'dmf': 'tab:red',
          'primary': 'tab:blue', 'secondary': 'tab:red'}
LOAD_SET_COLORS = {'A': 'tab:blue', 'B': 'tab:orange', 'C': 'tab:green'}
NO_PERIODIC_SHADE = '0.88'   # speeds without a stable periodic state
RESONANCE_MARK_COLOR = '0.35'  # sharp resonances (an order meeting a lightly damped mode)

_Y_MARGIN = 1.25          # wind-up axis: this times the largest vibration quantity
_BAND_WIDTH = 4.0         # line width of the red 3rd-order band [pt]
_LOG_XI_ABOVE = 20.0      # NNM figure: logarithmic xi axis beyond this xi_max
_LABEL_GAP = 0.03         # NNM figure: smallest gap between flat-branch labels (axis fraction)
_LINE_WIDTH = 1.3         # other lines [pt]
_TITLE_GAP_PX = 6.0       # smallest gap between a title and the canvas edge or the title beside it
_WRAP_MIN_CHARS = 12      # a title is not wrapped narrower than this many characters
_LAYOUT_PASSES = 3        # wrapping changes the layout, which changes the room: draw again

_OUTSIDE_LOC = tuple(int(p) for p in matplotlib.__version__.split('.')[:2]) >= (3, 7)
"""matplotlib places a legend with loc='outside ...' from 3.7 on (Ubuntu 24.04 has 3.6.3)."""


def legend_below(fig: Figure, handles=None, ncols: int = 2, **kw):
    """The figure's legend centred under its panels, outside the data; the one way a figure here
    places a figure legend. ``handles`` None: the labelled artists of every panel.

    matplotlib >= 3.7: ``loc='outside lower center'`` (the constrained layout makes room).
    matplotlib 3.6 (Ubuntu 24.04's, what rosdep installs for ROS 2 Jazzy) has no 'outside'
    location: the legend goes to the bottom edge and the constrained layout's rectangle starts
    above it, so it never covers an axis or its label."""
    if _OUTSIDE_LOC:
        return fig.legend(handles=handles, loc='outside lower center', ncols=ncols, **kw)
    legend = fig.legend(handles=handles, loc='lower center', ncols=ncols, **kw)
    bottom = legend.get_window_extent().y1 / fig.bbox.height     # legend top [figure fraction]
    fig.get_layout_engine().set(rect=(0.0, bottom, 1.0, 1.0 - bottom))
    return legend


def legend_beside(ax, **kw):
    """The panel's legend right of its axes, top-aligned, outside the data; the one way a panel
    here places its own legend (the constrained layout makes room for it)."""
    kw.setdefault('fontsize', 8)
    kw.setdefault('frameon', False)
    return ax.legend(loc='upper left', bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0, **kw)


def fit_titles(fig: Figure) -> None:
    """Wrap every title that would not fit, at spaces, so that no text is cut: the figure's
    suptitle and every legend title within the canvas, each panel's left / centre / right titles
    together within the panel's width (each its share, in proportion to its length). Run by
    :func:`save`; the constrained layout makes room for the extra lines when the figure is drawn
    again."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    if not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    for _ in range(_LAYOUT_PASSES):
        fig.draw_without_rendering()
        renderer = fig.canvas.get_renderer()
        canvas = fig.bbox.width - 2.0 * _TITLE_GAP_PX
        texts = [getattr(fig, '_suptitle', None)]
        texts += [legend.get_title() for legend in fig.legends]
        texts += [ax.get_legend().get_title() for ax in fig.axes if ax.get_legend()]
        changed = False
        for text in texts:
            if text is not None and text.get_text():
                changed |= _wrap(text, canvas, renderer)
        for ax in fig.axes:
            titles = [t for t in (getattr(ax, '_left_title', None), ax.title,
                                  getattr(ax, '_right_title', None))
                      if t is not None and t.get_text()]
            if not titles:
                continue
            widths = [t.get_window_extent(renderer).width for t in titles]
            room = ax.get_window_extent(renderer).width - _TITLE_GAP_PX * (len(titles) - 1)
            for t, w in zip(titles, widths):
                changed |= _wrap(t, room * w / sum(widths) if sum(widths) > room else room,
                                 renderer)
        if not changed:
            return


def _wrap(text, width_px: float, renderer) -> bool:
    """Break ``text`` (a matplotlib Text) into lines no wider than ``width_px``; False if it fits
    already (or is mathtext, which is not broken)."""
    full = text.get_window_extent(renderer).width
    if full <= width_px or '$' in text.get_text():
        return False
    lines = text.get_text().split('\n')
    chars = max(int(max(map(len, lines)) * width_px / full), _WRAP_MIN_CHARS)
    while True:
        text.set_text('\n'.join(textwrap.fill(line, chars, break_long_words=False,
                                               break_on_hyphens=False) for line in lines))
        if text.get_window_extent(renderer).width <= width_px or chars <= _WRAP_MIN_CHARS:
            return True
        chars = max(chars - max(chars // 20, 1), _WRAP_MIN_CHARS)


# ------------------------------------------------------------------------------------------------
# Fig. 13 / 15: DMF wind-up quantities over engine speed
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class WindupCurves:
    """The paper's Fig. 13 quantities over engine speed, one solution branch or one measurement.

    Arrays of equal length: speed [rpm]; 3rd- and 1.5th-order amplitude, max/min deviation from
    the mean, theta minus the static wind-up of the mean torque [rad]; ``stable`` 1/0 per point
    (NaN or None = unknown, drawn solid). ``marker`` draws points instead of lines (measured
    data); ``main`` draws the lines thicker (the branch from the lowest speed)."""

    speed_rpm: np.ndarray
    order_3: np.ndarray
    order_1_5: np.ndarray
    max_deviation: np.ndarray
    min_deviation: np.ndarray
    theta_minus_static: np.ndarray
    stable: np.ndarray | None = None
    marker: str | None = None
    main: bool = True

    @classmethod
    def from_branch(cls, branch, main: bool = True) -> WindupCurves:
        """From a ``dmf_sim.solvers.hbm.Branch`` (its points' summaries and stability)."""
        col = branch.column
        return cls(col('speed_rpm'), col('order_3'), col('order_1_5'), col('max_deviation'),
                   col('min_deviation'), col('theta_minus_static'), col('stable'), main=main)


def windup_panel(ax, curves: Sequence[WindupCurves], title: str,
                 bands: Sequence[tuple[float, float]] = (),
                 marks: Sequence[tuple[float, str]] = ()) -> None:
    """Draw one Fig. 13 panel (any number of branches / measurements) on ``ax``; ``bands``:
    speed ranges [rpm] where no periodic state is stable (shaded); ``marks``: (speed [rpm],
    label) of sharp resonances, a dotted line labelled at the top (:func:`sweep_marks`)."""
    for lo, hi in bands:
        ax.axvspan(lo, hi, color=NO_PERIODIC_SHADE, lw=0, zorder=0)
    for speed, label in marks:
        ax.axvline(speed, color=RESONANCE_MARK_COLOR, lw=0.7, ls=':', zorder=1)
        ax.annotate(label, (speed, 1.0), xycoords=('data', 'axes fraction'),
                    xytext=(-1, -2), textcoords='offset points', ha='right', va='top',
                    fontsize=6.5, color=RESONANCE_MARK_COLOR, rotation=90)
    vib_hi, vib_lo = 0.0, 0.0
    for c in curves:
        lw = _LINE_WIDTH if c.main else 0.7 * _LINE_WIDTH
        s = np.asarray(c.speed_rpm, dtype=float)
        _draw(ax, s, c.order_3, c.stable, c.marker, color=COLORS['order_3'],
              lw=_BAND_WIDTH if c.main else 0.7 * _BAND_WIDTH, alpha=0.45, zorder=2)
        _draw(ax, s, c.order_1_5, c.stable, c.marker, color=COLORS['order_1_5'], lw=lw, zorder=4)
        for key in ('max_deviation', 'min_deviation'):
            _draw(ax, s, getattr(c, key), c.stable, c.marker, color=COLORS['deviation'],
                  lw=0.8 * lw, zorder=5)
        _draw(ax, s, c.theta_minus_static, c.stable, c.marker, color=COLORS['green'], lw=lw,
              zorder=3)
        vals = [np.asarray(getattr(c, k), float)
                for k in ('order_3', 'order_1_5', 'max_deviation')]
        vib_hi = max(vib_hi, *(np.nanmax(v) for v in vals if v.size))
        vib_lo = min(vib_lo, np.nanmin(np.asarray(c.min_deviation, float)))
    top = _Y_MARGIN * max(vib_hi, 1e-6)
    bottom = _Y_MARGIN * min(vib_lo, -1e-6)
    ax.set_ylim(bottom, top)
    ax.axhline(0.0, color='0.6', lw=0.6, zorder=1)
    ax.set_title(title, fontsize=9, loc='left')
    note = _off_scale_note(curves, bottom, top)
    if note:
        ax.set_title(note, fontsize=7.5, loc='right', color=COLORS['green'])
    ax.set_ylabel('wind-up [rad]', fontsize=9)
    ax.grid(alpha=0.3)


def _off_scale_note(curves: Sequence[WindupCurves], bottom: float, top: float) -> str:
    """Where the green line leaves the axis: its extreme value and the speeds it is off scale."""
    parts = []
    for sign, limit, word in ((1.0, top, 'above'), (-1.0, bottom, 'below')):
        spans, extreme = [], None
        for c in curves:
            s = np.asarray(c.speed_rpm, float)
            g = np.asarray(c.theta_minus_static, float)
            off = sign * g > sign * limit
            if not off.any():
                continue
            k = int(np.argmax(np.where(off, sign * g, -np.inf)))
            if extreme is None or sign * g[k] > sign * extreme[0]:
                extreme = (g[k], s[k])
            cuts = np.flatnonzero(np.diff(off.astype(int))) + 1
            for run in np.split(np.arange(len(s)), cuts):
                if off[run[0]]:
                    lo, hi = f'{s[run].min():.0f}', f'{s[run].max():.0f}'
                    spans.append(lo if lo == hi else f'{lo}-{hi}')
        if extreme is not None:
            parts.append(f'green off scale {word} at {", ".join(dict.fromkeys(spans))} rpm '
                         f'(to {extreme[0]:+.3f} rad at {extreme[1]:.0f} rpm)')
    return '; '.join(parts)


def panel_title(alpha: float, theta: float, load_set: str, load: float) -> str:
    """The parameters of one wind-up panel."""
    return f'α = {alpha:g}, θ = {theta:g} rad, Load {load_set}, load {load:g}'


def sweep_curves(res) -> list:
    """WindupCurves of every branch of a SweepResult (the branch from the lowest speed first),
    then the time-integration envelope of its non-periodic speeds (markers)."""
    curves = [WindupCurves.from_branch(b, main=(b.kind == 'main' and b.id == 0))
              for b in res.branches]
    rows = [r for band in res.non_periodic for r in band.results]
    if rows:
        col = {k: np.array([getattr(r, k) for r in rows]) for k in
               ('speed_rpm', 'order_3', 'order_1_5', 'max_deviation', 'min_deviation')}
        curves.append(WindupCurves(col['speed_rpm'], col['order_3'], col['order_1_5'],
                                   col['max_deviation'], col['min_deviation'],
                                   np.full(len(rows), np.nan), marker='x', main=False))
    return curves


def order_label(order: float) -> str:
    """'6th', '4.5th', '1st', '0.5th' order names."""
    if order != int(order):
        return f'{order:g}th'
    k = int(order)
    return f'{k}{"th" if 10 <= k % 100 <= 20 else {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")}'


def sweep_marks(res) -> list[tuple[float, str]]:
    """(speed [rpm], label) of the sharp resonances of a SweepResult: where an order meets a
    lightly damped mode (``SweepResult.sharp_resonances``), e.g. '6th × 125.1 Hz'."""
    return [(r['speed_rpm'], f'{order_label(r["order"])} × {r["frequency_hz"]:.1f} Hz')
            for r in getattr(res, 'sharp_resonances', ())]


def sweep_panel(title: str, res) -> tuple:
    """The wind-up panel of a SweepResult for :func:`windup_figure`: its title, every branch
    and the non-periodic envelope, the shaded non-periodic bands and the sharp resonances."""
    return title, sweep_curves(res), sweep_bands(res), sweep_marks(res)


def sweep_bands(res) -> list[tuple[float, float]]:
    """Speed ranges [rpm] without a stable periodic state (shaded in the figures)."""
    return [(b.speed_min_rpm - b.half_width_rpm, b.speed_max_rpm + b.half_width_rpm)
            for b in res.non_periodic]


def windup_legend_handles() -> list[Line2D]:
    """Legend entries of a wind-up panel (for a figure legend outside the axes)."""
    return [Line2D([], [], color=COLORS['order_3'], lw=_BAND_WIDTH, alpha=0.45,
                   label='3rd order amplitude'),
            Line2D([], [], color=COLORS['order_1_5'], lw=_LINE_WIDTH,
                   label='1.5th order amplitude'),
            Line2D([], [], color=COLORS['deviation'], lw=_LINE_WIDTH,
                   label='max / min deviation from the mean'),
            Line2D([], [], color=COLORS['green'], lw=_LINE_WIDTH,
                   label='θ − static wind-up of the mean torque (drive +)'),
            Line2D([], [], color='0.3', lw=_LINE_WIDTH, ls='--', label='unstable (Floquet)'),
            Patch(color=NO_PERIODIC_SHADE, label='no stable periodic state (x: time integration)'),
            Line2D([], [], color=RESONANCE_MARK_COLOR, lw=0.7, ls=':',
                   label='order × lightly damped mode (sharp resonance)')]


def windup_figure(panels: Sequence[tuple], title: str) -> Figure:
    """One wind-up panel per (title, curves[, bands[, marks]]), stacked over a shared speed
    axis, legend below."""
    n = len(panels)
    fig = Figure(figsize=(9.5, 2.6 * n + 1.6), layout='constrained')
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    for ax, (label, curves, *bands) in zip(axes, panels, strict=True):
        windup_panel(ax, curves, label, *bands)
    axes[-1].set_xlabel('engine speed [rpm]')
    fig.suptitle(title, fontsize=11)
    legend_below(fig, windup_legend_handles(), ncols=3, fontsize=8,
                 title='green above both black lines: primary region only; below both: secondary '
                       'only; between: both', title_fontsize=8)
    return fig


def _draw(ax, x, y, stable, marker, **kw) -> None:
    """Solid where stable (or unknown), dashed where unstable; segments share their end points.
    With ``marker``: points only."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    if marker:
        kw.pop('lw', None)
        ax.plot(x, y, ls='none', marker=marker, ms=3, **kw)
        return
    st = np.ones(len(x), bool) if stable is None else \
        np.where(np.isnan(np.asarray(stable, float)), 1.0, np.asarray(stable, float)) > 0.5
    start = 0
    for i in range(1, len(x) + 1):
        if i == len(x) or st[i] != st[start]:
            j = min(i + 1, len(x))
            ax.plot(x[start:j], y[start:j], ls='-' if st[start] else '--', **kw)
            start = i


# ------------------------------------------------------------------------------------------------
# Fig. 12: mode shapes
# ------------------------------------------------------------------------------------------------
def mode_shapes_figure(conventional, dmf, n_modes: int = 4, dmf_label: str = 'DMF') -> Figure:
    """Modes 1..n_modes (``dmf_sim.physics.modal.ModalResult``) of the conventional driveline
    (blue) and the DMF driveline (red dashed), angles x cumulative gear ratio; element names of the
    DMF driveline on the axis, the conventional name below where it differs."""
    fig = Figure(figsize=(10, 2.3 * n_modes + 2.2), layout='constrained')
    axes = fig.subplots(n_modes, 1, sharex=True, squeeze=False)[:, 0]
    x = np.arange(len(dmf.names))
    for k, ax in enumerate(axes, start=1):
        ax.plot(x, conventional.element_shapes[:, k], '-o', color=COLORS['conventional'], ms=3,
                label=f'conventional {conventional.frequencies_hz[k]:.1f} Hz')
        ax.plot(x, dmf.element_shapes[:, k], '--s', color=COLORS['dmf'], ms=3,
                label=f'{dmf_label} {dmf.frequencies_hz[k]:.1f} Hz')
        ax.axhline(0.0, color='0.6', lw=0.6)
        ax.set_ylabel(f'mode {k}\nangle × R [-]', fontsize=9)
        legend_beside(ax)
        ax.grid(alpha=0.3)
    labels = [d if d == c else f'{d}\n(conv. {c})' for d, c in zip(dmf.names, conventional.names,
                                                                    strict=True)]
    axes[-1].set_xticks(x)
    axes[-1].set_xticklabels(labels, rotation=70, fontsize=7)
    axes[-1].set_xlabel('element (Table 1; DMF driveline names)')
    fig.suptitle('Mode shapes: element angle × cumulative gear ratio, normalized to max |.| = 1 '
                 '(paper Fig. 12)', fontsize=10)
    return fig


# ------------------------------------------------------------------------------------------------
# Fig. 14: non-linear normal modes
# ------------------------------------------------------------------------------------------------
def nnm_figure(res, xi_max: float = 10.0) -> Figure:
    """Frequency [Hz] against xi like the paper's Fig. 14 (``dmf_sim.solvers.nnm.NNMResult``): blue
    primary-region branch, red secondary-region branch, dotted linear frequencies, flat branches
    labelled with their multiple n."""
    fig = Figure(figsize=(8.5, 6.0), layout='constrained')
    ax = fig.subplots()
    labels = {'primary': 'static wind-up in the primary region',
              'secondary': 'static wind-up in the secondary region'}
    lo, hi = np.inf, -np.inf
    for region, br in res.branches.items():
        color = COLORS[region]
        first = True
        for seg in np.unique(br.segment):
            s = br.segment == seg
            m = s & (br.xi <= xi_max)
            if not m.any():
                continue
            ax.plot(br.xi[s], br.frequency_hz[s], '-', color=color, lw=0.8, alpha=0.6)
            ax.plot(br.xi[m], br.frequency_hz[m], 'o', color=color, ms=2.5,
                    label=labels[region] if first else None)
            first = False
            lo, hi = min(lo, br.frequency_hz[m].min()), max(hi, br.frequency_hz[m].max())
        ax.axhline(br.linear_frequency_hz, color=color, ls=':', lw=0.8,
                   label=f'linear mode, {region} stiffness ({br.linear_frequency_hz:.1f} Hz)')
    pad = 0.05 * (hi - lo) if np.isfinite(hi - lo) and hi > lo else 1.0
    ax.set_ylim(lo - pad, hi + pad)
    flats = sorted((fb for fb in res.flat_branches if fb.xi_min <= xi_max),
                   key=lambda fb: fb.frequency_hz)
    last_y = -np.inf
    for fb in flats:           # labels at the branch ends, stacked where they would overlap
        y = max(fb.frequency_hz, last_y + _LABEL_GAP * (hi - lo + 2 * pad))
        ax.annotate(f' {fb.harmonic}', (min(fb.xi_max, xi_max), fb.frequency_hz),
                    xytext=(min(fb.xi_max, xi_max), y), textcoords='data', fontsize=8,
                    color=COLORS[fb.region], annotation_clip=False, ha='left',
                    va='center')
        last_y = y
    if xi_max > _LOG_XI_ABOVE:
        ax.set_xscale('log')
        ax.set_xlim(0.95, xi_max)
    else:
        ax.set_xlim(1.0 - 0.02 * (xi_max - 1), xi_max)
    ax.set_xlabel(r'$\xi = E / E_{nl}$ [-] (energy over the energy that reaches the knee)')
    ax.set_ylabel('frequency of the fundamental [Hz]')
    ax.set_title(f'Non-linear normal modes, α = {res.alpha:g}, θ = {res.theta:g} rad '
                 f'(mode {res.mode}; paper Fig. 14)\nnumbers: n of flat branches, '
                 'n × frequency = a resonance in front of / behind the DMF', fontsize=9)
    ax.grid(alpha=0.3)
    legend_below(fig, ncols=2, fontsize=8)
    return fig


# ------------------------------------------------------------------------------------------------
# Fig. 8 and the engine loads
# ------------------------------------------------------------------------------------------------
def mean_torque_panel(ax, speeds_rpm: np.ndarray, mean_nm: Mapping[str, Sequence[float]],
                      load: float) -> None:
    """Engine mean torque [Nm] over speed, one line per load set (paper Fig. 8 left)."""
    for name, values in mean_nm.items():
        ax.plot(speeds_rpm, values, color=LOAD_SET_COLORS.get(name), label=f'Load {name}')
    ax.set_xlabel('engine speed [rpm]')
    ax.set_ylabel('engine mean torque [Nm]')
    ax.set_title(f'Engine mean torque, load {load:g} (Fig. 8 left)', fontsize=10)
    legend_beside(ax)
    ax.grid(alpha=0.3)


def order_bars_panel(ax, orders: Sequence[Mapping[str, float]], speed_rpm: float,
                     load_set: str, load: float) -> None:
    """Amplitudes [Nm] of the engine orders on a rigid crank and of one cylinder."""
    o = np.array([r['order'] for r in orders])
    ax.bar(o, [r['engine_nm'] for r in orders], width=0.35, label='engine (rigid crank)')
    ax.bar(o + 0.2, [r['cylinder_nm'] for r in orders], width=0.2, label='one cylinder')
    ax.set_xlabel('engine order [-]')
    ax.set_ylabel('torque amplitude [Nm]')
    ax.set_title(f'Order content at {speed_rpm:g} rpm, Load {load_set}, load {load:g}',
                 fontsize=10)
    legend_beside(ax)
    ax.grid(alpha=0.3)


def torque_over_angle_panel(ax, psi_deg: np.ndarray, torque_nm: Mapping[float, np.ndarray],
                            what: str) -> None:
    """Torque [Nm] over one 720 deg engine cycle, one line per engine speed [rpm]."""
    for speed, tq in torque_nm.items():
        ax.plot(psi_deg, tq, lw=1.0, label=f'{speed:g} rpm')
    ax.set_xlabel('crank angle [deg] (0 = cylinder 1 firing TDC)')
    ax.set_ylabel('torque [Nm]')
    ax.set_xlim(0.0, 720.0)
    ax.set_xticks(np.arange(0, 721, 120))
    ax.set_title(what, fontsize=10)
    legend_beside(ax)
    ax.grid(alpha=0.3)


def two_panel_figure(title: str, width: float = 12.0) -> tuple[Figure, object, object]:
    """An empty figure with two side-by-side panels (left, right)."""
    fig = Figure(figsize=(width, 4.4), layout='constrained')
    left, right = fig.subplots(1, 2)
    fig.suptitle(title, fontsize=11)
    return fig, left, right


def save(fig: Figure, path: str | Path) -> Path:
    """Write the figure as PNG (:data:`DPI`) and return the path; every figure of the package
    is written here, its titles fitted to the canvas first (:func:`fit_titles`)."""
    path = Path(path)
    fit_titles(fig)
    fig.savefig(path, dpi=DPI)
    return path


def fig8(mean_speeds, mean, load: float, psi_deg, torque: dict, load_set: str, engine: str):
    """Paper Fig. 8: mean torque of the load sets (left), torque before the flywheel of the
    conventional driveline over the engine cycle (right)."""
    fig, left, right = two_panel_figure(f'Engine loads, engine {engine} (paper Fig. 8)')
    mean_torque_panel(left, mean_speeds, mean, load)
    torque_over_angle_panel(right, psi_deg, torque,
                            f'Torque into the flywheel, conventional driveline, Load {load_set}, '
                            f'load {load:g} (Fig. 8 right)')
    return fig
