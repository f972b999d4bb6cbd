"""Benchmark: the live node recording for a long time with changing setpoints (a truck shift).

Starts ``python -m dmf_sim.node`` recording (dt 1e-4 s, every stream at 1 kHz) on a private DDS
domain (localhost only), and from a second process over real DDS:

* sends a new speed setpoint (800..1800 rpm) and load setpoint (0.2..1.0) every 2-3 s (fixed
  random seed), from a reliable keep-all publisher;
* samples the node's resident memory (RSS, /proc) every second; after the warm-up a straight
  line fitted to RSS(t) gives ``rss_growth_mib_per_h`` (with the fit's residual);
* measures CPU [% of one core], the real-time factor (1-s diagnostics windows), the node-side
  lag over the whole run (p99 and max, overruns included) and the overruns;
* counts lost messages: ``setpoints_lost`` = setpoints sent minus the arrivals the node counted;
  ``joint_states_lost`` = JointState samples in the bag (everything the node published) within
  the span this process received, minus those it received.

The bag is closed by SIGTERM and checked. Last line: one JSON object.

    python benchmarks/bench_soak.py [--minutes 30] [--warmup-minutes 2]
"""
from __future__ import annotations

import argparse
import json
import os
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_node import (  # noqa: E402
    NodeRun,
    Probe,
    clean_json,
    default_domain,
    diag_values,
    proc_cpu_seconds,
    proc_rss_mib,
)

SPEED_RANGE_RPM = (800.0, 1800.0)
LOAD_RANGE = (0.2, 1.0)
SETPOINT_PERIOD_S = (2.0, 3.0)
RSS_PERIOD_S = 1.0


def bag_joint_state_stamps(bag: Path) -> np.ndarray:
    """Log times [ns] of every JointState in the bag (all its MCAP files), sorted."""
    from mcap.reader import make_reader

    out = []
    for path in sorted(bag.glob('*.mcap')):
        with open(path, 'rb') as f:
            for _schema, channel, message in make_reader(f).iter_messages(
                    topics=['/driveline/joint_states']):
                out.append(message.log_time)
    return np.sort(np.asarray(out, dtype=np.int64))


