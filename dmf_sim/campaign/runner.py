"""A fault campaign: a grid of (speed, load, fault, sensor noise) offline runs on Dask, scored.

Each case is a ``dmf-sim run`` of a steady point (:func:`case_profile`: ``SETTLE_S`` settling,
then ``duration_s``) of the shipped DMF truck with its default sensors, their noise (timer
jitter, bus noise) scaled by the case's ``noise`` factor; the fault ``misfire`` injects single
misfires every ``MISFIRE_SPACING_S`` on the cylinders in turn, ``none`` is a healthy run. The
bag is read by the reference detector (:func:`dmf_sim.analysis.misfire_detector.detect_bag`)
and only its score is kept (the bag too with ``keep_bags``). The cases run as tasks on the Dask
cluster of :mod:`dmf_sim.cluster` (the one the design studies use), or in this process without
a client.

Outputs (:func:`write_outputs`): ``scores.csv`` (one row per case: misfires, detected,
missed, false alarms, engine cycles, rates), ``summary.json`` (detection rate and false alarms
per engine cycle over the campaign, per fault and noise level, runs per second), and
``campaign.png`` (detection rate and false alarms per cycle against speed, one line per load).
"""
from __future__ import annotations

import itertools
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Sequence

from dmf_sim.core.csv_out import write_csv
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import write_json

__all__ = ['FAULTS', 'SETTLE_S', 'MISFIRE_SPACING_S', 'DEFAULT_DURATION_S', 'MAX_NOISE',
           'Case', 'cases', 'case_profile', 'run_case', 'run_campaign', 'summarize',
           'write_outputs']

FAULTS = ('none', 'misfire')
SETTLE_S = 0.5                 # from static equilibrium, not scored
MISFIRE_SPACING_S = 0.5        # between single misfires: the DMF's swing has decayed
DEFAULT_DURATION_S = 3.0       # scored seconds of a case
MAX_NOISE = 100.0              # sensor noise factor: 100 x the default jitter is 20 us
DRIVELINE = 'truck_dmf'


@dataclass(frozen=True)
class Case:
    """One run: steady speed [rpm] and load, fault (:data:`FAULTS`), sensor-noise factor."""

    speed_rpm: float
    load: float
    fault: str
    noise: float


def cases(speeds: Sequence[float], loads: Sequence[float], faults: Sequence[str],
          noises: Sequence[float]) -> list[Case]:
    """The grid (speed x load x fault x noise), checked: one line naming the bad value."""
    for s in speeds:
        if not 0 < s:
            raise ConfigError(f'--speeds: {s!r} rpm must be > 0')
    for ld in loads:
        if not 0 <= ld <= 1:
            raise ConfigError(f'--loads: {ld!r} must be in [0, 1]')
    for f in faults:
        if f not in FAULTS:
            raise ConfigError(f'--faults: {f!r} is not one of {", ".join(FAULTS)}')
    for n in noises:
        if not 0 <= n <= MAX_NOISE:
            raise ConfigError(f'--noise: {n!r} must be in [0, {MAX_NOISE:g}] (x the default '
                              'sensor noise)')
    return [Case(float(s), float(ld), f, float(n))
            for s, ld, f, n in itertools.product(speeds, loads, faults, noises)]


def case_profile(case: Case, duration_s: float):
    """The case's steady profile (settling ``SETTLE_S`` then ``duration_s``)."""
    from dmf_sim.transient.profiles import make_profile

    prof = make_profile([(0.0, case.speed_rpm, case.load),
                         (SETTLE_S + duration_s, case.speed_rpm, case.load)],
                        name=f'campaign_{case.speed_rpm:g}_{case.load:g}')
    return replace(prof, settle_s=SETTLE_S)


def _driveline(case: Case, work: Path) -> str:
    """The shipped truck, its sensors' noise scaled (a YAML in ``work``), or its name."""
    if case.noise == 1.0:
        return DRIVELINE
    import yaml

    from dmf_sim.core.paths import config_file

    data = yaml.safe_load(Path(config_file(DRIVELINE + '.yaml')).read_text())
    for w in data['sensors'].get('tooth_wheels', []):
        w['timer_jitter_s'] = w.get('timer_jitter_s', 0.0) * case.noise
    for b in data['sensors'].get('bus_signals', []):
        b['noise_rpm'] = b.get('noise_rpm', 0.0) * case.noise
    path = work / f'{DRIVELINE}_noise_{case.noise:g}.yaml'
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _schedule(work: Path, duration_s: float) -> Path:
    n = max(1, int(duration_s / MISFIRE_SPACING_S) - 1)
    lines = ['faults:'] + [f'  - {{kind: misfire, cylinders: [{i % 6 + 1}], '
                           f'at_s: {SETTLE_S + MISFIRE_SPACING_S * (i + 0.5):g}}}'
                           for i in range(n)]
    path = work / 'misfires.yaml'
    path.write_text('\n'.join(lines) + '\n')
    return path


