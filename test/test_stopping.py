"""Stopping the live node closes its bag whatever signals follow the first one.

``ros2 launch`` killed with SIGTERM: the node got two SIGTERMs 4-40 ms apart (the one to the
job's process group, then the parent-death SIGTERM when launch ended at once); the first started
the shutdown and reset SIGTERM to its default action, so the second killed the node before the
bag was closed (last file without its footer, missing from ``metadata.yaml``). Now the first
SIGINT/SIGTERM stops the node and every later one is logged and ignored
(:class:`dmf_sim.live.stop_signals.StopSignals`).

Two levels, both sending 2-3 signals (SIGTERM/SIGINT mixed) with random gaps of 0-50 ms at
random moments, with a fixed seed, and checking every bag with :func:`bag_checks.
assert_complete_bag`:

* without DDS: a recorder process (the node's signal handling around a ``BagRecorder``) through
  many rounds, some of the signals timed to land while the bag is being closed;
* the node itself over DDS (slow): signals right at the start of recording (during the node's
  construction), while it runs, to its whole process group (``kill -TERM %1``), and the death
  of its launch-like parent followed by more signals. The monitor's worker processes must end
  with the node.

More rounds by hand: ``DMF_SIM_STOP_ROUNDS=200 DMF_SIM_STOP_SEED=7 pytest test/test_stopping.py``.
"""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from bag_checks import assert_complete_bag

REPO = Path(__file__).resolve().parents[1]
ROUNDS = int(os.environ.get('DMF_SIM_STOP_ROUNDS', '0'))     # 0: each test's own default
SEED = int(os.environ.get('DMF_SIM_STOP_SEED', '20'))
GAP_S = (0.0, 0.05)           # between the signals of one burst [s]
SIGNALS = (signal.SIGTERM, signal.SIGINT)

RECORDER = r'''
import struct, sys, time
from pathlib import Path
from dmf_sim.bags.writer import BagRecorder
from dmf_sim.live.stop_signals import StopSignals

root = Path(sys.argv[1])
previous = None
for line in sys.stdin:
    if previous is not None:
        print('received', ' '.join(previous.received), flush=True)
    if line.strip() == 'end':
        break
    signals = StopSignals(lambda text: print('log', text, flush=True)).install()
    # small chunks and 1 s splits: many chunk indexes to write at close, a split being finished
    rec = BagRecorder(root / f'bag{line.strip()}', {'/x': 'std_msgs/msg/Float64'},
                      max_duration_s=1.0, chunk_bytes=1024)
    print('recording', flush=True)
    t = 0
    while not signals.requested.is_set():
        rec.write('/x', t, b'\x00\x01\x00\x00' + struct.pack('<d', t * 1e-9))
        t += 1_000_000                     # 1 ms of log time per message
        if t % 50_000_000 == 0:
            time.sleep(0.001)
    signals.doing = f'closing the bag {rec.path}'
    print('closing', flush=True)
    rec.close()
    signals.doing = 'waiting'
    print('closed', rec.message_count, flush=True)
    previous = signals
'''


def _more(rng: random.Random, send, count: int, wait_first: bool = True) -> list[str]:
    """``count`` more signals (SIGTERM or SIGINT) with random gaps; returns their names."""
    names = []
    for i in range(count):
        if i or wait_first:
            time.sleep(rng.uniform(*GAP_S))
        signum = rng.choice(SIGNALS)
        send(signum)
        names.append(signal.Signals(signum).name)
    return names


def _expect(proc, word: str, timeout: float = 60.0) -> str:
    """The child's next line, which must start with ``word`` (log lines are kept aside)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        line = proc.stdout.readline()
        assert line, f'the recorder ended (rc {proc.poll()}) while {word!r} was expected'
        if not line.startswith('log '):
            assert line.startswith(word), (word, line)
            return line.strip()
        _expect.logs.append(line.strip())
    raise AssertionError(f'no {word!r} within {timeout} s')


_expect.logs = []


def test_later_signals_never_interrupt_closing_a_bag(tmp_path):
    """Without DDS: the first signal stops the recording; the 1-2 that follow, sent at once or
    after 0-50 ms, are ignored (and logged) also while the bag is being closed, in every round;
    every bag is complete. With the old handling (the first signal reset SIGTERM/SIGINT to their
    default action) the second signal killed the process, mostly during the close."""
    rng = random.Random(SEED)
    rounds = ROUNDS or 16
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO),
                                                      os.environ.get('PYTHONPATH', '')]))
    proc = subprocess.Popen([sys.executable, '-c', RECORDER, str(tmp_path)], env=env,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    _expect.logs = []
    sent: list[list[str]] = []

    def command(text: str) -> None:
        proc.stdin.write(text + '\n')
        proc.stdin.flush()
        if sent:                                         # what the last round received
            received = _expect(proc, 'received').split()[1:]
            assert received == sent[-1], (len(sent) - 1, received, sent[-1])

    try:
        for i in range(rounds):
            command(str(i))
            _expect(proc, 'recording')
            time.sleep(rng.uniform(0.0, 0.2))            # a random moment of the recording
            first = rng.choice(SIGNALS)
            proc.send_signal(first)
            count = rng.randint(1, 2)
            if rng.random() < 0.5:                       # the later ones timed to the close
                _expect(proc, 'closing')
                more = _more(rng, proc.send_signal, count, wait_first=False)
            else:
                more = _more(rng, proc.send_signal, count)
                _expect(proc, 'closing')
            sent.append([signal.Signals(first).name, *more])
            closed = _expect(proc, 'closed')
            time.sleep(max(GAP_S) + 0.05)                # every signal of the burst delivered
            assert proc.poll() is None, f'round {i}: killed by {sent[-1]}'
            assert assert_complete_bag(tmp_path / f'bag{i}') == int(closed.split()[1]) > 0
        command('end')
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    ignored = sum(len(s) - 1 for s in sent)
    assert len(_expect.logs) == ignored, _expect.logs          # each later signal logged once
    assert all('SIGKILL stops at once' in line for line in _expect.logs)
    assert any('ignored while closing the bag' in line for line in _expect.logs), _expect.logs
