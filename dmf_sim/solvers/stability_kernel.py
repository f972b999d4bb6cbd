"""Compiled Floquet analysis of a periodic wind-up (numba: nopython, cached): the knee crossings,
the exact monodromy of the piecewise-linear system region by region, and the multipliers — the
hot part of :meth:`dmf_sim.solvers.stability.FloquetAnalyzer.analyze`, whose readable numpy path
(``segments_from``, ``monodromy``, ``analyze_reference``) is the reference the tests compare it
with. Region lookup: :func:`dmf_sim.solvers.spring_kernels.region_of` on the spring's own arrays
(the law written once).
"""
from __future__ import annotations

import math

import numpy as np

from dmf_sim.core.compiled import jit
from dmf_sim.core.units import CYCLE_RAD
from dmf_sim.solvers.lapack_kernel import eigenvalues_into
from dmf_sim.solvers.spring_kernels import friction_parts, region_of, stop_parts, travel_range

__all__ = ['floquet_segments', 'monodromy_similar', 'floquet', 'floquet_many', 'flow_factors',
           'flow_apply', 'flow_real',
           'law_steps', 'monodromy_law', 'floquet_law_many']


def floquet_segments(c, w, omega, knees, primary, n_newton, stages, taus):
    """Knee crossings of the periodic wind-up and the stretches between them (reference
    ``FloquetAnalyzer.segments_from``). ``c`` complex wind-up harmonics, ``w`` the wind-up on a
    uniform grid of the cycle, omega [rad/s]. Crossings are bracketed on the grid and refined by
    ``n_newton`` Newton steps on the trigonometric polynomial w(phi) - knee. Writes the stage and
    duration [s] of each stretch from the first crossing into ``stages``/``taus`` (capacity at
    least the number of crossings, or 1); returns (count, t_start [s])."""
    N = w.shape[0]
    T = CYCLE_RAD / omega
    idx = np.empty(N, dtype=np.int64)
    for i in range(N):
        idx[i] = region_of(w[i], knees, primary)
    total = 0
    for i in range(N):
        a = idx[i]
        b = idx[(i + 1) % N]
        total += abs(b - a)
    if total == 0:
        stages[0] = idx[0] - primary
        taus[0] = T
        return 1, 0.0
    phis = np.empty(total)
    after = np.empty(total, dtype=np.int64)
    dphi = 2.0 * np.pi / N
    nc = c.shape[0]
    m = 0
    for i in range(N):
        ia = idx[i]
        ib = idx[(i + 1) % N]
        if ia == ib:
            continue
        step = 1 if ib > ia else -1
        for k in range(abs(ib - ia)):
            ki = ia + k if step > 0 else ia - 1 - k
            level = knees[ki]
            after[m] = ki + 1 if step > 0 else ki
            w0 = w[i]
            w1 = w[(i + 1) % N]
            f = (level - w0) / (w1 - w0)
            f = min(max(f, 0.0), 1.0)
            ph = (i + f) * dphi
            lo_ph = i * dphi
            hi_ph = (i + 1) * dphi
            for _ in range(n_newton):
                fv = 0.0
                dfv = 0.0
                # e^{i n ph} by the recurrence z_(n+1) = z_n e^{i ph}: one cos/sin per step
                # instead of one per harmonic (rounding grows as n eps, n <= H)
                cr = math.cos(ph)
                ci = math.sin(ph)
                zr = 1.0
                zi = 0.0
                for n in range(nc):
                    re = c[n].real * zr - c[n].imag * zi      # Re(c_n e^{i n ph})
                    im = c[n].real * zi + c[n].imag * zr
                    fv += re
                    dfv += -n * im                           # Re(i n c_n e^{i n ph})
                    t = zr * cr - zi * ci
                    zi = zr * ci + zi * cr
                    zr = t
                fv -= level
                upd = fv / dfv if dfv != 0.0 else 0.0
                ph = min(max(ph - upd, lo_ph), hi_ph)
            phis[m] = ph
            m += 1
    for i in range(1, total):                               # crossings in time order
        if phis[i] < phis[i - 1]:
            phis[i] = phis[i - 1]
    for i in range(total):
        t0 = phis[i] * 2.0 / omega
        t1 = phis[i + 1] * 2.0 / omega if i + 1 < total else phis[0] * 2.0 / omega + T
        stages[i] = after[i] - primary
        taus[i] = t1 - t0
    return total, phis[0] * 2.0 / omega


