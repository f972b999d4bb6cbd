"""The private state of ``mcap``'s writer that the bag writer's block path uses, in one place.

:meth:`dmf_sim.bags.writer.BagRecorder.write_block` builds whole chunks with numpy (thousands of
messages at once) and hands them to the ``mcap`` writer as if its own chunk builder had filled
them: it needs the writer's name-mangled attributes (``Writer.__stream`` ...) and the fields of
its ``ChunkBuilder``. They are not part of ``mcap``'s API, so:

* this module is the only one that reads or writes them (:data:`WRITER_STATE`,
  :data:`CHUNK_BUILDER_FIELDS`; the statistics are ``mcap.records.Statistics``, public);
* :func:`writer_state` is None for a writer that lacks any of them, and the bag writer then
  writes message by message through the public API (correct, slower);
* ``setup.py`` bounds ``mcap`` below its next major version (present from 1.1 through 1.6), and
  ``test/bags/test_mcap_internals.py`` fails when the installed ``mcap`` no longer has them, so a
  release that renames them is noticed rather than silently slower.
"""
from __future__ import annotations

from typing import Any, NamedTuple

from mcap.writer import Writer

__all__ = ['WRITER_STATE', 'CHUNK_BUILDER_FIELDS', 'STATISTICS_FIELDS', 'WriterState',
           'writer_state', 'set_data_section_crc']

WRITER_STATE = ('stream', 'record_builder', 'chunk_builder', 'chunk_indices', 'statistics',
                'enable_crcs', 'enable_data_crcs', 'data_section_crc', 'index_types')
"""The writer's private attributes used (``Writer.__<name>``, i.e. ``_Writer__<name>``)."""

CHUNK_BUILDER_FIELDS = ('count', 'record_writer', 'num_messages', 'message_start_time',
                        'message_end_time', 'message_indices')
"""The fields of the writer's chunk builder that a block fills."""

STATISTICS_FIELDS = ('message_count', 'message_start_time', 'message_end_time',
                     'channel_message_counts', 'chunk_count')
"""The fields of the writer's statistics a block updates (a public record of ``mcap``)."""


class WriterState(NamedTuple):
    """A started writer's private state (:data:`WRITER_STATE`, in that order)."""

    stream: Any
    record_builder: Any
    chunk_builder: Any
    chunk_indices: list
    statistics: Any
    enable_crcs: bool
    enable_data_crcs: bool
    data_section_crc: int
    index_types: Any


def _private(name: str) -> str:
    return f'_{Writer.__name__}__{name}'


def writer_state(writer: Writer) -> WriterState | None:
    """The writer's state now, or None when this ``mcap``'s writer (or its chunk builder) lacks
    any of it (another version; or a writer without chunking)."""
    values = [getattr(writer, _private(name), None) for name in WRITER_STATE]
    if any(v is None for v in values):
        return None
    state = WriterState(*values)
    if not all(hasattr(state.chunk_builder, f) for f in CHUNK_BUILDER_FIELDS):
        return None
    return state


def set_data_section_crc(writer: Writer, crc: int) -> None:
    """The writer's running CRC of its data section, after records it did not write itself."""
    setattr(writer, _private('data_section_crc'), crc)
