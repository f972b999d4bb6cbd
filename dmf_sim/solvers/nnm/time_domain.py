"""Time integration of the conservative driveline (verification of the NNM orbits)."""
from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp

from dmf_sim.physics.loads import ConstantTorque, DrivelineExcitation
from dmf_sim.physics.model import ReducedModel
from dmf_sim.solvers.nnm.subsystems import require_dmf

__all__ = ['energy_norm', 'integrate_chain', 'static_state', 'integrate_physical']


def energy_norm(K, J, dx, dv, E) -> float:
    return float(np.sqrt(max(dx @ K @ dx + dv @ J @ dv, 0.0) / (2.0 * E)))


def integrate_chain(J, K, e, force, levels, P, x0, v0, t_end: float, rtol: float = 1e-11):
    """Integrate J x'' + K x + e force(e.x) = P (constant P) from (x0, v0) over t_end [s].

    scipy DOP853 with tight tolerances; the integration is restarted at every crossing of a knee
    level of the wind-up e.x (``levels``), so the kink of the piecewise-linear force is never
    stepped over. Returns (x, v) at t_end."""
    n = len(x0)
    Jinv = np.linalg.inv(J)
    JK, Je, JP = Jinv @ K, Jinv @ e, Jinv @ P

    def rhs(t, y):
        x = y[:n]
        return np.concatenate([y[n:], JP - JK @ x - Je * float(force(e @ x))])

    events = []
    for lev in levels:
        def ev(t, y, lev=float(lev)):
            return e @ y[:n] - lev
        ev.terminal = True
        events.append(ev)
    y = np.concatenate([x0, v0]).astype(float)
    atol = 1e-13 * max(np.abs(y).max(), 1e-300)
    t = 0.0
    while t < t_end:
        sol = solve_ivp(rhs, (t, t_end), y, method='DOP853', rtol=rtol, atol=atol, events=events)
        if sol.status < 0:
            raise RuntimeError(f'time integration failed: {sol.message}')
        y, t = sol.y[:, -1], float(sol.t[-1])
        if sol.status == 0:
            break
        dt = min(1e-12, t_end - t)          # step off the knee (the event is located to round-off)
        y = y + dt * rhs(t, y)
        t += dt
    return y[:n], y[n:]


def static_state(model: ReducedModel, windup_static: float) -> tuple[np.ndarray, np.ndarray]:
    """Static DOF deflection q_s [rad] and the balanced mean load P0 [Nm] (an engine mean torque
    on the cylinder elements, minus it times the cumulative ratio on the rear-load element:
    DrivelineExcitation with a :class:`dmf_sim.physics.loads.ConstantTorque` engine) that hold the
    DMF at ``windup_static`` [rad]."""
    require_dmf(model)
    n_cyl = len(model.line.cylinders)
    unit = DrivelineExcitation(model, ConstantTorque(1.0, n_cyl)).static_state(0.0, 1.0)
    torque_per_unit = float(model.spring.torque(unit.windup))      # statics of a chain: linear
    T = float(model.spring.torque(windup_static)) / torque_per_unit
    L = DrivelineExcitation(model, ConstantTorque(T, n_cyl))
    st = L.static_state(0.0, 1.0)
    return st.q, np.real(L.dof_harmonics(0.0, 1.0)[0])


def integrate_physical(model: ReducedModel, P0: np.ndarray, q0: np.ndarray, v0: np.ndarray,
                       t_end: float, rtol: float = 1e-11) -> tuple[np.ndarray, np.ndarray]:
    """Integrate the undamped driveline J q'' + K q + e g(e.q) = P0 with the full DMF spring
    (no linearization about any static point) from (q0, v0) over t_end [s]."""
    sp = model.spring
    return integrate_chain(model.J, model.K, model.e, sp.extra_torque, list(sp.knees), P0, q0, v0,
                           t_end, rtol=rtol)
