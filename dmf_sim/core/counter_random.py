"""Counter-based random numbers: the ``k``-th number of a stream is a pure function of (seed,
stream, k), so a signal cut into chunks of any length draws exactly the numbers of one long run,
in any thread, on any machine, with any numpy version.

The generator is SplitMix64 (Steele, Lea and Flood, "Fast splittable pseudorandom number
generators", OOPSLA 2014; the finalizer of Java's ``SplittableRandom``): a key from (seed,
stream), mixed with the counter. Uniform numbers take the top 53 bits; Gaussian numbers come from
two uniforms by the Box-Muller transform. Compiled with :func:`dmf_sim.core.compiled.jit`, so
the kernels call them per draw; :func:`gaussians` fills an array from Python.
These are test signals (timer jitter, noise, pitch-error patterns, sensor faults), not
cryptography.
"""
from __future__ import annotations

import math

import numpy as np

from dmf_sim.core.compiled import jit

__all__ = ['uniform', 'gaussian', 'gaussians']

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_TWO_M53 = 1.0 / 9007199254740992.0      # 2^-53


def _mix(z):
    """SplitMix64's finalizer of a uint64."""
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


def uniform(seed, stream, k):
    """The ``k``-th uniform number in [0, 1) of stream ``stream`` of ``seed`` (integers in
    [0, 2^63))."""
    key = _mix(np.uint64(seed) * _GOLDEN + np.uint64(stream))
    return float(_mix(key + np.uint64(k) * _GOLDEN) >> _S11) * _TWO_M53


def gaussian(seed, stream, k):
    """The ``k``-th standard normal number of stream ``stream`` of ``seed`` (Box-Muller on the
    uniforms 2k and 2k + 1)."""
    u1 = uniform(seed, stream, 2 * k)
    u2 = uniform(seed, stream, 2 * k + 1)
    return math.sqrt(-2.0 * math.log(1.0 - u1)) * math.cos(2.0 * math.pi * u2)


def gaussians(seed, stream, first, out):
    """``out[i]`` = :func:`gaussian` (seed, stream, first + i)."""
    for i in range(out.shape[0]):
        out[i] = gaussian(seed, stream, first + i)


_mix = jit(_mix)
uniform = jit(uniform)
gaussian = jit(gaussian)
gaussians = jit(gaussians)