def monodromy_similar(regions, taus, count, kind, sigma, freq, W, X):
    """X = W_(r_1, r_k) B_k W_(r_k, r_k-1) ... W_(r_2, r_1) B_1: the monodromy of the
    piecewise-linear system up to the similarity Q_(r_1) (same multipliers), in the real
    eigenbasis of each region.

    Per region r, A_r = Q_r blockdiag(B_r) Q_r^-1 with real Q_r (columns Re v, Im v of each
    complex pair) and blocks exp(B tau) = exp(sigma tau) [[cos w tau, sin w tau],
    [-sin w tau, cos w tau]] (1 x 1 exp(sigma tau) for a real eigenvalue); crossing from region b
    into region a is the constant W_(a, b) = Q_a^-1 Q_b. So each stretch costs one block-diagonal
    scaling and one real matrix product (instead of forming exp(A tau) = V diag V^-1 in complex
    arithmetic and multiplying). ``kind[r, i]``: 0 real eigenvalue, 1 first of a pair, 2 second.
    The crossing products go into a spare buffer (no temporary per stretch); the result is in X.
    """
    ns = X.shape[0]
    out = X
    Y = np.empty((ns, ns))
    for i in range(ns):
        for j in range(ns):
            X[i, j] = 1.0 if i == j else 0.0
    for k in range(count):
        r = regions[k]
        tau = taus[k]
        i = 0
        while i < ns:
            e = math.exp(sigma[r, i] * tau)
            if kind[r, i] == 0:
                for j in range(ns):
                    X[i, j] *= e
                i += 1
            else:
                c = e * math.cos(freq[r, i] * tau)
                sn = e * math.sin(freq[r, i] * tau)
                for j in range(ns):
                    a = X[i, j]
                    b = X[i + 1, j]
                    X[i, j] = c * a + sn * b
                    X[i + 1, j] = -sn * a + c * b
                i += 2
        nxt = regions[k + 1] if k + 1 < count else regions[0]
        if nxt != r:
            np.dot(W[nxt, r], X, Y)         # into the spare buffer, no temporary
            X, Y = Y, X
    if X is not out:
        out[:, :] = X
    return out


def floquet(c, w, omega, knees, primary, n_newton, kind, sigma, freq, W):
    """(X, count, stages, durations [s]): the stretches of one cycle between knee crossings and
    the monodromy up to similarity (:func:`monodromy_similar`; its eigenvalues are the Floquet
    multipliers). With one stretch (no crossing) X is not formed (the multipliers are
    exp(lambda T) in closed form)."""
    nk = knees.shape[0]
    cap = max(w.shape[0] * (nk if nk > 0 else 1), 1)
    stages = np.empty(cap, dtype=np.int64)
    taus = np.empty(cap)
    count, t0 = floquet_segments(c, w, omega, knees, primary, n_newton, stages, taus)
    ns = sigma.shape[1]
    X = np.empty((ns, ns))
    if count > 1:
        monodromy_similar(stages[:count] + primary, taus, count, kind, sigma, freq, W, X)
    return X, count, stages[:count].copy(), taus[:count].copy()


