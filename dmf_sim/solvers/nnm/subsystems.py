"""Linear pieces of the NNM picture: subsystem and clamped frequencies, static wind-ups."""
from __future__ import annotations

import numpy as np
import scipy.linalg
from scipy.sparse.csgraph import connected_components

from dmf_sim.core.errors import ConfigError
from dmf_sim.physics.model import ReducedModel
from dmf_sim.solvers.nnm.results import REGIONS, TWO_PI

__all__ = ['require_dmf', 'subsystem_frequencies', 'clamped_frequencies', 'static_windup']


def require_dmf(model: ReducedModel) -> None:
    if model.spring is None:
        raise ConfigError(f'driveline {model.line.name!r} has no dmf section: '
                          'no non-linear normal modes')


def subsystem_frequencies(model: ReducedModel) -> dict[str, np.ndarray]:
    """Natural frequencies [Hz] of the parts in front of ('front') and behind ('rear') the DMF,
    each on its own with the DMF spring removed (free at the DMF); rigid-body modes dropped."""
    require_dmf(model)
    K0 = model.K - model.spring.k * np.outer(model.e, model.e)
    _, labels = connected_components((np.abs(K0) > 0) | np.eye(model.n_dof, dtype=bool),
                                     directed=False)
    primary_dof = int(np.argmax(model.e))  # e = +1 on the primary side, -1 on the secondary side
    secondary_dof = int(np.argmin(model.e))
    out = {}
    for name, dof in (('front', primary_dof), ('rear', secondary_dof)):
        idx = np.flatnonzero(labels == labels[dof])
        w2 = scipy.linalg.eigh(K0[np.ix_(idx, idx)], model.J[np.ix_(idx, idx)], eigvals_only=True)
        w2 = w2[w2 > 1e-8 * max(w2.max(), 1.0)]
        out[name] = np.sqrt(w2) / TWO_PI
    return out


def clamped_frequencies(model: ReducedModel) -> np.ndarray:
    """Natural frequencies [Hz] with the DMF wind-up held at zero (flywheels rigidly joined);
    the rigid-body mode dropped. These are the zeros of the wind-up receptance h(Omega)."""
    require_dmf(model)
    N = scipy.linalg.null_space(model.e[None, :])
    w2 = scipy.linalg.eigh(N.T @ model.K @ N, N.T @ model.J @ N, eigvals_only=True)
    w2 = w2[w2 > 1e-8 * w2.max()]
    return np.sqrt(w2) / TWO_PI


def static_windup(model: ReducedModel, region: str, distance: float | None = None) -> float:
    """Static wind-up [rad] at ``distance`` [rad] below ('primary') or above ('secondary') the knee
    theta (default distance theta / 2)."""
    require_dmf(model)
    if region not in REGIONS:
        raise ConfigError(f'region={region!r}: allowed {", ".join(REGIONS)}')
    th = model.spring.theta
    d = 0.5 * th if distance is None else float(distance)
    if not (np.isfinite(d) and d > 0):
        raise ConfigError(f'distance={distance}: must be > 0 rad (static wind-up off the knee)')
    return th - d if region == 'primary' else th + d
