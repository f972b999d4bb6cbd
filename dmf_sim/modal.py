"""Modal analysis: the generalized eigenproblem (K, J) of the merged model (paper Fig. 12).

For the DMF driveline the spring stiffness is chosen by ``region``: 'primary' uses k,
'secondary' uses k (1 + alpha), the two linear limits of the two-step spring.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from dmf_sim.model import ReducedModel

REGIONS = ('primary', 'secondary')


def stiffness_matrix(model: ReducedModel, region: str = 'primary') -> np.ndarray:
    """K with the DMF at primary stiffness k or secondary stiffness k (1 + alpha) [Nm/rad]."""
    if region not in REGIONS:
        raise ValueError(f'region={region!r}: allowed {", ".join(REGIONS)}')
    if region == 'secondary' and model.spring is not None:
        return model.K + model.spring.b * np.outer(model.e, model.e)
    return model.K


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
            'mode_shapes_scaled': [[float(v) for v in self.element_shapes[:, i]] for i in range(k)],
        }


def modes(model: ReducedModel, region: str = 'primary') -> ModalResult:
    """Solve K v = omega^2 J v (scipy.linalg.eigh). Tiny negative eigenvalues of the rigid-body
    mode (round-off) are clipped to zero."""
    K = stiffness_matrix(model, region)
    w2, V = scipy.linalg.eigh(K, model.J)
    scale = np.abs(w2).max()
    w2 = np.where(np.abs(w2) < 1e-10 * scale, 0.0, w2)
    if np.any(w2 < 0):
        raise ValueError('stiffness matrix is not positive semi-definite')
    omega = np.sqrt(w2)
    phi = model.T @ V * model.R[:, None]
    idx = np.argmax(np.abs(phi), axis=0)
    norm = phi[idx, np.arange(phi.shape[1])]
    shapes = phi / norm
    first = shapes[0]
    shapes = shapes * np.where(first < 0, -1.0, 1.0)
    return ModalResult(frequencies_hz=omega / (2 * np.pi), omega=omega, dof_shapes=V,
                       element_shapes=shapes, names=model.names)
