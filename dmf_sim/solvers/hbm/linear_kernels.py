"""Compiled linear parts of the condensed harmonic-balance system (numba: nopython, cached): the
modal sums of the condensed receptances for a batch of speeds, and at one speed off the grid the
engine's A_n query with them (every arc-length corrector iteration is a new speed). The solvers
that use them are in :mod:`dmf_sim.solvers.hbm.kernels`.

References (the same operations): the numpy branch of ``CondensedHBM._linear_parts_many``,
``CondensedHBM._linear_parts_one`` and ``Engine.coefficients`` (bitwise).
"""
from __future__ import annotations

import math

import numpy as np

from dmf_sim.core.compiled import jit
from dmf_sim.core.units import RPM_TO_RAD_S

__all__ = ['ENGINE_OK', 'ENGINE_OUTSIDE', 'ENGINE_NOT_READY', 'modal_sums', 'linear_parts',
           'engine_at', 'linear_parts_at', 'one_speed_work', 'linear_parts_many_at']


# ------------------------------------------------------------------------------------------------
# Linear parts: the modal sums of the condensed receptances
# ------------------------------------------------------------------------------------------------

def modal_sums(omega, dOm, d, ml, a, unit, dunit, h, dh):
    """For K crank speeds omega [rad/s] and harmonics n = 1..H (Om_n = n omega / 2, dOm_n its
    speed derivative): with the poles p_nk = 1 / (i Om_n - d_k) of the chain's complex modes,
    ``unit_n = sum_k p_nk ml_nk`` (wlin_n per unit A_n), ``h_n = sum_k p_nk a_k`` and their
    speed derivatives through dp/dOm = -i p^2 (reference: ``CondensedHBM._linear_parts_many``
    in numpy).

    The harmonics are the innermost loop, so it runs in SIMD; each sum still runs over the modes
    k in order, and the complex operations are written out as numba performs them (``1j * Om``
    as a complex product, ``1 / z`` by CPython's algorithm, products as ``ac - bd``, ``ad + bc``):
    the complex arithmetic's values to rounding (usually its bits; a compilation may order an
    operation differently: within a few ulps), 3.4x faster at K = 141, H = 24, 32 modes."""
    K = omega.shape[0]
    H = ml.shape[0]
    m = d.shape[0]
    ml_re = np.empty((m, H))                    # ml by mode, harmonics contiguous
    ml_im = np.empty((m, H))
    for n in range(H):
        for k in range(m):
            ml_re[k, n] = ml[n, k].real
            ml_im[k, n] = ml[n, k].imag
    Om = np.empty(H)
    su_re, su_im, sdu_re, sdu_im = np.empty(H), np.empty(H), np.empty(H), np.empty(H)
    sh_re, sh_im, sdh_re, sdh_im = np.empty(H), np.empty(H), np.empty(H), np.empty(H)
    for q in range(K):
        for n in range(H):
            Om[n] = omega[q] * ((n + 1) / 2.0)
            su_re[n] = su_im[n] = sdu_re[n] = sdu_im[n] = 0.0
            sh_re[n] = sh_im[n] = sdh_re[n] = sdh_im[n] = 0.0
        for k in range(m):
            d_re, d_im = d[k].real, d[k].imag
            a_re, a_im = a[k].real, a[k].imag
            for n in range(H):
                z_re = (0.0 * Om[n] - 1.0 * 0.0) - d_re        # z = 1j * Om_n - d_k
                z_im = (0.0 * 0.0 + 1.0 * Om[n]) - d_im
                if abs(z_re) >= abs(z_im):                      # p = (1 + 0j) / z
                    ratio = z_im / z_re
                    denom = z_re + z_im * ratio
                    p_re = (1.0 + 0.0 * ratio) / denom
                    p_im = (0.0 - 1.0 * ratio) / denom
                else:
                    ratio = z_re / z_im
                    denom = z_re * ratio + z_im
                    p_re = (1.0 * ratio + 0.0) / denom
                    p_im = (0.0 * ratio - 1.0) / denom
                sq_re = p_re * p_re - p_im * p_im               # p2 = -1j * (p * p)
                sq_im = p_re * p_im + p_im * p_re
                p2_re = -0.0 * sq_re - (-1.0) * sq_im
                p2_im = -0.0 * sq_im + (-1.0) * sq_re
                m_re = ml_re[k, n]
                m_im = ml_im[k, n]
                su_re[n] += p_re * m_re - p_im * m_im
                su_im[n] += p_re * m_im + p_im * m_re
                sdu_re[n] += p2_re * m_re - p2_im * m_im
                sdu_im[n] += p2_re * m_im + p2_im * m_re
                sh_re[n] += p_re * a_re - p_im * a_im
                sh_im[n] += p_re * a_im + p_im * a_re
                sdh_re[n] += p2_re * a_re - p2_im * a_im
                sdh_im[n] += p2_re * a_im + p2_im * a_re
        for n in range(H):
            unit[q, n] = complex(su_re[n], su_im[n])
            dunit[q, n] = complex(sdu_re[n], sdu_im[n]) * dOm[n]
            h[q, n] = complex(sh_re[n], sh_im[n])
            dh[q, n] = complex(sdh_re[n], sdh_im[n]) * dOm[n]