def floquet_many(C, w, omegas, knees, primary, n_newton, kind, sigma, freq, W, counts, stage0,
                 tau0, wr, wi, status):
    """:func:`floquet` of K periodic wind-ups in one call, with the multipliers: point k's
    harmonics C[k], samples w[k], omega [rad/s] omegas[k]. Writes counts[k] (stretches), and
    either (count 1: no knee crossed, the multipliers are exp(lambda T) of that region in closed
    form) its stage0[k] and duration tau0[k] [s], or (count > 1) the eigenvalues wr[k] + i wi[k]
    of the monodromy by :func:`dmf_sim.solvers.lapack_kernel.eigenvalues_into` (the same bits as
    ``stability.eigenvalues`` of :func:`floquet`'s X). status[k]: 0, or 1 for a monodromy with
    an inf or NaN, 2 where the eigenvalues did not converge (the caller raises as ``eigenvalues``
    does)."""
    K = C.shape[0]
    for k in range(K):
        X, count, stages, taus = floquet(C[k], w[k], omegas[k], knees, primary, n_newton, kind,
                                         sigma, freq, W)
        counts[k] = count
        stage0[k] = stages[0]
        tau0[k] = taus[0]
        status[k] = 0
        if count == 1:
            continue
        if not np.isfinite(X).all():
            status[k] = 1
            continue
        if eigenvalues_into(X, wr[k], wi[k]) != 0:
            status[k] = 2


def flow_factors(kind, sigma, freq, tau, fa, fb):
    """fa, fb <- the entries of exp(B tau) for the block-diagonal B of a region's real
    eigenbasis (:func:`dmf_sim.solvers.stability.real_eigenbasis`: ``kind`` 0 a real eigenvalue
    ``sigma``, fa = exp(sigma tau); 1 and 2 the rows of a pair sigma +- i freq, whose block is
    [[fa, fb], [-fb, fa]] with fa = exp(sigma tau) cos(freq tau), fb = exp(sigma tau)
    sin(freq tau))."""
    ns = kind.shape[0]
    for i in range(ns):
        e = math.exp(sigma[i] * tau)
        if kind[i] == 0:
            fa[i] = e
            fb[i] = 0.0
        else:
            fa[i] = e * math.cos(freq[i] * tau)
            fb[i] = e * math.sin(freq[i] * tau)


def flow_apply(X, kind, fa, fb):
    """X <- exp(B tau) X with the factors of :func:`flow_factors`, in place."""
    ns = X.shape[0]
    i = 0
    while i < ns:
        if kind[i] == 0:
            e = fa[i]
            for j in range(ns):
                X[i, j] *= e
            i += 1
        else:
            c = fa[i]
            sn = fb[i]
            for j in range(ns):
                a = X[i, j]
                b = X[i + 1, j]
                X[i, j] = c * a + sn * b
                X[i + 1, j] = -sn * a + c * b
            i += 2


def flow_real(X, kind, sigma, freq, tau):
    """X <- exp(B tau) X for the block-diagonal B of a region's real eigenbasis, in place
    (:func:`flow_factors`, :func:`flow_apply`)."""
    ns = kind.shape[0]
    fa = np.empty(ns)
    fb = np.empty(ns)
    flow_factors(kind, sigma, freq, tau, fa, fb)
    flow_apply(X, kind, fa, fb)


def law_steps(w, v, amp, knees, slopes, offsets, primary, law, base, k, c):
    """base, k, c <- for each step of the cycle's uniform grid, from (w[j], v[j]) to the next
    sample (wind-up [rad], rate [rad/s]; the last step back to the first): the spring region
    of its start (``base``, the region whose state matrix carries the step's flow), and the
    extra stiffness [Nm/rad] beyond that region's and the damping [Nms/rad] of the DMF's
    non-linear torque over the step, as the linearized system of a spring with friction and end
    stops sees them (doc/theory.md §8): the secants of g over w (minus the base region's slope;
    zero where the step stays in its region) and of the friction T_f over w_dot (exact averages
    of the tangents when w, w_dot are linear in time over the step: the friction's tangent is a
    spike of width ~omega_reg / |w_ddot| at a reversal, which a sample would miss or
    overweight), plus the end stop's tangents at the step's middle. g and T_f are evaluated
    once per sample. Returns the number of steps with k or c non-zero."""
    N = w.shape[0]
    slo, shi = travel_range(law)
    g = np.empty(N)
    tf = np.empty(N)
    dtf = np.empty(N)
    for j in range(N):
        r = region_of(w[j], knees, primary)
        base[j] = r
        g[j] = slopes[r] * w[j] + offsets[r]
        tf[j], dtf[j], _ = friction_parts(v[j], amp, law)
    active = 0
    for j in range(N):
        m = j + 1 if j + 1 < N else 0
        w0 = w[j]
        w1 = w[m]
        v0 = v[j]
        v1 = v[m]
        r = base[j]
        kj = 0.0 if base[m] == r else (g[m] - g[j]) / (w1 - w0) - slopes[r]
        cj = (tf[m] - tf[j]) / (v1 - v0) if v1 != v0 else 0.5 * (dtf[j] + dtf[m])
        wm = 0.5 * (w0 + w1)
        if wm > shi or wm < slo:
            _, dsw, dsv = stop_parts(wm, 0.5 * (v0 + v1), law)
            kj += dsw
            cj += dsv
        k[j] = kj
        c[j] = cj
        if k[j] != 0.0 or c[j] != 0.0:
            active += 1
    return active


