"""Harmonic balance (HBM) of the DMF driveline, condensed onto the DMF wind-up (paper eq. 9-15).

Equation of motion in vibratory DOF coordinates q (model.py, eq. 7 merged):

    J q'' + C q' + K q + e g(e q) = P(psi),     P(psi) = Re( sum_n P_n exp(i n psi/2) )

with ``e`` the wind-up row (w = e q, positive when the engine drives) and ``g(w)`` the extra torque
of the DMF spring (dmf_sim.physics.spring). The base frequency is omega/2: one 720 deg engine
cycle, so half-orders (the 1.5th order, n = 3) are representable. A periodic steady state
is written

    w(psi) = Re( sum_{n=0}^{H} w_n exp(i n psi/2) ),
    g(w(psi)) ~ Re( sum_{n=0}^{H} g_n exp(i n psi/2) )

(eq. 9: the non-linear torque tau of the paper is e g, truncated to the same H harmonics).

Condensation (the paper's split at the non-linear element, eq. 10-14). Balancing each harmonic of
the linear chain with the non-linear torque as an extra load (eq. 10-13) gives

    q_n = H_n (P_n - e g_n),        H_n = (K - Om_n^2 J + i Om_n C)^-1,   Om_n = n omega / 2

and the wind-up row of it (eq. 14) is one scalar equation per harmonic:

    r_n = w_n - wlin_n + h_n g_n(w_0..w_H) = 0,     wlin_n = e.H_n P_n,   h_n = e.H_n e    (eq. 15)

``wlin_n`` is the linear (alpha = 0) wind-up response and ``h_n`` the wind-up receptance of the
chain at the DMF. At n = 0 the free-free chain is singular: the static problem is solved with the
rigid mode removed (harmonic.solve_static), which is the paper's mean offset delta of eq. (14)
found from the mean torque. The Newton unknowns are only the 2H + 1 real numbers of the wind-up
harmonics, whatever the size of the driveline. h_n and wlin_n are computed once per speed — from
the chain's complex modes, computed once per model (exactly the direct n_dof x n_dof solves, see
``linear_parts_direct`` and the tests) — so a Newton iteration costs one alternating
frequency-time (AFT) pass: w(psi_j) on M samples of the cycle -> g(w(psi_j)) -> g_n, with the
analytic Jacobian dg_n/dw_m = (2/M) sum_j g'(w_j) exp(-i n phi_j) dw_j/dw_m.

All element responses follow afterwards (the expansion), ``q_n = H_n (P_n - e g_n)``
(:mod:`dmf_sim.solvers.hbm.expansion`, the collaborator ``CondensedHBM.expansion``).

Real unknown layout used throughout: ``x = [w_0, Re w_1..Re w_H, Im w_1..Im w_H]`` [rad].
"""
from __future__ import annotations

import functools
from collections import OrderedDict

import numpy as np

from dmf_sim.core.errors import ConfigError, ConvergenceError, OperatingRangeError
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.physics.harmonic import solve_static
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.orders import summarize_orders, summarize_rows, synthesize
from dmf_sim.solvers.continuation import CompiledSteps, solve_small
from dmf_sim.solvers.hbm import kernels, linear_kernels
from dmf_sim.solvers.hbm.continuation_steps import CondensedSteps
from dmf_sim.solvers.hbm.expansion import DrivelineExpansion
from dmf_sim.solvers.hbm.faulted import FaultedParts, combustion_factors, is_symmetric
from dmf_sim.solvers.hbm.point import HBMOptions, HBMPoint, LinearParts
from dmf_sim.solvers.hbm.unknowns import fit_harmonics, times_h, to_complex, to_real
from dmf_sim.solvers.spring_kernels import law_parts
from dmf_sim.solvers.stability import FlexibleModes

__all__ = ['aft_tables', 'REGULARIZATION_HOMOTOPY', 'SHARP_DAMPING_RATIO', 'RESONANCE_SHARE',
           'LINEAR_PARTS_CACHE', 'PREPARE_BATCH', 'ENGINE_BATCH_MIN', 'CondensedHBM']

SHARP_DAMPING_RATIO = 0.01
"""A mode damped less than this (damping ratio [-]) makes a resonance a few rpm wide: a spike in
the wind-up curves (:meth:`CondensedHBM.sharp_resonances`)."""

RESONANCE_SHARE = 0.05
"""A sharp resonance is reported where its mode's peak contribution to the wind-up's half order
reaches this share of the linear wind-up's dynamic amplitude (sum of |w_n|, n >= 1) there."""

#: linear parts kept per problem (one per speed; a sweep's grid + search revisit ~150 speeds)
LINEAR_PARTS_CACHE = 512
REGULARIZATION_HOMOTOPY = (1024.0, 256.0, 64.0, 16.0, 4.0, 1.0)
"""Factors on the friction's slip speed omega_reg of the stages of
:meth:`CondensedHBM.newton_regularized`, softest first, the last the spring's own law."""

#: speeds per vectorized batch of :meth:`CondensedHBM.prepare`
PREPARE_BATCH = 64
#: fewest speeds asked of the engine in one vectorized query (``Engine.coefficients_many``);
#: below it one query per speed costs fewer numpy calls (measured: 2 speeds 24 us each, one
#: vectorized query ~60 us; 128 speeds 3 ms one by one, 0.3 ms vectorized)
ENGINE_BATCH_MIN = 8

# ------------------------------------------------------------------------------------------------
# The condensed harmonic balance problem
# ------------------------------------------------------------------------------------------------