def linear_parts(omega, dOm, d, ml, a, A, dA, wlin0, dwlin0, h0, h, dh, wlin, dw, wr, dwr):
    """The linear parts of K speeds in one call: :func:`modal_sums`, then ``h_0 = h0``,
    ``wlin_n = A_n unit_n``, ``dwlin_n = A_n dunit_n + dA_n unit_n`` (n >= 1), the static
    ``wlin_0``, ``dwlin_0`` as given, and wlin, dwlin on the real layout (``wr``, ``dwr``).
    ``A``, ``dA``: (K, H+1) engine coefficients and their speed derivatives. Reference: the
    numpy branch of ``CondensedHBM._linear_parts_many``."""
    K = omega.shape[0]
    H = ml.shape[0]
    unit = np.empty((K, H), dtype=np.complex128)
    dunit = np.empty((K, H), dtype=np.complex128)
    modal_sums(omega, dOm, d, ml, a, unit, dunit, h[:, 1:], dh[:, 1:])
    for q in range(K):
        h[q, 0] = h0
        dh[q, 0] = 0.0
        wlin[q, 0] = wlin0[q]
        dw[q, 0] = dwlin0[q]
        wr[q, 0] = wlin0[q]
        dwr[q, 0] = dwlin0[q]
        for n in range(1, H + 1):
            u = unit[q, n - 1]
            w = A[q, n] * u
            v = A[q, n] * dunit[q, n - 1] + dA[q, n] * u
            wlin[q, n] = w
            dw[q, n] = v
            wr[q, n] = w.real
            wr[q, H + n] = w.imag
            dwr[q, n] = v.real
            dwr[q, H + n] = v.imag


# ------------------------------------------------------------------------------------------------
# The linear parts at one speed off the grid, engine query included
# ------------------------------------------------------------------------------------------------

ENGINE_OK, ENGINE_OUTSIDE, ENGINE_NOT_READY = 0, 1, 2


def engine_at(s, table, out):
    """out <- the engine's A_n at speed s [rpm] (``Engine.coefficients`` from
    ``Engine.speed_table``: the load set's effective speed, the speed step of
    ``GasGrid.__call__`` on the load-interpolated rows and the inertia part, the same
    operations), truncated or zero-padded to out's length. Returns ENGINE_OK, ENGINE_OUTSIDE
    (s or its effective speed outside the data) or ENGINE_NOT_READY (grid nodes not computed
    yet)."""
    speeds, rows, ready, inertia, shift, limit = table
    n = speeds.shape[0]
    lo = speeds[0]
    hi = speeds[n - 1]
    if not (math.isfinite(s) and lo <= s <= hi):
        return ENGINE_OUTSIDE
    s_eff = min(s + shift, max(s, limit))
    if not (math.isfinite(s_eff) and lo <= s_eff <= hi):
        return ENGINE_OUTSIDE
    i = 0
    while i < n and speeds[i] <= s_eff:        # bisect_right - 1, clipped to [0, n - 2]
        i += 1
    i = min(max(i - 1, 0), n - 2)
    if not (ready[i] and ready[i + 1]):
        return ENGINE_NOT_READY
    ts = (s_eff - speeds[i]) / (speeds[i + 1] - speeds[i])
    omega = s * RPM_TO_RAD_S
    w2 = omega * omega
    m = rows.shape[1]
    for k in range(out.shape[0]):
        if k < m:
            out[k] = (rows[i, k] * (1.0 - ts) + rows[i + 1, k] * ts) + w2 * inertia[k]
        else:
            out[k] = 0.0
    return ENGINE_OK


