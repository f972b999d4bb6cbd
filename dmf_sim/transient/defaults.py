"""Defaults of the transient commands, importable without numba (``dmf-sim --help`` loads the
commands' options, not the solvers)."""
from __future__ import annotations

__all__ = ['DEFAULT_CHUNK_S', 'CHUNK_RANGE_S', 'DEFAULT_THREADS', 'DEFAULT_BIN_RPM',
           'JUMP_WINDOW_CYCLES']

DEFAULT_CHUNK_S = 0.1       # dmf-sim run: simulated time per chunk at most [s]: the excitation
                            # coefficients and the load are held over a chunk (the speed ramp
                            # is exact in it)
CHUNK_RANGE_S = (1e-3, 1.0)
DEFAULT_THREADS = 1         # dmf-sim run: integrate and write in turn (2: integrate in a thread
                            # of its own; measured no faster on a busy 2-core machine)
DEFAULT_BIN_RPM = 10.0      # dmf-sim runup: speed bins of the quasi-static comparison [rpm]
JUMP_WINDOW_CYCLES = 8      # dmf-sim runup: engine cycles averaged before and after a jump
