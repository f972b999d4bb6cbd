"""Newmark time integration of the non-linear driveline (design.md §3) — the live node's hot loop.

Equation of motion in vibratory DOF coordinates q (deviation from the reference rotation psi/R_i):

    J q'' + C q' + K q + e g(e q) = P(psi) + a_dal domega/dt                    (eq. 7, merged)

with g the DMF's non-linear extra torque and e the wind-up row. Newmark's scheme (beta, gamma;
average acceleration beta = 1/4, gamma = 1/2 by default) gives per step

    Khat q_{n+1} + e g(e q_{n+1}) = rhs,   Khat = K + a0 J + a1 C,
    rhs = P_{n+1} + J (a0 q_n + a2 v_n + a3 a_n) + C (a1 q_n + a4 v_n + a5 a_n).

Condensed on the wind-up (u = Khat^-1 e, h = e.u): w + h g(w) = e.Khat^-1 rhs — a scalar
equation solved by Newton's method with the active spring region checked, which is exact on the
piecewise-linear spring (knee crossings are resolved inside the step, not at its end). Then
q_{n+1} = Khat^-1 rhs - u g(w).

Khat is tridiagonal (a chain of merged inertias), so each step is O(n): a Thomas solve with a
precomputed factorization. The kernel is compiled with numba (cached); ``_step_reference`` is the
readable numpy path the tests compare against.

Speed: the reference rotation's crank speed omega ramps toward its target at ``ramp`` [rad/s^2];
the excitation phase is psi = integral of omega dt (trapezoid, exact for a linear ramp), never
omega t. The reference acceleration enters as the balanced d'Alembert load (see loads.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dmf_sim.errors import ConfigError
from dmf_sim.harmonic import solve_static
from dmf_sim.loads import RPM_TO_RAD_S, DrivelineLoads

try:
    import numba
    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - numba is a hard dependency, kept optional for readability
    HAVE_NUMBA = False


# ------------------------------------------------------------------------------------------------
# The kernel (plain Python; compiled by numba below)
# ------------------------------------------------------------------------------------------------

def _factor(h, beta, gam, Jd, Klo, Kd, Kup, Clo, Cd, Cup, e, coef, f_lo, f_inv, f_cp, u):
    """Newmark constants for a step h [s] into ``coef`` = [h, a0..a5, gamma, e.Khat^-1 e], the
    Thomas factors of the tridiagonal Khat = K + a0 J + a1 C, and u = Khat^-1 e (all in place)."""
    n = Jd.shape[0]
    a0 = 1.0 / (beta * h * h)
    a1 = gam / (beta * h)
    coef[0] = h
    coef[1] = a0
    coef[2] = a1
    coef[3] = 1.0 / (beta * h)
    coef[4] = 1.0 / (2.0 * beta) - 1.0
    coef[5] = gam / beta - 1.0
    coef[6] = h * (gam / (2.0 * beta) - 1.0)
    coef[7] = gam
    f_inv[0] = 1.0 / (Kd[0] + a0 * Jd[0] + a1 * Cd[0])
    for i in range(1, n):
        f_lo[i - 1] = Klo[i - 1] + a1 * Clo[i - 1]
        f_cp[i - 1] = (Kup[i - 1] + a1 * Cup[i - 1]) * f_inv[i - 1]
        f_inv[i] = 1.0 / (Kd[i] + a0 * Jd[i] + a1 * Cd[i] - f_lo[i - 1] * f_cp[i - 1])
    _thomas(f_lo, f_inv, f_cp, e, u)
    hc = 0.0
    for i in range(n):
        hc += e[i] * u[i]
    coef[8] = hc


def _thomas(f_lo, f_inv, f_cp, rhs, x):
    """Solve Khat x = rhs with the precomputed Thomas factors (O(n))."""
    n = rhs.shape[0]
    x[0] = rhs[0] * f_inv[0]
    for i in range(1, n):
        x[i] = (rhs[i] - f_lo[i - 1] * x[i - 1]) * f_inv[i]
    for i in range(n - 2, -1, -1):
        x[i] -= f_cp[i] * x[i + 1]


def _advance_kernel(nsteps, stride, q, v, a, scal, coef, beta, fixed, Jd, Klo, Kd, Kup, Clo, Cd,
                    Cup, f_lo, f_inv, f_cp, e, u, B, cyl_dof, cyl_scale, dal, spring,
                    out_t, out_psi, out_omega, out_q, out_v, out_a, out_w, counters):
    """Advance ``nsteps`` Newmark steps of coef[0] seconds in place.

    A step in which the wind-up crosses a knee is redone as two sub-steps that end and start at
    the crossing (time from linear interpolation of w), so the kink of the spring falls on a step
    boundary and the trapezoidal rule never straddles it.

    scal: [t, psi, omega, omega_target, ramp_rad_s2, omega_dot]       (state, updated in place)
    coef: [dt, a0, a1, a2, a3, a4, a5, gamma, e.Khat^-1 e] with f_lo/f_inv/f_cp/u for dt
    fixed: (n,) constant generalized load (rear load etc.) [Nm]
    B: (n_cyl, N+1) complex cylinder coefficients A_n exp(-i n beta_k/2)
    spring: [b, theta, b_coast, theta_coast]   (theta_coast = inf for none)
    counters: [knee_crossings, steps_secondary, steps_coast, split_steps]
    Every ``stride`` steps the state is written to the out_* arrays (row j = step // stride).
    """
    n = q.shape[0]
    dt = coef[0]
    gam = coef[7]
    b = spring[0]
    th = spring[1]
    bc = spring[2]
    thc = spring[3]
    n_cyl = B.shape[0]
    n_h = B.shape[1]
    rhs = np.empty(n)
    y = np.empty(n)
    x = np.empty(n)
    zp = np.empty(n_h, dtype=np.complex128)
    q0 = np.empty(n)
    v0 = np.empty(n)
    a00 = np.empty(n)
    s0 = np.empty(6)
    sub = np.empty(9)
    s_lo = np.empty(max(n - 1, 1))
    s_inv = np.empty(n)
    s_cp = np.empty(max(n - 1, 1))
    s_u = np.empty(n)
    w_prev = 0.0
    for i in range(n):
        w_prev += e[i] * q[i]
    region_prev = 1 if w_prev > th else (-1 if w_prev < -thc else 0)
    w = w_prev
    region = region_prev
    j = 0
    for step in range(nsteps):
        for i in range(n):
            q0[i] = q[i]
            v0[i] = v[i]
            a00[i] = a[i]
        for i in range(6):
            s0[i] = scal[i]
        n_parts = 1
        part = 0
        frac = 1.0
        while part < n_parts:
            if n_parts == 1:                      # the regular step: precomputed factors
                c = coef
                fl, fi, fc, uu = f_lo, f_inv, f_cp, u
            else:                                 # split step: factors for this part's length
                h_part = frac * dt if part == 0 else (1.0 - frac) * dt
                _factor(h_part, beta, gam, Jd, Klo, Kd, Kup, Clo, Cd, Cup, e, sub, s_lo, s_inv,
                        s_cp, s_u)
                c = sub
                fl, fi, fc, uu = s_lo, s_inv, s_cp, s_u
            h = c[0]
            a0 = c[1]
            a1 = c[2]
            a2 = c[3]
            a3 = c[4]
            a4 = c[5]
            a5 = c[6]
            hc = c[8]
            # --- reference speed and excitation phase psi = integral of omega dt ------------
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
            # --- load: eq. (16)-(17) with z = exp(i psi/2), plus fixed and d'Alembert loads --
            for i in range(n):
                rhs[i] = fixed[i] + dal[i] * omega_dot
            z = complex(math.cos(0.5 * psi), math.sin(0.5 * psi))
            zp[0] = 1.0
            for k in range(1, n_h):
                zp[k] = zp[k - 1] * z
            for cc in range(n_cyl):
                acc = 0.0
                for k in range(n_h):
                    acc += B[cc, k].real * zp[k].real - B[cc, k].imag * zp[k].imag
                rhs[cyl_dof[cc]] += cyl_scale[cc] * acc
            # --- rhs += J (a0 q + a2 v + a3 a) + C (a1 q + a4 v + a5 a) ------------------
            for i in range(n):
                y[i] = a1 * q[i] + a4 * v[i] + a5 * a[i]
                rhs[i] += Jd[i] * (a0 * q[i] + a2 * v[i] + a3 * a[i]) + Cd[i] * y[i]
            for i in range(n - 1):
                rhs[i] += Cup[i] * y[i + 1]
                rhs[i + 1] += Clo[i] * y[i]
            # --- Thomas solve Khat x = rhs ---------------------------------------------------
            x[0] = rhs[0] * fi[0]
            for i in range(1, n):
                x[i] = (rhs[i] - fl[i - 1] * x[i - 1]) * fi[i]
            for i in range(n - 2, -1, -1):
                x[i] -= fc[i] * x[i + 1]
            # --- condensed DMF equation w + hc g(w) = w_lin, Newton with the region checked --
            w_lin = 0.0
            for i in range(n):
                w_lin += e[i] * x[i]
            if w_lin > th:
                w = (w_lin + hc * b * th) / (1.0 + hc * b)
                g = b * (w - th)
                region = 1
            elif w_lin < -thc:
                w = (w_lin - hc * bc * thc) / (1.0 + hc * bc)
                g = -bc * (-w - thc)
                region = -1
            else:
                w = w_lin
                g = 0.0
                region = 0
            for i in range(n):
                qn = x[i] - uu[i] * g
                an = a0 * (qn - q[i]) - a2 * v[i] - a3 * a[i]
                v[i] = v[i] + h * ((1.0 - gam) * a[i] + gam * an)
                a[i] = an
                q[i] = qn
            part += 1
            if n_parts == 1 and region != region_prev:
                counters[0] += 1
                knee = th if (region == 1 or region_prev == 1) else -thc
                frac = (knee - w_prev) / (w - w_prev) if w != w_prev else 0.5
                if 0.01 < frac < 0.99:            # redo as [t, t + frac dt] + the rest
                    for i in range(n):
                        q[i] = q0[i]
                        v[i] = v0[i]
                        a[i] = a00[i]
                    for i in range(6):
                        scal[i] = s0[i]
                    n_parts = 2
                    part = 0
                    counters[3] += 1
        if region == 1:
            counters[1] += 1
        elif region == -1:
            counters[2] += 1
        region_prev = region
        w_prev = w
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


if HAVE_NUMBA:
    _jit = numba.njit(cache=True, nogil=True)
    _thomas = _jit(_thomas)
    _factor = _jit(_factor)
    _advance_compiled = _jit(_advance_kernel)
else:  # pragma: no cover
    _advance_compiled = _advance_kernel


# ------------------------------------------------------------------------------------------------
# Integrator object (stepping API for the node; simulate() for offline use)
# ------------------------------------------------------------------------------------------------

def _tridiag(M: np.ndarray, name: str):
    n = M.shape[0]
    off = M - np.diag(np.diag(M)) - np.diag(np.diag(M, 1), 1) - np.diag(np.diag(M, -1), -1)
    if np.abs(off).max() > 1e-9 * max(np.abs(M).max(), 1.0):
        raise ConfigError(f'{name} is not tridiagonal: the Newmark kernel needs a series chain')
    return np.diag(M, -1).copy(), np.diag(M).copy(), np.diag(M, 1).copy()


def _two_step_arrays(sp) -> np.ndarray:
    """[b, theta, b_coast, theta_coast] of a spring with at most one stage per side."""
    if sp is None:
        return np.array([0.0, np.inf, 0.0, np.inf])
    if len(sp.drive) > 1 or len(sp.coast) > 1:
        raise NotImplementedError('the Newmark kernel takes one drive and one coast stage')
    b = sp.stage_stiffness(1) if sp.drive else 0.0
    bc = sp.stage_stiffness(-1) if sp.coast else 0.0
    thc = sp.coast[0].angle_rad if sp.coast else np.inf
    return np.array([b, sp.theta, bc, thc])


@dataclass
class StepRecord:
    """Preallocated buffers the stepper writes into (rows = recorded steps). SI units."""

    t: np.ndarray
    psi: np.ndarray
    omega: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    windup: np.ndarray
    count: int = 0

    def rows_from(self, start: int) -> 'StepRecord':
        """A view of these buffers from row ``start`` on (the stepper writes into it)."""
        return StepRecord(self.t[start:], self.psi[start:], self.omega[start:], self.q[start:],
                          self.v[start:], self.a[start:], self.windup[start:])

    @classmethod
    def allocate(cls, rows: int, n_dof: int) -> 'StepRecord':
        return cls(np.zeros(rows), np.zeros(rows), np.zeros(rows), np.zeros((rows, n_dof)),
                   np.zeros((rows, n_dof)), np.zeros((rows, n_dof)), np.zeros(rows))


@dataclass
class NewmarkIntegrator:
    """Fixed-step Newmark integrator on a merged model with the two-step DMF.

    Args:
        loads: DrivelineLoads (model + engine).
        dt: time step [s].
        beta, gamma: Newmark parameters (average acceleration: 1/4, 1/2).
        use_numba: compiled kernel (True) or the readable numpy reference path (False).
    """

    loads: DrivelineLoads
    dt: float = 1e-4
    beta: float = 0.25
    gamma: float = 0.5
    use_numba: bool = True
    knee_crossings: int = field(default=0, init=False)
    steps_secondary: int = field(default=0, init=False)
    steps_coast: int = field(default=0, init=False)
    split_steps: int = field(default=0, init=False)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ConfigError(f'dt={self.dt}: must be > 0 s')
        if not (0 < self.beta <= 0.5 and 0.5 <= self.gamma <= 1.0 and self.beta >= self.gamma / 4 - 1e-12):
            raise ConfigError(f'beta={self.beta}, gamma={self.gamma}: need 0.5 <= gamma <= 1 and '
                             'gamma/4 <= beta <= 0.5 (unconditionally stable Newmark)')
        m = self.loads.model
        self.model = m
        n = m.n_dof
        Jd = np.diag(m.J).copy()
        if np.abs(m.J - np.diag(Jd)).max() > 0:
            raise ConfigError('J is not diagonal')
        self._Jd = Jd
        self._Clo, self._Cd, self._Cup = _tridiag(m.C, 'C')
        self._Klo, self._Kd, self._Kup = _tridiag(m.K, 'K')
        # Newmark constants, Thomas factors of Khat = K + a0 J + a1 C and u = Khat^-1 e for dt
        self._coef = np.zeros(9)
        self._f_lo, self._f_inv, self._f_cp = np.zeros(max(n - 1, 1)), np.zeros(n), np.zeros(max(n - 1, 1))
        self._u = np.zeros(n)
        _factor(self.dt, self.beta, self.gamma, Jd, self._Klo, self._Kd, self._Kup, self._Clo,
                self._Cd, self._Cup, m.e, self._coef, self._f_lo, self._f_inv, self._f_cp, self._u)
        self.Khat = m.K + self._coef[1] * m.J + self._coef[2] * m.C
        self._spring = _two_step_arrays(m.spring)
        L = self.loads
        self._cyl_dof = np.array([int(np.flatnonzero(row)[0]) for row in L.cylinder_dof_vectors])
        self._cyl_scale = np.array([row[d] for row, d in zip(L.cylinder_dof_vectors, self._cyl_dof)])
        self._dal = L.dalembert_dof.copy()
        self._rear_vec = L.rear_dof_vector.copy()
        # state
        self.q = np.zeros(n)
        self.v = np.zeros(n)
        self.a = np.zeros(n)
        self._scal = np.zeros(6)  # t, psi, omega, omega_target, ramp, omega_dot
        self._counters = np.zeros(4, dtype=np.int64)  # crossings, secondary, coast, split steps
        self.load = 0.0
        self._B = np.zeros((len(self._cyl_dof), L.n_max + 1), dtype=complex)
        self._fixed = np.zeros(n)
        self._rear_torque = 0.0
        self._coef_speed_rpm = None

    # ---- state accessors ---------------------------------------------------------------
    @property
    def t(self) -> float:
        return float(self._scal[0])

    @property
    def psi(self) -> float:
        """Crank angle of the reference rotation [rad], continuous."""
        return float(self._scal[1])

    @property
    def omega(self) -> float:
        """Reference crank speed [rad/s]."""
        return float(self._scal[2])

    @property
    def speed_rpm(self) -> float:
        return self.omega / RPM_TO_RAD_S

    @property
    def omega_dot(self) -> float:
        return float(self._scal[5])

    @property
    def windup(self) -> float:
        return float(self.model.e @ self.q)

    # ---- set-up --------------------------------------------------------------------------
    def update_excitation(self, speed_rpm: float | None = None, load: float | None = None) -> None:
        """Recompute the cylinder coefficients and rear load for the current (or given) speed
        [rpm] and load fraction. Called by the stepper between chunks; coefficients are held
        constant inside a chunk."""
        if speed_rpm is None:
            speed_rpm = self.speed_rpm
        if load is not None:
            self.load = float(load)
        L = self.loads
        A = L.engine.coefficients(speed_rpm, self.load)        # one engine query per update
        self._B[:] = L.cylinder_coefficients_for(A)
        self._rear_torque = L.rear_load_for(A)
        self._fixed[:] = self._rear_vec * self._rear_torque
        self._coef_speed_rpm = speed_rpm

    def set_target(self, speed_rpm: float, ramp_rpm_per_s: float) -> None:
        """Ramp the reference speed toward ``speed_rpm`` at ``ramp_rpm_per_s``."""
        self._scal[3] = speed_rpm * RPM_TO_RAD_S
        self._scal[4] = ramp_rpm_per_s * RPM_TO_RAD_S

    def reset(self, speed_rpm: float, load: float, psi: float = 0.0, t: float = 0.0) -> None:
        """Start at constant speed from the static equilibrium under the mean torque.

        The rigid-body velocity is set to the forced periodic rigid-body velocity at psi so the
        free chain's mean speed does not drift away from the reference (the rigid mode is
        decoupled: r^T K = r^T C = 0).
        """
        self._scal[:] = [t, psi, speed_rpm * RPM_TO_RAD_S, speed_rpm * RPM_TO_RAD_S, 0.0, 0.0]
        self.update_excitation(speed_rpm, load)
        st = self.loads.static_state(speed_rpm, load)
        self.q[:] = st.q
        self.v[:] = 0.0
        r = self.model.rigid_mode
        if r is not None and speed_rpm > 0:
            P = self.loads.dof_harmonics(speed_rpm, load)
            Jr = float(r @ self.model.J @ r)
            n = np.arange(1, P.shape[0])
            Om = n / 2 * speed_rpm * RPM_TO_RAD_S
            F = P[1:] @ r
            # eta'' = Re(F e^{i n psi/2})/Jr  ->  eta' = Re(F/(i Om Jr) e^{i n psi/2})
            eta_dot = np.real(np.sum(F / (1j * Om * Jr) * np.exp(1j * n * psi / 2)))
            self.v[:] = r * eta_dot
        self.a[:] = self.acceleration(self.q, self.v)
        self._counters[:] = 0

    def acceleration(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """a = J^-1 (P - C v - K q - e g(e q)) at the current psi and omega_dot."""
        P = self.generalized_load(self.psi, self.omega_dot)
        m = self.model
        g = float(m.spring.extra_torque(m.e @ q)) if m.spring is not None else 0.0
        return (P - m.C @ v - m.K @ q - m.e * g) / self._Jd

    def generalized_load(self, psi, omega_dot=0.0) -> np.ndarray:
        """Generalized load [Nm] with the current coefficients at crank angle(s) psi [rad]:
        ``T^T p`` of :meth:`element_loads` (virtual work)."""
        return self.model.element_vector(self.element_loads(psi, omega_dot))

    def element_loads(self, psi, omega_dot=0.0) -> np.ndarray:
        """Element torques [Nm] (cylinders, rear, d'Alembert) at crank angle(s) psi."""
        psi = np.asarray(psi, dtype=float)
        L = self.loads
        n = np.arange(self._B.shape[1])
        cyl = np.real(np.exp(1j * np.multiply.outer(psi, n) / 2) @ self._B.T)
        p = np.multiply.outer(np.asarray(omega_dot, float) * np.ones_like(psi), L.dalembert_elements)
        p[..., L.cylinder_elements] += cyl
        p[..., L.rear_element] += self._rear_torque
        return p

    # ---- stepping ------------------------------------------------------------------------
    def advance(self, nsteps: int, record: StepRecord | None = None, stride: int = 1) -> int:
        """Advance ``nsteps`` steps; every ``stride`` steps write the state into ``record``
        (rows from 0; needs nsteps // stride rows). Returns the number of rows written."""
        if record is None:
            record = self._scratch(max(nsteps // stride, 1))
            stride = max(nsteps, 1)
        args = (int(nsteps), int(stride), self.q, self.v, self.a, self._scal, self._coef,
                float(self.beta), self._fixed, self._Jd, self._Klo, self._Kd, self._Kup, self._Clo,
                self._Cd, self._Cup, self._f_lo, self._f_inv, self._f_cp,
                self.model.e, self._u, self._B, self._cyl_dof, self._cyl_scale, self._dal,
                self._spring, record.t, record.psi, record.omega, record.q, record.v, record.a,
                record.windup, self._counters)
        rows = (_advance_compiled if self.use_numba else _advance_reference)(*args)
        record.count = rows
        self.knee_crossings, self.steps_secondary, self.steps_coast, self.split_steps = (
            int(c) for c in self._counters)
        return rows

    def _scratch(self, rows: int) -> StepRecord:
        buf = getattr(self, '_scratch_buf', None)
        if buf is None or buf.t.shape[0] < rows:
            buf = StepRecord.allocate(rows, self.model.n_dof)
            self._scratch_buf = buf
        return buf


def _advance_reference(nsteps, stride, q, v, a, scal, coef, beta, fixed, Jd, Klo, Kd, Kup, Clo, Cd,
                       Cup, f_lo, f_inv, f_cp, e, u, B, cyl_dof, cyl_scale, dal, spring, out_t,
                       out_psi, out_omega, out_q, out_v, out_a, out_w, counters):
    """Readable numpy version of the kernel (same arguments, same results): dense matrices,
    numpy.linalg.solve and Newton on the condensed DMF equation."""
    dt, gam = coef[0], coef[7]
    b, th, bc, thc = spring
    K = np.diag(Kd) + np.diag(Kup, 1) + np.diag(Klo, -1)
    C = np.diag(Cd) + np.diag(Cup, 1) + np.diag(Clo, -1)
    J = np.diag(Jd)
    nh = np.arange(B.shape[1])

    def g_of(w):                                   # DMF extra torque and its tangent
        g = b * max(w - th, 0.0) - bc * max(-w - thc, 0.0)
        return g, (b if w > th else 0.0) + (bc if w < -thc else 0.0)

    def region_of(w):
        return 1 if w > th else (-1 if w < -thc else 0)

    def step(h, q, v, a):
        a0, a1, a2 = 1 / (beta * h * h), gam / (beta * h), 1 / (beta * h)
        a3, a4, a5 = 1 / (2 * beta) - 1, gam / beta - 1, h * (gam / (2 * beta) - 1)
        Khat = K + a0 * J + a1 * C
        omega = scal[2]
        d = np.clip(scal[3] - omega, -scal[4] * h, scal[4] * h)
        scal[5] = d / h
        scal[1] += (omega + 0.5 * d) * h                         # psi = integral of omega
        scal[2] = omega + d
        scal[0] += h
        P = fixed + dal * scal[5]
        np.add.at(P, cyl_dof, cyl_scale * np.real(B @ np.exp(1j * nh * scal[1] / 2)))   # eq. (17)
        rhs = P + J @ (a0 * q + a2 * v + a3 * a) + C @ (a1 * q + a4 * v + a5 * a)
        x = np.linalg.solve(Khat, rhs)
        uu = np.linalg.solve(Khat, e)
        hc, w_lin = e @ uu, e @ x
        w = w_lin                                  # Newton on w + hc g(w) = w_lin
        for _ in range(6):
            g, dg = g_of(w)
            r = w + hc * g - w_lin
            if abs(r) <= 1e-15 * max(1.0, abs(w_lin)):
                break
            w -= r / (1 + hc * dg)
        qn = x - uu * g_of(w)[0]
        an = a0 * (qn - q) - a2 * v - a3 * a
        return qn, v + h * ((1 - gam) * a + gam * an), an, w

    w_prev = e @ q
    j = 0
    for n_step in range(nsteps):
        saved = (q.copy(), v.copy(), a.copy(), scal.copy())
        qn, vn, an, w = step(dt, q, v, a)
        r_new, r_old = region_of(w), region_of(w_prev)
        if r_new != r_old:
            knee = th if 1 in (r_new, r_old) else -thc
            frac = (knee - w_prev) / (w - w_prev) if w != w_prev else 0.5
            if 0.01 < frac < 0.99:                  # split the step at the knee crossing
                scal[:] = saved[3]
                qn, vn, an, _ = step(frac * dt, *saved[:3])
                qn, vn, an, w = step((1 - frac) * dt, qn, vn, an)
                counters[3] += 1
            counters[0] += 1
        q[:], v[:], a[:] = qn, vn, an
        r = region_of(w)
        counters[1] += r == 1
        counters[2] += r == -1
        w_prev = w
        if (n_step + 1) % stride == 0:
            out_t[j], out_psi[j], out_omega[j], out_w[j] = scal[0], scal[1], scal[2], w
            out_q[j], out_v[j], out_a[j] = q, v, a
            j += 1
    return j


# ------------------------------------------------------------------------------------------------
# Offline: one call, one result (like scipy.integrate.solve_ivp)
# ------------------------------------------------------------------------------------------------

@dataclass
class SimulationResult:
    """Result of :func:`simulate` (SI units; speed in rpm as named).

    Attributes:
        t, psi, speed_rpm, windup: recorded time [s], crank angle [rad], reference speed, DMF
            wind-up [rad] (every ``record_stride`` steps; for steady-state runs, the last cycles).
        q, v: recorded DOF angles [rad] and velocities [rad/s].
        steady: whether the cycle-to-cycle change fell below ``steady_tol``.
        cycles: engine cycles integrated; change: the last relative cycle-to-cycle change.
        windup_orders: complex half-order coefficients c_n of the wind-up over the last
            ``eval_cycles`` whole cycles (steady-state runs; None otherwise).
        summary: OrderSummary of the wind-up (3rd/1.5th order, max/min deviation, mean - theta).
        knee_crossings: DMF region changes counted by the kernel.
        message: human-readable status.
    """

    t: np.ndarray
    psi: np.ndarray
    speed_rpm: np.ndarray
    windup: np.ndarray
    q: np.ndarray
    v: np.ndarray
    steady: bool
    cycles: int
    change: float
    windup_orders: np.ndarray | None
    summary: object | None
    knee_crossings: int
    message: str
    integrator: NewmarkIntegrator | None = None

    @property
    def success(self) -> bool:
        return self.steady


def simulate(loads: DrivelineLoads, speed_rpm: float, load: float, *, t_end: float | None = None,
             target_speed_rpm: float | None = None, ramp_rpm_per_s: float = 0.0,
             dt: float = 1e-4, beta: float = 0.25, gamma: float = 0.5,
             steady_tol: float = 1e-4, min_cycles: int = 5, max_cycles: int = 400,
             eval_cycles: int = 4, record_stride: int = 1, chunk_s: float = 0.01,
             initial: tuple[np.ndarray, np.ndarray] | None = None, use_numba: bool = True,
             progress: bool = False) -> SimulationResult:
    """Integrate the driveline at speed ``speed_rpm`` and load fraction ``load``.

    Without ``t_end``: run whole engine cycles at constant speed until the wind-up's
    cycle-to-cycle change (max abs difference over one cycle on a crank-angle grid, relative to
    its peak-to-peak) is below ``steady_tol``, then return the wind-up orders of the last
    ``eval_cycles`` cycles. With ``t_end`` [s]: a transient run, optionally ramping toward
    ``target_speed_rpm`` at ``ramp_rpm_per_s``, recording every ``record_stride`` steps; the
    excitation coefficients follow the speed every ``chunk_s`` seconds.
    ``initial`` = (q, v) replaces the static equilibrium start.
    """
    from dmf_sim.orders import CYCLE_RAD, resample_on_angle, half_order_coefficients, summarize

    integ = NewmarkIntegrator(loads, dt=dt, beta=beta, gamma=gamma, use_numba=use_numba)
    integ.reset(speed_rpm, load)
    if initial is not None:
        integ.q[:] = initial[0]
        integ.v[:] = initial[1]
        integ.a[:] = integ.acceleration(integ.q, integ.v)
    theta = loads.model.spring.theta if loads.model.spring is not None else 0.0
    n_max = loads.n_max

    if t_end is not None:
        if target_speed_rpm is not None:
            integ.set_target(target_speed_rpm, ramp_rpm_per_s)
        n_total = int(round(t_end / dt))
        chunk = max(int(round(chunk_s / dt)) // record_stride, 1) * record_stride
        rows_total = n_total // record_stride
        rec = StepRecord.allocate(rows_total, loads.model.n_dof)
        done = row = 0
        bar = _bar(progress, n_total, 'simulate')
        while done < n_total:
            k = min(chunk, n_total - done)
            k -= k % record_stride if k >= record_stride else 0
            k = max(k, 1)
            row += integ.advance(k, rec.rows_from(row), record_stride)
            done += k
            integ.update_excitation()
            bar.update(k)
        bar.close()
        return SimulationResult(rec.t[:row], rec.psi[:row], rec.omega[:row] / RPM_TO_RAD_S,
                                rec.windup[:row], rec.q[:row], rec.v[:row], steady=False,
                                cycles=int(integ.psi // CYCLE_RAD), change=float('nan'),
                                windup_orders=None, summary=None,
                                knee_crossings=integ.knee_crossings,
                                message=f'transient run of {t_end} s', integrator=integ)

    # --- steady state at constant speed, cycle by cycle -----------------------------------
    omega = speed_rpm * RPM_TO_RAD_S
    steps_per_cycle = CYCLE_RAD / (omega * dt)
    keep = eval_cycles + 2
    cap = int(np.ceil(steps_per_cycle)) + 2
    ring = [StepRecord.allocate(cap, loads.model.n_dof) for _ in range(keep)]
    grid_pts = 256

    def stitched(first: int, last: int, attr: str) -> np.ndarray:
        recs = [ring[j % keep] for j in range(first, last + 1)]
        return np.concatenate([getattr(r, attr)[:r.count] for r in recs])

    prev = None
    change = np.inf
    steady = False
    cyc = 0
    bar = _bar(progress, max_cycles, f'steady state {speed_rpm:.0f} rpm')
    for cyc in range(1, max_cycles + 1):
        # record j covers crank angle [(j-1) 4pi + ~2 omega dt, j 4pi + ~2 omega dt)
        nsteps = int(np.ceil((cyc * CYCLE_RAD - integ.psi) / (omega * dt))) + 1
        integ.advance(nsteps, ring[cyc % keep], 1)
        if cyc >= 2:
            cur = resample_on_angle(stitched(cyc - 1, cyc, 'psi'), stitched(cyc - 1, cyc, 'windup'),
                                    (cyc - 1) * CYCLE_RAD, 1, grid_pts)
            if prev is not None:
                change = float(np.max(np.abs(cur - prev))) / max(float(np.ptp(cur)), 1e-9)
                if cyc >= min_cycles and change < steady_tol:
                    steady = True
                    bar.update(1)
                    break
            prev = cur
        bar.update(1)
    bar.close()
    n_eval = max(min(eval_cycles, cyc - 1), 1)
    first = cyc - n_eval
    psi, w = stitched(first, cyc, 'psi'), stitched(first, cyc, 'windup')
    start = (cyc - n_eval) * CYCLE_RAD
    samples = resample_on_angle(psi, w, start, n_eval, grid_pts)
    coeffs = half_order_coefficients(samples, n_eval, n_max)
    summ = summarize(samples, n_eval, theta, n_max)
    cat = lambda attr: stitched(first, cyc, attr)  # noqa: E731
    msg = (f'steady after {cyc} cycles (change {change:.2e})' if steady
           else f'not steady after {cyc} cycles (change {change:.2e} > {steady_tol:g})')
    return SimulationResult(cat('t'), psi, np.full(len(psi), speed_rpm), w, cat('q'), cat('v'),
                            steady=steady, cycles=cyc, change=change, windup_orders=coeffs,
                            summary=summ, knee_crossings=integ.knee_crossings, message=msg,
                            integrator=integ)


def _bar(enabled: bool, total: int, desc: str):
    if enabled:
        from tqdm import tqdm
        return tqdm(total=total, desc=desc, unit='step' if total > 1000 else 'cycle', leave=False)

    class _Null:
        def update(self, n): pass
        def close(self): pass
    return _Null()