def linear_parts_at(s, fd, table, statics, modal, A, A2, dA, h, dh, wlin, dw, wr, dwr):
    """The linear parts of one speed s [rpm] with the engine query (reference:
    ``CondensedHBM._linear_parts_one``, the same operations): ``fd`` the finite-difference step
    [rpm] (backward at the top of the engine data), ``statics`` = (static wind-up per unit
    cylinder mean torque, per unit rear load, rear load per unit A_0), ``modal`` = (dOm, d, ml,
    a, h0). Outputs (1, .) rows as :func:`linear_parts`. Returns the engine status."""
    speeds = table[0]
    ds = -fd if s + fd > speeds[speeds.shape[0] - 1] else fd
    st = engine_at(s, table, A[0])
    if st != ENGINE_OK:
        return st
    st = engine_at(s + ds, table, A2[0])
    if st != ENGINE_OK:
        return st
    # (A2 - A) / ds as numpy divides complex by real (Smith's algorithm: times 1 / ds)
    rat = 0.0 / ds
    scl = 1.0 / (ds + 0.0 * rat)
    for k in range(A.shape[1]):
        d = A2[0, k] - A[0, k]
        dA[0, k] = complex((d.real + d.imag * rat) * scl, (d.imag - d.real * rat) * scl)
    static_cyl, static_rear, rear_factor = statics
    rear = -A[0, 0].real * rear_factor
    rear2 = -A2[0, 0].real * rear_factor
    wlin0 = np.empty(1)
    dwlin0 = np.empty(1)
    wlin0[0] = A[0, 0].real * static_cyl + rear * static_rear
    dwlin0[0] = dA[0, 0].real * static_cyl + (rear2 - rear) / ds * static_rear
    omega = np.empty(1)
    omega[0] = s * RPM_TO_RAD_S
    dOm, d_, ml, a, h0 = modal
    linear_parts(omega, dOm, d_, ml, a, A, dA, wlin0, dwlin0, h0, h, dh, wlin, dw, wr, dwr)
    return ENGINE_OK


def one_speed_work(n):
    """The outputs of :func:`linear_parts_at` for one speed, n = 2H + 1 unknowns: A, A2, dA, h,
    dh, wlin, dw as (1, H + 1) complex rows and wr, dwr as (1, n) real rows."""
    H = (n - 1) // 2
    return (np.empty((1, H + 1), dtype=np.complex128), np.empty((1, H + 1), dtype=np.complex128),
            np.empty((1, H + 1), dtype=np.complex128), np.empty((1, H + 1), dtype=np.complex128),
            np.empty((1, H + 1), dtype=np.complex128), np.empty((1, H + 1), dtype=np.complex128),
            np.empty((1, H + 1), dtype=np.complex128), np.empty((1, n)), np.empty((1, n)))


def linear_parts_many_at(speeds, fd, table, statics, modal, A, A2, dA, h, dh, wlin, dw, wr, dwr,
                         status):
    """:func:`linear_parts_at` of K speeds [rpm] in one call (a sweep's grid), row q of every
    output for speed q; ``status[q]`` the engine's status there (that row unset unless
    ENGINE_OK). Reference: ``CondensedHBM._linear_parts_many``, the same values."""
    for q in range(speeds.shape[0]):
        status[q] = linear_parts_at(speeds[q], fd, table, statics, modal, A[q:q + 1],
                                    A2[q:q + 1], dA[q:q + 1], h[q:q + 1], dh[q:q + 1],
                                    wlin[q:q + 1], dw[q:q + 1], wr[q:q + 1], dwr[q:q + 1])


modal_sums = jit(modal_sums)
linear_parts = jit(linear_parts)
engine_at = jit(engine_at)
linear_parts_at = jit(linear_parts_at)
one_speed_work = jit(one_speed_work)
linear_parts_many_at = jit(linear_parts_many_at)
