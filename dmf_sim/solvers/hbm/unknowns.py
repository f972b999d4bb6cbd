"""The real unknown layout of the condensed harmonic balance, and shift-invariant fingerprints.

A wind-up harmonic vector ``c_n`` (n = 0..H, complex, ``w = Re sum c_n exp(i n psi/2)``) is stored
as the real vector ``x = [w_0, Re w_1..Re w_H, Im w_1..Im w_H]`` [rad] for Newton and continuation.
"""
from __future__ import annotations

import functools

import numpy as np

__all__ = ['SUB_HARMONICS', 'fit_harmonics', 'to_complex', 'to_real', 'times_h', 'amplitudes',
           'sub_part', 'shift', 'all_shifts']

# half-orders n = 3 mod 6: the 1.5th-order family (1.5, 4.5, 7.5, 10.5)
SUB_HARMONICS = (3, 9, 15, 21)


def fit_harmonics(a: np.ndarray, H: int, axis: int = 0) -> np.ndarray:
    """Complex harmonics n = 0..N along ``axis`` kept to n = 0..H: truncated, or zero-padded when
    N < H (``a`` itself when N = H)."""
    n = a.shape[axis]
    if n == H + 1:
        return a
    shape = list(a.shape)
    shape[axis] = H + 1
    out = np.zeros(shape, dtype=complex)
    k = min(n, H + 1)
    index = (slice(None),) * (axis % a.ndim) + (slice(0, k),)
    out[index] = a[index]
    return out


def to_complex(x: np.ndarray, H: int) -> np.ndarray:
    """(2H+1,) real unknowns -> (H+1,) complex w_n (w_0 real); rows (K, 2H+1) -> (K, H+1)."""
    c = np.empty(x.shape[:-1] + (H + 1,), dtype=complex)
    c[..., 0] = x[..., 0]
    c[..., 1:] = x[..., 1:H + 1] + 1j * x[..., H + 1:]
    return c


def to_real(c: np.ndarray, H: int) -> np.ndarray:
    """(H+1,) complex w_n -> (2H+1,) real unknowns (Im w_0 dropped); rows (K, H+1) -> (K, 2H+1)."""
    c = np.asarray(c)
    x = np.empty(c.shape[:-1] + (2 * H + 1,))
    x[..., 0] = c[..., 0].real
    x[..., 1:H + 1] = c[..., 1:H + 1].real
    x[..., H + 1:] = c[..., 1:H + 1].imag
    return x


def times_h(h: np.ndarray, v: np.ndarray, H: int) -> np.ndarray:
    """Complex product h_n * v_n written on the real layout; v is (2H+1,) or (2H+1, k)."""
    hr, hi = h.real[1:], h.imag[1:]
    if v.ndim == 2:
        hr, hi = hr[:, None], hi[:, None]
    out = np.empty_like(v)
    re, im = v[1:H + 1], v[H + 1:]
    out[0] = h[0].real * v[0]
    out[1:H + 1] = hr * re - hi * im
    out[H + 1:] = hr * im + hi * re
    return out


def amplitudes(x: np.ndarray, H: int) -> np.ndarray:
    """|w_n| (n = 0..H) of real-layout vectors x (..., 2H+1): a fingerprint that ignores time
    shifts, so the 120 deg shifted twin of a 1.5th-order solution has the same one (exactly so
    when the excitation is exactly 120 deg periodic)."""
    amp = np.empty(x.shape[:-1] + (H + 1,))
    amp[..., 0] = np.abs(x[..., 0])
    amp[..., 1:] = np.hypot(x[..., 1:H + 1], x[..., H + 1:])
    return amp


def sub_part(c: np.ndarray, H: int) -> np.ndarray:
    """Real-layout vector holding only the n = 3, 9, 15, 21 harmonics of the complex ``c``."""
    out = np.zeros(H + 1, dtype=complex)
    for n in SUB_HARMONICS:
        if n <= H and n < len(c):
            out[n] = c[n]
    return to_real(out, H)


def shift(x: np.ndarray, k: int, H: int) -> np.ndarray:
    """The same wind-up delayed by k x 120 deg of crank angle (one firing interval of the six):
    ``c_n -> c_n exp(-i n k pi / 3)``. For a 120 deg periodic excitation every shift of a solution
    is a solution; a 1.5th-order state and its 120 deg shift are twins (one physical state)."""
    c = to_complex(np.asarray(x, dtype=float), H)
    n = np.arange(H + 1)
    return to_real(c * np.exp(-1j * n * k * np.pi / 3.0), H)


@functools.lru_cache(maxsize=8)
def _shift_rotations(n_shifts: int, H: int) -> np.ndarray:
    """exp(-i n k pi / 3) for k = 0..n_shifts-1 (rows), n = 1..H (columns): the phase factors of
    :func:`all_shifts`, made once per (n_shifts, H) (read-only)."""
    rot = np.exp(-1j * np.outer(np.arange(n_shifts), np.arange(1, H + 1)) * np.pi / 3.0)
    rot.flags.writeable = False
    return rot


def all_shifts(X: np.ndarray, n_shifts: int, H: int) -> np.ndarray:
    """Every state of the rows of X (K, 2H+1) delayed by k x 120 deg, k = 0..n_shifts-1, as rows
    (K n_shifts, 2H+1) in the order [shift(x, k) for x in X for k in range(n_shifts)] (the same
    products as :func:`shift`, for all rows at once)."""
    X = np.atleast_2d(np.asarray(X, dtype=float))
    rot = _shift_rotations(int(n_shifts), int(H))                           # (n_shifts, H)
    c = X[:, 1:H + 1] + 1j * X[:, H + 1:]                                    # (K, H)
    cs = c[:, None, :] * rot[None, :, :]                                     # (K, n_shifts, H)
    out = np.empty((X.shape[0], n_shifts, 2 * H + 1))
    out[..., 0] = X[:, :1]
    out[..., 1:H + 1] = cs.real
    out[..., H + 1:] = cs.imag
    return out.reshape(-1, 2 * H + 1)
