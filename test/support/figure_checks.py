"""Checks of drawn figures, in display coordinates (pixels): every text on the canvas, no
plotted data point under a legend."""
from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg

TOLERANCE_PX = 1.0


def drawn(fig):
    """The figure laid out (constrained layout runs at draw time); its renderer."""
    if not isinstance(fig.canvas, FigureCanvasAgg):
        FigureCanvasAgg(fig)
    fig.draw_without_rendering()
    return fig.canvas.get_renderer()


def _texts(fig):
    suptitle = getattr(fig, '_suptitle', None)
    yield 'suptitle', suptitle
    for legend in list(fig.legends) + [ax.get_legend() for ax in fig.axes]:
        if legend is not None:
            yield 'legend title', legend.get_title()
            yield from (('legend', t) for t in legend.get_texts())
    for ax in fig.axes:
        for name in ('_left_title', 'title', '_right_title'):
            yield 'axes title', getattr(ax, name, None)
        yield 'x label', ax.xaxis.label
        yield 'y label', ax.yaxis.label


def texts_off_canvas(fig) -> list[str]:
    """Titles, axis labels and legend texts that reach beyond the canvas, and left / centre /
    right titles of one panel that run into each other."""
    r = drawn(fig)
    box = fig.bbox
    bad = []
    for kind, text in _texts(fig):
        if text is None or not text.get_visible() or not text.get_text().strip():
            continue
        e = text.get_window_extent(r)
        if (e.x0 < box.x0 - TOLERANCE_PX or e.x1 > box.x1 + TOLERANCE_PX
                or e.y0 < box.y0 - TOLERANCE_PX or e.y1 > box.y1 + TOLERANCE_PX):
            bad.append(f'{kind} {text.get_text()!r} at x {e.x0:.0f}..{e.x1:.0f}, '
                       f'y {e.y0:.0f}..{e.y1:.0f} on a {box.width:.0f} x {box.height:.0f} canvas')
    for ax in fig.axes:
        titles = [t for t in (getattr(ax, n, None) for n in ('_left_title', 'title',
                                                               '_right_title'))
                  if t is not None and t.get_text()]
        extents = [t.get_window_extent(r) for t in titles]
        for a, b in zip(extents, extents[1:]):
            if a.x1 > b.x0 + TOLERANCE_PX and a.y1 > b.y0 and b.y1 > a.y0:
                bad.append(f'titles {titles[0].get_text()!r} ... overlap')
    return bad


def points_under_legends(fig) -> list[str]:
    """Plotted data points (line vertices, scatter offsets) inside a legend's box [pixels]."""
    r = drawn(fig)
    legends = list(fig.legends) + [ax.get_legend() for ax in fig.axes if ax.get_legend()]
    boxes = [legend.get_window_extent(r) for legend in legends]
    bad = []
    for ax in fig.axes:
        clouds = [(line.get_label(), line.get_transform().transform(line.get_xydata()))
                  for line in ax.get_lines() if len(line.get_xydata())]
        clouds += [(coll.get_label(), coll.get_offset_transform().transform(coll.get_offsets()))
                   for coll in ax.collections if len(coll.get_offsets())]
        view = ax.get_window_extent(r)
        for label, xy in clouds:
            xy = xy[np.isfinite(xy).all(axis=1)]
            seen = ((xy[:, 0] >= view.x0) & (xy[:, 0] <= view.x1) & (xy[:, 1] >= view.y0)
                    & (xy[:, 1] <= view.y1))
            for box in boxes:
                inside = seen & (xy[:, 0] > box.x0) & (xy[:, 0] < box.x1) \
                    & (xy[:, 1] > box.y0) & (xy[:, 1] < box.y1)
                if inside.any():
                    bad.append(f'{inside.sum()} point(s) of {label!r} under a legend')
    return bad
