"""Benchmark: order analysis of a long bag (``dmf-sim analyze``), its reader and its memory.

Writes a synthetic bag as the node records it -- ``/driveline/joint_states`` (sensor_msgs/
JointState, 22 elements), ``/driveline/dmf_windup``, ``/engine/speed``, ``/engine/crank_angle``
(std_msgs/Float64), all at 1 kHz, with BagRecorder's defaults (64 KiB / 0.1 s chunks, 60 s
splits), a run-up and run-down 600 -> 2000 -> 600 rpm and known half-order content -- then
measures, in a fresh process (so its peak RSS is the analysis' own):

* ``analyze_seconds``: what ``dmf-sim analyze BAG --json`` does: read the wind-up, speed and
  crank-angle topics, resample on the crank angle, half orders per cycle, 20 rpm bins, modes,
  static wind-up, HBM overlay, JSON; ``analyze_rss_growth_mib`` / ``analyze_peak_rss_mib``: the
  memory it took (it must not grow with the bag's size beyond the signals kept);
  ``analyze_cpu_seconds``: its CPU time (the test suite's check: load-independent);
* ``read_seconds`` (the fast reader, dmf_sim.bags.columns) against ``library_read_seconds``
  (the same three topics through the libraries alone: mcap's StreamReader + rosbags decoding,
  dmf_sim.bags.read) -- ``fast_reader_speedup`` is why the fast path exists (and
  ``fast_reader_cpu_speedup``, the same in CPU time); both must give the
  same values (``readers_agree``);
* ``joint_analyze_seconds``: element signals from the JointState stream (``--signal angle:CYL1
  --signal torque:INPUT SHAFT``, every one of its messages read), without HBM;
* ``plots_seconds``: the PNG plots.

The recovered 3rd / 1.5th order amplitudes are checked against the synthetic truth. Last line:
one JSON object.

    python benchmarks/bench_analyze.py [--minutes 10] [--rate 1000] [--keep DIR]
"""
from __future__ import annotations

import argparse
import json
import math
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dmf_sim.bags.writer import BagRecorder
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.physics.model import read_driveline

TOPICS = {'/driveline/joint_states': 'sensor_msgs/msg/JointState',
          '/driveline/dmf_windup': 'std_msgs/msg/Float64',
          '/engine/speed': 'std_msgs/msg/Float64',
          '/engine/crank_angle': 'std_msgs/msg/Float64'}
T0_NS = 1_700_000_000_000_000_000
CDR_LE = b'\x00\x01\x00\x00'
# synthetic content: x(psi) = mean + sum a cos(n psi / 2 + phase)
WINDUP = {'mean': 0.2, 3: (0.0012, 0.4), 6: (0.011, -1.1), 12: (0.002, 0.3)}
CYL1 = {'mean': 1e-3, 6: (4e-4, 0.2), 12: (1e-4, 1.0)}
INPUT_TORQUE = {'mean': 1500.0, 3: (40.0, 0.0), 6: (300.0, 2.0)}


def signal(spec: dict, psi: np.ndarray) -> np.ndarray:
    x = np.full_like(psi, spec['mean'])
    for n, (a, ph) in ((k, v) for k, v in spec.items() if k != 'mean'):
        x += a * np.cos(n * psi / 2 + ph)
    return x


def speed_profile(t: np.ndarray, duration: float) -> np.ndarray:
    """600 -> 2000 -> 600 rpm, linear ramps (about 4.7 rpm/s for 10 minutes)."""
    return 600.0 + 1400.0 * (1.0 - np.abs(2.0 * t / duration - 1.0))