def monodromy_law(w, v, period, amp, knees, slopes, offsets, primary, law, kind, sigma, freq, W,
                  beta, p, q, er2, bound, drop, Z):
    """Z <- the monodromy (up to similarity) of the driveline linearized about a periodic wind-up
    with friction and end stops, in the real eigen-coordinates z = Q_r^-1 y of the state matrix
    A_r = Q_r blockdiag(B_r) Q_r^-1 of the spring region r its first step starts in
    (:func:`dmf_sim.solvers.stability.real_eigenbasis` of each region, stacked by region
    index: ``kind``, ``sigma``, ``freq``; ``W[a, b]`` = Q_a^-1 Q_b; doc/theory.md §8).
    Returns that region's index.

    The linearized DMF torque beyond region r's is rank one along the wind-up: ``y' = A_r y +
    b (k(t) er.dy + c(t) er.dy')``, b = [0, -er]. Over each of the N steps of the uniform grid
    ``w``, ``v`` (wind-up and rate on the cycle, period [s]) the base region r (where the step
    starts), k and c are held at the step's values (:func:`law_steps`) and the step is split
    (Strang): ``exp(A_r h/2) R_j exp(A_r h/2)``, the exact flow of A_r (2 x 2 rotation blocks,
    :func:`flow_real`) and the exact exponential of the rank-one part,
    ``R_j = I + beta u^T (exp(sigma h) - 1) / sigma`` with u = k p + c q,
    sigma = u.beta = -c |er|^2 (``beta[r]`` = Q_r^-1 b, ``p[r]`` and ``q[r]`` the rows [er, 0] Q_r
    and [0, er] Q_r, er2 = |er|^2); a step in another region than the one before first changes
    coordinates (W), so the half steps on either side of a crossing flow in their own regions.
    Real arithmetic, O(n^2) per step. Where k = c = 0 (the friction saturated, the step inside
    one region: most of a slipping cycle) R_j = I, the flow is exact, and the flows of
    consecutive such steps are applied as one (exp(A_r m h)): the cost is that of the steps
    near the reversals and the crossings. So is a step whose |R_j - I| <= h (|k| bound[r, 0] +
    |c| bound[r, 1]) (``bound[r]`` = |beta_r| |p_r|, |beta_r| |q_r|) is at most ``drop`` / N:
    the far tails of the regularized friction, where its slope is tiny but not zero; together
    they change the product by about ``drop`` at most. Second order in h, unconditionally
    stable for any friction damping (the stiff part is exact)."""
    N = w.shape[0]
    n = sigma.shape[1]
    h = period / N
    base = np.empty(N, dtype=np.int64)
    k = np.empty(N)
    c = np.empty(N)
    law_steps(w, v, amp, knees, slopes, offsets, primary, law, base, k, c)
    cut = drop / N
    for j in range(N):
        r = base[j]
        if h * (abs(k[j]) * bound[r, 0] + abs(c[j]) * bound[r, 1]) <= cut:
            k[j] = 0.0
            c[j] = 0.0
    for i in range(n):
        for j in range(n):
            Z[i, j] = 1.0 if i == j else 0.0
    Y = np.empty((n, n))
    u = np.empty(n)
    srow = np.empty(n)
    R = sigma.shape[0]
    fa = np.empty((R, n))               # each region's flow over one step, made once
    fb = np.empty((R, n))
    for r in range(R):
        flow_factors(kind[r], sigma[r], freq[r], h, fa[r], fb[r])
    first = base[0]
    cur = first
    half = 0.5 * h
    pending = 0                         # half steps of flow not applied yet (in region cur)
    for step in range(N):
        r = base[step]
        if r != cur:
            if pending:
                flow_real(Z, kind[cur], sigma[cur], freq[cur], pending * half)
                pending = 0
            np.dot(W[r, cur], Z, Y)
            Z[:, :] = Y
            cur = r
        kj = k[step]
        cj = c[step]
        if kj == 0.0 and cj == 0.0:
            pending += 2
            continue
        if pending == 1:                # the step before was active too: one step's flow
            flow_apply(Z, kind[r], fa[r], fb[r])
        else:
            flow_real(Z, kind[r], sigma[r], freq[r], (pending + 1) * half)
        pending = 1
        for i in range(n):
            u[i] = kj * p[r, i] + cj * q[r, i]
        sig = -cj * er2
        x = sig * h
        phi = h if abs(x) < 1e-12 else math.expm1(x) / sig
        for j in range(n):
            srow[j] = 0.0
        for i in range(n):
            ui = u[i]
            for j in range(n):
                srow[j] += ui * Z[i, j]
        for i in range(n):
            bi = beta[r, i] * phi
            for j in range(n):
                Z[i, j] += bi * srow[j]
    if pending:
        flow_real(Z, kind[cur], sigma[cur], freq[cur], pending * half)
    if cur != first:                    # back to the coordinates of the start
        np.dot(W[first, cur], Z, Y)
        Z[:, :] = Y
    return first


