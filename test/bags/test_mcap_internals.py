"""The private state of mcap's writer that the block writer uses (dmf_sim/bags/mcap_internals.py):
present in the installed mcap, used nowhere else, and not needed for a correct bag."""
from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.records import Statistics
from mcap.writer import Writer

from dmf_sim.bags import mcap_internals, writer as bag_writer
from dmf_sim.bags.layout import resolve_bag
from dmf_sim.bags.writer import BagRecorder
from dmf_sim.transient.encode import SampleEncoder

PACKAGE = Path(__file__).resolve().parents[2] / 'dmf_sim'


def test_the_installed_mcap_has_the_private_state_the_block_writer_uses():
    """Fails when an mcap release renames or drops what the block writer reads and writes:
    the bags would still be right (written message by message), but several times slower."""
    w = Writer(io.BytesIO())
    w.start(profile='ros2', library='test')
    state = mcap_internals.writer_state(w)
    assert state is not None, 'mcap.writer.Writer lacks ' + ', '.join(
        n for n in mcap_internals.WRITER_STATE if not hasattr(w, f'_Writer__{n}'))
    assert isinstance(state.chunk_indices, list) and isinstance(state.data_section_crc, int)
    assert isinstance(state.statistics, Statistics)
    for name in mcap_internals.CHUNK_BUILDER_FIELDS:
        assert hasattr(state.chunk_builder, name), name
    for name in mcap_internals.STATISTICS_FIELDS:
        assert hasattr(state.statistics, name), name
    mcap_internals.set_data_section_crc(w, 12345)
    assert mcap_internals.writer_state(w).data_section_crc == 12345


def test_no_other_module_reads_mcaps_private_state():
    private = re.compile(r'_Writer__|_chunk_builder\b')
    users = sorted(str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob('*.py')
                   if private.search(p.read_text()))
    assert users == ['bags/mcap_internals.py']


def _block_bag(path: Path) -> Path:
    topics = {'/js': 'sensor_msgs/msg/JointState', '/f': 'std_msgs/msg/Float64'}
    enc = SampleEncoder(['a', 'b'])
    n = 1200
    t = 10 ** 9 + np.arange(n, dtype=np.int64) * 1_000_000       # 1.2 s at 1 kHz
    x = np.random.default_rng(1).normal(size=(n, 2))
    js, fl = enc.joint_states(t, x, x, x), enc.floats(x[:, 0])
    with BagRecorder(path, topics, max_duration_s=1.0) as rec:
        for a in range(0, n, 500):
            rec.write_block(t[a:a + 500], [('/js', js[a:a + 500]), ('/f', fl[a:a + 500])])
    return path


def _messages(bag: Path) -> list[tuple]:
    out = []
    for f in resolve_bag(bag).files:
        with open(f, 'rb') as stream:
            reader = make_reader(stream)
            stats = reader.get_summary().statistics
            got = [(m.channel_id, m.sequence, m.log_time, m.data)
                   for _, _, m in reader.iter_messages(log_time_order=False)]
            assert stats.message_count == len(got)
            out += got
    return out


def test_without_the_private_state_blocks_are_written_message_by_message(tmp_path, monkeypatch):
    fast = _messages(_block_bag(tmp_path / 'fast'))
    monkeypatch.setattr(bag_writer, 'writer_state', lambda writer: None)
    slow = _messages(_block_bag(tmp_path / 'slow'))
    assert len(fast) == 2 * 1200 and slow == fast