def run_case(case: Case, duration_s: float = DEFAULT_DURATION_S,
             keep_dir: str | None = None) -> dict[str, Any]:
    """Run, detect and score one case (a Dask task); the bag is kept in ``keep_dir`` (a
    directory per case) or deleted. Returns the case's score row."""
    from dmf_sim.analysis.misfire_detector import detect_bag
    from dmf_sim.transient.run import RunOptions, run_profile

    work = Path(tempfile.mkdtemp(prefix='dmf_campaign_'))
    name = (f'{case.speed_rpm:g}rpm_load{case.load:g}_{case.fault}_noise{case.noise:g}')
    try:
        base = Path(keep_dir) if keep_dir else work
        base.mkdir(parents=True, exist_ok=True)
        faults = str(_schedule(work, duration_s)) if case.fault == 'misfire' else None
        opts = RunOptions(driveline=_driveline(case, base), faults=faults, threads=1)
        t0 = time.perf_counter()
        run_profile(case_profile(case, duration_s), base / name, opts)
        _, score = detect_bag(base / name)
        row = asdict(case)
        row.update(score.as_dict())
        del row['per_cylinder']
        row.update(case=name, seconds=time.perf_counter() - t0,
                   bag=str(base / name) if keep_dir else '')
        return row
    finally:
        shutil.rmtree(work, ignore_errors=True)


def summarize(rows: Sequence[dict[str, Any]], seconds: float, workers: int) -> dict[str, Any]:
    """Detection rate and false alarms per engine cycle over the rows, per fault and noise."""
    def rates(sel):
        mis = sum(r['misfires'] for r in sel)
        cyc = sum(r['cycles'] for r in sel)
        return {'runs': len(sel), 'misfires': mis, 'detected': sum(r['detected'] for r in sel),
                'false_alarms': sum(r['false_alarms'] for r in sel), 'engine_cycles': cyc,
                'detection_rate': sum(r['detected'] for r in sel) / mis if mis else None,
                'false_alarm_rate': sum(r['false_alarms'] for r in sel) / cyc if cyc else None}
    out = rates(rows)
    out['per_noise'] = {f'{n:g}': rates([r for r in rows if r['noise'] == n])
                        for n in sorted({r['noise'] for r in rows})}
    out.update(seconds=seconds, workers=workers,
               runs_per_s=len(rows) / seconds if seconds > 0 else None)
    return out


def run_campaign(grid: Sequence[Case], client=None, *, duration_s: float = DEFAULT_DURATION_S,
                 keep_dir: Path | None = None) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Every case of ``grid``: as tasks of ``client`` (a Dask client) or here without one.
    Returns the score rows (grid order) and :func:`summarize`."""
    keep = None if keep_dir is None else str(keep_dir)
    t0 = time.perf_counter()
    if client is None:
        rows = [run_case(c, duration_s, keep) for c in grid]
        workers = 1
    else:
        futures = client.map(run_case, list(grid), duration_s=duration_s, keep_dir=keep,
                             pure=False)
        rows = client.gather(futures)
        workers = len(client.scheduler_info().get('workers', {})) or 1
    return rows, summarize(rows, time.perf_counter() - t0, workers)


def write_outputs(rows: Sequence[dict[str, Any]], summary: dict[str, Any], out: Path, *,
                  plots: bool = True) -> dict[str, str]:
    """``scores.csv``, ``summary.json`` and (``plots``) ``campaign.png`` in ``out``."""
    files = {}
    keys = ['case', 'speed_rpm', 'load', 'fault', 'noise', 'misfires', 'detected', 'missed',
            'false_alarms', 'cycles', 'detection_rate', 'false_alarm_rate', 'mean_speed_rpm',
            'seconds', 'bag']
    write_csv(out / 'scores.csv', keys, rows)
    files['scores'] = str(out / 'scores.csv')
    write_json(out / 'summary.json', summary)
    files['summary'] = str(out / 'summary.json')
    if plots and rows:
        files['plot'] = str(_plot(rows, out / 'campaign.png'))
    return files


def _plot(rows, path: Path) -> Path:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    for load in sorted({r['load'] for r in rows}):
        for label, ax, key, fault in (('detection rate', ax1, 'detection_rate', 'misfire'),
                                      ('false alarms / cycle', ax2, 'false_alarm_rate', None)):
            sel = sorted((r for r in rows if r['load'] == load
                          and (fault is None or r['fault'] == fault)),
                         key=lambda r: r['speed_rpm'])
            speeds = sorted({r['speed_rpm'] for r in sel})
            if not speeds:
                continue
            vals = []
            for s in speeds:
                rs = [r for r in sel if r['speed_rpm'] == s]
                num = sum(r['detected' if fault else 'false_alarms'] for r in rs)
                den = sum(r['misfires' if fault else 'cycles'] for r in rs)
                vals.append(num / den if den else float('nan'))
            ax.plot(speeds, vals, 'o-', label=f'load {load:g}')
            ax.set_ylabel(label)
    for ax in (ax1, ax2):
        ax.set_xlabel('engine speed [rpm]')
        ax.grid(True, alpha=0.3)
        ax.legend()
    ax1.set_ylim(-0.02, 1.02)
    fig.suptitle('reference misfire detector: fault campaign')
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
