"""Does the DMF monitor (per-cycle orders + HBM prediction) slow the node's tick thread?

Emulates the node's real-time loop (dmf_sim/node.py): a tick every 1 ms of wall time integrates
10 Newmark steps of 1e-4 s (LiveSimulation.advance, one published sample) and hands the sample
to the monitor, then polls it. The lag of each sample is the wall time at the end of its tick
minus its due time. The speed setpoint moves every ``--hold`` seconds through speeds around the
DMF's 1.5th-order resonance (alpha 3, theta 0.2 rad, full load), so the prediction is computed
again and again. Variants: no monitor; monitor with worker threads; with worker processes.

    python benchmarks/bench_monitor.py [--seconds 12] [--hold 1.5]
    python benchmarks/bench_monitor.py --ticks 2300 --hold 1 --variants process   # smoke run

``--ticks N`` ends a variant after N ticks, and after its monitor's first prediction (waited for
up to PREDICTION_WAIT_S, the setpoint held from tick N on), instead of after ``--seconds``: the
counts then do not depend on how busy the machine is (the test suite's smoke run).

Prints a table and, as its LAST line, one JSON object with the figures.
"""
from __future__ import annotations

import argparse
import gc
import json
import sys
import time

import numpy as np

from dmf_sim.live.simulation import LiveSimulation
from dmf_sim.monitor.worker import LiveMonitor, MonitorSettings

SPEEDS_RPM = (960.0, 1010.0, 905.0, 1100.0, 940.0, 1050.0, 980.0, 920.0, 1200.0, 870.0)
TICK_S = 1e-3          # wall time per tick (the node's 1 kHz publish rate)
PREDICTION_WAIT_S = 240.0   # --ticks: longest wait for the first prediction [s]
STEPS_PER_TICK = 10    # dt 1e-4 s


def run(variant: str, seconds: float, hold: float, ticks: int | None = None) -> dict:
    sim = LiveSimulation.from_config(alpha=3.0, theta=0.2, speed_rpm=1000.0, load=1.0,
                                     speed_ramp_rpm_per_s=500.0)
    mon = None
    start = time.perf_counter()
    if variant != 'none':
        mon = LiveMonitor(sim.line, sim.engine, MonitorSettings(worker=variant))
        mon.wait_ready(120.0)
    worker_start_s = time.perf_counter() - start
    lags, latencies, cycles = [], [], 0
    sys.setswitchinterval(1e-3)     # as the node does
    gc.collect()
    gc.freeze()
    t0 = time.perf_counter()
    k, i_speed, next_change, asked = 0, 0, t0, None
    while True:
        now = time.perf_counter()
        if ticks is None and now - t0 > seconds:
            break
        if ticks is not None and k >= ticks and (
                mon is None or latencies or now - t0 > PREDICTION_WAIT_S):
            break
        if now >= next_change and (ticks is None or k < ticks):
            speed = SPEEDS_RPM[i_speed % len(SPEEDS_RPM)]
            i_speed += 1
            sim.set_speed_setpoint(speed)
            if mon is not None:
                mon.set_setpoint(speed, sim.load_setpoint)
                asked = now
            next_change = now + hold
        due = t0 + k * TICK_S
        samples = sim.advance(STEPS_PER_TICK)
        if mon is not None:
            mon.add_samples(samples, sim.load)
            up = mon.poll()
            cycles += len(up.cycles)
            if up.prediction is not None and asked is not None:
                latencies.append(time.perf_counter() - asked)
                asked = None
        lags.append(time.perf_counter() - due)
        k += 1
        wait = t0 + k * TICK_S - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
    gc.unfreeze()
    if mon is not None:
        mon.close()
    lag = np.asarray(lags[200:]) * 1e3        # skip the first 0.2 s
    return {'variant': variant, 'ticks': len(lag), 'lag_p50_ms': float(np.percentile(lag, 50)),
            'lag_p99_ms': float(np.percentile(lag, 99)), 'lag_max_ms': float(lag.max()),
            'cycles': cycles, 'predictions': len(latencies), 'worker_start_s': worker_start_s,
            'prediction_latency_max_s': float(max(latencies)) if latencies else float('nan'),
            'prediction_latency_median_s': (float(np.median(latencies)) if latencies
                                            else float('nan'))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seconds', type=float, default=12.0, help='wall time per variant [s]')
    ap.add_argument('--hold', type=float, default=1.5, help='seconds between setpoint changes')
    ap.add_argument('--ticks', type=int, default=None,
                    help='end after this many ticks and the first prediction (not --seconds)')
    ap.add_argument('--variants', nargs='+', default=['none', 'thread', 'process'])
    args = ap.parse_args(argv)
    rows = [run(v, args.seconds, args.hold, args.ticks) for v in args.variants]
    print(f'{"variant":8s} {"ticks":>6s} {"lag p50":>8s} {"p99":>7s} {"max":>7s} {"cycles":>6s} '
          f'{"predictions":>11s} {"latency median/max":>19s} {"start":>6s}')
    for r in rows:
        print(f'{r["variant"]:8s} {r["ticks"]:6d} {r["lag_p50_ms"]:7.3f}ms '
              f'{r["lag_p99_ms"]:6.3f}ms '
              f'{r["lag_max_ms"]:6.2f}ms {r["cycles"]:6d} {r["predictions"]:11d} '
              f'{r["prediction_latency_median_s"]:8.3f}s /{r["prediction_latency_max_s"]:6.3f}s '
              f'{r["worker_start_s"]:5.2f}s')
    print(json.dumps({r['variant']: r for r in rows}))
    return 0


if __name__ == '__main__':
    sys.exit(main())
