"""The one-page durability report: JSON and a PNG with the torque histogram, the rainflow
matrix, the damage by speed band and the dissipated power over the record (one point per engine
cycle). Drawn with :mod:`dmf_sim.figures`' rules, written by :func:`dmf_sim.figures.save`."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from dmf_sim.analysis.outputs import to_jsonable
from dmf_sim.core.json_out import write_json as write_json_file
from dmf_sim.durability.read import DurabilityRun
from dmf_sim.figures import legend_beside, save

__all__ = ['MATRIX_PANEL_BINS', 'report_dict', 'write_json', 'report_figure', 'plot_report']

MATRIX_PANEL_BINS = 200
"""Most bins per axis of the report's rainflow-matrix panel: the panel is ~500 pixels wide, so
finer bins are not seen. A record whose ranges or means span more bins of ``bins.range_nm`` /
``bins.mean_nm`` (a torque swinging over 10 kNm at 50 Nm bins, or up to the torque bound, which
would ask for a matrix of gigabytes) is drawn with neighbouring bins merged by a whole factor,
which the panel's title states; the JSON keeps every cell."""

_SIZE_IN = (11.0, 9.0)
_POWER_COLOR = 'tab:orange'
_POWER_MEAN_COLOR = 'saddlebrown'
_SPEED_COLOR = '0.55'


def report_dict(run: DurabilityRun) -> dict:
    d = run.result.as_dict()
    d.update(bag=run.bag, files=run.files, model=run.model, read_seconds=run.read_seconds,
             peak_rss_mib=run.peak_rss_mib, batches=run.batches, truncated=run.truncated,
             corrupt_chunks=run.corrupt)
    return to_jsonable(d)


def write_json(run: DurabilityRun, path: Path) -> Path:
    write_json_file(path, report_dict(run))
    return path


def _text(run: DurabilityRun) -> str:
    r = run.result
    sn = r.settings.sn
    lines = [
        f'{Path(run.bag).name}: {r.duration_s:.1f} s, {r.samples} samples; model '
        f'{run.model.get("driveline")}, {run.model.get("engine")} load set '
        f'{run.model.get("load_set")}',
        f'spring torque {r.torque_min_nm:.0f} .. {r.torque_max_nm:.0f} Nm; {r.cycles:.0f} '
        f'rainflow cycles; damage {r.damage:.3g} = {r.damage_per_hour:.3g} per hour',
        f'S-N: N = {sn.reference_cycles:.3g} (S / {sn.reference_range_nm:g} Nm)^-'
        f'{sn.exponent:g}, S = torque range'
        + (' -- PLACEHOLDER curve, not spring data' if sn.placeholder else ''),
        'stages: ' + '; '.join(f'{name} {st.time_s / r.duration_s:.0%} of the time, '
                               f'{st.torque_min_nm:.0f}..{st.torque_max_nm:.0f} Nm'
                               for name, st in r.stages.items()),
    ]
    if r.has_friction:
        lines += [f'DMF heat, damping c (dw/dt)^2 + arc-spring friction T_f dw/dt: mean '
                  f'{r.power_mean_w:.0f} W, highest engine-cycle mean {r.power_max_cycle_w:.0f} '
                  f'W; friction {r.friction_energy_j:.0f} J of {r.energy_j:.0f} J']
    else:
        lines += [f'DMF damping power c (dw/dt)^2: mean {r.power_mean_w:.0f} W, highest '
                  f'engine-cycle mean {r.power_max_cycle_w:.0f} W',
                  '  (the model\'s viscous damping only: this spring has no arc-spring friction)']
    if r.stop_contacts is not None:
        lines.append(f'end stops: {r.stop_contacts} contacts, peak impact torque '
                     f'{r.peak_stop_torque_nm:.0f} Nm')
    if r.largest:
        top = r.largest[0]
        lines.append(f'largest torque {top[1]:.0f} Nm at {top[3]:.0f} rpm (t = {top[2]:.1f} s)')
    return '\n'.join(lines)


def plot_report(run: DurabilityRun, path: Path) -> Path:
    """Save :func:`report_figure` as ``path`` (PNG)."""
    return save(report_figure(run), path)


