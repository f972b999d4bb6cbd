"""Modal analysis: the generalized eigenproblem (K, J) of the merged model (paper Fig. 12).

For the DMF driveline the spring stiffness is chosen by ``region``: the tangent stiffness of one
spring stage ('primary' = k, 'secondary' = k (1 + alpha) of the first drive stage, 'drive stage 2',
'coast', ... or the stage number), a linear limit of the piecewise-linear spring.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from dmf_sim.core.errors import ConfigError
from dmf_sim.physics.model import ReducedModel

__all__ = ['REGIONS', 'region_names', 'stiffness_matrix', 'ModalResult', 'modes']

REGIONS = ('primary', 'secondary')


def region_names(model: ReducedModel) -> list[str]:
    """The spring stages of the model's DMF by name, ascending in wind-up ('primary' without
    DMF)."""
    sp = model.spring
    return [sp.region_name(st) for st in sp.stages()] if sp is not None else ['primary']


def stiffness_matrix(model: ReducedModel, region: str | int = 'primary') -> np.ndarray:
    """K with the DMF at the tangent stiffness of one spring stage [Nm/rad] (name or number)."""
    sp = model.spring
    if isinstance(region, str):
        names = region_names(model)
        if region not in names:
            if region in REGIONS:          # 'secondary' of a DMF without drive stage, or no DMF
                return model.K
            raise ConfigError(f'region={region!r}: allowed {", ".join(names)}')
        if sp is None:
            return model.K
        stage = sp.stages()[names.index(region)]
    else:
        stage = int(region)
        if sp is None or stage not in sp.stages():
            raise ConfigError(f'region={region!r}: allowed stages {sp.stages() if sp else [0]}')
    return model.K + sp.stage_stiffness(stage) * np.outer(model.e, model.e)


@dataclass(frozen=True)
class ModalResult:
    """Natural frequencies and mode shapes.

    Attributes:
        frequencies_hz: (n,) ascending natural frequencies [Hz]; the rigid-body mode is 0.
        omega: (n,) angular frequencies [rad/s].
        dof_shapes: (n_dof, n) mass-normalized eigenvectors (columns).
        element_shapes: (m, n) element angles of each mode times the cumulative gear ratio
            (the paper's Fig. 12 scaling), normalized to max |.| = 1, sign so the engine end is +.
        names: element names.
    """

    frequencies_hz: np.ndarray
    omega: np.ndarray
    dof_shapes: np.ndarray
    element_shapes: np.ndarray
    names: list[str]

    def as_dict(self, n_modes: int | None = None) -> dict:
        k = len(self.frequencies_hz) if n_modes is None else n_modes
        return {
            'frequencies_hz': [float(f) for f in self.frequencies_hz[:k]],
            'elements': list(self.names),
            'mode_shapes_scaled': [[float(v) for v in self.element_shapes[:, i]]
                                   for i in range(k)],
        }


def modes(model: ReducedModel, region: str = 'primary') -> ModalResult:
    """Solve K v = omega^2 J v (scipy.linalg.eigh). Tiny negative eigenvalues of the rigid-body
    mode (round-off) are clipped to zero."""
    K = stiffness_matrix(model, region)
    w2, V = scipy.linalg.eigh(K, model.J)
    scale = np.abs(w2).max()
    w2 = np.where(np.abs(w2) < 1e-10 * scale, 0.0, w2)
    if np.any(w2 < 0):
        raise ConfigError('stiffness matrix is not positive semi-definite')
    omega = np.sqrt(w2)
    phi = model.T @ V * model.R[:, None]
    idx = np.argmax(np.abs(phi), axis=0)
    norm = phi[idx, np.arange(phi.shape[1])]
    shapes = phi / norm
    first = shapes[0]
    shapes = shapes * np.where(first < 0, -1.0, 1.0)
    return ModalResult(frequencies_hz=omega / (2 * np.pi), omega=omega, dof_shapes=V,
                       element_shapes=shapes, names=model.names)