@functools.lru_cache(maxsize=8)
def aft_tables(H: int, M: int) -> tuple[np.ndarray, ...]:
    """The AFT matrices of H harmonics on M samples of the base angle phi_j = psi_j / 2 =
    2 pi j / M (one 720 deg cycle), made once per (H, M) (read-only; a problem takes copies):
    (phi, E, weights, F, cos table, sin table) with

        w_j = E x        (E = [1, cos n phi_j, -sin n phi_j])
        G   = F g_j      (F = W E^T: mean and 2/M-weighted Fourier sums)

    and the tables cos(m phi_j), sin(m phi_j), m = 0..2H, the compiled Jacobian reads."""
    phi = 2.0 * np.pi * np.arange(M) / M
    n = np.arange(1, H + 1)
    E = np.hstack([np.ones((M, 1)), np.cos(np.outer(phi, n)), -np.sin(np.outer(phi, n))])
    weights = np.full(2 * H + 1, 2.0 / M)
    weights[0] = 1.0 / M
    F = np.ascontiguousarray(weights[:, None] * E.T)
    m_all = np.arange(2 * H + 1)
    out = (phi, E, weights, F, np.cos(np.outer(phi, m_all)), np.sin(np.outer(phi, m_all)))
    for a in out:
        a.flags.writeable = False
    return out


