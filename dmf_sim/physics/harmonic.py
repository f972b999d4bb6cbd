"""Linear harmonic response per half-order: the industry's classic evaluation.

For a harmonic load ``Re(P exp(i Omega t))`` with Omega = n/2 * omega (n the half-order index,
omega the crank speed [rad/s]) the complex DOF response is

    q_hat = H(Omega) P,      H(Omega) = (K - Omega^2 J + i Omega C)^-1         (from eq. 5)

Element angles are ``T q_hat``, spring torques ``-(k + i Omega c) D q_hat``. For Omega = 0 the
free-free chain is singular; the static problem is solved with the rigid-body component of the
response set to zero (a balanced load is required: ``rigid_mode . P = 0``).

``Receptance`` gives H between chosen DOFs over many frequencies — the linear core reused by
the harmonic balance solver.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.physics.model import ReducedModel

__all__ = ['dynamic_stiffness', 'solve_static', 'solve_harmonic', 'HarmonicResponse',
           'harmonic_response', 'receptance']


def dynamic_stiffness(model: ReducedModel, Omega: float, K: np.ndarray | None = None
                      ) -> np.ndarray:
    """Z(Omega) = K - Omega^2 J + i Omega C  [Nm/rad] (complex, n x n)."""
    K = model.K if K is None else K
    return K - Omega**2 * model.J + 1j * Omega * model.C


def solve_static(model: ReducedModel, P: np.ndarray, K: np.ndarray | None = None) -> np.ndarray:
    """Static DOF deflection for a (balanced) load P, rigid-body part removed.

    Solved as a bordered system [K  Jr; (Jr)^T 0] so the solution is J-orthogonal to the rigid
    mode r (zero mean momentum: the deviation from the mean rotation).
    """
    K = model.K if K is None else K
    r = model.rigid_mode
    P = np.asarray(P)
    if r is None:
        return np.linalg.solve(K, P)
    Jr = model.J @ r
    imbalance = abs(r @ P) / max(np.abs(P).max() * np.abs(r).sum(), 1e-300)
    if imbalance > 1e-8:
        raise ConfigError('static load is not balanced (it would accelerate the free driveline); '
                         'add the rear load')
    n = model.n_dof
    A = np.zeros((n + 1, n + 1), dtype=np.result_type(K, P))
    A[:n, :n] = K
    A[:n, n] = Jr
    A[n, :n] = Jr
    b = np.zeros(n + 1, dtype=A.dtype)
    b[:n] = P
    return np.linalg.solve(A, b)[:n]


def solve_harmonic(model: ReducedModel, Omega: float, P: np.ndarray,
                   K: np.ndarray | None = None) -> np.ndarray:
    """Complex DOF amplitudes for load amplitude(s) P (n,) or (n, k) at Omega [rad/s]."""
    if Omega == 0.0:
        return solve_static(model, P, K)
    return np.linalg.solve(dynamic_stiffness(model, Omega, K), P)


@dataclass(frozen=True)
class HarmonicResponse:
    """Complex response to one half-order over engine speeds.

    Attributes:
        speeds_rpm: (s,) engine speeds.
        half_order: n; the excitation frequency is n/2 times the crank speed.
        q: (s, n_dof) complex DOF amplitudes [rad].
        angles: (s, m) complex element angle amplitudes [rad].
        spring_torques: (s, m) complex transmitted torque amplitudes [Nm] (0 at rigid links).
        windup: (s,) complex DMF wind-up amplitude [rad] (zeros without DMF).
    """

    speeds_rpm: np.ndarray
    half_order: int
    q: np.ndarray
    angles: np.ndarray
    spring_torques: np.ndarray
    windup: np.ndarray


def harmonic_response(model: ReducedModel, speeds_rpm, half_order: int, element_loads,
                      K: np.ndarray | None = None) -> HarmonicResponse:
    """Steady-state response to the half-order harmonic load ``Re(p exp(i n/2 omega t))``.

    ``element_loads`` is a complex (m,) vector of element torque amplitudes [Nm], or a callable
    ``f(speed_rpm) -> (m,)`` when the load depends on speed.
    """
    speeds = np.atleast_1d(np.asarray(speeds_rpm, dtype=float))
    qs = []
    for s in speeds:
        p = element_loads(s) if callable(element_loads) else element_loads
        Omega = half_order / 2.0 * s * RPM_TO_RAD_S
        qs.append(solve_harmonic(model, Omega,
                                 model.element_vector(np.asarray(p, dtype=complex)), K))
    q = np.array(qs)
    Omegas = half_order / 2.0 * speeds * RPM_TO_RAD_S
    dphi = q @ model.D.T
    torques = np.zeros((len(speeds), model.n_elements), dtype=complex)
    torques[:, model.spring_elements] = (-(model.spring_k + 1j * Omegas[:, None] * model.spring_c)
                                         * dphi)
    return HarmonicResponse(speeds_rpm=speeds, half_order=half_order, q=q,
                            angles=q @ model.T.T, spring_torques=torques, windup=q @ model.e)


def receptance(model: ReducedModel, Omegas, a: np.ndarray, b: np.ndarray,
               K: np.ndarray | None = None) -> np.ndarray:
    """Receptance a^T H(Omega) b [rad/Nm] between generalized directions a and b (DOF vectors),
    for each Omega [rad/s]. With a = b = e (the DMF wind-up row) this is the condensed
    flexibility the harmonic balance solver uses."""
    Omegas = np.atleast_1d(np.asarray(Omegas, dtype=float))
    return np.array([a @ solve_harmonic(model, W, b.astype(complex), K) for W in Omegas])
