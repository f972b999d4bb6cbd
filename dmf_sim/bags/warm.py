"""The compiled kernel of bag reading (the MCAP record scanner of every reader), as a group of
:mod:`dmf_sim.core.kernel_cache`: loaded (compiled the first time) by ``dmf-sim warm-up`` and
before a command reads a bag."""
from __future__ import annotations

import numpy as np

from dmf_sim.bags.records import RECORD_HEAD, record_offsets
from dmf_sim.core.kernel_cache import KernelGroup

__all__ = ['warm_up', 'BAG_READING', 'BAG_READING_COMPILE_S']

BAG_READING_COMPILE_S = 2.0
"""Seconds :func:`warm_up` took to compile on the 2-core reference machine."""


def warm_up() -> None:
    """Scan an empty records area with the argument type of the readers (a read-only uint8 array
    over the chunk's bytes, ``np.frombuffer``)."""
    record_offsets(np.frombuffer(bytes(2 * RECORD_HEAD), np.uint8))


BAG_READING = KernelGroup('bag reading', 'the MCAP record scanner (analyze, durability, '
                          'bag-recover)', warm_up, lambda: (record_offsets,),
                          BAG_READING_COMPILE_S)
