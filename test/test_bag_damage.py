"""Damaged bags (issue 20, items 9 and 10): real recorded files with flipped bytes inside chunks,
a damaged index, a corrupt first chunk, truncations; what ``analyze`` and ``bag-recover`` make
of them, and the output directory of ``analyze`` checked before anything is computed.

The bags are written by the project's recorder (BagRecorder, CDR: ``synthetic_bags``) and
damaged on disk as a bad sector or a bit-rotted copy would: 64 bytes inverted in the middle of a
chunk's records. Chunk CRCs catch it; the readers skip the chunk and report it.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from synthetic_bags import WINDUP, check_table, chunk_spans, flip_chunks, write_synthetic
from test_analyze_inputs import one_line_error

from dmf_sim.analysis.pipeline import analyze_bag, read_bag_series
from dmf_sim.bags.read import read_messages
from dmf_sim.bags.records import Scan
from dmf_sim.bags.recovery import recover_bag
from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import BagError

RAMP = {'duration': 6.0, 'v0': 900.0, 'v1': 1300.0}        # ~55 cycles, 3 files of 2 s
TOPICS = ('windup', 'speed', 'crank')
FLIPPED = (5, 9, 14)                                        # chunks of the middle file


@pytest.fixture(scope='module')
def recorded(tmp_path_factory):
    root = tmp_path_factory.mktemp('damage')
    return write_synthetic(root / 'intact', TOPICS, max_duration_s=2.0, **RAMP)


def copy(bag: Path, dst: Path) -> Path:
    shutil.copytree(bag, dst)
    return dst


@pytest.fixture(scope='module')
def corrupt(recorded):
    """The recording with three 64-byte flips inside chunks of its middle split (complete)."""
    bag = copy(recorded, recorded.parent / 'corrupt')
    middle = bag / 'intact_1.mcap'
    spans = flip_chunks(middle, FLIPPED)
    return bag, middle, spans


def _count(bag: Path) -> int:
    return sum(1 for _ in read_messages(bag))


def test_corrupt_chunks_are_skipped_and_reported(recorded, corrupt, capsys):
    """Before: analyze read the flipped chunks as data (55 of 62 cycles, no warning). Now each
    corrupt chunk is skipped by both readers and reported: file, reason, time range, messages
    lost per topic (from the message index); the orders of the remaining cycles are exact."""
    bag, middle, spans = corrupt
    intact = analyze_bag(recorded)
    assert cli_main(['analyze', str(bag), '--json', '--no-hbm', '--load', '1']) == 0
    data = json.loads(capsys.readouterr().out)
    chunks = data['corrupt_chunks']
    assert len(chunks) == 3
    t0 = int(intact.series.series['crank'].t_ns[0])
    for got, (_, _, start, end) in zip(chunks, spans):
        assert got['file'] == middle.name and 'CRC mismatch' in got['reason']
        assert got['t_start_s'] == pytest.approx((start - t0) * 1e-9, abs=1e-9)
        assert got['t_end_s'] == pytest.approx((end - t0) * 1e-9, abs=1e-9)
        samples = {got['topics'][t] for t in ('/driveline/dmf_windup', '/engine/speed',
                                              '/engine/crank_angle')}
        assert len(samples) == 1 and samples.pop() > 0     # the same samples of every topic
        assert got['messages_lost'] == sum(got['topics'].values())
    assert sum('corrupt chunk skipped' in w for w in data['warnings']) == 3
    lost = sum(c['messages_lost'] for c in chunks)
    # the message reader skips the same chunks, and reports them the same way
    scans: list[Scan] = []
    assert sum(1 for _ in read_messages(bag, scans=scans)) == _count(recorded) - lost
    assert [c.topics for s in scans for c in s.corrupt] == [c['topics'] for c in chunks]
    ref = read_bag_series(bag, reader='reference')
    fast = read_bag_series(bag)
    assert [c.offset for c in ref.corrupt] == [c.offset for c in fast.corrupt]
    for key in ('crank', 'speed'):
        assert (ref.series[key].t_ns == fast.series[key].t_ns).all()
        assert (ref.series[key].values == fast.series[key].values).all()
        assert len(fast.series[key]) == len(intact.series.series[key]) - sum(
            c['topics']['/engine/speed'] for c in chunks)
    # cycles touching the gaps are dropped; what is left is exact
    res = analyze_bag(bag)
    w = res.signal('windup')
    assert len(w.cycles) < len(intact.signal('windup').cycles)
    check_table(w.table, WINDUP)


def test_bag_recover_drops_corrupt_chunks(corrupt, tmp_path, capsys):
    """Before: "input was complete", corrupt chunks copied. Now the damaged file is rewritten
    without them and bag-recover says what it dropped; the repaired bag reads clean."""
    bag, middle, _ = corrupt
    out = tmp_path / 'repaired'
    assert cli_main(['bag-recover', str(bag), '-o', str(out)]) == 0
    text = capsys.readouterr().out
    assert '3 corrupt part(s) dropped' in text and 'input was complete' not in text
    assert text.count('dropped: intact_1.mcap chunk at byte') == 3
    assert 'rewritten: intact_1.mcap' in text
    assert 'intact_0.mcap' not in text.split('rewritten:')[1]       # intact files copied
    assert (out / 'intact_0.mcap').read_bytes() == (bag / 'intact_0.mcap').read_bytes()
    scans: list[Scan] = []
    assert sum(1 for _ in read_messages(out, scans=scans)) == _count(bag)
    assert all(s.complete and not s.corrupt and not s.data_crc_error for s in scans)
    again = recover_bag(out, tmp_path / 'again')
    assert 'input was complete and intact' in str(again) and not again.rewritten


def test_corrupt_and_truncated(corrupt, tmp_path, capsys):
    """The damaged split cut short as well (a crash after the damage): analyze reports both,
    bag-recover repairs both."""
    bag = copy(corrupt[0], tmp_path / 'both')
    last = bag / 'intact_2.mcap'
    flip_chunks(last, [3])
    size = last.stat().st_size
    with last.open('r+b') as fh:
        fh.truncate(size * 2 // 3)
    assert cli_main(['analyze', str(bag), '--json', '--no-hbm', '--load', '1']) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['truncated'] and len(data['corrupt_chunks']) == 4
    report = recover_bag(bag, tmp_path / 'both_repaired')
    assert report.truncated and len(report.corrupt) == 4 and report.dropped_messages > 0
    assert set(report.rewritten) == {'intact_1.mcap', 'intact_2.mcap'}


def test_corrupt_first_chunk_takes_declarations_from_the_summary(recorded, tmp_path):
    """The first chunk declares the schemas and channels: when it is corrupt, a complete file's
    summary still names them, so the rest of the file reads."""
    bag = copy(recorded, tmp_path / 'first')
    flip_chunks(bag / 'intact_0.mcap', [0])
    res = analyze_bag(bag)
    assert len(res.corrupt) == 1 and res.corrupt[0]['file'] == 'intact_0.mcap'
    assert res.corrupt[0]['messages_lost'] > 0
    check_table(res.signal('windup').table, WINDUP)


def test_damaged_index_fails_the_data_section_crc(recorded, tmp_path):
    """A flipped byte in a message index (outside every chunk) leaves the data intact but the
    data section CRC (the recorder writes it) catches it: the message reader and an analysis
    with it warn, bag-recover rewrites the file. The fast reader skips the indexes (and the
    second pass over the file the data CRC costs): its values are the intact ones."""
    bag = copy(recorded, tmp_path / 'index')
    file = bag / 'intact_1.mcap'
    off, length, _, _ = chunk_spans(file)[2]
    index_entry = off + length + 9 + 2 + 4 + 3      # message index after the chunk: a time stamp
    raw = bytearray(file.read_bytes())
    raw[index_entry] ^= 0xFF
    file.write_bytes(bytes(raw))
    scans: list[Scan] = []
    assert sum(1 for _ in read_messages(bag, scans=scans)) == _count(recorded)
    assert not scans[1].corrupt and 'data section CRC mismatch' in scans[1].data_crc_error
    assert not scans[0].data_crc_error and not scans[2].data_crc_error
    res = analyze_bag(bag, reader='reference')
    assert any('data section CRC mismatch' in w for w in res.warnings)
    fast, intact = analyze_bag(bag), analyze_bag(recorded)
    assert not fast.warnings and (fast.signal('windup').table.amplitudes
                                  == intact.signal('windup').table.amplitudes).all()
    report = recover_bag(bag, tmp_path / 'index_repaired')
    assert report.rewritten == ('intact_1.mcap',) and report.message_count == _count(recorded)


@pytest.mark.parametrize('size', [10, 100])
def test_stub_is_refused(recorded, tmp_path, capsys, size):
    """Before: bag-recover of a 100-byte stub exited 0 writing an empty bag, and analyze of a
    10-byte cut raised OSError from the summary reader. Both are one-line errors now (exit 2)."""
    stub = tmp_path / 'stub.mcap'
    stub.write_bytes((recorded / 'intact_0.mcap').read_bytes()[:size])
    assert cli_main(['bag-recover', str(stub)]) == 2
    assert 'nothing to recover' in one_line_error(capsys)
    assert not (tmp_path / 'stub_recovered.mcap').exists()
    for cut in (0, 10, 100, 4096):
        stub.write_bytes((recorded / 'intact_0.mcap').read_bytes()[:cut])
        assert cli_main(['analyze', str(stub), '--json']) == 2
        assert one_line_error(capsys).startswith('dmf-sim analyze: error: ')
    with pytest.raises(BagError, match='nothing to recover'):
        recover_bag(stub if size > 8 else stub)


def test_analyze_out_checked_before_computing(recorded, tmp_path, capsys, monkeypatch):
    """Before: `analyze BAG --out /etc/passwd` analysed the whole bag, then raised
    FileExistsError. Now the output is checked first: one line, exit 2, nothing read."""
    import dmf_sim.analysis.pipeline as pipeline

    def must_not_run(*args, **kwargs):
        raise AssertionError('the bag was analysed before the output was checked')

    monkeypatch.setattr(pipeline, 'analyze_bag', must_not_run)
    afile = tmp_path / 'passwd'
    afile.write_text('root:x:0:0\n')
    for out, why in ((afile, 'exists and is not a directory'),
                     (afile / 'sub', 'is not a directory')):
        assert cli_main(['analyze', str(recorded), '--out', str(out)]) == 2
        err = one_line_error(capsys)
        assert err.startswith('dmf-sim analyze: error: --out') and why in err, err
