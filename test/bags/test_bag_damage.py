"""Damaged bags: real recorded files with flipped bytes inside chunks,
a damaged index, a corrupt first chunk, truncations; what ``analyze``, ``durability``, ``runup``
and ``bag-recover`` make of them (the same words for what each skipped), stubs and bags whose
topics hold no message, and the output directory of ``analyze`` checked before anything is
computed.

The bags are written by the project's recorder (BagRecorder, CDR: ``synthetic_bags``) and
damaged on disk as a bad sector or a bit-rotted copy would: 64 bytes inverted in the middle of a
chunk's records. Chunk CRCs catch it; the readers skip the chunk and report it.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from support import synthetic_bags
from support.cdr import Float64, String, serialize_message
from support.cli_output import one_line_error
from support.synthetic_bags import (
    T0,
    WINDUP,
    check_table,
    chunk_spans,
    flip_chunks,
    write_synthetic,
)

from dmf_sim.analysis.pipeline import AnalysisOptions, analyze_bag, read_bag_series
from dmf_sim.bags.read import read_messages
from dmf_sim.bags.records import Scan
from dmf_sim.bags.recovery import recover_bag
from dmf_sim.bags.writer import BagRecorder
from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import BagError
from dmf_sim.transient.profiles import read_profile
from dmf_sim.transient.run import RunOptions, run_profile

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


@pytest.mark.slow
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
    ref = read_bag_series(bag, reader='messages')
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


@pytest.mark.slow
def test_bag_recover_drops_corrupt_chunks(corrupt, tmp_path, capsys):
    """Before: "input was complete", corrupt chunks copied. Now the damaged file is rewritten
    without them and bag-recover says what it dropped; the repaired bag reads clean."""
    bag, middle, _ = corrupt
    out = tmp_path / 'repaired'
    assert cli_main(['bag-recover', str(bag), '-o', str(out)]) == 0
    text = capsys.readouterr().out
    assert '3 corrupt part(s) dropped' in text and 'input was complete' not in text
    assert text.count('corrupt chunk dropped: intact_1.mcap chunk at byte') == 3
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


@pytest.mark.slow
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
    res = analyze_bag(bag, options=AnalysisOptions(reader='messages'))
    assert any('data section CRC mismatch' in w for w in res.warnings)
    fast, intact = analyze_bag(bag), analyze_bag(recorded)
    assert not fast.warnings and (fast.signal('windup').table.amplitudes
                                  == intact.signal('windup').table.amplitudes).all()
    report = recover_bag(bag, tmp_path / 'index_repaired')
    assert report.rewritten == ('intact_1.mcap',) and report.message_count == _count(recorded)


@pytest.mark.parametrize('size', [10, 100])
def test_stub_is_refused(recorded, tmp_path, capsys, size):
    """Before: bag-recover of a 100-byte stub exited 0 writing an empty bag, and analyze of a
    10-byte cut raised OSError from the summary reader. Both are one-line errors now (exit 2),
    and analyze and durability diagnose the stub in bag-recover's words (before: "the bag has
    neither a crank angle topic ... topics found: none")."""
    stub = tmp_path / 'stub.mcap'
    stub.write_bytes((recorded / 'intact_0.mcap').read_bytes()[:size])
    assert cli_main(['bag-recover', str(stub)]) == 2
    err = one_line_error(capsys)
    assert 'nothing to recover' in err
    diagnosis = err.split('nothing to recover: ')[1]
    assert diagnosis.startswith(f'no complete message in {size} bytes (reading stopped at: ')
    assert not (tmp_path / 'stub_recovered.mcap').exists()
    for command in ('analyze', 'durability'):
        assert cli_main([command, str(stub), '--json']) == 2
        err = one_line_error(capsys)
        assert err.startswith(f'dmf-sim {command}: error: {stub}: nothing to ') \
            and err.endswith(diagnosis), err
    for cut in (0, 10, 100, 4096):
        stub.write_bytes((recorded / 'intact_0.mcap').read_bytes()[:cut])
        assert cli_main(['analyze', str(stub), '--json']) == 2
        assert one_line_error(capsys).startswith('dmf-sim analyze: error: ')
    with pytest.raises(BagError, match='nothing to recover'):
        recover_bag(stub if size > 8 else stub)


