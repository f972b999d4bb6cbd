"""The two-step DMF spring (paper Fig. 2, eq. 3 and 8), reusable by every solver.

Wind-up ``w`` [rad] is primary minus secondary angle (through the gear ratio), positive when the
engine drives. The full spring torque [Nm] is

    T(w) = k w + b (w - theta) H(w - theta)                       (eq. 3, drive side; b = alpha k)
           - b_c (-w - theta_c) H(-w - theta_c)                    (optional coast-side knee)

The linear part ``k w`` belongs to the driveline's K matrix; the solvers treat only the extra
``g(w) = T(w) - k w`` as non-linear (eq. 7-8, with the (dphi - theta) factor the print drops).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TwoStepSpring:
    """Piecewise-linear DMF spring.

    Attributes:
        k: primary stiffness [Nm/rad].
        theta: drive-side stiffness change angle [rad] (> 0).
        alpha: drive-side extra stiffness factor; secondary stiffness is k (1 + alpha).
        theta_coast: coast-side knee angle [rad] (> 0) or None for no coast knee.
        alpha_coast: coast-side extra stiffness factor.
    """

    k: float
    theta: float
    alpha: float
    theta_coast: float | None = None
    alpha_coast: float = 0.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.k) and self.k > 0):
            raise ValueError(f'dmf: stiffness k={self.k} must be finite and > 0 Nm/rad')
        if not (np.isfinite(self.theta) and self.theta > 0):
            raise ValueError(f'dmf.theta_rad={self.theta} must be finite and > 0 rad')
        if not (np.isfinite(self.alpha) and self.alpha >= 0):
            raise ValueError(f'dmf.alpha={self.alpha} must be finite and >= 0')
        if self.theta_coast is not None and not (np.isfinite(self.theta_coast) and self.theta_coast > 0):
            raise ValueError(f'dmf.coast.theta_rad={self.theta_coast} must be finite and > 0 rad')
        if not (np.isfinite(self.alpha_coast) and self.alpha_coast >= 0):
            raise ValueError(f'dmf.coast.alpha={self.alpha_coast} must be finite and >= 0')

    @property
    def b(self) -> float:
        """Drive-side extra stiffness alpha k [Nm/rad]."""
        return self.alpha * self.k

    @property
    def b_coast(self) -> float:
        """Coast-side extra stiffness [Nm/rad] (0 without a coast knee)."""
        return self.alpha_coast * self.k if self.theta_coast is not None else 0.0

    @property
    def theta_coast_or_inf(self) -> float:
        return self.theta_coast if self.theta_coast is not None else np.inf

    def extra_torque(self, w):
        """Non-linear part g(w) [Nm] of the spring torque (array or scalar wind-up [rad])."""
        w = np.asarray(w, dtype=float)
        g = self.b * np.maximum(w - self.theta, 0.0)
        if self.theta_coast is not None:
            g = g - self.b_coast * np.maximum(-w - self.theta_coast, 0.0)
        return g

    def extra_stiffness(self, w):
        """Tangent of g: dg/dw [Nm/rad]."""
        w = np.asarray(w, dtype=float)
        s = np.where(w > self.theta, self.b, 0.0)
        if self.theta_coast is not None:
            s = s + np.where(w < -self.theta_coast, self.b_coast, 0.0)
        return s

    def torque(self, w):
        """Full spring torque T(w) = k w + g(w) [Nm]."""
        return self.k * np.asarray(w, dtype=float) + self.extra_torque(w)

    def stiffness(self, w):
        """Full tangent stiffness dT/dw [Nm/rad]."""
        return self.k + self.extra_stiffness(w)

    def region(self, w: float) -> str:
        """'primary', 'secondary' (drive knee passed) or 'coast' (coast knee passed)."""
        if w > self.theta:
            return 'secondary'
        if self.theta_coast is not None and w < -self.theta_coast:
            return 'coast'
        return 'primary'

    def windup_for_torque(self, torque: float) -> float:
        """Inverse of T(w): the static wind-up [rad] carrying ``torque`` [Nm] (T is monotone)."""
        k, th = self.k, self.theta
        if torque > k * th:
            return (torque + self.b * th) / (k + self.b)
        if self.theta_coast is not None and torque < -k * self.theta_coast:
            return (torque - self.b_coast * self.theta_coast) / (k + self.b_coast)
        return torque / k

    def solve_condensed(self, w_lin: float, h: float) -> float:
        """Solve w + h g(w) = w_lin for w (h >= 0): exact on the piecewise-linear g.

        This is Newton's method on the scalar condensed equation with the active region checked:
        with g linear in each region one Newton step from inside the right region is exact.
        """
        if w_lin > self.theta:
            return (w_lin + h * self.b * self.theta) / (1.0 + h * self.b)
        if self.theta_coast is not None and w_lin < -self.theta_coast:
            return (w_lin - h * self.b_coast * self.theta_coast) / (1.0 + h * self.b_coast)
        return w_lin

    def energy(self, w):
        """Potential energy of the full spring [J] for wind-up w (zero at w = 0)."""
        w = np.asarray(w, dtype=float)
        e = 0.5 * self.k * w**2 + 0.5 * self.b * np.maximum(w - self.theta, 0.0) ** 2
        if self.theta_coast is not None:
            e = e + 0.5 * self.b_coast * np.maximum(-w - self.theta_coast, 0.0) ** 2
        return e