def run(args) -> dict:
    domain = args.domain or default_domain()
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['ROS_DOMAIN_ID'] = str(domain)
    tmp = Path(tempfile.mkdtemp(prefix='bench_soak_'))
    node = NodeRun('', tmp / 'soak_bag', tmp, ['-p', 'diagnostics_rate:=1.0'])
    duration = args.minutes * 60.0
    warmup = args.warmup_minutes * 60.0
    rng = random.Random(args.seed)
    probe = None
    rss_t, rss = [], []
    sent = 0
    try:
        from std_msgs.msg import Float64

        probe = Probe(domain, int((duration + 10) * 1000 * 1.2) + 1000, [node.fqn])
        if not probe.wait(lambda: probe.diags[node.fqn], 120.0):
            raise RuntimeError(f'node did not publish diagnostics; log in {tmp}')
        pubs = probe.setpoint_publishers()
        ovr0 = int(probe.diags[node.fqn][-1][1]['overruns'])
        t0 = time.monotonic()
        c0 = proc_cpu_seconds(node.proc.pid)
        probe.recording = True
        next_setpoint, next_rss = t0, t0
        while (now := time.monotonic()) < t0 + duration:
            if now >= next_setpoint:
                pubs['speed'].publish(Float64(data=rng.uniform(*SPEED_RANGE_RPM)))
                pubs['load'].publish(Float64(data=rng.uniform(*LOAD_RANGE)))
                sent += 2
                next_setpoint += rng.uniform(*SETPOINT_PERIOD_S)
            if now >= next_rss:
                rss_t.append(now - t0)
                rss.append(proc_rss_mib(node.proc.pid))
                next_rss += RSS_PERIOD_S
            time.sleep(max(0.0, min(next_setpoint, next_rss) - time.monotonic()))
        probe.recording = False
        c1, t1 = proc_cpu_seconds(node.proc.pid), time.monotonic()
        time.sleep(2.5)                             # last diagnostics; setpoints all counted
        diags = probe.diags[node.fqn]
        last = diags[-1][1]
        rtf = diag_values(diags, t0 + 0.5, t1 + 0.5, 'real_time_factor')
        received_js = np.sort(probe.stamp[node.fqn][:probe.n[node.fqn]])
    finally:
        if probe is not None:
            probe.close()
        code = node.stop()

    rss_t, rss = np.asarray(rss_t), np.asarray(rss)
    fit = rss_t >= warmup
    if fit.sum() >= 3:
        coef, res, *_ = np.polyfit(rss_t[fit] / 3600.0, rss[fit], 1, full=True)
        growth = float(coef[0])
        resid = float(np.sqrt(res[0] / fit.sum())) if len(res) else 0.0
    else:
        growth = resid = float('nan')
    in_bag = bag_joint_state_stamps(node.bag)
    if len(received_js):
        span = in_bag[(in_bag >= received_js[0]) & (in_bag <= received_js[-1])]
        js_lost = int(len(np.setdiff1d(span, received_js, assume_unique=True)))
    else:
        js_lost = -1
    check = node.bag_check()
    result = {
        'minutes': args.minutes, 'warmup_minutes': args.warmup_minutes,
        'rss_growth_mib_per_h': growth, 'rss_fit_residual_mib': resid,
        'rss_start_mib': float(rss[0]) if len(rss) else float('nan'),
        'rss_end_mib': float(rss[-1]) if len(rss) else float('nan'),
        'rss_samples': int(len(rss)),
        'cpu_pct': 100.0 * (c1 - c0) / (t1 - t0),
        'rtf_mean': float(np.mean(rtf)) if rtf else float('nan'),
        'rtf_min': float(np.min(rtf)) if rtf else float('nan'),
        'lag_p99_ms_total': float(last['lag_p99_ms_total']),
        'lag_max_ms_total': float(last['lag_max_ms_total']),
        'overruns': int(last['overruns']) - ovr0,
        'setpoints_sent': sent,
        'setpoints_lost': sent - int(last['setpoints_received']),
        'setpoints_rejected': int(last['rejected_setpoints']),
        'joint_states_received': int(len(received_js)),
        'joint_states_lost': js_lost,
        'recording_at_end': last.get('recording') == 'true',
        'node_exit_code': code, **check,
    }
    if not args.keep:
        shutil.rmtree(tmp, ignore_errors=True)
    else:
        result['bag_dir'] = str(tmp)
    return result


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--minutes', type=float, default=30.0, help='measured duration [min]')
    ap.add_argument('--warmup-minutes', type=float, default=2.0,
                    help='start of the run left out of the RSS fit [min]')
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--domain', type=int, default=None,
                    help='ROS_DOMAIN_ID (default: from DMF_SIM_TEST_DOMAINS and the pid)')
    ap.add_argument('--keep', action='store_true', help='keep the bag directory')
    args = ap.parse_args(argv)
    if not 0 <= args.warmup_minutes < args.minutes:
        ap.error('need 0 <= --warmup-minutes < --minutes')
    r = run(args)
    print(f'soak: {r["minutes"]:g} min recording, setpoints every 2-3 s, RSS fit after '
          f'{r["warmup_minutes"]:g} min')
    print(f'  RSS {r["rss_start_mib"]:.1f} -> {r["rss_end_mib"]:.1f} MiB, growth '
          f'{r["rss_growth_mib_per_h"]:.2f} MiB/h (fit residual {r["rss_fit_residual_mib"]:.2f} '
          f'MiB, {r["rss_samples"]} samples)')
    print(f'  CPU {r["cpu_pct"]:.1f} % of one core; real-time factor mean {r["rtf_mean"]:.4f} '
          f'min {r["rtf_min"]:.4f}; lag p99 {r["lag_p99_ms_total"]:.2f} ms, max '
          f'{r["lag_max_ms_total"]:.2f} ms; overruns {r["overruns"]}')
    print(f'  lost: {r["setpoints_lost"]} of {r["setpoints_sent"]} setpoints, '
          f'{r["joint_states_lost"]} of {r["joint_states_received"]} JointState; bag '
          f'{r["bag_messages"]} messages in {r["bag_files"]} file(s), complete '
          f'{r["bag_complete"]}, still recording at the end: {r["recording_at_end"]}')
    print(json.dumps(clean_json(r)))
    return r


if __name__ == '__main__':
    main()
