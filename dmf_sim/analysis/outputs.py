"""Outputs of the bag analysis: one JSON-ready dict, CSV tables, and the files of ``--out``.

Columns per speed bin (or cycle): speed, cycles, ``steady`` (enough cycles, see
:mod:`dmf_sim.analysis.order_bins`), 3rd and 1.5th order, max/min deviation from the mean, the
dynamic ``mean`` and ``mean_minus_theta``, the model's ``static_windup`` and ``theta_minus_static``
(the paper's green line), the HBM values (``hbm_*``) and every half order (``o0``, ``o0.5``, ...).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dmf_sim.core.csv_out import write_csv as write_table
from dmf_sim.core.json_out import jsonable as to_jsonable, write_json

__all__ = ['to_jsonable', 'table_rows', 'analysis_dict', 'write_csv', 'write_cycles_csv',
           'write_outputs']


def _f(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def _optional(values: np.ndarray | None, i: int) -> float | None:
    return None if values is None else _f(values[i])


def table_rows(sig) -> list[dict[str, Any]]:
    """Rows (dicts) of a signal's table, as written to CSV/JSON."""
    t = sig.table
    steady = t.steady
    rows = []
    for i in range(len(t)):
        row = {'speed_rpm': float(t.speed_rpm[i]), 'speed_mean_rpm': float(t.speed_mean_rpm[i]),
               'n_cycles': int(t.n_cycles[i]), 'steady': bool(steady[i]),
               'load': _optional(t.load, i),
               'order_3': _f(t.order_3[i]), 'order_1_5': _f(t.order_1_5[i]),
               'max_deviation': _f(t.max_deviation[i]), 'min_deviation': _f(t.min_deviation[i]),
               'mean': _f(t.mean[i]),
               'mean_minus_theta': _optional(t.mean_minus_theta, i),
               'static_windup': _optional(t.static_windup, i),
               'theta_minus_static': _optional(t.theta_minus_static, i),
               'amplitudes': [_f(a) for a in t.amplitudes[i]]}
        if sig.hbm is not None:
            for k, v in sig.hbm.values.items():
                row[f'hbm_{k}'] = _f(v[i])
            if sig.hbm.stable is not None:
                row['hbm_stable'] = None if sig.hbm.stable[i] is None else bool(sig.hbm.stable[i])
            if sig.hbm.branch is not None:
                row['hbm_branch'] = int(sig.hbm.branch[i])
        rows.append(row)
    return rows


def analysis_dict(res, extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The whole analysis as one JSON-ready dict (what ``dmf-sim analyze --json`` prints)."""
    signals = {}
    for sig in res.signals:
        d = {'signal': sig.signal.label, 'description': sig.signal.description,
             'unit': sig.signal.unit, 'topic': sig.topic, 'samples': sig.n_samples,
             'cycles': len(sig.cycles), 'steady_rows': int(sig.table.steady.sum()),
             'rows': table_rows(sig)}
        if sig.hbm is not None:
            h = sig.hbm
            d['hbm'] = {'method': h.method, 'settings': dict(h.settings), 'seconds': h.seconds,
                        'difference': h.difference, 'events': h.events, 'curve': h.curve}
        signals[sig.signal.label] = d
    out = {
        'bag': str(res.bag), 'files': [str(f) for f in res.files], 'reader': res.reader,
        'truncated': res.truncated, 'namespace': res.namespace,
        'crank_angle_source': res.crank_source, 'duration_s': res.duration_s,
        'sample_rate_hz': res.sample_rate_hz,
        'mode': 'bins' if res.bin_rpm > 0 else 'cycles', 'bin_rpm': res.bin_rpm,
        'min_cycles': res.min_cycles, 'points_per_cycle': res.points_per_cycle,
        'n_max': res.n_max, 'orders': [n / 2 for n in range(res.n_max + 1)],
        'theta_rad': res.theta, 'read_seconds': res.read_seconds,
        'analyze_seconds': res.analyze_seconds, 'warnings': list(res.warnings),
        'corrupt_chunks': list(getattr(res, 'corrupt', [])),
        'load_timeline': _timeline(getattr(res, 'load_timeline', None), res),
        'signals': signals,
    }
    if extra:
        out.update(extra)
    return to_jsonable(out)


def _timeline(tl, res) -> dict[str, Any] | None:
    """Where the per-row loads came from: sources, the loads found, the intervals [s from the
    first crank-angle sample] where the load was changing or unknown."""
    if tl is None:
        return None
    t0 = int(res.series.series['crank'].t_ns[0]) if 'crank' in res.series.series else 0
    unknown = [[(a - t0) * 1e-9, (b - t0) * 1e-9]
               for a, b, v in zip(tl.t0_ns, tl.t1_ns, tl.value) if not math.isfinite(v)]
    return {'sources': list(tl.sources), 'levels': tl.levels, 'unknown_s': unknown,
            'notes': list(tl.notes)}


def write_csv(sig, path: Path) -> Path:
    """One row per speed bin (or cycle): speed, Fig. 13 quantities, HBM columns, half orders."""
    rows = table_rows(sig)
    orders = [f'o{n / 2:g}' for n in range(sig.table.amplitudes.shape[1])]
    fixed = [k for k in rows[0] if k != 'amplitudes'] if rows else []
    return write_table(path, fixed + orders,
                       ([r[k] for k in fixed] + list(r['amplitudes']) for r in rows))


def write_cycles_csv(sig, path: Path) -> Path:
    """Every engine cycle: start/end time, crank angle, speed, Fig. 13 quantities, |c_n|."""
    c = sig.cycles
    amp = np.abs(c.coeffs)
    header = ['t_start_s', 't_end_s', 'psi_start_rad', 'speed_rpm', 'mean', 'max_deviation',
              'min_deviation'] + [f'o{n / 2:g}' for n in range(amp.shape[1])]
    return write_table(path, header, (
        [c.t_start[i], c.t_end[i], c.psi_start[i], c.speed_rpm[i], c.mean[i],
         c.max_deviation[i], c.min_deviation[i]] + [_f(a) for a in amp[i]]
        for i in range(len(c))))


def write_outputs(res, out: Path, *, natural: Mapping[str, Sequence[float]] | None = None,
                  plots: bool = True, extra: Mapping[str, Any] | None = None) -> list[Path]:
    """Write ``analysis.json`` and per signal ``<slug>_orders.csv``, ``<slug>_cycles.csv``,
    ``<slug>_campbell.png``, ``<slug>_fig13.png`` into ``out``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    p = out / 'analysis.json'
    write_json(p, analysis_dict(res, extra))
    written = [p]
    for sig in res.signals:
        written.append(write_csv(sig, out / f'{sig.signal.slug}_orders.csv'))
        written.append(write_cycles_csv(sig, out / f'{sig.signal.slug}_cycles.csv'))
        if plots:
            from dmf_sim.analysis.plots import plot_campbell, plot_fig13

            written.append(plot_campbell(res, sig, out / f'{sig.signal.slug}_campbell.png',
                                         natural))
            written.append(plot_fig13(res, sig, out / f'{sig.signal.slug}_fig13.png'))
    return written