def _declared(path: Path, messages: dict[str, int]) -> Path:
    """A bag declaring the node's topics and /rosout_like, with ``messages`` per topic."""
    topics = {**synthetic_bags.TOPICS, '/rosout_like': 'std_msgs/msg/String'}
    with BagRecorder(path, topics) as rec:
        for topic, n in messages.items():
            for i in range(n):
                data = (String(data=f'tick {i}') if topic == '/rosout_like'
                        else Float64(data=float(i)))
                rec.write(topic, T0 + i * 1_000_000, serialize_message(data))
    return path


def test_declared_topics_without_messages(tmp_path, capsys):
    """Before: "neither a crank angle topic (/engine/crank_angle) ... topics found: ...,
    /engine/crank_angle" for a bag whose crank-angle topic is declared but empty. Now the
    message says which topics are declared without a message; a bag with no message at all
    gets bag-recover's diagnosis with the topics it declares."""
    bag = _declared(tmp_path / 'empty_crank', {'/rosout_like': 3, '/engine/speed': 1})
    assert cli_main(['analyze', str(bag), '--json']) == 2
    err = one_line_error(capsys)
    assert ('neither a crank angle topic (/engine/crank_angle holds no messages) nor an engine '
            'speed topic (/engine/speed holds 1 message)') in err, err
    assert '/engine/crank_angle (no messages), /engine/speed, /rosout_like (use' in err, err
    assert '/rosout_like (no' not in err and '/engine/speed (no' not in err
    crank_only = _declared(tmp_path / 'crank_only', {'/engine/crank_angle': 3})
    with pytest.raises(BagError, match='topic /driveline/joint_states holds no messages; '):
        analyze_bag(crank_only, ['torque:CYL1'])
    silent = _declared(tmp_path / 'silent', {})
    assert cli_main(['analyze', str(silent), '--json']) == 2
    err = one_line_error(capsys)
    assert 'nothing to analyze: no complete message in' in err
    assert 'topics declared: /driveline/dmf_windup, /driveline/joint_states' in err, err


# ------------------------------------------------------- every command that reads a bag

@pytest.fixture(scope='module')
def run_damaged(tmp_path_factory):
    """A ``dmf-sim run`` bag (joint states for durability, a ramp for runup) split every
    second, and a copy whose third file has its chunk of samples flipped."""
    root = tmp_path_factory.mktemp('run_damage')
    intact = root / 'ramp'
    run_profile(read_profile('ramp:900:1000:20:1.0:0.5'), intact, RunOptions(split_s=1.0))
    bag = copy(intact, root / 'flipped')
    file = bag / 'ramp_2.mcap'
    spans = chunk_spans(file)
    flip_chunks(file, [max(range(len(spans)), key=lambda i: spans[i][1])])
    return intact, bag


@pytest.mark.slow
def test_every_command_reports_skipped_chunks_alike(run_damaged, tmp_path, capsys):
    """Before: durability noted only "1 gap in the time stamps", runup said nothing. Now
    analyze, durability and runup report the flipped chunk in the same words, in their text
    and in their JSON (corrupt_chunks)."""
    intact, bag = run_damaged
    lines = [w for w in analyze_bag(bag).warnings if w.startswith('corrupt chunk')]
    assert len(lines) == 1 and lines[0].startswith('corrupt chunk skipped: ramp_2.mcap chunk at')
    assert 'CRC mismatch' in lines[0] and '/driveline/joint_states' in lines[0]
    assert not [w for w in analyze_bag(intact).warnings if w.startswith('corrupt chunk')]

    assert cli_main(['durability', str(bag), '--json']) == 0
    report = json.loads(capsys.readouterr().out)
    assert [n for n in report['notes'] if n.startswith('corrupt chunk')] == lines
    (chunk,) = report['corrupt_chunks']
    assert chunk['file'] == 'ramp_2.mcap' and chunk['messages_lost'] > 0
    assert f'corrupt chunk skipped: {chunk["text"]}' == lines[0]
    assert cli_main(['durability', str(bag), '--out', str(tmp_path / 'dur'), '--no-plots']) == 0
    assert f'note: {lines[0]}' in capsys.readouterr().out

    assert cli_main(['runup', str(bag), '--no-hbm', '--json']) == 0
    data = json.loads(capsys.readouterr().out)
    assert [w for w in data['warnings'][0] if w.startswith('corrupt chunk')] == lines
    assert [c['text'] for c in data['corrupt_chunks'][0]] == [chunk['text']]
    assert cli_main(['runup', str(bag), '--no-hbm', '--out', str(tmp_path / 'ru')]) == 0
    assert f': {lines[0]}' in capsys.readouterr().out


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