class CondensedHBM(FaultedParts):
    """Harmonic balance of one driveline at one load fraction, condensed on the DMF wind-up.

    Args:
        loads: DrivelineExcitation (merged model with a DMF + engine).
        load: engine load fraction (torque demand) -1..1, below 0 engine braking.
        options: HBMOptions.
        factors: per-cylinder combustion factors s_k (1 fires, 0 misfires every cycle; see
            :mod:`dmf_sim.solvers.hbm.faulted`), None (or all 1) for the healthy engine.

    Attributes:
        symmetric: every cylinder fires alike (the 120 deg shift symmetries hold).
        steps: what the continuation calls on the problem, compiled
            (:class:`~dmf_sim.solvers.hbm.continuation_steps.CondensedSteps`).
        expansion: the solution expanded to the whole driveline
            (:class:`~dmf_sim.solvers.hbm.expansion.DrivelineExpansion`; its methods are also
            the problem's: ``linear_parts_direct``, ``dof_harmonics``, ``element_harmonics``,
            ``torque_harmonics``, ``dof_state``, ``newmark_from``).
    """

    def __init__(self, loads: DrivelineExcitation, load: float, options: HBMOptions | None = None,
                 factors=None):
        self.loads = loads
        self.load = float(load)
        self.options = options or HBMOptions()
        self.model = loads.model
        if self.model.spring is None:
            raise ConfigError(f'driveline {self.model.line.name!r} has no dmf section: '
                              'nothing to condense on')
        self.spring = self.model.spring
        #: the spring has friction or end stops (eq. 8a-8b): the AFT adds their torque N
        self.has_law = not self.spring.smooth_elastic
        self.H = H = int(self.options.n_harmonics)
        if H < 1:
            raise ConfigError(f'n_harmonics={H}: must be >= 1')
        self.M = M = self.options.time_samples()
        if M < 2 * H + 2:
            raise ConfigError(f'n_time={M}: needs at least 2 (n_harmonics + 1) = '
                              f'{2 * H + 2} samples')
        # AFT matrices (:func:`aft_tables`, this problem's own copies)
        self.phi, self.E, weights, self.F, cos_m, sin_m = (a.copy() for a in aft_tables(H, M))
        self.compiled = bool(self.options.compiled)
        m = self.model
        # Static (n = 0) flexibility at the DMF, rigid mode removed: u_0 = K^+ e, h_0 = e.K^+ e.
        self._u0 = solve_static(m, m.e.astype(float))
        self._h0 = float(m.e @ self._u0)
        # Receptances of the flexible chain by its complex modes (computed once per model):
        # with the J-orthonormal flexible modes Phi, the first-order matrix
        # A = [[0, I], [-Lam, -Cr]] = V diag(d) V^-1, and for Om > 0
        #     e.H(Om) f = sum_k (e.Phi V_top)_k (V^-1_bottom Phi^T f)_k / (i Om - d_k).
        # The rigid-body part of H(Om) (-r r^T / (Om^2 r.J r)) does not reach the wind-up
        # (e.r = 0).
        self.modes = FlexibleModes(m)
        d, V, Vinv = self.modes.eig(0.0)
        self._d = d
        self._ell = self.modes.er @ V[:self.modes.nf]                         # (2nf,)
        self._B = self.modes.Phi @ Vinv[:, self.modes.nf:].T                   # (n_dof, 2nf)
        self._a = self._ell * (self.modes.er @ Vinv[:, self.modes.nf:].T)      # residues of h
        self._dOm = np.arange(1, H + 1) * (RPM_TO_RAD_S / 2.0)                 # dOm_n / ds
        self._cache: OrderedDict[float, LinearParts] = OrderedDict()
        # modal load per unit engine coefficient A_n, times the wind-up read-out ell: P_n =
        # A_n sum_k phase_kn T_k (cylinder rows of T, eq. 17), so e.H_n P_n = A_n sum(pole ml_n)
        L = loads
        k = min(L.n_max, H) + 1
        phase = np.zeros((H + 1, L.phase.shape[0]), dtype=complex)
        phase[:k] = L.phase[:, :k].T
        self._modal_load = (phase @ (L.cylinder_dof_vectors @ self._B)) * self._ell
        # static wind-up per unit cylinder mean torque and per unit rear load
        self._static_cyl = float(L.cylinder_dof_vectors.sum(axis=0) @ self._u0)
        self._static_rear = float(L.rear_dof_vector @ self._u0)
        self._primary = self.spring.primary_bounds()           # (lower, upper) wind-up [rad]
        self._eye = np.eye(2 * H + 1)
        # what the compiled kernels read: the AFT matrices and the spring's arrays (the same
        # ones the Newmark kernel reads)
        self._aft_mats = (self.E, weights, cos_m, sin_m)
        self._spring_arrays = (*self.spring.arrays(), int(self.spring.primary_index),
                               self.spring.law_array())
        # the wind-up rate per unit omega / 2 on the AFT samples: w_dot_j = (omega/2) (D x)_j
        nn = np.arange(1, H + 1)
        self._D = np.hstack([np.zeros((M, 1)), nn * self.E[:, H + 1:], -nn * self.E[:, 1:H + 1]])
        self._newton_opts = (float(self.options.tol), int(self.options.max_iter),
                             int(self.options.stall_iter), float(self.options.stall_ratio))
        self.factors = combustion_factors(factors, L.phase.shape[0])
        self.symmetric = is_symmetric(self.factors)
        self.steps = CondensedSteps(self)
        self.expansion = DrivelineExpansion(self)
        if self.factors is not None:
            self._set_up_faults()

    # ---- the expansion to the whole driveline (DrivelineExpansion) ----------------------------
    def linear_parts_direct(self, speed_rpm: float):
        """:meth:`.DrivelineExpansion.linear_parts_direct`."""
        return self.expansion.linear_parts_direct(speed_rpm)

    def dof_harmonics(self, point: HBMPoint) -> np.ndarray:
        """:meth:`.DrivelineExpansion.dof_harmonics`."""
        return self.expansion.dof_harmonics(point)

    def element_harmonics(self, point: HBMPoint) -> np.ndarray:
        """:meth:`.DrivelineExpansion.element_harmonics`."""
        return self.expansion.element_harmonics(point)

    def torque_harmonics(self, point: HBMPoint) -> np.ndarray:
        """:meth:`.DrivelineExpansion.torque_harmonics`."""
        return self.expansion.torque_harmonics(point)

    def dof_state(self, point: HBMPoint, psi: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`.DrivelineExpansion.dof_state`."""
        return self.expansion.dof_state(point, psi)

    def newmark_from(self, point: HBMPoint, *, perturb: np.ndarray | None = None, **fields):
        """:meth:`.DrivelineExpansion.newmark_from`."""
        return self.expansion.newmark_from(point, perturb=perturb, **fields)

    # ---- loads and linear parts -------------------------------------------------------------
    def dof_loads(self, speed_rpm: float) -> np.ndarray:
        """(H+1, n_dof) complex generalized load harmonics P_n [Nm]
        (DrivelineExcitation.dof_harmonics truncated or zero-padded to H)."""
        return fit_harmonics(np.asarray(self.loads.dof_harmonics(speed_rpm, self.load,
                                                                 self.factors),
                                        dtype=complex), self.H)

    def engine_harmonics(self, speed_rpm: float) -> np.ndarray:
        """(H+1,) complex per-cylinder engine coefficients A_n [Nm] (eq. 16-17), truncated or
        zero-padded to H: the one engine query per speed."""
        return fit_harmonics(np.asarray(self.loads.engine.coefficients(speed_rpm, self.load),
                                        dtype=complex), self.H)

    def linear_parts(self, speed_rpm: float) -> LinearParts:
        """h_n, wlin_n and their speed derivatives at ``speed_rpm`` (the most recent
        ``LINEAR_PARTS_CACHE`` speeds are cached: a sweep revisits its grid speeds in the search).

        The load enters only through the engine coefficients: P_n = A_n p_n (p_n: the cylinders'
        phased DOF load vectors, plus the rear load at n = 0), so ``wlin_n = A_n e.H_n p_n`` with
        the modal load of p_n computed once per problem (``_modal_load``)."""
        key = float(speed_rpm)
        lp = self._cache.get(key)
        if lp is not None:
            self._cache.move_to_end(key)
            return lp
        lp = self._linear_parts_many([key])[0]
        self._remember(lp)
        return lp

    def linear_parts_of(self, speeds_rpm: list[float]) -> list[LinearParts]:
        """:meth:`linear_parts` of each speed in turn, those not cached computed in one batch
        first (the points of a traced branch: many arc-length speeds off the grid); the cache
        ends as after the calls one by one."""
        todo = list(dict.fromkeys(s for s in map(float, speeds_rpm) if s not in self._cache))
        fresh = {lp.speed_rpm: lp for lp in self._linear_parts_many(todo)} if todo else {}
        out = []
        for key in map(float, speeds_rpm):
            lp = self._cache.get(key)
            if lp is not None:
                self._cache.move_to_end(key)
            else:
                lp = fresh.get(key)
                if lp is None:          # cached at first, evicted since by this batch
                    lp = self._linear_parts_many([key])[0]
                self._remember(lp)
            out.append(lp)
        return out

    def prepare(self, speeds_rpm) -> None:
        """Compute the linear parts of many speeds at once (a sweep's grid: the per-speed work done
        in one vectorized pass before the continuation asks for them); speeds outside the engine's
        data are left out (asking for them later raises as usual)."""
        lo, hi = self._speed_range()
        todo = [s for s in np.atleast_1d(np.asarray(speeds_rpm, dtype=float)).tolist()
                if s not in self._cache and lo <= s <= hi]
        todo = todo[-LINEAR_PARTS_CACHE:]
        for start in range(0, len(todo), PREPARE_BATCH):
            batch = todo[start:start + PREPARE_BATCH]
            try:
                parts = self._linear_parts_many(batch)
            except OperatingRangeError:        # an engine with narrower data: one by one
                parts = []
                for s in batch:
                    try:
                        parts.extend(self._linear_parts_many([s]))
                    except OperatingRangeError:
                        continue
            for lp in parts:
                self._remember(lp)

    def _remember(self, lp: LinearParts) -> None:
        self._cache[lp.speed_rpm] = lp
        if len(self._cache) > LINEAR_PARTS_CACHE:
            self._cache.popitem(last=False)

    def engine_harmonics_many(self, speeds: np.ndarray) -> np.ndarray:
        """(K, H+1) :meth:`engine_harmonics` at K speeds: one vectorized engine query for a
        batch (an engine with ``coefficients_many``: bitwise the same values), else one query
        per speed (fewer numpy calls for a speed or two)."""
        if len(speeds) < ENGINE_BATCH_MIN:
            return np.stack([self.engine_harmonics(s) for s in speeds.tolist()])
        return fit_harmonics(self.loads.engine_coefficients_many(speeds, self.load), self.H,
                             axis=1)

    def _linear_parts_many(self, speeds: list[float]) -> list[LinearParts]:
        if self.factors is not None:
            return self._linear_parts_faulted(speeds)
        if self.compiled:
            parts = self._linear_parts_compiled(speeds)
            if parts is not None:
                return parts
        if len(speeds) == 1 and self.compiled:
            return [self._linear_parts_one(float(speeds[0]))]
        H = self.H
        K = len(speeds)
        S = np.asarray(speeds, dtype=float)
        omega = S * RPM_TO_RAD_S
        # engine load derivative by a forward difference (backward at the top of the engine's
        # range): the speeds and their shifted twins in one engine query
        ds = np.where(S + self.options.speed_fd_rpm > self._speed_range()[1],
                      -self.options.speed_fd_rpm, self.options.speed_fd_rpm)
        both = self.engine_harmonics_many(np.concatenate([S, S + ds]))          # (2K, H+1)
        A, A2 = both[:K], both[K:]
        dA = (A2 - A) / ds[:, None]
        # static: e.K^+ P_0 (rigid mode removed) and its speed derivative
        rear = self.loads.rear_loads_for(A)
        rear2 = self.loads.rear_loads_for(A2)
        wlin0 = A[:, 0].real * self._static_cyl + rear * self._static_rear
        dwlin0 = dA[:, 0].real * self._static_cyl + (rear2 - rear) / ds * self._static_rear
        ml = self._modal_load[1:]
        h = np.empty((K, H + 1), dtype=complex)
        wlin = np.empty((K, H + 1), dtype=complex)
        dh = np.empty((K, H + 1), dtype=complex)
        dw = np.empty((K, H + 1), dtype=complex)
        if self.compiled:           # modal sums, wlin, dwlin and their real layouts in one call
            wr = np.empty((K, 2 * H + 1))
            dwr = np.empty((K, 2 * H + 1))
            linear_kernels.linear_parts(omega, self._dOm, self._d, ml, self._a, A, dA, wlin0,
                                        dwlin0, self._h0, h, dh, wlin, dw, wr, dwr)
        else:
            self._linear_numpy(omega, A, dA, ml, wlin0, dwlin0, h, dh, wlin, dw)
            wr, dwr = to_real(wlin, H), to_real(dw, H)          # (K, 2H+1) real layouts
        return [LinearParts(speeds[k], float(omega[k]), h[k], wlin[k], dh[k], dw[k],
                            (wr[k], h[k], float(omega[k])), (dwr[k], dh[k]))
                for k in range(K)]

    def _linear_numpy(self, omega, A, dA, ml, wlin0, dwlin0, h, dh, wlin, dw) -> None:
        """h, dh, wlin, dw (K, H+1) <- the linear parts of K speeds ``omega`` [rad/s] in numpy
        (the compiled kernel's reference, :func:`linear_kernels.linear_parts`): engine
        coefficients A, dA (K, H+1), modal load ``ml`` (H, 2nf) of n >= 1, the static
        ``wlin0``, ``dwlin0`` (K,)."""
        H = self.H
        n = np.arange(1, H + 1)
        Om = omega[:, None] * (n / 2.0)                      # Om_n = n omega / 2
        pole = 1.0 / (1j * Om[..., None] - self._d)          # (K, H, 2nf): 1/(i Om_n - d_k)
        unit = (pole * ml).sum(axis=-1)                      # wlin_n per unit A_n
        pole2 = -1j * pole ** 2                              # d/dOm of the pole
        dunit = (pole2 * ml).sum(axis=-1) * self._dOm        # its speed derivative
        h[:, 1:] = pole @ self._a
        dh[:, 1:] = (pole2 @ self._a) * self._dOm
        h[:, 0] = self._h0                                   # static: e.K^+ e
        dh[:, 0] = 0.0
        wlin[:, 0] = wlin0
        dw[:, 0] = dwlin0
        wlin[:, 1:] = A[:, 1:] * unit
        dw[:, 1:] = A[:, 1:] * dunit + dA[:, 1:] * unit

    def _linear_parts_compiled(self, speeds: list[float]) -> list[LinearParts] | None:
        """:meth:`_linear_parts_many` in one kernel call with the engine query compiled
        (:func:`linear_kernels.linear_parts_many_at` on the engine's speed table: the same
        values); None where the engine has no table, a speed lies outside its data (the Python
        path raises as usual) or its grid nodes there are not computed yet (the Python path
        computes them; the table is read anew next time)."""
        args = self._engine_kernel_args()
        if args is None:
            return None
        fd, table, statics, modal = args
        H, K = self.H, len(speeds)
        S = np.array(speeds, dtype=float)
        A, A2, dA, h, dh, wlin, dw = (np.empty((K, H + 1), dtype=complex) for _ in range(7))
        wr = np.empty((K, 2 * H + 1))
        dwr = np.empty((K, 2 * H + 1))
        status = np.empty(K, dtype=np.int64)
        linear_kernels.linear_parts_many_at(S, fd, table, statics, modal, A, A2, dA, h, dh, wlin,
                                            dw, wr, dwr, status)
        if status.any():
            if (status == linear_kernels.ENGINE_NOT_READY).any():
                self.__dict__.pop('_kernel_engine', None)
            return None
        omega = (S * RPM_TO_RAD_S).tolist()
        return [LinearParts(speeds[k], omega[k], h[k], wlin[k], dh[k], dw[k],
                            (wr[k], h[k], float(omega[k])), (dwr[k], dh[k])) for k in range(K)]

    def _linear_parts_one(self, s: float) -> LinearParts:
        """:meth:`_linear_parts_many` of one speed (each arc-length corrector iteration asks for
        a new one): the same operations on scalars, without the batch's array bookkeeping."""
        if self.factors is not None:
            return self._linear_parts_faulted([s])[0]
        H = self.H
        fd = self.options.speed_fd_rpm
        ds = -fd if s + fd > self._speed_range()[1] else fd
        A = self.engine_harmonics(s)
        A2 = self.engine_harmonics(s + ds)
        dA = (A2 - A) / ds
        rear = self.loads.rear_load_for(A)
        rear2 = self.loads.rear_load_for(A2)
        wlin0 = A[0].real * self._static_cyl + rear * self._static_rear
        dwlin0 = dA[0].real * self._static_cyl + (rear2 - rear) / ds * self._static_rear
        omega = s * RPM_TO_RAD_S
        h = np.empty((1, H + 1), dtype=complex)
        wlin = np.empty((1, H + 1), dtype=complex)
        dh = np.empty((1, H + 1), dtype=complex)
        dw = np.empty((1, H + 1), dtype=complex)
        wr = np.empty((1, 2 * H + 1))
        dwr = np.empty((1, 2 * H + 1))
        linear_kernels.linear_parts(np.array([omega]), self._dOm, self._d, self._modal_load[1:],
                                    self._a, A[None], dA[None], np.array([wlin0]),
                                    np.array([dwlin0]), self._h0, h, dh, wlin, dw, wr, dwr)
        return LinearParts(s, omega, h[0], wlin[0], dh[0], dw[0], (wr[0], h[0], omega),
                           (dwr[0], dh[0]))

    def linear_response(self, speeds_rpm) -> np.ndarray:
        """(K, H+1) complex linear wind-up harmonics wlin_n at K speeds at once (same modal
        receptances as :meth:`linear_parts`): the solution wherever the wind-up stays below the
        knee."""
        speeds = np.atleast_1d(np.asarray(speeds_rpm, dtype=float))
        cached = [self._cache.get(s) for s in speeds.tolist()]
        if all(lp is not None for lp in cached):        # prepared (a sweep's grid)
            return np.stack([lp.wlin for lp in cached])
        if self.factors is not None:
            return np.stack([lp.wlin for lp in self._linear_parts_faulted(speeds.tolist())])
        A = np.stack([self.engine_harmonics(s) for s in speeds])                 # (K, H+1)
        Om = np.outer(speeds * (RPM_TO_RAD_S / 2.0), np.arange(1, self.H + 1))  # (K, H)
        pole = 1.0 / (1j * Om[..., None] - self._d)                              # (K, H, 2nf)
        w = np.empty((len(speeds), self.H + 1), dtype=complex)
        rear = self.loads.rear_loads_for(A)
        w[:, 0] = A[:, 0].real * self._static_cyl + rear * self._static_rear
        w[:, 1:] = A[:, 1:] * (pole * self._modal_load[1:]).sum(axis=-1)
        return w

    def time_series_batch(self, C: np.ndarray, n_samples: int = 1024) -> np.ndarray:
        """(K, n_samples) wind-up over one cycle for K complex harmonic vectors (K, H+1)."""
        return synthesize(C, n_samples)

    def static_windup(self, speed_rpm: float, wlin0: float | None = None) -> float:
        """Wind-up [rad] the mean torque alone causes at ``speed_rpm`` (the non-linear static
        equilibrium; the paper's green line is theta minus it). ``wlin0``: the linear static
        wind-up e.K^+ P_0 if already at hand."""
        if wlin0 is None:
            wlin0 = float(self.linear_parts(speed_rpm).wlin[0].real)
        return self.spring.solve_condensed(float(wlin0), self._h0)

    def sharp_resonances(self, speed_range: tuple[float, float],
                         share: float = RESONANCE_SHARE,
                         max_damping_ratio: float = SHARP_DAMPING_RATIO) -> list[dict]:
        """Where a half order n of the excitation meets a lightly damped natural frequency of the
        linear part (primary DMF stiffness), so that the wind-up curves show a spike there.

        For each complex mode d_k (damping ratio < ``max_damping_ratio``) and half order n with
        n omega / 2 = Im d_k inside ``speed_range`` [rpm], the mode's contribution to the
        wind-up's n-th harmonic at that speed is (Q_n . B_k) ell_k / (-Re d_k) (the receptance's
        modal sum, :meth:`linear_parts`); it is reported if it reaches ``share`` of the linear
        wind-up's dynamic amplitude there. Returns dicts: speed_rpm, half_order n, order (n/2),
        frequency_hz, damping_ratio, contribution_rad, share, sorted by speed."""
        lo, hi = speed_range
        out = []
        todo = []                  # (mode k, half order n, speed) inside the range
        for k in np.flatnonzero(self._d.imag > 0):
            d = self._d[k]
            zeta = -d.real / abs(d)
            if zeta >= max_damping_ratio:
                continue
            for n in range(1, self.H + 1):
                s = 2.0 * d.imag / n / RPM_TO_RAD_S
                if lo <= s <= hi:
                    todo.append((k, n, s, zeta))
        if not todo:
            return out
        speeds = [s for _, _, s, _ in todo]
        self.prepare(speeds)                       # their linear parts in one batch
        # P_n . B_k ell_k = A_n (modal load of the phased cylinder vectors)_nk (n >= 1); with
        # faults the sum of the two components (FaultedParts.faulted_modal_loads)
        if self.factors is None:
            A = self.engine_harmonics_many(np.asarray(speeds))
            ML = A[..., None] * self._modal_load
        else:
            ML = self.faulted_modal_loads(np.asarray(speeds))
        for (k, n, s, zeta), ml in zip(todo, ML):
            d = self._d[k]
            peak = abs(ml[n, k] / -d.real)
            dyn = float(np.abs(self.linear_parts(s).wlin[1:]).sum())
            if dyn > 0 and peak >= share * dyn:
                out.append({'speed_rpm': float(s), 'half_order': n, 'order': n / 2,
                            'frequency_hz': float(d.imag / (2 * np.pi)),
                            'damping_ratio': float(zeta), 'contribution_rad': float(peak),
                            'share': float(peak / dyn)})
        return sorted(out, key=lambda r: r['speed_rpm'])

    def _speed_range(self) -> tuple[float, float]:
        rng = getattr(self.loads.engine, 'speed_range_rpm', None)
        return (float(rng[0]), float(rng[1])) if rng is not None else (-np.inf, np.inf)

    def residual_and_jacobians(self, x: np.ndarray, speed_rpm: float):
        """(r, dr/dx, dr/ds) at wind-up harmonics x and speed [rpm]: the continuation problem
        (:meth:`CondensedSteps.residual_and_jacobians`)."""
        return self.steps.residual_and_jacobians(x, speed_rpm)

    def compiled_steps(self) -> CompiledSteps:
        """The compiled continuation steps to hand ``continue_branch`` (``BranchHooks.steps``);
        empty when ``compiled`` is off."""
        return self.steps.compiled_steps()

    def _engine_kernel_args(self):
        """(fd, engine table, statics, modal): what the kernels that query the engine read
        (:func:`linear_kernels.linear_parts_many_at`,
        :func:`continuation_kernels.residual_jacobians_at`), or None for an engine without
        ``speed_table`` (then the linear parts are computed in Python)."""
        args = self.__dict__.get('_kernel_engine')
        if args is None:
            table = getattr(self.loads.engine, 'speed_table', None)
            if table is None or self.factors is not None:     # faulted: the Python path
                self._kernel_engine = args = ()
            else:
                self._kernel_engine = args = (
                    float(self.options.speed_fd_rpm), table(self.load),
                    (self._static_cyl, self._static_rear, float(self.loads.rear_load_factor)),
                    (self._dOm, self._d, np.ascontiguousarray(self._modal_load[1:]), self._a,
                     float(self._h0)))
        return args or None

    # ---- AFT: non-linear torque harmonics and their Jacobian ---------------------------------
    def windup_samples(self, x: np.ndarray) -> np.ndarray:
        """w(psi_j) on the M AFT samples of one cycle [rad]."""
        return self.E @ x

    def nonlinear_harmonics(self, x: np.ndarray, jacobian: bool = False,
                            speed_rpm: float | None = None):
        """G = harmonics of the non-linear DMF torque on the real layout [Nm] (and dG/dx
        [Nm/rad], None if zero): ``g(w(psi))``, plus with friction or end stops
        ``N(w, w_dot, Omega)`` (eq. 8a-8b) at engine speed ``speed_rpm`` (then required).

        AFT: w_j = E x -> g(w_j) (+ N) -> G = F g. Jacobian dG/dx = F diag(g'(w_j)) E, summed
        over the samples where g' != 0 only (the others contribute nothing); with N also
        F diag(dN/dw_dot) dw_dot/dx.
        """
        if not self.compiled:
            return self.nonlinear_harmonics_reference(x, jacobian, speed_rpm)
        G, dG, count = kernels.harmonics_py(np.ascontiguousarray(x, dtype=float),
                                            self._law_omega(speed_rpm), self._aft_mats,
                                            self._spring_arrays, jacobian)
        n = 2 * self.H + 1
        if not jacobian:
            return G[:n]
        return G[:n], (dG if count else None)

    def _law_omega(self, speed_rpm: float | None) -> float:
        """Engine speed [rad/s] the friction law reads (0.0 for an elastic spring, where it
        reads none); a spring with friction or stops needs the speed."""
        if speed_rpm is None:
            if self.has_law:
                raise ValueError('the non-linear torque of a spring with friction or end stops '
                                 'depends on the engine speed: give speed_rpm')
            return 0.0
        return float(speed_rpm) * RPM_TO_RAD_S

    def nonlinear_harmonics_reference(self, x: np.ndarray, jacobian: bool = False,
                                      speed_rpm: float | None = None):
        """:meth:`nonlinear_harmonics` in readable numpy (the compiled kernel's reference); the
        law N through the spring's own :meth:`~dmf_sim.physics.spring.PiecewiseLinearSpring.
        law_torque` and its derivatives by :meth:`law_tangents`."""
        G, dG, _ = self._nonlinear_reference(x, jacobian, speed_rpm)
        return (G, dG) if jacobian else G

    def law_tangents(self, w: np.ndarray, w_dot: np.ndarray, omega: float):
        """(N, dN/dw, dN/dw_dot, dN/domega) [Nm, Nm/rad, Nms/rad, Nm s/rad] of the friction and
        end-stop law at wind-ups ``w``, rates ``w_dot`` and engine speed ``omega`` [rad/s]: N by
        the spring's ``law_torque``; the derivatives of the compiled law
        (:func:`dmf_sim.solvers.spring_kernels.law_parts`), sample by sample, and the omega
        derivative at fixed harmonics (w_dot scales with omega, the amplitude with omega^2)."""
        law = self._spring_arrays[4]
        amp = float(self.spring.friction.amplitude(omega)) if self.spring.friction else 0.0
        N = np.asarray(self.spring.law_torque(w, w_dot, omega), dtype=float)
        parts = np.array([law_parts(a, b, amp, law) for a, b in zip(w.tolist(),
                                                                        w_dot.tolist())])
        parts = parts.reshape(-1, 5)
        dw = parts[:, 3]
        dv = parts[:, 2] + parts[:, 4]
        damp = 2.0 * law[1] * omega
        dom = dv * (w_dot / omega if omega else 0.0) + damp * np.tanh(w_dot / law[2])
        return N, dw, dv, dom

    def _nonlinear_reference(self, x: np.ndarray, jacobian: bool, speed_rpm: float | None):
        """(G, dG/dx or None, dG/domega or None) in numpy: the reference of the compiled
        :func:`kernels.nonlinear`."""
        omega = self._law_omega(speed_rpm)
        w = self.E @ x
        sp = self.spring
        lo, hi = self._primary
        if not self.has_law:
            if w.max() <= hi and w.min() >= lo:      # primary region only (knees tie to it)
                G = np.zeros(2 * self.H + 1)
                return G, None, None
            idx = np.flatnonzero((w > hi) | (w < lo))
            Fa = self.F[:, idx]
            g, dg = sp.extra_torque_and_stiffness(w[idx])
            G = Fa @ g
            return G, ((Fa * dg) @ self.E[idx] if jacobian else None), None
        wd = 0.5 * omega * (self._D @ x)
        g, dg = sp.extra_torque_and_stiffness(w)
        N, dNw, dNv, dNo = self.law_tangents(w, wd, omega)
        G = self.F @ (g + N)
        Gs = self.F @ dNo
        if not jacobian:
            return G, None, Gs
        dG = (self.F * (dg + dNw)) @ self.E + (self.F * dNv) @ (0.5 * omega * self._D)
        return G, dG, Gs

    # ---- residual (eq. 15) -------------------------------------------------------------------
    def residual(self, x: np.ndarray, lp: LinearParts) -> np.ndarray:
        """r = w - wlin + h (g(w) + N) on the real layout [rad]."""
        G = self.nonlinear_harmonics(x, speed_rpm=lp.speed_rpm)
        return x - to_real(lp.wlin, self.H) + times_h(lp.h, G, self.H)

    def residual_and_jacobian(self, x: np.ndarray, lp: LinearParts):
        """(r, dr/dx) with the analytic AFT Jacobian dr/dx = I + h dG/dx."""
        if self.compiled:
            r, Jx, _ = kernels.residual_jacobian_py(np.ascontiguousarray(x, dtype=float),
                                                    lp.lin, self._aft_mats,
                                                    self._spring_arrays, True)
            return r, Jx
        return self.residual_and_jacobian_reference(x, lp)

    def residual_and_jacobian_reference(self, x: np.ndarray, lp: LinearParts):
        """:meth:`residual_and_jacobian` in readable numpy (the compiled kernel's reference)."""
        G, dG = self.nonlinear_harmonics_reference(x, jacobian=True, speed_rpm=lp.speed_rpm)
        if dG is None:                          # no sample beyond a knee: the linear problem
            return x - to_real(lp.wlin, self.H), self._eye.copy()
        r = x - to_real(lp.wlin, self.H) + times_h(lp.h, G, self.H)
        Jx = times_h(lp.h, dG, self.H)
        Jx[np.diag_indices_from(Jx)] += 1.0
        return r, Jx

    def residual_speed_derivative(self, x: np.ndarray, lp: LinearParts) -> np.ndarray:
        """dr/ds [rad/rpm] at fixed wind-up harmonics: -dwlin/ds + dh/ds G, plus with friction
        or end stops h dG/ds (w_dot scales with the speed, the friction amplitude with its
        square)."""
        if not self.has_law:
            G = self.nonlinear_harmonics(x)
            return -to_real(lp.dwlin_ds, self.H) + times_h(lp.dh_ds, G, self.H)
        G, _, Gs = self._nonlinear_reference(x, False, lp.speed_rpm)
        return (-to_real(lp.dwlin_ds, self.H) + times_h(lp.dh_ds, G, self.H)
                + RPM_TO_RAD_S * times_h(lp.h, Gs, self.H))

    # ---- solving at one speed ------------------------------------------------------------------
    def linear_solution(self, speed_rpm: float) -> np.ndarray:
        """x of the linear (primary stiffness, alpha = 0) response, the usual initial guess."""
        return to_real(self.linear_parts(speed_rpm).wlin, self.H)

    def solve(self, speed_rpm: float, x0: np.ndarray | None = None) -> HBMPoint:
        """Periodic steady state at ``speed_rpm`` by damped Newton from ``x0`` (default: the
        static mean plus the linear dynamic response)."""
        lp = self.linear_parts(speed_rpm)
        if x0 is None:
            x0 = self.linear_solution(speed_rpm)
            x0[0] = self.spring.solve_condensed(float(lp.wlin[0].real), float(lp.h[0].real))
        try:
            x, it, res = self.newton(x0, lp)
        except ConvergenceError:
            if not (self.compiled and self.spring.has_friction):
                raise
            x, it, res = self.newton_regularized(x0, lp)
        return self.make_point(speed_rpm, x, res, it)

    def newton_regularized(self, x0: np.ndarray, lp: LinearParts
                           ) -> tuple[np.ndarray, int, float]:
        """Newton by a homotopy in the friction's regularization (HBM-specific, doc/theory.md
        §7): where the friction torque is large against the motion the residual is as stiff as
        T_f / omega_reg and Newton from the linear guess stalls; solved first with omega_reg
        times each factor of :data:`REGULARIZATION_HOMOTOPY` (a softer law), each solution the
        next one's start, ending on the spring's own omega_reg. Returns (x, iterations in all,
        max|r|); raises ConvergenceError where a stage fails."""
        base = self._spring_arrays
        x = np.array(x0, dtype=float)
        out = np.empty_like(x)
        total = 0
        for factor in REGULARIZATION_HOMOTOPY:
            law = base[4].copy()
            law[2] *= factor
            status, it, nr = kernels.newton(x, lp.lin, self._aft_mats, (*base[:4], law),
                                            self._newton_opts, out)
            total += it
            if status != kernels.CONVERGED:
                raise ConvergenceError(f'HBM Newton: residual {nr:.2e} rad with the friction '
                                       f'regularization x{factor:g} at {lp.speed_rpm:.1f} rpm')
            x = out.copy()
        return x, total, nr

    def newton(self, x0: np.ndarray, lp: LinearParts) -> tuple[np.ndarray, int, float]:
        """Damped Newton on r(x) = 0 at fixed speed; returns (x, iterations, max|r|)."""
        if not self.compiled:
            return self.newton_reference(x0, lp)
        x0 = np.array(x0, dtype=float)
        x = np.empty_like(x0)
        status, it, nr = kernels.newton(x0, lp.lin, self._aft_mats, self._spring_arrays,
                                        self._newton_opts, x)
        if status == kernels.CONVERGED:
            return x, it, nr
        if status == kernels.STALLED:
            raise ConvergenceError(f'HBM Newton: stalled at residual {nr:.2e} rad after '
                                   f'{it} iterations at {lp.speed_rpm:.1f} rpm')
        if status == kernels.SINGULAR:
            raise np.linalg.LinAlgError('singular matrix')
        raise ConvergenceError(f'HBM Newton: residual {nr:.2e} rad after '
                               f'{self.options.max_iter} iterations '
                               f'at {lp.speed_rpm:.1f} rpm')

    def newton_reference(self, x0: np.ndarray, lp: LinearParts
                         ) -> tuple[np.ndarray, int, float]:
        """:meth:`newton` in readable numpy (the compiled kernel's reference)."""
        x = np.array(x0, dtype=float)
        r, Jx = self.residual_and_jacobian_reference(x, lp)
        nr = np.abs(r).max()
        history = [nr]
        opt = self.options
        for it in range(1, opt.max_iter + 1):
            if nr <= opt.tol:
                return x, it - 1, nr
            stalled = (len(history) > opt.stall_iter
                       and nr > opt.stall_ratio * history[-1 - opt.stall_iter])
            if stalled:
                raise ConvergenceError(f'HBM Newton: stalled at residual {nr:.2e} rad after '
                                       f'{it - 1} iterations at {lp.speed_rpm:.1f} rpm')
            dx = solve_small(Jx, -r)
            lam = 1.0
            while True:   # backtracking on the max norm (the residual is only piecewise smooth)
                xn = x + lam * dx
                rn, Jn = self.residual_and_jacobian_reference(xn, lp)
                nn = np.abs(rn).max()
                if nn < nr or lam < 1e-3:
                    break
                lam *= 0.5
            x, r, Jx, nr = xn, rn, Jn, nn
            history.append(nr)
        if nr <= self.options.tol:
            return x, self.options.max_iter, nr
        raise ConvergenceError(f'HBM Newton: residual {nr:.2e} rad after '
                               f'{self.options.max_iter} iterations '
                               f'at {lp.speed_rpm:.1f} rpm')

    def make_point(self, speed_rpm: float, x: np.ndarray, residual: float = 0.0,
                   iterations: int = 0, samples: np.ndarray | None = None,
                   wlin0: float | None = None, c: np.ndarray | None = None) -> HBMPoint:
        """Wrap a solution vector with its Fig. 13 summary (``samples``: w over the cycle,
        ``wlin0``: the linear static wind-up, ``c``: x as complex harmonics, if at hand; ``c``
        becomes the point's ``windup_orders``)."""
        if c is None:
            c = to_complex(x, self.H)
        w = synthesize(c, 1024) if samples is None else samples
        summ = summarize_orders(c, w, self.spring.theta, self.static_windup(speed_rpm, wlin0))
        return HBMPoint(float(speed_rpm), np.array(x, dtype=float), c, summ, float(residual),
                        int(iterations))

    def make_points(self, speeds_rpm: np.ndarray, C: np.ndarray, samples: np.ndarray,
                    wlin0: np.ndarray, X: np.ndarray | None = None) -> list[HBMPoint]:
        """:meth:`make_point` of K solutions at once (a sweep's linear stretch, or the points of
        a traced branch): complex harmonics ``C`` (K, H+1) at ``speeds_rpm`` (K,), ``samples``
        (K, N) each one's wind-up over the cycle, ``wlin0`` (K,) the linear static wind-ups,
        ``X`` (K, 2H+1) the same solutions as real unknowns if at hand; residual and iterations
        0. The same values as K calls of :meth:`make_point`."""
        C = np.array(C, dtype=complex)
        X = to_real(C, self.H) if X is None else np.array(X, dtype=float)
        static = [self.spring.solve_condensed(w0, self._h0)
                  for w0 in np.asarray(wlin0, dtype=float).tolist()]
        summaries = summarize_rows(C, samples, self.spring.theta, static)
        return [HBMPoint(s, X[k], C[k], summ, 0.0, 0) for k, (s, summ) in enumerate(
            zip(np.asarray(speeds_rpm, dtype=float).tolist(), summaries))]

    # ---- the wind-up over the cycle ----------------------------------------------------------
    def time_series(self, x: np.ndarray, n_samples: int = 512) -> np.ndarray:
        """w(psi) on ``n_samples`` uniform points of one cycle (psi = 0 .. 4 pi) [rad]."""
        return synthesize(to_complex(x, self.H), n_samples)