def joint_template(names: list[str]) -> tuple[bytes, int, int, int]:
    """CDR of a JointState (rosbags serializer) and the byte offsets of its three arrays."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    JS, Header, Time = (ts.types[n] for n in ('sensor_msgs/msg/JointState', 'std_msgs/msg/Header',
                                              'builtin_interfaces/msg/Time'))
    n = len(names)
    msg = JS(header=Header(stamp=Time(sec=0, nanosec=0), frame_id='driveline'), name=names,
             position=np.full(n, 1.5), velocity=np.full(n, 2.5), effort=np.full(n, 3.5))
    data = bytes(ts.serialize_cdr(msg, 'sensor_msgs/msg/JointState'))
    offs = [data.find(struct.pack('<%dd' % n, *[v] * n)) for v in (1.5, 2.5, 3.5)]
    assert min(offs) > 0
    return data, *offs


def write_bag(path: Path, minutes: float, rate_hz: float = 1000.0) -> dict:
    """Write the synthetic bag (BagRecorder with its defaults); returns what was written."""
    names = read_driveline('truck_dmf').names
    i_cyl, i_in = names.index('CYL1'), names.index('INPUT SHAFT')
    tmpl, off_p, off_v, off_e = joint_template(names)
    m = len(names)
    duration = minutes * 60.0
    n = int(round(duration * rate_hz))
    t = np.arange(n) / rate_hz
    rpm = speed_profile(t, duration)
    omega = rpm * RPM_TO_RAD_S
    psi = np.concatenate(([0.0], np.cumsum(0.5 * (omega[1:] + omega[:-1]) / rate_hz)))
    w = signal(WINDUP, psi)
    pos_cyl = signal(CYL1, psi)
    eff_in = signal(INPUT_TORQUE, psi)
    stamps = T0_NS + np.round(t * 1e9).astype(np.int64)
    block = 2000
    base = np.frombuffer(tmpl, np.uint8)
    t0 = time.perf_counter()
    with BagRecorder(path, TOPICS) as rec, \
            tqdm(total=n, desc='writing bag', unit='sample', unit_scale=True, leave=False) as bar:
        write = rec.write
        for s in range(0, n, block):
            e = min(n, s + block)
            k = e - s
            js = np.tile(base, (k, 1))
            sec = (stamps[s:e] // 1_000_000_000).astype('<i4')
            nsec = (stamps[s:e] % 1_000_000_000).astype('<u4')
            js[:, 4:8] = sec.view(np.uint8).reshape(k, 4)
            js[:, 8:12] = nsec.view(np.uint8).reshape(k, 4)
            pos = np.zeros((k, m))
            pos[:, i_cyl] = pos_cyl[s:e]
            vel = np.gradient(pos, axis=0) * rate_hz
            eff = np.zeros((k, m))
            eff[:, i_in] = eff_in[s:e]
            for off, arr in ((off_p, pos), (off_v, vel), (off_e, eff)):
                js[:, off:off + 8 * m] = arr.astype('<f8').view(np.uint8).reshape(k, 8 * m)
            wb, rb, pb = (a[s:e].astype('<f8').tobytes() for a in (w, rpm, psi))
            for j in range(k):
                ns = int(stamps[s + j])
                sl = slice(8 * j, 8 * j + 8)
                write('/driveline/joint_states', ns, js[j].tobytes())
                write('/driveline/dmf_windup', ns, CDR_LE + wb[sl])
                write('/engine/speed', ns, CDR_LE + rb[sl])
                write('/engine/crank_angle', ns, CDR_LE + pb[sl])
            bar.update(k)
    return {'samples': n, 'messages': 4 * n, 'write_seconds': time.perf_counter() - t0}


def max_rel_error(table, n: int, amplitude: float) -> float:
    a = table.amplitudes[:, n]
    a = a[np.isfinite(a)]
    return float(np.max(np.abs(a - amplitude)) / amplitude)


# ------------------------------------------------------------- the measuring child process

def _rss_mib(field: str) -> float:
    """VmRSS (now) or VmHWM (peak) of this process [MiB]."""
    for line in Path('/proc/self/status').read_text().splitlines():
        if line.startswith(field + ':'):
            return int(line.split()[1]) / 1024.0
    return math.nan


def _reset_peak() -> None:
    """Restart the VmHWM peak from the current RSS (Linux: clear_refs 5)."""
    try:
        Path('/proc/self/clear_refs').write_text('5')
    except OSError:
        pass


def measure(bag: Path, plots_dir: Path | None) -> dict:
    """Everything timed and measured on an existing bag (runs in a fresh process)."""
    from dmf_sim.analysis.pipeline import (
        AnalysisOptions,
        SignalSpec,
        analysis_dict,
        analyze_bag,
        model_settings,
        overlay_all,
        read_bag_series,
        write_outputs,
    )
    from dmf_sim.bags.columns import _record_offsets

    settings = model_settings(None)
    _record_offsets(np.zeros(64, np.uint8))           # the jitted walker loaded (cache)
    t0, c0 = time.perf_counter(), time.process_time()
    windup = AnalysisOptions(bin_rpm=20.0, theta=settings['theta_rad'])
    res = analyze_bag(bag, ['windup'], options=windup)
    t_orders = time.perf_counter()
    natural = overlay_all(res, settings, hbm=True)
    t_hbm = time.perf_counter()
    text = json.dumps(analysis_dict(res, {'natural_frequencies_hz': natural}))
    analyze_seconds = time.perf_counter() - t0
    analyze_cpu_seconds = time.process_time() - c0
    peak = _rss_mib('VmHWM')                          # the whole `analyze --json` process
    sig = res.signal('windup')
    kept_mib = sum(s.t_ns.nbytes + s.values.nbytes for s in res.series.series.values()) / 2**20
    # what reading + orders take on top of a warm process (imports and JIT caches loaded)
    base = _rss_mib('VmRSS')
    _reset_peak()
    again = analyze_bag(bag, ['windup'], options=windup)
    growth = _rss_mib('VmHWM') - base
    del again

    base_j = _rss_mib('VmRSS')
    _reset_peak()
    t1 = time.perf_counter()
    res_j = analyze_bag(bag, ['angle:CYL1', 'torque:INPUT SHAFT'],
                        options=AnalysisOptions(bin_rpm=20.0))
    joint_seconds = time.perf_counter() - t1
    joint_growth = _rss_mib('VmHWM') - base_j

    specs = [SignalSpec.parse('windup')]
    t2, c2 = time.perf_counter(), time.process_time()
    fast = read_bag_series(bag, signals=specs)
    fast_seconds, fast_cpu = time.perf_counter() - t2, time.process_time() - c2
    t3, c3 = time.perf_counter(), time.process_time()
    lib = read_bag_series(bag, signals=specs, reader='messages')
    library_seconds, library_cpu = time.perf_counter() - t3, time.process_time() - c3
    agree = all(np.array_equal(fast.series[k].values, lib.series[k].values)
                and np.array_equal(fast.series[k].t_ns, lib.series[k].t_ns)
                for k in ('crank', 'speed', 'windup'))
    plots_seconds = None
    if plots_dir is not None:
        t4 = time.perf_counter()
        write_outputs(res, plots_dir, natural=natural)
        plots_seconds = time.perf_counter() - t4
    return {
        'files': len(res.files), 'analyze_seconds': analyze_seconds,
        'analyze_cpu_seconds': analyze_cpu_seconds,
        'read_seconds': fast_seconds, 'library_read_seconds': library_seconds,
        'fast_reader_speedup': library_seconds / fast_seconds,
        'fast_reader_cpu_speedup': library_cpu / fast_cpu, 'readers_agree': agree,
        'orders_seconds': t_orders - t0, 'hbm_seconds': t_hbm - t_orders,
        'json_bytes': len(text), 'analyze_peak_rss_mib': peak,
        'analyze_rss_growth_mib': growth, 'kept_signals_mib': kept_mib,
        'joint_analyze_seconds': joint_seconds, 'joint_read_seconds': res_j.read_seconds,
        'joint_rss_growth_mib': joint_growth, 'plots_seconds': plots_seconds,
        'cycles': len(sig.cycles), 'bins': len(sig.table), 'reader': res.reader,
        'order_3_max_rel_error': max_rel_error(sig.table, 6, WINDUP[6][0]),
        'order_1_5_max_rel_error': max_rel_error(sig.table, 3, WINDUP[3][0]),
        'cyl1_order_3_max_rel_error': max_rel_error(res_j.signal('angle:CYL1').table, 6,
                                                    CYL1[6][0]),
        'input_torque_order_3_max_rel_error': max_rel_error(
            res_j.signal('torque:INPUT SHAFT').table, 6, INPUT_TORQUE[6][0]),
    }


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--minutes', type=float, default=10.0, help='bag length [min] (default 10)')
    ap.add_argument('--rate', type=float, default=1000.0, help='sample rate of every topic [Hz]')
    ap.add_argument('--keep', type=Path, help='write the bag (and plots) here and keep them; an '
                                              'existing bag there is reused')
    ap.add_argument('--no-plots', action='store_true', help='skip timing the plots')
    ap.add_argument('--measure', type=Path, help=argparse.SUPPRESS)   # the child process
    args = ap.parse_args(argv)
    if args.measure is not None:
        plots = None if args.no_plots else args.measure.parent / 'plots'
        print(json.dumps(measure(args.measure, plots)))
        return {}
    if not (math.isfinite(args.minutes) and 0 < args.minutes <= 600):
        ap.error('--minutes must be within (0, 600]')
    if not (math.isfinite(args.rate) and 10 <= args.rate <= 10000):
        ap.error('--rate must be within [10, 10000] Hz')
    tmp = None
    if args.keep is not None:
        work = args.keep
        work.mkdir(parents=True, exist_ok=True)
    else:
        tmp = tempfile.mkdtemp(prefix='bench_analyze_')
        work = Path(tmp)
    bag = work / 'bench_bag'
    try:
        if bag.exists():
            info = {'samples': None, 'messages': None, 'write_seconds': None, 'reused_bag': True}
        else:
            info = write_bag(bag, args.minutes, args.rate)
        info['bag_bytes'] = sum(f.stat().st_size for f in bag.glob('*.mcap'))
        print(f'bag: {bag} ({info["bag_bytes"] / 1e6:.0f} MB, {info["messages"]} messages, '
              f'written in {info["write_seconds"] or 0:.1f} s)', file=sys.stderr)
        child = [sys.executable, str(Path(__file__).resolve()), '--measure', str(bag)]
        run = subprocess.run(child + (['--no-plots'] if args.no_plots else []),
                             capture_output=True, text=True, check=True)
        out = {'minutes': args.minutes, 'rate_hz': args.rate, **info,
               'bag_mib': info['bag_bytes'] / 2**20, **json.loads(run.stdout.splitlines()[-1])}
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    print(f'analysis of {args.minutes:g} min ({out["bag_mib"]:.0f} MiB, {out["files"]} files): '
          f'{out["analyze_seconds"]:.2f} s (read {out["read_seconds"]:.2f} s, HBM '
          f'{out["hbm_seconds"]:.2f} s), peak RSS {out["analyze_peak_rss_mib"]:.0f} MiB, reading '
          f'+ orders +{out["analyze_rss_growth_mib"]:.1f} MiB (kept signals '
          f'{out["kept_signals_mib"]:.1f} MiB); libraries alone read in '
          f'{out["library_read_seconds"]:.2f} s (fast reader x{out["fast_reader_speedup"]:.1f}); '
          f'JointState signals {out["joint_analyze_seconds"]:.2f} s'
          + (f'; plots {out["plots_seconds"]:.2f} s' if out['plots_seconds'] else ''),
          file=sys.stderr)
    print(json.dumps(out))
    return out


if __name__ == '__main__':
    main()
