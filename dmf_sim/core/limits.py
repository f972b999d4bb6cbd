"""Software limits on how much work one input may ask for, each with its reason.

A value beyond one of these is almost always a typo (``1e9`` for ``1e3``) or a file that is not
what it seems; without a bound it would run for days, fill the disk or start more processes than
the machine holds. Each is refused in one line naming the option or file and the limit
(``doc/errors.md``, "Limits").
"""
from __future__ import annotations

import os

__all__ = ['MAX_PROFILE_DURATION_S', 'MAX_PROFILE_ROWS', 'MAX_PROFILE_CSV_BYTES',
           'MAX_PROFILE_YAML_BYTES', 'MAX_WAIT_S', 'MAX_WORKERS_PER_CPU', 'usable_cpus',
           'max_local_workers']

MAX_PROFILE_DURATION_S = 24 * 3600.0
"""Longest speed/load profile [s]: a day of driving. ``dmf-sim run`` writes about 1 MB of bag per
simulated second at 1 kHz (86 GB for a day); the node follows a profile in real time."""

MAX_PROFILE_ROWS = 1_000_000
"""Most rows of a profile table: a measured cycle at 1 kHz for 17 minutes, or one row per second
for 11 days. Read in about a second (numpy); each row is checked."""

MAX_PROFILE_CSV_BYTES = 64 * 2**20
"""Largest CSV profile file [bytes]: :data:`MAX_PROFILE_ROWS` rows of three numbers written with
full precision (~60 bytes a row). A larger file is refused before it is read."""

MAX_PROFILE_YAML_BYTES = 2**20
"""Largest YAML profile file [bytes] (~35 000 rows, read in a few seconds): YAML is read about
100 times slower than a CSV table; longer tables belong in a CSV file."""

MAX_WAIT_S = 3600.0
"""Longest wait for a node or a Dask scheduler to answer [s] (``--timeout``,
``--connect-timeout``): beyond an hour a script should wait in a loop of its own."""

MAX_WORKERS_PER_CPU = 4
"""Local Dask worker processes per usable CPU at most (``--workers``): each worker holds the
compiled kernels (~300 MB); more workers than CPUs add memory and start-up time, not speed."""


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask on Linux, else the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def max_local_workers() -> int:
    """Most worker processes of a local Dask cluster on this machine."""
    return MAX_WORKERS_PER_CPU * usable_cpus()
