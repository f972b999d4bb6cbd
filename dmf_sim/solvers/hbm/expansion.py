"""Expansion of a condensed harmonic balance solution to the whole driveline (paper eq. 10-13):
every DOF's and element's harmonics, the torque transmitted into every element, the DOF state at
a crank angle, and the Newmark cross-check started on it. A collaborator of
:class:`dmf_sim.solvers.hbm.condensed.CondensedHBM` (its ``expansion``) that reads of the
problem only what :class:`ExpansionHost` lists: the condensed solver itself needs none of it,
only the wind-up.
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.physics.harmonic import solve_harmonic, solve_static
from dmf_sim.solvers.hbm.point import HBMPoint
from dmf_sim.solvers.hbm.unknowns import to_complex

__all__ = ['ExpansionHost', 'DrivelineExpansion']


@runtime_checkable
class ExpansionHost(Protocol):
    """What :class:`DrivelineExpansion` reads of the condensed problem it expands.

    1. ``model`` (the reduced driveline: ``J``, ``C``, ``K``, ``e``, its elements), ``loads``
       (the :class:`~dmf_sim.physics.loads.DrivelineExcitation`), ``load`` (the load fraction)
       and ``factors`` (per-cylinder combustion factors, None: healthy) are the problem's
       inputs, never changed.
    2. ``H`` is the number of harmonics of the 720 deg base frequency, and ``_u0`` the static
       flexibility K^+ e at the DMF (rigid mode removed).
    3. ``dof_loads(speed_rpm)`` gives the generalized loads P_n on every DOF (H+1, n_dof).
    4. ``nonlinear_harmonics(x, jacobian=False, speed_rpm=None)`` gives the harmonics g_n of
       the spring's non-linear torque (extra torque, plus friction and end stops at engine
       speed ``speed_rpm``) of a wind-up solution x (and their Jacobian, or None).
    """

    model: object
    loads: object
    load: float
    factors: object
    H: int
    _u0: np.ndarray

    def dof_loads(self, speed_rpm: float) -> np.ndarray: ...

    def nonlinear_harmonics(self, x: np.ndarray, jacobian: bool = False,
                            speed_rpm: float | None = None): ...


class DrivelineExpansion:
    """Every element's motion and torque from a wind-up solution, by direct solves of the whole
    chain (the condensed solver's modal receptances are its fast path; these are the check).

    Args:
        host: the condensed problem (an :class:`ExpansionHost`), read at every call.
    """

    def __init__(self, host: ExpansionHost) -> None:
        self.host = host

    def linear_parts_direct(self, speed_rpm: float
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(h, wlin, u, v) by direct complex solves Z_n [u_n, v_n] = [e, P_n]
        (harmonic.solve_harmonic); u_n = H_n e, v_n = H_n P_n are DOF vectors (H+1, n_dof). Used
        for the expansion and as a check."""
        m = self.host.model
        P = self.host.dof_loads(speed_rpm)
        omega = float(speed_rpm) * RPM_TO_RAD_S
        u = np.empty((self.host.H + 1, m.n_dof), dtype=complex)
        v = np.empty((self.host.H + 1, m.n_dof), dtype=complex)
        u[0], v[0] = self.host._u0, solve_static(m, P[0].real)
        for n in range(1, self.host.H + 1):
            sol = solve_harmonic(m, n * omega / 2.0, np.stack([m.e.astype(complex), P[n]], axis=1))
            u[n], v[n] = sol[:, 0], sol[:, 1]
        return u @ m.e, v @ m.e, u, v

    def dof_harmonics(self, point: HBMPoint) -> np.ndarray:
        """(H+1, n_dof) complex DOF harmonics q_n = H_n (P_n - e g_n) [rad] (eq. 10-13), by direct
        solves of the whole chain (rigid-body motion included for n >= 1, removed at n = 0)."""
        _, _, u, v = self.linear_parts_direct(point.speed_rpm)
        g = to_complex(self.host.nonlinear_harmonics(point.x, speed_rpm=point.speed_rpm),
                       self.host.H)
        return v - u * g[:, None]

    def element_harmonics(self, point: HBMPoint) -> np.ndarray:
        """(H+1, m) complex element angle harmonics [rad] through the rigid constraints."""
        return self.dof_harmonics(point) @ self.host.model.T.T

    def torque_harmonics(self, point: HBMPoint) -> np.ndarray:
        """(H+1, m) complex harmonics of the torque transmitted into every element [Nm], positive
        when driving (ReducedModel.transmitted_torques in the frequency domain): flexible
        connections -(k + i Om c) dphi_n, plus g_n at the DMF; rigid connections from the element
        equation T_i = -Om^2 j_i phi_i - p_i + T_{i+1} / r_{i+1}."""
        m = self.host.model
        qn = self.dof_harmonics(point)
        Om = (np.arange(self.host.H + 1) * (point.speed_rpm * RPM_TO_RAD_S / 2.0))[:, None]
        p = np.zeros((self.host.H + 1, m.n_elements), dtype=complex)
        pe = self.host.loads.element_harmonics(point.speed_rpm, self.host.load, self.host.factors)
        k = min(len(pe), self.host.H + 1)
        p[:k] = pe[:k]
        g = to_complex(self.host.nonlinear_harmonics(point.x, speed_rpm=point.speed_rpm),
                       self.host.H)
        return m.transmitted_torques(qn, 1j * Om * qn, -(Om ** 2) * qn, p, extra_torque=g)

    def dof_state(self, point: HBMPoint, psi: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """DOF angles q [rad] and velocities q' [rad/s] at crank angle psi (e.g. to start
        Newmark)."""
        qn = self.dof_harmonics(point)
        n = np.arange(self.host.H + 1)
        z = np.exp(1j * n * psi / 2.0)
        omega = point.speed_rpm * RPM_TO_RAD_S
        q = np.real(z @ qn)
        v = np.real((1j * n * omega / 2.0 * z) @ qn)
        return q, v

    # ---- cross-check by time integration -------------------------------------------------------
    def newmark_from(self, point: HBMPoint, *, perturb: np.ndarray | None = None, **fields):
        """Newmark steady state (newmark.simulate) started on this HBM solution's DOF state at
        psi = 0 (plus an optional DOF perturbation ``perturb`` [rad]); ``fields``: those of
        :class:`~dmf_sim.solvers.newmark.SimulationOptions` (the defaults otherwise). On a stable
        solution it stays there; an unstable one is left."""
        from dmf_sim.solvers.newmark import SimulationOptions, simulate
        q, v = self.dof_state(point, 0.0)
        if perturb is not None:
            q = q + perturb
        return simulate(self.host.loads, point.speed_rpm, self.host.load, initial=(q, v),
                        factors=self.host.factors, options=SimulationOptions(**fields))