def report_figure(run: DurabilityRun) -> Figure:
    """One page: text summary, torque histogram, rainflow matrix, damage by speed band,
    dissipated power over time (a dot per engine cycle, their mean over ``power_time_s``)."""
    r = run.result
    s = r.settings
    fig = Figure(figsize=_SIZE_IN, layout='constrained')
    grid = fig.add_gridspec(3, 2, height_ratios=[0.42, 1, 1])
    ax_t = fig.add_subplot(grid[0, :])
    ax_t.axis('off')
    ax_t.text(0.0, 1.0, _text(run), va='top', ha='left', fontsize=8.5, family='monospace',
              transform=ax_t.transAxes)
    ax_t.set_title('DMF durability', loc='left', fontsize=12)

    ax = fig.add_subplot(grid[1, 0])
    keys = np.array(sorted(r.torque_hist))
    if len(keys):
        ax.bar(keys * s.torque_bin_nm + s.torque_bin_nm / 2,
               [r.torque_hist[k] for k in keys], width=s.torque_bin_nm, color='tab:blue')
    ax.set_xlabel('spring torque T(w) [Nm]')
    ax.set_ylabel('time [s]')
    ax.set_title('torque histogram (time per bin)', fontsize=10)

    ax = fig.add_subplot(grid[1, 1])
    title = 'rainflow matrix'
    if r.rainflow:
        cells = np.array([(rb, mb, c) for (rb, mb), c in r.rainflow.items()])
        r0, m0 = int(cells[:, 0].min()), int(cells[:, 1].min())
        fr = -(-(int(cells[:, 0].max()) - r0 + 1) // MATRIX_PANEL_BINS)    # merge factors
        fm = -(-(int(cells[:, 1].max()) - m0 + 1) // MATRIX_PANEL_BINS)
        ri = (cells[:, 0].astype(np.int64) - r0) // fr
        mi = (cells[:, 1].astype(np.int64) - m0) // fm
        mat = np.zeros((int(ri.max()) + 1, int(mi.max()) + 1))
        np.add.at(mat, (ri, mi), cells[:, 2])
        mat[mat == 0] = np.nan
        rbin, mbin = fr * s.range_bin_nm, fm * s.mean_bin_nm
        im = ax.imshow(np.log10(mat), origin='lower', aspect='auto', cmap='viridis',
                       extent=[m0 * s.mean_bin_nm, m0 * s.mean_bin_nm + mat.shape[1] * mbin,
                               r0 * s.range_bin_nm, r0 * s.range_bin_nm + mat.shape[0] * rbin])
        # in an inset beside the axes: the column's right margin is shared with the power
        # panel's speed axis below, so a layout colorbar would sit at the margin's far edge
        fig.colorbar(im, cax=ax.inset_axes([1.03, 0.0, 0.04, 1.0]), label='log10 cycles')
        if fr > 1 or fm > 1:
            title += f' (bins merged to {rbin:g} x {mbin:g} Nm)'
    ax.set_xlabel('cycle mean torque [Nm]')
    ax.set_ylabel('cycle torque range [Nm]')
    ax.set_title(title, fontsize=10)

    ax = fig.add_subplot(grid[2, 0])
    bands = sorted(set(r.damage_by_band) | set(r.time_by_band))
    if bands:
        x = np.array(bands) * s.speed_bin_rpm + s.speed_bin_rpm / 2
        dmg = np.array([r.damage_by_band.get(k, 0.0) for k in bands])
        share = dmg / r.damage if r.damage > 0 else dmg
        ax.bar(x, 100 * share, width=0.9 * s.speed_bin_rpm, color='tab:red', label='damage')
        tim = np.array([r.time_by_band.get(k, 0.0) for k in bands])
        ax.plot(x, 100 * tim / max(tim.sum(), 1e-12), 'ko-', ms=3, lw=1, label='time')
        legend_beside(ax)
    ax.set_xlabel('engine speed band [rpm]')
    ax.set_ylabel('share [%]')
    resid = r.damage_residue / r.damage if r.damage > 0 else 0.0
    ax.set_title('damage by speed band' + (' (placeholder S-N)' if s.sn.placeholder else '')
                 + f'\nresidue half cycles (no band): {resid:.0%} of the damage', fontsize=9)

    ax = fig.add_subplot(grid[2, 1])
    n = len(r.cycle_t_s)
    if n:
        ax2 = ax.twinx()
        ax2.plot(r.cycle_t_s, r.cycle_speed_rpm, color=_SPEED_COLOR, lw=0.8, zorder=1)
        ax2.set_ylabel('engine speed [rpm] (grey)', color=_SPEED_COLOR)
        ax.set_zorder(ax2.get_zorder() + 1)          # the power over the speed
        ax.patch.set_visible(False)
        ax.plot(r.cycle_t_s, r.cycle_power_w, '.', ms=2.5 if n > 500 else 4,
                color=_POWER_COLOR)
        ax.plot(r.power_t_s + s.power_time_s / 2, r.power_w, color=_POWER_MEAN_COLOR, lw=1)
    ax.set_xlabel('time [s]')
    ax.set_ylabel('damping power [W]')
    what = ('c (dw/dt)² + friction T_f dw/dt' if r.has_friction
            else 'c (dw/dt)², viscous only')
    ax.set_title(f'DMF damping power {what}\ndots: each engine cycle ({n}), '
                 f'line: their mean over {s.power_time_s:g} s', fontsize=9)
    return fig
