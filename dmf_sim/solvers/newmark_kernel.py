"""The Newmark step of the DMF driveline — the live node's hot loop — and its readable reference.

Equation of motion in vibratory DOF coordinates q (deviation from the reference rotation psi/R_i):

    J q'' + C q' + K q + e g(e q) = P(psi) + a_dal domega/dt                    (eq. 7, merged)

with g the DMF spring's extra torque (dmf_sim.physics.spring) and e the wind-up row. Newmark's
scheme (beta, gamma; average acceleration beta = 1/4, gamma = 1/2 by default) gives per step
of length h

    Khat q_{n+1} + e g(e q_{n+1}) = rhs,   Khat = K + a0 J + a1 C,
    rhs = P_{n+1} + J (a0 q_n + a2 v_n + a3 a_n) + C (a1 q_n + a4 v_n + a5 a_n).

Condensed on the wind-up (u = Khat^-1 e, h_c = e.u): ``w + h_c g(w) = w_lin = e.Khat^-1 rhs``, a
scalar equation solved exactly region by region of the piecewise-linear spring (the region whose
image under F(w) = w + h_c g(w) holds w_lin; one Newton step from inside it is exact), then
``q_{n+1} = Khat^-1 rhs - u g(w)``.

Knee crossings: a step whose wind-up changes region is redone in pieces that end at the knees
it crosses (time from linear interpolation of w), so every kink of the spring falls on a step
boundary and the trapezoidal rule never straddles one.

Khat is tridiagonal (a chain of merged inertias), so each step is O(n): a Thomas solve with a
precomputed factorization. The reference speed, phase and cylinder loads of the regular steps do
not depend on the vibratory state: :func:`regular_block` computes them LOOKAHEAD_STEPS steps
ahead in one vectorizable pass, with the step's own arithmetic (the same bits); a split step
computes its pieces' own and the steps ahead start again from its end.
:func:`advance_compiled` is the numba kernel (arguments packed in tuples, see
:class:`dmf_sim.solvers.newmark.NewmarkIntegrator`; the cold parts — factorization, region
lookup — are small jitted helpers); :func:`advance_reference` is the readable numpy path with
dense solves and the spring object itself, which the tests compare against.

Speed: the reference crank speed omega ramps toward its target at ``ramp`` [rad/s^2]; the
excitation phase is psi = integral of omega dt (trapezoid, exact for a linear ramp), never
omega t. The reference acceleration enters as the balanced d'Alembert load (see loads.py).

Packed arguments (all float64 unless noted):

* ``state`` = (q, v, a, scal) with scal = [t, psi, omega, omega_target, ramp, omega_dot]
* ``system`` = (Jd, Klo, Kd, Kup, Clo, Cd, Cup, e, params) with params = [beta, gamma]
* ``factors`` = (coef, f_lo, f_inv, f_cp, u): Newmark constants coef = [h, a0..a5, gamma, h_c],
  Thomas factors of Khat for the regular step, u = Khat^-1 e
* ``spring`` = (knees, slopes, offsets, primary_index, law, sums):
  ``PiecewiseLinearSpring.arrays()``, its ``law_array()`` (friction and end stops, eq.
  8a-8b; all zero but omega_reg: none) and
  ``sums`` float64[7], accumulated in place: [friction heat J, largest |end-stop torque| Nm,
  smallest wind-up rad, largest wind-up rad, the time s of each, and (read only) the time s
  from which steps count for them]: the wind-up's extremes over every step's end from that
  time on, not only the recorded ones (the caller starts them at +inf, -inf)
* ``excitation`` = (B complex (n_cyl, N+1), cyl_dof int64, cyl_scale, dal, fixed, dB, dfixed,
  ramp): the cylinder coefficients B and fixed loads at time ramp[0] [s], their rates dB, dfixed
  [per s] and ramp = [t0, t1] [s]: a (piece of a) step ending at time t uses B + tau dB and
  fixed + tau dfixed, tau = clip(t - t0, 0, t1 - t0) (the setpoints' ramps followed step by
  step: :meth:`dmf_sim.solvers.newmark.NewmarkIntegrator.ramp_excitation`); t1 <= t0: no ramp,
  B and fixed as they are (the same arithmetic as without a ramp)
* ``out`` = (t, psi, omega, q, v, a, w) recorded every ``stride`` steps
* ``track`` = (dofs int64 (k,), rows (nsteps, 3 + 2k)): every step's t, psi, omega and the
  angles and velocities of DOFs ``dofs`` (the sensors' elements), row j = step j; or None (no
  sensors): numba compiles that call without the tracking at all (its dead-branch pruning of
  ``track is not None`` on a None argument), so the kernel without sensors is the one it was
* ``counters`` int64 = [knee crossings, steps beyond a drive knee, steps beyond a coast knee,
  steps split at a knee, drive end-stop contacts, coast end-stop contacts]

Friction and end stops (doc/theory.md §2, eq. 8a-8b) are torques N(w, w_dot) along the wind-up
like g. With Newmark's velocity update the wind-up rate of the new state is linear in the new
wind-up, ``w_dot = a1 (w - w_n) - a4 w_dot_n - a5 w_ddot_n``, so the condensed equation stays one
scalar equation (eq. 8c),

    w + h_c (g(w) + N(w, w_dot(w))) = w_lin,

still increasing in w (every term is non-decreasing), solved by Newton's method safeguarded by
bisection on a bracket (:func:`law_solve`); the engine speed Omega of the centrifugal friction
is the reference speed at the step's end. Without friction and stops the kernel runs the exact
region solve above and nothing else (the same bits as a kernel without them). The friction heat
is the trapezoidal work of T_f over each (piece of a) step, the work the average-acceleration
rule's energy balance books (doc/theory.md §5). End-stop contacts are not split at the contact
(the contact is resolved by the step: see the configuration guide's stiffness rule); a contact
is counted when the wind-up goes from inside to beyond a stop.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq

from dmf_sim.core.compiled import jit
from dmf_sim.solvers.spring_kernels import law_parts, region_of

__all__ = ['MAX_PIECES', 'SPLIT_MIN_FRACTION', 'LOOKAHEAD_STEPS', 'newmark_constants', 'thomas',
           'factor', 'knee_between', 'regular_block', 'law_solve',
           'advance_kernel', 'advance_reference', 'LAW_MAX_ITER', 'LAW_TOL_RAD']


MAX_PIECES = 8           # a step is split at most this many times (knees crossed in one step)
SPLIT_MIN_FRACTION = 0.01  # crossings this close to a step end are not split (no tiny steps)
LAW_MAX_ITER = 200       # iterations of the safeguarded Newton solve with friction / end stops
LAW_TOL_RAD = 1e-15      # its wind-up tolerance [rad] (a few ulp of a 0.1 rad wind-up)
LOOKAHEAD_STEPS = 64     # regular steps whose speed, phase and cylinder loads are computed ahead
                         # in one vectorizable pass (see :func:`regular_block`)


# ------------------------------------------------------------------------------------------------
# Small helpers (plain Python; compiled by numba below)
# ------------------------------------------------------------------------------------------------

def newmark_constants(h, beta, gam, coef):
    """coef[0:8] = [h, a0, a1, a2, a3, a4, a5, gamma] for a step h [s]."""
    coef[0] = h
    coef[1] = 1.0 / (beta * h * h)
    coef[2] = gam / (beta * h)
    coef[3] = 1.0 / (beta * h)
    coef[4] = 1.0 / (2.0 * beta) - 1.0
    coef[5] = gam / beta - 1.0
    coef[6] = h * (gam / (2.0 * beta) - 1.0)
    coef[7] = gam


def thomas(f_lo, f_inv, f_cp, rhs, x):
    """Solve Khat x = rhs with the precomputed Thomas factors (O(n))."""
    n = rhs.shape[0]
    x[0] = rhs[0] * f_inv[0]
    for i in range(1, n):
        x[i] = (rhs[i] - f_lo[i - 1] * x[i - 1]) * f_inv[i]
    for i in range(n - 2, -1, -1):
        x[i] -= f_cp[i] * x[i + 1]


def factor(h, Jd, Klo, Kd, Kup, Clo, Cd, Cup, e, params, coef, f_lo, f_inv, f_cp, u):
    """Newmark constants for a step h [s], Thomas factors of Khat = K + a0 J + a1 C, u = Khat^-1 e
    and h_c = e.u (into coef[8]), all in place (``system`` unpacked: Jd..e,
    params = [beta, gamma])."""
    n = Jd.shape[0]
    newmark_constants(h, params[0], params[1], coef)
    a0 = coef[1]
    a1 = coef[2]
    f_inv[0] = 1.0 / (Kd[0] + a0 * Jd[0] + a1 * Cd[0])
    for i in range(1, n):
        f_lo[i - 1] = Klo[i - 1] + a1 * Clo[i - 1]
        f_cp[i - 1] = (Kup[i - 1] + a1 * Cup[i - 1]) * f_inv[i - 1]
        f_inv[i] = 1.0 / (Kd[i] + a0 * Jd[i] + a1 * Cd[i] - f_lo[i - 1] * f_cp[i - 1])
    thomas(f_lo, f_inv, f_cp, e, u)
    hc = 0.0
    for i in range(n):
        hc += e[i] * u[i]
    coef[8] = hc


def knee_between(r_from, r_to, knees):
    """The first knee crossed going from region r_from toward region r_to."""
    return knees[r_from] if r_to > r_from else knees[r_from - 1]


def law_solve(w_lin, hc, a1, w_n, rate0, amp, law, knees, slopes, offsets, primary, w0):
    """Solve the condensed equation with friction and end stops (eq. 8c),
    ``w + hc (g(w) + T_f(w_dot) + T_s(w, w_dot)) = w_lin`` with ``w_dot = a1 (w - w_n) + rate0``,
    for w: Newton's method from ``w0`` (the solution without friction and stops), kept inside a
    bracket of the root and bisecting when a Newton step leaves it. F is increasing in w, so the
    bracket is found by doubling a step away from w0. Returns w [rad]."""
    r = region_of(w0, knees, primary)
    tf, ts, dtf, dws, dvs = law_parts(w0, a1 * (w0 - w_n) + rate0, amp, law)
    f0 = w0 + hc * (slopes[r] * w0 + offsets[r] + tf + ts) - w_lin
    if f0 == 0.0:
        return w0
    d = abs(f0) + hc * amp + 1e-12
    lo = w0
    hi = w0
    for _ in range(LAW_MAX_ITER):
        x = w0 - d if f0 > 0.0 else w0 + d
        r = region_of(x, knees, primary)
        tf, ts, dtf, dws, dvs = law_parts(x, a1 * (x - w_n) + rate0, amp, law)
        fx = x + hc * (slopes[r] * x + offsets[r] + tf + ts) - w_lin
        if (fx > 0.0) == (f0 > 0.0) and fx != 0.0:
            d *= 2.0
            continue
        if f0 > 0.0:
            lo = x
        else:
            hi = x
        break
    x = w0
    for _ in range(LAW_MAX_ITER):
        r = region_of(x, knees, primary)
        tf, ts, dtf, dws, dvs = law_parts(x, a1 * (x - w_n) + rate0, amp, law)
        fx = x + hc * (slopes[r] * x + offsets[r] + tf + ts) - w_lin
        if fx == 0.0:
            return x
        if fx > 0.0:
            hi = x
        else:
            lo = x
        dfx = 1.0 + hc * (slopes[r] + dtf * a1 + dws + dvs * a1)
        xn = x - fx / dfx
        if not lo < xn < hi:
            xn = 0.5 * (lo + hi)
        if abs(xn - x) <= LAW_TOL_RAD or hi - lo <= LAW_TOL_RAD:
            return xn
        x = xn
    return x


def regular_block(nb, h, scal, Br, Bi, blk_scal, blk_cyl, cr, ci, zr, zi, ramping, dBr, dBi,
                  blk_dcyl):
    """The next ``nb`` regular steps of length h, ahead of the state: the reference speed, phase
    and time of each (the kernel's own ramp arithmetic from ``scal``, so the same numbers) into
    ``blk_scal[0:4, s]`` = t, psi, omega, omega_dot, and each cylinder's excitation
    Re(sum_k B_ck z^k), z = exp(i psi/2), into ``blk_cyl[c, s]``; ``ramping``: also the
    coefficient rates' Re(sum_k dB_ck z^k) into ``blk_dcyl[c, s]`` (per s of the ramp).

    Neither depends on the vibratory state, so they are computed for many steps at once, the
    steps in the inner loops (vectorized by the compiler) instead of one step's 25 dependent
    complex products and n_cyl dot products each step: ~3x less time per step for the
    excitation. The arithmetic of every value is the step's own (z^k = z^(k-1) z, the sum in k
    order), so the results are bit for bit those of the step-by-step evaluation.
    """
    n_cyl = Br.shape[0]
    n_h = Br.shape[1]
    t = scal[0]
    psi = scal[1]
    omega = scal[2]
    lim = scal[4] * h
    for j in range(nb):
        diff = scal[3] - omega
        if diff > lim:
            diff = lim
        elif diff < -lim:
            diff = -lim
        omega_new = omega + diff
        psi = psi + 0.5 * (omega + omega_new) * h
        t += h
        blk_scal[0, j] = t
        blk_scal[1, j] = psi
        blk_scal[2, j] = omega_new
        blk_scal[3, j] = diff / h
        omega = omega_new
        cr[j] = math.cos(0.5 * psi)
        ci[j] = math.sin(0.5 * psi)
        zr[j] = 1.0
        zi[j] = 0.0
    for c in range(n_cyl):
        b_r = Br[c, 0]
        b_i = Bi[c, 0]
        for j in range(nb):
            blk_cyl[c, j] = 0.0 + (b_r * zr[j] - b_i * zi[j])
        if ramping:
            d_r = dBr[c, 0]
            d_i = dBi[c, 0]
            for j in range(nb):
                blk_dcyl[c, j] = 0.0 + (d_r * zr[j] - d_i * zi[j])
    for k in range(1, n_h):
        for j in range(nb):
            a = zr[j]
            b = zi[j]
            zr[j] = a * cr[j] - b * ci[j]
            zi[j] = a * ci[j] + b * cr[j]
        for c in range(n_cyl):
            b_r = Br[c, k]
            b_i = Bi[c, k]
            for j in range(nb):
                blk_cyl[c, j] += b_r * zr[j] - b_i * zi[j]
            if ramping:
                d_r = dBr[c, k]
                d_i = dBi[c, k]
                for j in range(nb):
                    blk_dcyl[c, j] += d_r * zr[j] - d_i * zi[j]


# ------------------------------------------------------------------------------------------------
# The kernel
# ------------------------------------------------------------------------------------------------

def advance_kernel(nsteps, stride, state, system, factors, spring, excitation, out, counters,
                   track):
    """Advance ``nsteps`` Newmark steps of factors[0][0] seconds in place; every ``stride`` steps
    write the state into ``out`` (row j = step // stride), every step the tracked DOFs into
    ``track`` (when it tracks any). Returns the rows written.

    One loop body does every (sub)step: the regular step with the precomputed factors, or a piece
    of a step split at a knee with factors for its length (:func:`factor`). The body is written
    out here rather than called: numba's inlining of helpers that take many arrays costs 25-35 %
    of the step time (measured with numba 0.68), and this loop is the node's hot path. The
    Thomas sweeps carry the damping's off-diagonal terms and the wind-up sum with them (one pass
    down, one up: 10-25 % less time per step than separate loops, measured).
    """
    q, v, a, scal = state
    Jd, Klo, Kd, Kup, Clo, Cd, Cup, e, params = system
    coef, f_lo, f_inv, f_cp, u = factors
    knees, slopes, offsets, primary, law, sums = spring
    B, cyl_dof, cyl_scale, dal, fixed, dB, dfixed, ramp = excitation
    out_t, out_psi, out_omega, out_q, out_v, out_a, out_w = out
    n = q.shape[0]
    n_cyl = B.shape[0]
    n_h = B.shape[1]
    nk = knees.shape[0]
    dt = coef[0]
    rhs = np.empty(n)
    y = np.empty(n)
    x = np.empty(n)
    zp = np.empty(n_h, dtype=np.complex128)
    q0 = np.empty(n)                 # state at the start of the (rest of the) step
    v0 = np.empty(n)
    a00 = np.empty(n)
    s0 = np.empty(6)
    s_coef = np.empty(9)             # factors of a split piece
    s_lo = np.empty(max(n - 1, 1))
    s_inv = np.empty(n)
    s_cp = np.empty(max(n - 1, 1))
    s_u = np.empty(n)
    # regular steps computed ahead (regular_block): speed/phase, cylinder loads, work rows
    Br = np.empty((n_cyl, n_h))
    Bi = np.empty((n_cyl, n_h))
    dBr = np.empty((n_cyl, n_h))
    dBi = np.empty((n_cyl, n_h))
    for cc in range(n_cyl):
        for k in range(n_h):
            Br[cc, k] = B[cc, k].real
            Bi[cc, k] = B[cc, k].imag
            dBr[cc, k] = dB[cc, k].real
            dBi[cc, k] = dB[cc, k].imag
    # the setpoints' ramp (load and speed followed step by step): tau = clip(t - t0, 0, t1 - t0)
    ramping = ramp[1] > ramp[0]
    t_ramp = ramp[0]
    tau_max = ramp[1] - ramp[0]
    tau = 0.0
    blk_scal = np.empty((4, LOOKAHEAD_STEPS))
    blk_cyl = np.empty((n_cyl, LOOKAHEAD_STEPS))
    blk_dcyl = np.empty((n_cyl, LOOKAHEAD_STEPS))
    blk_w = np.empty((4, LOOKAHEAD_STEPS))
    nb = 0                           # steps in the block, the next one's index
    jb = 0
    w_prev = 0.0
    for i in range(n):
        w_prev += e[i] * q[i]
    r_prev = region_of(w_prev, knees, primary)
    w = w_prev
    r = r_prev
    j = 0
    # friction and end stops (eq. 8a-8c): off unless the spring has them
    law_on = law[0] > 0.0 or law[1] > 0.0 or law[5] > 0.0
    tf_a = 0.0                       # friction torque at the start of the rest of the step
    tf = 0.0
    ts = 0.0
    beyond = 0                       # +1 beyond the drive stop, -1 beyond the coast stop
    if law_on:
        wd_prev = 0.0
        for i in range(n):
            wd_prev += e[i] * v[i]
        tf_a, ts, _, _, _ = law_parts(w_prev, wd_prev,
                                      law[0] + law[1] * scal[2] * scal[2], law)
        if law[5] > 0.0:
            beyond = 1 if w_prev > law[4] else (-1 if w_prev < law[3] else 0)
    for step in range(nsteps):
        if jb >= nb:
            nb = min(LOOKAHEAD_STEPS, nsteps - step)
            regular_block(nb, dt, scal, Br, Bi, blk_scal, blk_cyl, blk_w[0], blk_w[1], blk_w[2],
                          blk_w[3], ramping, dBr, dBi, blk_dcyl)
            jb = 0
        for i in range(n):
            q0[i] = q[i]
            v0[i] = v[i]
            a00[i] = a[i]
        for i in range(6):
            s0[i] = scal[i]
        phase = 0            # 0: the regular step; 1: a piece ending at a knee; 2: the rest
        pieces = 0
        h_rem = dt
        frac = 1.0
        w_a = w_prev         # wind-up and region at the start of the rest of the step
        r_a = r_prev
        while True:
            if phase == 0:
                c = coef
                fl = f_lo
                fi = f_inv
                fc = f_cp
                uu = u
            else:
                c = s_coef
                fl = s_lo
                fi = s_inv
                fc = s_cp
                uu = s_u
            h = c[0]
            a0 = c[1]
            a1 = c[2]
            a2 = c[3]
            a3 = c[4]
            a4 = c[5]
            a5 = c[6]
            gam = c[7]
            hc = c[8]
            if phase == 0:
                # --- the regular step: speed, phase and cylinder loads computed ahead -------
                omega_dot = blk_scal[3, jb]
                scal[0] = blk_scal[0, jb]
                scal[1] = blk_scal[1, jb]
                scal[2] = blk_scal[2, jb]
                scal[5] = omega_dot
                if ramping:
                    tau = min(max(scal[0] - t_ramp, 0.0), tau_max)
                    for i in range(n):
                        rhs[i] = fixed[i] + tau * dfixed[i] + dal[i] * omega_dot
                    for cc in range(n_cyl):
                        rhs[cyl_dof[cc]] += cyl_scale[cc] * (blk_cyl[cc, jb]
                                                             + tau * blk_dcyl[cc, jb])
                else:
                    for i in range(n):
                        rhs[i] = fixed[i] + dal[i] * omega_dot
                    for cc in range(n_cyl):
                        rhs[cyl_dof[cc]] += cyl_scale[cc] * blk_cyl[cc, jb]
            else:
                # --- a piece of a split step: the same, for this piece alone ----------------
                # reference speed and excitation phase psi = integral of omega dt
                omega = scal[2]
                diff = scal[3] - omega
                lim = scal[4] * h
                if diff > lim:
                    diff = lim
                elif diff < -lim:
                    diff = -lim
                omega_new = omega + diff
                omega_dot = diff / h
                psi = scal[1] + 0.5 * (omega + omega_new) * h
                scal[0] += h
                scal[1] = psi
                scal[2] = omega_new
                scal[5] = omega_dot
                # load: eq. (16)-(17) with z = exp(i psi/2), plus fixed and d'Alembert loads
                if ramping:
                    tau = min(max(scal[0] - t_ramp, 0.0), tau_max)
                for i in range(n):
                    rhs[i] = fixed[i] + dal[i] * omega_dot
                    if ramping:
                        rhs[i] += tau * dfixed[i]
                z = complex(math.cos(0.5 * psi), math.sin(0.5 * psi))
                zp[0] = 1.0
                for k in range(1, n_h):
                    zp[k] = zp[k - 1] * z
                for cc in range(n_cyl):
                    acc = 0.0
                    for k in range(n_h):
                        acc += B[cc, k].real * zp[k].real - B[cc, k].imag * zp[k].imag
                    if ramping:
                        for k in range(n_h):
                            acc += tau * (dB[cc, k].real * zp[k].real
                                          - dB[cc, k].imag * zp[k].imag)
                    rhs[cyl_dof[cc]] += cyl_scale[cc] * acc
            # --- rhs += J (a0 q + a2 v + a3 a) + C (a1 q + a4 v + a5 a) ------------------
            for i in range(n):
                y[i] = a1 * q[i] + a4 * v[i] + a5 * a[i]
                rhs[i] += Jd[i] * (a0 * q[i] + a2 * v[i] + a3 * a[i]) + Cd[i] * y[i]
            # --- Thomas solve Khat x = rhs, the off-diagonal C terms added on the way down and
            # the wind-up w_lin = e.x summed on the way up (one pass each) --------------------
            if n == 1:
                xp = rhs[0] * fi[0]
                x[0] = xp
                w_lin = e[0] * xp
            else:
                xp = (rhs[0] + Cup[0] * y[1]) * fi[0]
                x[0] = xp
                for i in range(1, n - 1):
                    xp = (rhs[i] + Clo[i - 1] * y[i - 1] + Cup[i] * y[i + 1]
                          - fl[i - 1] * xp) * fi[i]
                    x[i] = xp
                xp = (rhs[n - 1] + Clo[n - 2] * y[n - 2] - fl[n - 2] * xp) * fi[n - 1]
                x[n - 1] = xp
                w_lin = e[n - 1] * xp
                for i in range(n - 2, -1, -1):
                    xp = x[i] - fc[i] * xp
                    x[i] = xp
                    w_lin += e[i] * xp
            # --- condensed DMF equation w + hc g(w) = w_lin, exact in the region that holds it
            r = 0
            while r < nk and knees[r] + hc * (slopes[r] * knees[r] + offsets[r]) < w_lin:
                r += 1
            w = (w_lin - hc * offsets[r]) / (1.0 + hc * slopes[r])
            g = slopes[r] * w + offsets[r]
            if law_on:
                # eq. 8c: w_dot = a1 (w - w_n) + rate0, w_n and its rates those of this piece
                w_n = 0.0
                rate0 = 0.0
                for i in range(n):
                    w_n += e[i] * q[i]
                    rate0 -= e[i] * (a4 * v[i] + a5 * a[i])
                amp = law[0] + law[1] * scal[2] * scal[2]
                w = law_solve(w_lin, hc, a1, w_n, rate0, amp, law, knees, slopes, offsets,
                              primary, w)
                r = region_of(w, knees, primary)
                tf, ts, _, _, _ = law_parts(w, a1 * (w - w_n) + rate0, amp, law)
                g = slopes[r] * w + offsets[r] + tf + ts
            for i in range(n):
                qn = x[i] - uu[i] * g
                an = a0 * (qn - q[i]) - a2 * v[i] - a3 * a[i]
                v[i] = v[i] + h * ((1.0 - gam) * a[i] + gam * an)
                a[i] = an
                q[i] = qn
            # --- knee crossings: redo the step in pieces that end at the knees -------------
            if phase == 1:               # landed on a knee: try the rest of the step from here
                if law_on:
                    sums[0] += 0.5 * (tf_a + tf) * (w - w_a)
                    tf_a = tf
                w_a = w
                r_a = r
                pieces += 1
                counters[3] += 1
                h_rem -= frac * h_rem
                for i in range(n):
                    q0[i] = q[i]
                    v0[i] = v[i]
                    a00[i] = a[i]
                for i in range(6):
                    s0[i] = scal[i]
                factor(h_rem, Jd, Klo, Kd, Kup, Clo, Cd, Cup, e, params, s_coef, s_lo, s_inv,
                       s_cp, s_u)
                phase = 2
                continue
            if phase == 0 and r != r_prev:
                counters[0] += abs(r - r_prev)
            if r == r_a or pieces >= MAX_PIECES:
                break
            frac = (knee_between(r_a, r, knees) - w_a) / (w - w_a) if w != w_a else 0.5
            if not (SPLIT_MIN_FRACTION < frac < 1.0 - SPLIT_MIN_FRACTION):
                break                    # the crossing is at an end of the step: keep it
            for i in range(n):           # back to the start of the rest, then to the knee
                q[i] = q0[i]
                v[i] = v0[i]
                a[i] = a00[i]
            for i in range(6):
                scal[i] = s0[i]
            factor(frac * h_rem, Jd, Klo, Kd, Kup, Clo, Cd, Cup, e, params, s_coef, s_lo, s_inv,
                   s_cp, s_u)
            phase = 1
        jb += 1
        if law_on:                       # the step's last piece: its friction heat, stop contacts
            sums[0] += 0.5 * (tf_a + tf) * (w - w_a)
            tf_a = tf
            if abs(ts) > sums[1]:
                sums[1] = abs(ts)
            if law[5] > 0.0:
                now = 1 if w > law[4] else (-1 if w < law[3] else 0)
                if now != beyond and now != 0:
                    counters[4 if now > 0 else 5] += 1
                beyond = now
        if pieces > 0 or phase != 0:
            nb = 0                       # a split step: the steps ahead start from its end
        if r > primary:
            counters[1] += 1
        elif r < primary:
            counters[2] += 1
        if scal[0] >= sums[6]:
            if w < sums[2]:
                sums[2] = w
                sums[4] = scal[0]
            if w > sums[3]:
                sums[3] = w
                sums[5] = scal[0]
        r_prev = r
        w_prev = w
        if track is not None:
            track_dofs = track[0]
            track_rows = track[1]
            nt = track_dofs.shape[0]
            track_rows[step, 0] = scal[0]
            track_rows[step, 1] = scal[1]
            track_rows[step, 2] = scal[2]
            for i in range(nt):
                track_rows[step, 3 + i] = q[track_dofs[i]]
                track_rows[step, 3 + nt + i] = v[track_dofs[i]]
        if (step + 1) % stride == 0:
            out_t[j] = scal[0]
            out_psi[j] = scal[1]
            out_omega[j] = scal[2]
            out_w[j] = w
            for i in range(n):
                out_q[j, i] = q[i]
                out_v[j, i] = v[i]
                out_a[j, i] = a[i]
            j += 1
    return j


newmark_constants = jit(newmark_constants)
thomas = jit(thomas)
factor = jit(factor)
knee_between = jit(knee_between)
law_solve = jit(law_solve)
regular_block = jit(regular_block)
# reassociation and FMA contraction: the sums over the DOFs vectorize (~10 % less time per step,
# measured); the results differ from the strict order by round-off (~1e-12 rad over
# 2e5 steps), which the reference tests' tolerances state
advance_compiled = jit(advance_kernel, fastmath={'reassoc', 'contract'})


# ------------------------------------------------------------------------------------------------
# The readable reference: dense numpy solves and the spring object itself
# ------------------------------------------------------------------------------------------------

def advance_reference(nsteps, stride, state, system, factors, spring_obj, excitation, out,
                      counters, track):
    """Readable numpy version of :func:`advance_kernel` (same packed arguments, but the spring
    object instead of its arrays, and ``spring_obj`` may be a tuple (spring, sums) to collect the
    friction heat and peak stop torque): dense matrices, ``numpy.linalg.solve`` and Newton on
    the condensed DMF equation with the spring's own torque and tangent; with friction or end
    stops, Brent's method (``scipy.optimize.brentq``) on eq. 8c with the spring's own
    :meth:`~dmf_sim.physics.spring.PiecewiseLinearSpring.law_torque`."""
    sums = np.array([0.0, 0.0, np.inf, -np.inf, np.nan, np.nan, -np.inf])
    if isinstance(spring_obj, tuple):
        spring_obj, sums = spring_obj
    q, v, a, scal = state
    Jd, Klo, Kd, Kup, Clo, Cd, Cup, e, (beta, gam) = system
    dt = factors[0][0]
    B, cyl_dof, cyl_scale, dal, fixed, dB, dfixed, ramp = excitation
    K = np.diag(Kd) + np.diag(Kup, 1) + np.diag(Klo, -1)
    C = np.diag(Cd) + np.diag(Cup, 1) + np.diag(Clo, -1)
    J = np.diag(Jd)
    nh = np.arange(B.shape[1])
    sp = spring_obj
    p = sp.primary_index if sp is not None else 0

    def g_of(w):
        if sp is None:
            return 0.0, 0.0
        return float(sp.extra_torque(w)), float(sp.extra_stiffness(w))

    def region(w):
        return int(sp.region_index(w)) if sp is not None else 0

    has_law = sp is not None and not sp.smooth_elastic

    def law_at(w, wd):
        return float(sp.law_torque(w, wd, scal[2])) if has_law else 0.0

    def friction_at(wd):
        return (float(sp.friction.torque(wd, scal[2])) if has_law and sp.friction is not None
                else 0.0)

    def step(h, q, v, a):
        c = np.zeros(8)
        newmark_constants(h, beta, gam, c)
        _, a0, a1, a2, a3, a4, a5, _ = c
        Khat = K + a0 * J + a1 * C
        omega = scal[2]
        d = np.clip(scal[3] - omega, -scal[4] * h, scal[4] * h)
        scal[5] = d / h
        scal[1] += (omega + 0.5 * d) * h                         # psi = integral of omega
        scal[2] = omega + d
        scal[0] += h
        tau = min(max(scal[0] - ramp[0], 0.0), ramp[1] - ramp[0]) if ramp[1] > ramp[0] else 0.0
        P = fixed + tau * dfixed + dal * scal[5]
        np.add.at(P, cyl_dof, cyl_scale * np.real((B + tau * dB)
                                                  @ np.exp(1j * nh * scal[1] / 2)))   # eq. (17)
        rhs = P + J @ (a0 * q + a2 * v + a3 * a) + C @ (a1 * q + a4 * v + a5 * a)
        x = np.linalg.solve(Khat, rhs)
        uu = np.linalg.solve(Khat, e)
        hc, w_lin = e @ uu, e @ x
        w = w_lin                                  # Newton on w + hc g(w) = w_lin
        for _ in range(4 * (len(sp.knees) + 1) if sp is not None else 1):
            g, dg = g_of(w)
            res = w + hc * g - w_lin
            if abs(res) <= 1e-15 * max(1.0, abs(w_lin)):
                break
            w -= res / (1 + hc * dg)
        nl = g_of(w)[0]
        if has_law:                                # eq. 8c: w_dot linear in w (Newmark)
            w_n, rate0 = e @ q, -a4 * (e @ v) - a5 * (e @ a)

            def resid(x):
                return x + hc * (g_of(x)[0] + law_at(x, a1 * (x - w_n) + rate0)) - w_lin
            lo = hi = w
            step_w = abs(resid(w)) + 1e-12
            while resid(lo) > 0:
                lo -= step_w
                step_w *= 2
            while resid(hi) < 0:
                hi += step_w
                step_w *= 2
            w = w if lo == hi else brentq(resid, lo, hi, xtol=1e-16, rtol=4 * np.finfo(float).eps)
            nl = g_of(w)[0] + law_at(w, a1 * (w - w_n) + rate0)
        qn = x - uu * nl
        an = a0 * (qn - q) - a2 * v - a3 * a
        return qn, v + h * ((1 - gam) * a + gam * an), an, w

    w_prev = float(e @ q)
    r_prev = region(w_prev)
    stops = sp.stop_angles_rad if sp is not None else None
    def side(w):
        """+1 beyond the drive stop, -1 beyond the coast stop, 0 between (or no stops)."""
        return 0 if stops is None else int(w > stops[1]) - int(w < stops[0])

    beyond = side(w_prev)
    j = 0

    tf_a = [friction_at(e @ v)]          # friction torque at the end of the last piece

    def heat(qa, qb, vb):
        """Trapezoidal work [J] of the friction over a (piece of a) step from qa to (qb, vb),
        T_f at the start that of the last piece's end (its speed), at the end at this one's."""
        tf = friction_at(e @ vb)
        out = 0.5 * (tf_a[0] + tf) * (e @ qb - e @ qa)
        tf_a[0] = tf
        return out

    for n_step in range(nsteps):
        saved = (q.copy(), v.copy(), a.copy(), scal.copy())
        start = saved
        qn, vn, an, w = step(dt, q, v, a)                    # regular trial
        r = region(w)
        if r != r_prev:
            counters[0] += abs(r - r_prev)
            w_a, r_a, h_rem = w_prev, r_prev, dt
            for _ in range(MAX_PIECES):
                if r == r_a:
                    break
                knee = sp.knees[r_a] if r > r_a else sp.knees[r_a - 1]
                frac = (knee - w_a) / (w - w_a) if w != w_a else 0.5
                if not SPLIT_MIN_FRACTION < frac < 1 - SPLIT_MIN_FRACTION:
                    break                                    # keep the trial as it is
                scal[:] = saved[3]                           # back to the start of the rest
                qk, vk, ak, w_a = step(frac * h_rem, *saved[:3])   # piece ending at the knee
                sums[0] += heat(saved[0], qk, vk)
                start = (qk,)
                r_a = region(w_a)
                counters[3] += 1
                h_rem -= frac * h_rem
                saved = (qk, vk, ak, scal.copy())
                qn, vn, an, w = step(h_rem, qk, vk, ak)     # trial of the rest
                r = region(w)
        sums[0] += heat(start[0], qn, vn)
        q[:], v[:], a[:] = qn, vn, an
        counters[1] += r > p
        counters[2] += r < p
        if stops is not None:
            ts = float(sp.stops.torque(w, e @ v))
            sums[1] = max(sums[1], abs(ts))
            now = side(w)
            if now != beyond and now != 0:
                counters[4 if now > 0 else 5] += 1
            beyond = now
        if scal[0] >= sums[6] and w < sums[2]:
            sums[2], sums[4] = w, scal[0]
        if scal[0] >= sums[6] and w > sums[3]:
            sums[3], sums[5] = w, scal[0]
        r_prev, w_prev = r, w
        if track is not None:
            dofs, rows = track
            rows[n_step, :3] = scal[:3]
            rows[n_step, 3:] = np.concatenate([q[dofs], v[dofs]])
        if (n_step + 1) % stride == 0:
            out_t, out_psi, out_omega, out_q, out_v, out_a, out_w = out
            out_t[j], out_psi[j], out_omega[j], out_w[j] = scal[0], scal[1], scal[2], w
            out_q[j], out_v[j], out_a[j] = q, v, a
            j += 1
    return j
