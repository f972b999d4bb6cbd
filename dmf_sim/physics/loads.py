"""The engine's excitation of the driveline: cylinder torques, rear load, d'Alembert load, static
equilibrium (:class:`DrivelineExcitation`; its old name ``DrivelineLoads`` still works).

Cylinder k carries (eq. 16-17)

    P_k(t) = Re( sum_n A_n exp(i n/2 (psi - beta_k)) ),    psi = crank angle [rad]

so the complex element-load amplitude of half-order n is ``A_n exp(-i n beta_k / 2)``. The rear
element carries minus the engine mean torque times its cumulative gear ratio (paper, "Rear
driveline"), which balances the mean load so the mean speed stays fixed.

With faults (dmf_sim.physics.faults) the cylinders no longer fire alike: cylinder k fires with a
combustion factor s_k (1 healthy, 0 misfire, the factor of a weak cylinder) and carries

    A_kn = A^m_n + s_k (A^f_n - A^m_n),    phased exp(-i n beta_k / 2) as eq. (17)

with A^f the engine's coefficients at (speed, load) and A^m those of a cylinder that does not
fire at that operating point (compression without combustion,
:meth:`~dmf_sim.physics.engine.Engine.motored_coefficients`); the rear load balances the faulted
mean ``-sum_k Re(A_k0) R_rear / R_k``. :meth:`DrivelineExcitation.faulted_cylinder_coefficients` is
that one formula; Newmark, the harmonic balance and the prediction call it.

When the speed changes, the reference rotation psi(t)/R_i accelerates: the vibratory equations get
the d'Alembert load ``-j_i domega/dt / R_i`` on each element, balanced at the rear element by
``+R_rear J_eq domega/dt`` (the vehicle resistance that the speed setpoint implies).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dmf_sim.core.deprecation import renamed
from dmf_sim.core.errors import ConfigError
from dmf_sim.physics.harmonic import solve_static
from dmf_sim.physics.model import ReducedModel

__all__ = ['DrivelineExcitation', 'ConstantTorque', 'StaticState']


@dataclass
class DrivelineExcitation:
    """The excitation of one driveline model by one engine: the generalized loads on its DOFs.

    Args:
        model: the merged driveline.
        engine: an ``EngineExcitation`` (dmf_sim.physics.engine): ``coefficients(speed_rpm,
        load)``.
    """

    model: ReducedModel
    engine: object

    def __post_init__(self) -> None:
        line = self.model.line
        if not line.cylinders:
            raise ConfigError(f'driveline {line.name!r}: field \'cylinders\' is empty; '
                              'no engine load can act')
        n_cyl_engine = int(getattr(self.engine, 'n_cylinders', len(line.cylinders)))
        if n_cyl_engine != len(line.cylinders):
            raise ConfigError(f'engine has {n_cyl_engine} cylinders but driveline field '
                             f'\'cylinders\' lists {len(line.cylinders)}')
        self.cylinder_elements = np.array([line.index(c) for c in line.cylinders], dtype=int)
        self.beta = np.radians(np.asarray(line.firing_phases_deg, dtype=float))
        self.rear_element = line.index(line.rear_load_element)
        self.n_max = int(self.engine.n_max)
        n = np.arange(self.n_max + 1)
        self.phase = np.exp(-1j * np.outer(self.beta, n) / 2.0)         # (n_cyl, N+1), eq. (17)
        R = self.model.R
        # rear load = -R_rear * sum_k (mean torque of cylinder k reflected to element 1)
        self._rear_factor = R[self.rear_element] / R[self.cylinder_elements]
        self._rear_factor_sum = float(np.sum(self._rear_factor))
        # d'Alembert load per unit reference acceleration, element level [Nm per rad/s^2]
        m = self.model.n_elements
        dal = -np.array([el.inertia for el in line.elements]) / R
        dal[self.rear_element] += R[self.rear_element] * self.model.equivalent_inertia
        self.dalembert_elements = dal
        self.dalembert_dof = self.model.element_vector(dal)
        # generalized load of a unit torque on each cylinder / the rear element
        self.cylinder_dof_vectors = self.model.T[self.cylinder_elements]      # (n_cyl, n_dof)
        self.rear_dof_vector = self.model.T[self.rear_element]
        self._m = m

    # ---- frequency domain ------------------------------------------------------------------
    def engine_coefficients_many(self, speeds_rpm, load: float) -> np.ndarray:
        """(K, N+1) engine coefficients A_n at K speeds: one vectorized query where the engine
        has ``coefficients_many`` (bitwise the same values), else one query per speed."""
        speeds = np.asarray(speeds_rpm, dtype=float).reshape(-1)
        many = getattr(self.engine, 'coefficients_many', None)
        if many is not None:
            return np.asarray(many(speeds, load), dtype=complex)
        return np.array([self.engine.coefficients(s, load) for s in speeds.tolist()],
                        dtype=complex).reshape(len(speeds), -1)

    def cylinder_coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        """(n_cyl, N+1) complex amplitudes A_n exp(-i n beta_k/2) [Nm] of each cylinder's
        torque."""
        return self.cylinder_coefficients_for(self.engine.coefficients(speed_rpm, load))

    def cylinder_coefficients_for(self, A: np.ndarray) -> np.ndarray:
        """Eq. (17) phasing of the engine coefficients A_n (n = 0..N) onto every cylinder:
        (n_cyl, N+1); for K sets of coefficients (K, N+1): (K, n_cyl, N+1)."""
        return np.asarray(A, dtype=complex)[..., None, :] * self.phase

    # ---- faults: per-cylinder combustion factors --------------------------------------------
    @property
    def has_motored(self) -> bool:
        """Whether the engine has a model of a cylinder that does not fire (misfire and weak
        cylinder faults need it)."""
        return bool(getattr(self.engine, 'has_motored', False))

    def motored_coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        """A^m_n [Nm]: a cylinder that does not fire at (speed, load); one-line ConfigError for
        an engine without that model."""
        if not self.has_motored:
            raise ConfigError(f'engine {getattr(self.engine, "name", "")!r} has no model of a '
                              'cylinder that does not fire: misfire and weak_cylinder faults '
                              'need a pressure-model engine YAML such as engine_d13')
        return self.engine.motored_coefficients(speed_rpm, load)

    def faulted_cylinder_coefficients(self, A_fired: np.ndarray, A_motored: np.ndarray,
                                      factors) -> np.ndarray:
        """Eq. (17) with per-cylinder combustion factors: ``(A^m + s_k (A^f - A^m))
        exp(-i n beta_k / 2)`` [Nm], (n_cyl, N+1); for K sets of coefficients (K, N+1): (K, n_cyl,
        N+1). ``factors``: s_k per cylinder (n_cyl,), 1 = healthy, 0 = misfire. A pure function:
        every solver's faulted excitation is this."""
        Af = np.asarray(A_fired, dtype=complex)
        Am = np.asarray(A_motored, dtype=complex)
        s = np.asarray(factors, dtype=float)
        return (Am[..., None, :] + s[:, None] * (Af - Am)[..., None, :]) * self.phase

    def faulted_rear_load(self, A_fired: np.ndarray, A_motored: np.ndarray, factors):
        """Rear element torque [Nm] balancing the faulted engine's mean: ``-sum_k (Re A^m_0 +
        s_k Re(A^f_0 - A^m_0)) R_rear / R_k``; a float, or (K,) for K sets of coefficients."""
        Af = np.asarray(A_fired, dtype=complex)
        Am = np.asarray(A_motored, dtype=complex)
        s = np.asarray(factors, dtype=float)
        a0 = np.real(Am[..., :1]) + s * np.real(Af[..., :1] - Am[..., :1])     # (..., n_cyl)
        out = -(a0 @ self._rear_factor)
        return float(out) if np.ndim(out) == 0 else out

    def excitation(self, speed_rpm: float, load: float, factors=None
                   ) -> tuple[np.ndarray, float]:
        """(per-cylinder coefficients (n_cyl, N+1), rear load [Nm]) at (speed, load) with
        combustion ``factors`` (None or all ones: the healthy engine, one engine query)."""
        A = self.engine.coefficients(speed_rpm, load)
        if factors is None or np.all(np.asarray(factors) == 1.0):
            return self.cylinder_coefficients_for(A), self.rear_load_for(A)
        Am = self.motored_coefficients(speed_rpm, load)
        return (self.faulted_cylinder_coefficients(A, Am, factors),
                self.faulted_rear_load(A, Am, factors))

    def mean_engine_torque(self, speed_rpm: float, load: float) -> float:
        """Sum of the cylinders' mean torques [Nm] (reflected to element 1)."""
        A0 = float(np.real(self.engine.coefficients(speed_rpm, load)[0]))
        return A0 * float(np.sum(1.0 / self.model.R[self.cylinder_elements]))

    def rear_load(self, speed_rpm: float, load: float) -> float:
        """Rear element torque [Nm]: minus engine mean torque times cumulative gear ratio."""
        return self.rear_load_for(self.engine.coefficients(speed_rpm, load))

    def rear_load_for(self, A: np.ndarray) -> float:
        """Rear element torque [Nm] for engine coefficients A_n (only the mean A_0 counts)."""
        return -float(np.real(A[0])) * self._rear_factor_sum

    @property
    def rear_load_factor(self) -> float:
        """Rear element torque per unit engine mean coefficient [-]: rear_load_for(A) is
        -Re(A_0) times this."""
        return self._rear_factor_sum

    def rear_loads_for(self, A: np.ndarray) -> np.ndarray:
        """(K,) :meth:`rear_load_for` of K sets of coefficients (K, N+1) at once (the same
        operations, so the same values)."""
        return -np.real(A[:, 0]) * self._rear_factor_sum

    def element_harmonics(self, speed_rpm: float, load: float, factors=None) -> np.ndarray:
        """(N+1, m) complex element-load amplitudes per half-order n [Nm]; row 0 is the mean.
        ``factors``: per-cylinder combustion factors (:meth:`excitation`)."""
        P = np.zeros((self.n_max + 1, self._m), dtype=complex)
        B, rear = self.excitation(speed_rpm, load, factors)
        P[:, self.cylinder_elements] = B.T
        P[0, self.rear_element] += rear
        return P

    def dof_harmonics(self, speed_rpm: float, load: float, factors=None) -> np.ndarray:
        """(N+1, n_dof) complex generalized load amplitudes per half-order n [Nm]: the element
        loads of :meth:`element_harmonics` through ``T^T`` (only the cylinders' and the rear
        element's rows of T carry load)."""
        B, rear = self.excitation(speed_rpm, load, factors)
        P = B.T @ self.cylinder_dof_vectors
        P[0] += rear * self.rear_dof_vector
        return P

    # ---- time domain -----------------------------------------------------------------------
    def element_loads(self, psi, speed_rpm: float, load: float, factors=None) -> np.ndarray:
        """Element torques [Nm] at crank angles psi (array (s,) -> (s, m)), constant speed/load
        (and combustion factors)."""
        psi = np.atleast_1d(np.asarray(psi, dtype=float))
        P = self.element_harmonics(speed_rpm, load, factors)
        n = np.arange(self.n_max + 1)
        return np.real(np.exp(1j * np.outer(psi, n) / 2.0) @ P)

    # ---- statics ---------------------------------------------------------------------------
    def static_state(self, speed_rpm: float, load: float, factors=None) -> 'StaticState':
        """Static equilibrium under the mean loads (of the engine with combustion ``factors``),
        with the non-linear DMF spring.

        Solves K q + e g(e q) = P_0 (rigid-body part zero). Condensed on the wind-up: with
        q_lin = K^+ P_0 and u = K^+ e, w + (e.u) g(w) = e.q_lin, solved exactly on the
        piecewise-linear g; then q = q_lin - u g(w).
        """
        m = self.model
        P0 = np.real(self.dof_harmonics(speed_rpm, load, factors)[0])
        q_lin = solve_static(m, P0)
        if m.spring is None:
            return StaticState(q=q_lin, windup=0.0, dmf_torque=0.0, region='linear')
        u = solve_static(m, m.e)
        h = float(m.e @ u)
        w = m.spring.solve_condensed(float(m.e @ q_lin), h)
        q = q_lin - u * float(m.spring.extra_torque(w))
        return StaticState(q=q, windup=w, dmf_torque=float(m.spring.torque(w)),
                           region=m.spring.region(w))


@dataclass(frozen=True)
class ConstantTorque:
    """An engine excitation that is only a constant mean torque (no vibration): the engine's
    ``torque_nm`` [Nm] times the load fraction, shared equally by ``n_cylinders`` cylinders."""

    torque_nm: float
    n_cylinders: int
    n_max: int = 0

    def coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        return np.array([self.torque_nm * load / self.n_cylinders], dtype=complex)


@dataclass(frozen=True)
class StaticState:
    """Static equilibrium: DOF deflection q [rad], DMF wind-up [rad] and torque [Nm], region."""

    q: np.ndarray
    windup: float
    dmf_torque: float
    region: str


__getattr__ = renamed(__name__, {'DrivelineLoads': 'DrivelineExcitation'}, globals())
