"""Bags split into files of bounded duration and flat recorder memory.

Every closed split is a complete MCAP file listed in ``metadata.yaml``, so after SIGKILL the
bag stays readable by rosbags' rosbag2 reader, the ``mcap`` reader and the rosbag2 layout; the
last, unlisted split is read up to its last chunk and completed by ``bag-recover``. Splitting
also bounds the ``mcap`` writer's per-chunk index memory, which grew without bound before.
"""
from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from support.crash import sigkill_when_ready

from dmf_sim.bags.layout import resolve_bag
from dmf_sim.bags.writer import BagRecorder, read_messages, recover_bag
from dmf_sim.core.errors import BagError

REPO = Path(__file__).resolve().parents[2]
TOPICS = {'/a': 'std_msgs/msg/Float64', '/b': 'std_msgs/msg/Float64'}
T0 = 1_700_000_000_000_000_000
CDR = b'\x00\x01\x00\x00'           # little-endian CDR header of a std_msgs/Float64


def float64(value: float) -> bytes:
    import struct
    return CDR + struct.pack('<d', value)


def info_of(bag: Path) -> dict:
    return yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


def wait_listed(bag: Path, n: int, timeout_s: float = 10.0) -> dict:
    """metadata.yaml once it lists ``n`` files (a helper thread finishes each split)."""
    deadline = time.monotonic() + timeout_s
    while len((info := info_of(bag))['relative_file_paths']) < n and time.monotonic() < deadline:
        time.sleep(0.01)
    return info


def env_with_repo() -> dict:
    return {**os.environ, 'PYTHONPATH': os.pathsep.join([str(REPO),
                                                         os.environ.get('PYTHONPATH', '')])}


def test_splits_closed_listed_and_in_order(tmp_path: Path) -> None:
    """12.5 s of log time at max_duration_s=1: 13 files, each complete, listed in order
    (_10 after _9), counts consistent; rosbags and mcap read every one."""
    from rosbags.rosbag2 import Reader

    bag = tmp_path / 'run'
    n = 1250                            # 100 Hz
    with BagRecorder(bag, TOPICS, max_duration_s=1.0, custom_data={'k': 'v'}) as rec:
        for i in range(n):
            t = T0 + i * 10_000_000
            rec.write('/a', t, float64(i))
            rec.write('/b', t, float64(-i))
            if i == 150:                # mid-recording: one split closed and listed
                mid = wait_listed(bag, 1)
    assert mid['relative_file_paths'] == ['run_0.mcap']
    assert mid['message_count'] == 200 and mid['custom_data'] == {'k': 'v'}
    info = info_of(bag)
    names = [f'run_{i}.mcap' for i in range(13)]
    assert info['relative_file_paths'] == names
    assert sorted(p.name for p in bag.glob('*.mcap')) == sorted(names)
    assert [f['message_count'] for f in info['files']] == [200] * 12 + [100]
    assert info['message_count'] == 2 * n
    assert [t['message_count'] for t in info['topics_with_message_count']] == [n, n]
    assert info['files'][10]['starting_time']['nanoseconds_since_epoch'] == T0 + 10 * 10**9
    for name in names:
        with (bag / name).open('rb') as f:
            reader = make_reader(f)
            summary = reader.get_summary()           # footer + summary present: complete
            assert summary.statistics.message_count in (200, 100)
            assert [m.name for m in reader.iter_metadata()] == ['rosbag2']
    with Reader(bag) as reader:
        values = [raw for _, _, raw in reader.messages()]
    assert len(values) == 2 * n
    msgs = [m for m in read_messages(bag, '/a')]
    assert [m.msg.data for m in msgs] == [float(i) for i in range(n)]   # file order = time
    assert resolve_bag(bag).files == tuple(bag / nm for nm in names)


def test_split_duration_is_bounded(tmp_path: Path) -> None:
    for bad in (0.0, -1.0, float('nan'), 1e9):
        with pytest.raises(BagError, match='max_duration_s must be within'):
            BagRecorder(tmp_path / 'x', TOPICS, max_duration_s=bad)
    assert not (tmp_path / 'x').exists()


CHILD = textwrap.dedent('''
    import struct, sys, time
    from dmf_sim.bags.writer import BagRecorder

    rec = BagRecorder(sys.argv[1], {'/a': 'std_msgs/msg/Float64', '/b': 'std_msgs/msg/Float64'},
                      max_duration_s=1.0)
    t, i, told, after = 1_700_000_000_000_000_000, 0, 0, 0
    while True:                       # 1 kHz of log time, as fast as the recorder takes it
        data = b'\\x00\\x01\\x00\\x00' + struct.pack('<d', float(i))
        rec.write('/a', t, data)
        rec.write('/b', t, data)
        if len(rec.closed_files) != told:
            told = len(rec.closed_files)
            print(told, flush=True)
        t += 1_000_000
        i += 1
        after += told >= 3
        if after == 200:              # some chunks into the next split, then wait for SIGKILL
            rec.flush()               # (the split stays open: no footer, not listed)
            print('flushed', flush=True)
            time.sleep(120)
''')