def floquet_law_many(w, v, periods, amps, knees, slopes, offsets, primary, law, kind, sigma,
                     freq, W, beta, p, q, er2, bound, drop, Q, Qinv, M, wr, wi, status):
    """The Floquet multipliers of K periodic wind-ups with friction and end stops in one call:
    point k's wind-up w[k] and rate v[k] on the cycle's uniform grid, period periods[k] [s],
    sliding friction torque amps[k] [Nm]. M[k] <- the monodromy Q_r Z Q_r^-1 of
    :func:`monodromy_law`'s Z (``Q``, ``Qinv``: each region's real eigenbasis and its inverse,
    stacked by region index), wr[k] + i wi[k] <- its eigenvalues
    (:func:`dmf_sim.solvers.lapack_kernel.eigenvalues_into`); status[k]: 0, 1 for a monodromy
    with an inf or NaN, 2 where the eigenvalues did not converge (the caller raises as
    ``stability.eigenvalues`` does)."""
    K = w.shape[0]
    ns = sigma.shape[1]
    Z = np.empty((ns, ns))
    T = np.empty((ns, ns))
    for k in range(K):
        r = monodromy_law(w[k], v[k], periods[k], amps[k], knees, slopes, offsets, primary, law,
                          kind, sigma, freq, W, beta, p, q, er2, bound, drop, Z)
        np.dot(Q[r], Z, T)
        np.dot(T, Qinv[r], M[k])
        status[k] = 0
        if not np.isfinite(M[k]).all():
            status[k] = 1
            continue
        if eigenvalues_into(M[k], wr[k], wi[k]) != 0:
            status[k] = 2


floquet_segments = jit(floquet_segments)
monodromy_similar = jit(monodromy_similar)
floquet = jit(floquet)
floquet_many = jit(floquet_many)
flow_factors = jit(flow_factors)
flow_apply = jit(flow_apply)
flow_real = jit(flow_real)
law_steps = jit(law_steps)
monodromy_law = jit(monodromy_law, fastmath={'reassoc', 'contract'})
floquet_law_many = jit(floquet_law_many)
