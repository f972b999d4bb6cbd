"""Defaults of the transient commands, importable without numba (``dmf-sim --help`` loads the
commands' options, not the solvers)."""
from __future__ import annotations

from dmf_sim.core.limits import usable_cpus

__all__ = ['DEFAULT_CHUNK_S', 'CHUNK_RANGE_S', 'default_threads', 'DEFAULT_BIN_RPM',
           'JUMP_WINDOW_CYCLES']

DEFAULT_CHUNK_S = 1.0       # dmf-sim run: simulated time per chunk at most [s]: the excitation
                            # coefficients and the load of the chunk's middle are held over it
                            # (the speed ramp is exact in it)
CHUNK_RANGE_S = (1e-3, 1.0)
DEFAULT_BIN_RPM = 10.0      # dmf-sim runup: speed bins of the quasi-static comparison [rpm]
JUMP_WINDOW_CYCLES = 8      # dmf-sim runup: engine cycles averaged before and after a jump


def default_threads() -> int:
    """``dmf-sim run``'s threads when none are asked for: 2 (integrate the next chunks in a
    thread of their own while the last ones are read out and written) when this process may
    run on two or more CPUs, else 1 (integrate and write in turn). Both write the same bag;
    measured on the 2-core machine, two threads are faster when a core is free and no slower
    when the machine is busy (doc/performance.md)."""
    return 2 if usable_cpus() >= 2 else 1