@pytest.mark.slow
def test_sigkill_leaves_every_closed_split_readable(tmp_path: Path) -> None:
    """SIGKILL while recording; rosbags reads all closed splits as they are,
    mcap reads each of them, our reader reads the last one up to its last chunk, and
    bag-recover completes it (only it is rewritten)."""
    from rosbags.rosbag2 import Reader

    script = tmp_path / 'child.py'
    script.write_text(CHILD)
    bag = tmp_path / 'crash'

    def three_splits(proc) -> None:
        # three closed splits and a flushed chunk in the fourth (a fixed 0.3 s wait here left
        # the fourth without a chunk on a busy machine)
        while (proc.stdout.readline() or 'flushed').strip() != 'flushed':
            pass

    sigkill_when_ready(script, [str(bag)], three_splits)
    info = info_of(bag)
    listed = info['relative_file_paths']
    assert len(listed) >= 3
    present = sorted((p.name for p in bag.glob('*.mcap')), key=lambda s: int(s[6:-5]))
    unlisted = present[len(listed):]     # the open split (and one being finished, if any)
    assert present[:len(listed)] == listed and len(unlisted) in (1, 2)
    with Reader(bag) as reader:                       # rosbags, metadata.yaml as written
        assert reader.message_count == info['message_count'] > 0
        assert sum(1 for _ in reader.messages()) == info['message_count']
    for name, item in zip(listed, info['files']):
        with (bag / name).open('rb') as f:
            assert make_reader(f).get_summary().statistics.message_count == item['message_count']
    last = bag / present[-1]
    with last.open('rb') as f, pytest.raises(Exception):
        make_reader(f).get_summary()                   # the open split lacks its footer
    ours = [m.msg.data for m in read_messages(bag, '/a')]
    assert ours == [float(i) for i in range(len(ours))]
    total = sum(1 for _ in read_messages(bag))
    assert total > info['message_count']               # the last split is read as well

    report = recover_bag(bag, in_place=True)
    assert last.name in report.rewritten and set(report.rewritten) <= set(unlisted)
    assert report.truncated
    assert info_of(bag)['relative_file_paths'] == present
    with Reader(bag) as reader:
        assert sum(1 for _ in reader.messages()) == total == report.message_count


SOAK = textwrap.dedent('''
    import os, struct, sys
    from dmf_sim.bags.writer import BagRecorder

    def rss_mib():
        with open('/proc/self/statm') as f:
            return int(f.read().split()[1]) * os.sysconf('SC_PAGE_SIZE') / 2**20

    topics = {f'/t{k}': 'std_msgs/msg/Float64' for k in range(4)}
    rate, seconds, warm = int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    data = b'\\x00\\x01\\x00\\x00' + struct.pack('<d', 0.5)
    with BagRecorder(sys.argv[1], topics) as rec:
        for s in range(seconds):
            for i in range(rate):
                t = 1_700_000_000_000_000_000 + s * 1_000_000_000 + i * (1_000_000_000 // rate)
                for topic in topics:
                    rec.write(topic, t, data)
            if s >= warm and s % 30 == 0:
                print(f'{s} {rss_mib():.4f}', flush=True)
''')


@pytest.mark.slow
def test_recorder_memory_flat_over_ten_simulated_minutes(tmp_path: Path) -> None:
    """4 topics, 11 simulated minutes through BagRecorder as fast as it goes
    (chunks of 0.1 s of log time, ~6600 of them): RSS grows < 1 MiB after a 2-minute warm-up.
    Before the fix the writer's chunk indexes grew it by ~4 MiB over this run."""
    script = tmp_path / 'soak.py'
    script.write_text(SOAK)
    out = subprocess.run([sys.executable, str(script), str(tmp_path / 'soak'), '100', '660',
                          '120'], capture_output=True, text=True, env=env_with_repo(),
                         timeout=300, check=True).stdout.split('\n')
    rss = [float(line.split()[1]) for line in out if line.strip()]
    growth = max(rss) - rss[0]
    print(f'\nBagRecorder RSS after warm-up: {rss[0]:.2f} MiB, growth {growth * 1024:.0f} KiB '
          f'over {len(rss) - 1} x 30 simulated s')
    assert len(rss) >= 18
    assert growth < 1.0
    assert len(info_of(tmp_path / 'soak')['relative_file_paths']) == 11
