"""benchmarks/bench_monitor.py runs at a small size and reports its figures as JSON."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / 'benchmarks' / 'bench_monitor.py'


def test_bench_monitor_quick():
    out = subprocess.run([sys.executable, str(BENCH), '--seconds', '2.5', '--hold', '0.8',
                          '--variants', 'none', 'process'], capture_output=True, text=True,
                         timeout=300, check=True).stdout
    res = json.loads(out.strip().splitlines()[-1])
    assert set(res) == {'none', 'process'}
    proc = res['process']
    assert proc['ticks'] > 1500 and proc['cycles'] >= 8 and proc['predictions'] >= 2
    assert proc['prediction_latency_max_s'] > 0 and proc['worker_start_s'] > 0
    assert res['none']['cycles'] == 0
