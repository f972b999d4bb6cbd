"""Whether a bag was closed completely: what a clean stop of the node (or of a recorder) must
leave, checked with the independent readers (``mcap``'s summary reader and rosbags)."""
from __future__ import annotations

from pathlib import Path

import yaml


def assert_complete_bag(bag: Path) -> int:
    """Every ``.mcap`` file of ``bag`` is listed in ``metadata.yaml`` and has its summary and
    footer; the message counts of ``metadata.yaml``, of the files' summaries and of what
    rosbags reads agree. Returns the message count."""
    from mcap.reader import make_reader
    from rosbags.rosbag2 import Reader

    info = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    present = sorted((p.name for p in bag.glob('*.mcap')),
                     key=lambda name: int(name.rsplit('_', 1)[1][:-len('.mcap')]))
    assert present == info['relative_file_paths'], (present, info['relative_file_paths'])
    assert [f['path'] for f in info['files']] == present
    total = 0
    for name, item in zip(present, info['files']):
        with open(bag / name, 'rb') as fh:
            summary = make_reader(fh).get_summary()      # raises without a footer
        assert summary is not None and summary.statistics is not None, name
        assert summary.statistics.message_count == item['message_count'], name
        total += summary.statistics.message_count
    assert total == info['message_count']
    with Reader(bag) as reader:
        assert sum(1 for _ in reader.messages()) == reader.message_count == total
    return total
