"""Run a benchmark script as a user does and read its last line, the JSON of its figures
(helper)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[2] / 'benchmarks'


def bench_json(script: str, *args: str, timeout: float = 600.0) -> dict:
    """``benchmarks/<script> ARGS`` in this interpreter; a failure shows its output, else the
    last line of its standard output as JSON."""
    res = subprocess.run([sys.executable, str(BENCHMARKS / script), *args], capture_output=True,
                         text=True, timeout=timeout)
    assert res.returncode == 0, res.stdout + res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])
