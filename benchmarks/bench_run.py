"""Benchmark: offline transient runs (``dmf-sim run``), run-up physics, durability memory.

Each ``dmf-sim run`` / ``dmf-sim durability`` runs in a fresh process (its peak RSS is its
own), on the paper driveline (``truck_dmf``, ``engine_d13``, Load A, full load) unless said:

* ``realtime_factor``: simulated seconds per wall second of ``dmf-sim run`` writing the bag at
  1 kHz (a run-up ``ramp:800:2000:10``, 122 s simulated), ``realtime_factor_no_write`` the
  same without the bag; ``*_cpu`` per CPU second of the process (the figure a loaded machine
  distorts least). Each is the median of ``--repeat`` runs (alternating, each in a fresh
  process); ``speed_runs`` lists every run, ``speed_min`` / ``speed_median`` both. The
  headline figures are the command's default (``threads_default``: 2 threads on a machine with
  two CPUs), the ``*_threads1`` ones ``--threads 1`` (integrating and writing in turn), the
  ``*_threads2`` ones ``--threads 2`` (integrating in a thread of its own), the
  ``*_no_sensors`` ones ``--no-sensors`` (no tooth-wheel and bus topics: what the sensors
  cost). ``messages_by_topic``: the messages of the first bag per topic.
* ``breakdown_ms_per_sim_s``: where the time of one ``--threads 1`` run with the bag goes, in
  wall milliseconds per simulated second, timed in this process around the stages: the Newmark
  kernel, the excitation update and the rest of a chunk's integration, the read-out of the
  element angles and torques, encoding the messages (straight into the block of 1024 samples
  the bag gets at once) and writing the bag (``write_block``: the records, their CRC and the
  file write), and what is left (the loop); ``kernel_ceiling`` is
  simulated seconds per second of kernel alone, the bound no writing path can beat.
* ``quasi_static_rel_diff``: that slow run-up (10 rpm/s) against the HBM sweep's stable branch
  (``dmf-sim runup``): the largest |measured / HBM - 1| of the 3rd- and 1.5th-order wind-up
  amplitudes over the 10 rpm bins 30 rpm or more from jumps and sweep events where the HBM
  amplitude is >= 5 % of its peak (the 1.5th order of this case is a small imperfect-bifurcation
  hump: compared where it is not negligible).
  ``quasi_static_rel_diff_slow``: the same for a run-up at 2 rpm/s (``quasi_static_slow``
  names the order and speed of the largest difference).
* ``jump_speed_error_rpm``: the hardening fold case (:mod:`dmf_sim.transient.cases`: coexisting
  states between its two folds), run up and down at 5 rpm/s: the largest distance of a jump
  found in the records from the nearest sweep event (fold / stability loss).
* ``peak_rss_mib``: ``dmf-sim run`` of an hour-long profile (the road cycle repeated) at 1 kHz,
  peak RSS after 10 %, 50 % and 100 % of it; then ``dmf-sim durability`` of that bag against
  the same on its first minute (``durability_rss_growth_mib``: what an hour adds).

    python benchmarks/bench_run.py [--small] [--repeat 3] [--speed-only] [--hour-s 3600]
                                   [--keep DIR]

``--small``: seconds-long profiles, the commands in this process (a smoke test of the whole
chain, not the figures). ``--speed-only``: the speed figures and the breakdown only. Last
line: one JSON object.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


IN_PROCESS = False     # --small: run the commands in this process (no start-up cost per call)


def cli(*args: str) -> dict:
    """``dmf-sim ARGS --json`` in a fresh process (``--small``: in this one); its JSON."""
    if IN_PROCESS:
        import contextlib
        import io

        from dmf_sim.cli import main as cli_main
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            code = cli_main([*args, '--json'])
        if code != 0:
            raise RuntimeError(f'dmf-sim {" ".join(args)} failed with exit {code}')
        return json.loads(buf.getvalue().strip().splitlines()[-1])
    env = {**os.environ, 'PYTHONPATH': os.pathsep.join([str(REPO),
                                                         os.environ.get('PYTHONPATH', '')])}
    proc = subprocess.run([sys.executable, '-m', 'dmf_sim.cli', *args, '--json'], env=env,
                          capture_output=True, text=True, timeout=3 * 3600)
    if proc.returncode != 0:
        raise RuntimeError(f'dmf-sim {" ".join(args)} failed: {proc.stderr.strip()}')
    return json.loads(proc.stdout.strip().splitlines()[-1])


def speed_runs(profile: str, work: Path, repeat: int) -> dict:
    """``dmf-sim run`` with and without the bag, with its default threads, with 1 and 2 and
    without the sensors, ``repeat`` times each (alternating); per variant the wall and CPU
    factors of every run, min and median, and the default's thread count
    (``threads_default``)."""
    variants = {'': (), '_threads1': ('--threads', '1'), '_threads2': ('--threads', '2'),
                '_no_sensors': ('--no-sensors',)}
    runs: dict[str, list[float]] = {}
    first = None
    runs_threads = None
    for i in range(repeat):
        for suffix, opts in variants.items():
            for write in (True, False):
                out = work / f'speed{suffix}_{i}'
                args = ['--out', str(out)] if write else ['--no-write']
                r = cli('run', profile, *args, *opts)
                if not opts:
                    runs_threads = r['threads']
                if write and first is None:
                    first = (r, out)
                elif write:
                    shutil.rmtree(out, ignore_errors=True)
                key = f'realtime_factor{"" if write else "_no_write"}{suffix}'
                runs.setdefault(key, []).append(r['realtime_factor'])
                runs.setdefault(f'{key}_cpu', []).append(r['simulated_s'] / r['cpu_s'])
    out = {key: statistics.median(v) for key, v in runs.items()}
    out['threads_default'] = runs_threads
    out.update(speed_runs={k: [round(x, 1) for x in v] for k, v in runs.items()},
               speed_min={k: round(min(v), 1) for k, v in runs.items()},
               speed_median={k: round(statistics.median(v), 1) for k, v in runs.items()})
    return out, first


def messages_by_topic(bag: Path) -> dict[str, int]:
    """Topic -> messages of a bag, as its ``metadata.yaml`` counts them."""
    from dmf_sim.bags.layout import resolve_bag
    out: dict[str, int] = {}
    for item in resolve_bag(bag).metadata.get('topics_with_message_count') or []:
        out[item['topic_metadata']['name']] = int(item['message_count'])
    return out


def breakdown(profile: str, out: Path) -> dict:
    """Wall ms per simulated second in each stage of one ``--threads 1`` run with the bag
    (timers wrapped around the stage functions in this process; their own cost, ~1 us a call
    over ~5000 calls, is in the figures)."""
    import functools
    from collections import defaultdict

    from dmf_sim.bags.writer import BagRecorder
    from dmf_sim.live.simulation import LiveSimulation
    from dmf_sim.solvers.newmark import NewmarkIntegrator
    from dmf_sim.transient import run as run_mod
    from dmf_sim.transient.encode import EncodedBlock
    from dmf_sim.transient.profiles import read_profile

    spent: dict[str, float] = defaultdict(float)
    stages = [(NewmarkIntegrator, 'advance', 'kernel'),
              (NewmarkIntegrator, 'update_excitation', 'excitation'),
              (LiveSimulation, 'integrate', 'integrate'),
              (LiveSimulation, 'read_out', 'read_out'),
              (EncodedBlock, 'add', 'encode'),
              (BagRecorder, 'write_block', 'write_block')]
    saved = [(cls, name, getattr(cls, name)) for cls, name, _ in stages]

    def timed(fn, key):
        @functools.wraps(fn)
        def wrapper(*a, **k):
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                spent[key] += time.perf_counter() - t0
        return wrapper
    start = run_mod.TimeBase.start

    def loop_starts(self, *a, **k):         # the run's timed loop starts: set-up not counted
        spent.clear()
        return start(self, *a, **k)
    try:
        for cls, name, key in stages:
            setattr(cls, name, timed(getattr(cls, name), key))
        run_mod.TimeBase.start = loop_starts
        prof = read_profile(profile)
        run_mod.run_profile(read_profile('ramp:800:900:100:1.0:0.1'), None)   # warm
        s = run_mod.run_profile(prof, out, run_mod.RunOptions(threads=1))
    finally:
        for cls, name, fn in saved:
            setattr(cls, name, fn)
        run_mod.TimeBase.start = start
    sim = s.simulated_s
    ms = {k: 1000.0 * v / sim for k, v in spent.items()}
    ms['integrate_rest'] = ms.pop('integrate') - ms['kernel'] - ms['excitation']
    ms['loop_rest'] = 1000.0 * s.wall_s / sim - sum(ms.values())
    ms['total'] = 1000.0 * s.wall_s / sim
    return {'breakdown_ms_per_sim_s': {k: round(v, 3) for k, v in ms.items()},
            'breakdown_realtime_factor': s.realtime_factor,
            'kernel_ceiling': sim / spent['kernel']}


def hour_profile(path: Path, seconds: float) -> Path:
    """The road cycle repeated to ``seconds`` (CSV)."""
    from dmf_sim.transient.profiles import read_profile
    road = read_profile('truck_road_cycle')
    rows, t0 = [], 0.0
    while t0 < seconds:
        for t, s, x in zip(road.t_s, road.speed_rpm, road.load):
            if rows and t == 0:
                continue
            if t0 + t > seconds:
                break
            rows.append(f'{t0 + t:.3f},{s:g},{x:g}')
        t0 += road.duration_s
    path.write_text('time_s,speed_rpm,load\n' + '\n'.join(rows) + '\n')
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--small', action='store_true', help='seconds-long profiles (smoke test)')
    ap.add_argument('--hour-s', type=float, default=3600.0,
                    help='length of the memory profile [s] (default 3600)')
    ap.add_argument('--keep', type=Path, help='keep the bags and reports in this directory')
    ap.add_argument('--repeat', type=int, default=3,
                    help='runs per speed figure (min and median reported; default 3)')
    ap.add_argument('--speed-only', action='store_true',
                    help='the speed figures and the breakdown only')
    args = ap.parse_args()
    global IN_PROCESS
    IN_PROCESS = args.small
    from dmf_sim.transient.cases import write_fold_case
    from dmf_sim.transient.runup import runup_analysis

    work = args.keep or Path(tempfile.mkdtemp(prefix='bench_run_'))
    work.mkdir(parents=True, exist_ok=True)
    out: dict = {'date_utc': time.strftime('%Y-%m-%d %H:%M:%S', time.gmtime()),
                 'load_average_1min': os.getloadavg()[0], 'cpus': os.cpu_count(),
                 'python': platform.python_version(), 'small': args.small}
    try:
        # 1. run-up on the paper driveline: speed with and without the bag, quasi-static check
        up = 'ramp:1200:1300:100:1.0:0.5' if args.small else 'ramp:800:2000:10:1.0:2'
        speeds, (w, bag) = speed_runs(up, work, 1 if args.small else max(args.repeat, 1))
        out.update(profile_runup=up, simulated_s=w['simulated_s'], **speeds,
                   bag_mib=sum(f.stat().st_size for f in bag.glob('*.mcap')) / 2 ** 20,
                   messages=w['messages'], messages_by_topic=messages_by_topic(bag))
        out.update(breakdown(up, work / 'breakdown'))
        if args.speed_only:
            out['load_average_1min_end'] = os.getloadavg()[0]
            print(json.dumps(out))
            return
        qs = runup_analysis([bag]).quasi_static.get('up', {})
        out['quasi_static'] = qs
        rel = [v['max_rel_diff'] for v in qs.values() if v.get('max_rel_diff') is not None]
        out['quasi_static_rel_diff'] = max(rel) if rel else None
        # the same at 2 rpm/s: a ramp's lag behind the steady state shrinks with its rate
        slow = 'ramp:1200:1300:50:1.0:0.5' if args.small else 'ramp:800:2000:2:1.0:2'
        cli('run', slow, '--out', str(work / 'paper_up_slow'))
        qs = runup_analysis([work / 'paper_up_slow']).quasi_static.get('up', {})
        out['quasi_static_slow'] = {'profile': slow, **qs}
        rel = [v['max_rel_diff'] for v in qs.values() if v.get('max_rel_diff') is not None]
        out['quasi_static_rel_diff_slow'] = max(rel) if rel else None
        # 2. jumps on the fold case, up and down
        line, engine = write_fold_case(work / 'fold_case')
        rate = 50 if args.small else 5
        for name, spec in (('fold_up', f'ramp:330:420:{rate}:1.0:2'),
                           ('fold_down', f'ramp:420:330:{rate}:1.0:2')):
            cli('run', spec, '--out', str(work / name), '--config', str(line), '--engine',
                str(engine))
        res = runup_analysis([work / 'fold_up', work / 'fold_down'])
        out['jumps'] = [j.as_dict() for j in res.jumps]
        out['fold_events_rpm'] = [e['speed_rpm'] for e in res.events if e['kind'] == 'fold']
        errs = [j.error_rpm for j in res.jumps if j.error_rpm is not None]
        both = {j.direction for j in res.jumps} == {1, -1}
        out['jump_speed_error_rpm'] = max(errs) if errs and both else None
        out['jumps_found_up_and_down'] = both
        # 3. memory over an hour-long profile: run, then durability (whole vs first minute)
        seconds = 20.0 if args.small else args.hour_s
        prof = hour_profile(work / 'hour.csv', seconds)
        h = cli('run', str(prof), '--out', str(work / 'hour'))
        out.update(hour_simulated_s=h['simulated_s'], hour_realtime_factor=h['realtime_factor'],
                   run_peak_rss_mib=h['peak_rss_mib'],
                   run_rss_growth_mib=h['peak_rss_mib']['1'] - h['peak_rss_mib']['0.1'],
                   hour_bag_mib=sum(f.stat().st_size for f in (work / 'hour').glob('*.mcap'))
                   / 2 ** 20)
        t0 = time.perf_counter()
        d_all = cli('durability', str(work / 'hour'))
        out['durability_seconds'] = time.perf_counter() - t0
        d_one = cli('durability', str(sorted((work / 'hour').glob('*_0.mcap'))[0]))
        out.update(durability_peak_rss_mib=d_all['peak_rss_mib'],
                   durability_first_minute_peak_rss_mib=d_one['peak_rss_mib'],
                   durability_rss_growth_mib=d_all['peak_rss_mib'] - d_one['peak_rss_mib'],
                   durability_batches=d_all['batches'],
                   damage_per_hour=d_all['damage_per_hour'],
                   dissipated_power_mean_w=d_all['dissipated_power']['mean_w'])
        out['load_average_1min_end'] = os.getloadavg()[0]
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    print(json.dumps(out))


if __name__ == '__main__':
    main()
