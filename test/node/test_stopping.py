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

More rounds by hand:
``DMF_SIM_STOP_ROUNDS=200 DMF_SIM_STOP_SEED=7 pytest test/node/test_stopping.py``.
"""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
from support.bag_checks import assert_complete_bag

REPO = Path(__file__).resolve().parents[2]
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
    signals = StopSignals(lambda text: print(text, file=sys.stderr, flush=True)).install()
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


def _as_delivered(received: list[str], sent: list[str]) -> bool:
    """Whether ``received`` is what Linux and Python can deliver of ``sent``: a signal sent
    again while the first is pending is merged into it, and pending signals reach their Python
    handlers in signal-number order. So every kind sent arrives, at most as often as sent."""
    return set(received) == set(sent) and not Counter(received) - Counter(sent)


def _expect(proc, word: str) -> str:
    """The child's next line, which must start with ``word``."""
    line = proc.stdout.readline()
    assert line, f'the recorder ended (rc {proc.poll()}) while {word!r} was expected'
    assert line.startswith(word), (word, line)
    return line.strip()


@pytest.mark.slow
def test_later_signals_never_interrupt_closing_a_bag(tmp_path):
    """Without DDS: the first signal stops the recording; the 1-2 that follow, sent at once or
    after 0-50 ms, are ignored (and logged) also while the bag is being closed, in every round;
    every bag is complete. With the old handling (the first signal reset SIGTERM/SIGINT to their
    default action) the second signal killed the process, mostly during the close."""
    rng = random.Random(SEED)
    rounds = ROUNDS or 16
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO),
                                                      os.environ.get('PYTHONPATH', '')]))
    log_path = tmp_path / 'recorder.log'          # the log lines of the ignored signals
    with open(log_path, 'w') as log:
        proc = subprocess.Popen([sys.executable, '-c', RECORDER, str(tmp_path)], env=env,
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log,
                                text=True)
    sent: list[list[str]] = []
    got: list[list[str]] = []

    def command(text: str) -> None:
        proc.stdin.write(text + '\n')
        proc.stdin.flush()
        if sent:                                         # what the last round received
            received = _expect(proc, 'received').split()[1:]
            assert _as_delivered(received, sent[-1]), (len(sent) - 1, received, sent[-1])
            got.append(received)

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
    logs = log_path.read_text().splitlines()
    assert len(logs) == sum(len(r) - 1 for r in got), logs    # each later signal logged once
    assert all('SIGKILL stops at once' in line for line in logs), logs
    assert any('ignored while closing the bag' in line for line in logs), logs


# ------------------------------------------------------------------------------------------------
# The node over DDS
# ------------------------------------------------------------------------------------------------

LAUNCH_LIKE = '''
import subprocess, sys
node = subprocess.Popen(sys.argv[1:], stdout=sys.stderr)      # the node's log: our stderr
print(node.pid, flush=True)
node.wait()
'''
MOMENTS = ('recording starts', 'running', 'running later')   # when the first signal comes
WAYS = ('node', 'process group', 'parent dies')              # where it comes from


def _children(pid: int) -> set[int]:
    """The child processes of ``pid`` now (Linux /proc)."""
    out = set()
    for task in Path(f'/proc/{pid}/task').glob('*'):
        try:
            out |= {int(c) for c in (task / 'children').read_text().split()}
        except (FileNotFoundError, ProcessLookupError):
            pass
    return out


def _wait_for(path: Path, text: str, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.exists() and text in path.read_text():
            return True
        time.sleep(0.005)
    return False


@pytest.mark.ros
@pytest.mark.slow
def test_node_closes_its_bag_whatever_signals_follow(tmp_path):
    """The node recording, in rounds: 2-3 signals (TERM/INT mixed, 0-50 ms apart) to the node,
    to its whole process group (``kill -TERM %1`` on a launch job: the monitor's workers get
    them too) or after its launch-like parent died (Linux's parent-death SIGTERM first), the
    first one right when the recording starts (the node is still being built), while it runs
    or later. Every round: exit code 0, 'stopped recording' logged, the bag complete, no
    traceback, and the monitor's worker processes end with the node. Seeded; ~8 s a round."""
    from support.dds_peer import START_TIMEOUT, new_domain
    from support.processes import gone as _gone

    rng = random.Random(SEED)
    rounds = ROUNDS or 6
    plan = [(WAYS[i % len(WAYS)], MOMENTS[(i // len(WAYS) + i) % len(MOMENTS)])
            for i in range(rounds)]
    env = dict(os.environ, ROS_DOMAIN_ID=str(new_domain()), PYTHONUNBUFFERED='1',
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    for i, (way, moment) in enumerate(plan):
        bag, log_path = tmp_path / f'bag{i}', tmp_path / f'node{i}.log'
        cmd = [sys.executable, '-m', 'dmf_sim.node', '--ros-args', '-p', 'record:=true',
               '-p', f'bag_path:={bag}']
        parent = None
        with open(log_path, 'w') as log:
            if way == 'parent dies':
                parent = subprocess.Popen([sys.executable, '-c', LAUNCH_LIKE, *cmd], cwd=tmp_path,
                                          env=env, stdout=subprocess.PIPE, stderr=log, text=True)
                pid = int(parent.stdout.readline())
                node = None
            else:
                node = subprocess.Popen(cmd, cwd=tmp_path, env=env, stdout=log,
                                        stderr=subprocess.STDOUT,
                                        start_new_session=(way == 'process group'))
                pid = node.pid
        workers: set[int] = set()
        try:
            mark = 'recording to' if moment == 'recording starts' else 'stop: Ctrl-C'
            assert _wait_for(log_path, mark, START_TIMEOUT), log_path.read_text()
            if moment != 'recording starts':
                time.sleep(rng.uniform(0.0, 0.5) + (1.5 if moment == 'running later' else 0.0))
                workers = _children(pid)
            def send(signum: int, way=way, pid=pid) -> None:
                try:
                    (os.killpg if way == 'process group' else os.kill)(pid, signum)
                except ProcessLookupError:       # the node has ended already
                    pass

            if way == 'parent dies':
                parent.kill()                    # SIGKILL: the node gets the parent-death SIGTERM
                sent = ['SIGTERM', *_more(rng, send, rng.randint(1, 2))]
            else:
                first = rng.choice(SIGNALS)
                send(first)
                sent = [signal.Signals(first).name, *_more(rng, send, rng.randint(1, 2))]
            end = time.monotonic() + 60.0
            while not _gone(pid) and time.monotonic() < end:
                time.sleep(0.01)
            assert _gone(pid), f'round {i} ({way}, {moment}): the node still runs'
            rc = node.wait(timeout=10) if node is not None else 0
            time.sleep(0.5)                      # a worker killed with the node is reaped
            alive = [w for w in workers if not _gone(w)]
        finally:
            for p in (node, parent):
                if p is not None and p.poll() is None:
                    p.kill()
                    p.wait(timeout=10)
            if not _gone(pid):
                os.kill(pid, signal.SIGKILL)
        out = log_path.read_text()
        where = f'round {i} ({way}, {moment}, {sent}):\n{out}'
        assert rc == 0, where
        assert 'Traceback' not in out and f'stopped recording: bag {bag} closed' in out, where
        assert out.count('ignored while') <= len(sent) - 1, where      # repeats may merge
        assert not alive, f'{where}\nworkers {alive} outlived the node'
        # stopped before its first tick (while being built, or just after): 0 messages
        assert assert_complete_bag(bag) >= (moment == 'running later'), where
