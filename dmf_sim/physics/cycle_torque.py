"""Torque transmitted through one element of a linear driveline over the 720 deg engine cycle,
from the harmonic response per half order (paper eq. 5), and the engine's mean torque over speed:
the quantities of the paper's Fig. 8."""
from __future__ import annotations

import numpy as np

from dmf_sim.core.errors import ConfigError

__all__ = ['FIG8_SPEEDS_RPM', 'FIG8_DRIVELINE', 'FIG8_ELEMENT', 'CYCLE_SAMPLES',
           'element_torque_over_cycle', 'torque_before_flywheel', 'mean_torques']

FIG8_SPEEDS_RPM = (800.0, 1000.0, 1200.0, 1400.0)   # default speeds of Fig. 8 right [rpm]
FIG8_DRIVELINE = 'truck_conventional'
FIG8_ELEMENT = 'FLYWHEEL'
CYCLE_SAMPLES = 720                                   # samples per 720 deg cycle (1 deg)


def element_torque_over_cycle(loads, speed_rpm: float, load: float, element: str,
                              n_samples: int = CYCLE_SAMPLES) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state torque [Nm] transmitted into ``element`` over one 720 deg cycle of a linear
    driveline (``loads.model`` without DMF): harmonic response per half order (eq. 5), then the
    model's torque read-out (ReducedModel.transmitted_torques). Returns (psi [deg], torque)."""
    from dmf_sim.core.units import CYCLE_RAD, RPM_TO_RAD_S
    from dmf_sim.physics.harmonic import solve_harmonic, solve_static
    from dmf_sim.physics.orders import synthesize
    m = loads.model
    if m.spring is not None:
        raise ConfigError(f'driveline {m.line.name!r}: the torque over the cycle is computed for '
                          'a linear driveline (no dmf section)')
    col = m.line.index(element)
    P = loads.dof_harmonics(speed_rpm, load)
    om = np.arange(P.shape[0]) * (speed_rpm * RPM_TO_RAD_S / 2.0)       # Om_n = n omega / 2
    Q = np.empty_like(P)
    Q[0] = solve_static(m, P[0].real)
    for n in range(1, P.shape[0]):
        Q[n] = solve_harmonic(m, om[n], P[n])
    q, qd, qdd = (synthesize(c.T, n_samples).T for c in (Q, 1j * om[:, None] * Q,
                                                         -(om ** 2)[:, None] * Q))
    psi = CYCLE_RAD * np.arange(n_samples) / n_samples
    torque = m.transmitted_torques(q, qd, qdd, loads.element_loads(psi, speed_rpm, load))
    return np.degrees(psi), torque[:, col]


def torque_before_flywheel(engine, speeds_rpm, load: float) -> tuple[np.ndarray, dict]:
    """Paper Fig. 8 right: torque into the flywheel of the conventional driveline [Nm] over the
    crank angle [deg], per speed [rpm]."""
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_model
    loads = DrivelineExcitation(read_model(FIG8_DRIVELINE), engine)
    out = {}
    psi = None
    for s in speeds_rpm:
        psi, out[float(s)] = element_torque_over_cycle(loads, float(s), load, FIG8_ELEMENT)
    return psi, out


def mean_torques(engines: dict, speeds: np.ndarray, load: float) -> dict[str, list[float]]:
    """Whole-engine mean torque [Nm] over ``speeds`` per load set."""
    return {s: [float(e.mean_torque(v, load)) for v in speeds] for s, e in engines.items()}
