"""What the condensed harmonic balance (:mod:`dmf_sim.solvers.hbm.condensed`) takes and gives:
its numerical settings (:class:`HBMOptions`), the speed-dependent linear parts of eq. (15) at one
speed (:class:`LinearParts`) and one periodic steady state of the wind-up (:class:`HBMPoint`)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dmf_sim.physics.orders import OrderSummary
from dmf_sim.solvers.hbm.unknowns import SUB_HARMONICS

__all__ = ['HBMOptions', 'LinearParts', 'HBMPoint']


@dataclass(frozen=True)
class HBMOptions:
    """Numerical settings of the condensed harmonic balance.

    Attributes:
        n_harmonics: H, highest half-order index kept (24 = 12th engine order).
        n_time: M, AFT samples per 720 deg cycle (default: 8 (H+1) rounded up to a power of 2).
        tol: Newton tolerance on the residual's max norm [rad].
        max_iter: Newton iterations per solve.
        stall_iter, stall_ratio: Newton gives up when the residual has not fallen below
            ``stall_ratio`` x its value ``stall_iter`` iterations earlier (a seed outside the
            basin stalls at a kink of the piecewise-linear residual with ever shorter steps;
            converging solves take full steps and need at most ~6 iterations).
        speed_fd_rpm: finite-difference step for the speed derivative of the engine load [rpm].
        compiled: AFT, residual, Jacobian and Newton through the compiled kernels
            (:mod:`dmf_sim.solvers.hbm.kernels`); False: the readable numpy reference.
    """

    n_harmonics: int = 24
    n_time: int | None = None
    tol: float = 1e-10
    max_iter: int = 40
    stall_iter: int = 8
    stall_ratio: float = 0.5
    speed_fd_rpm: float = 0.05
    compiled: bool = True

    def time_samples(self) -> int:
        if self.n_time is not None:
            return int(self.n_time)
        return 1 << int(math.ceil(math.log2(8 * (self.n_harmonics + 1))))


@dataclass
class LinearParts:
    """Everything the condensed equation needs at one speed (computed once per speed).

    Attributes:
        speed_rpm: engine speed.
        omega: crank speed [rad/s].
        h: (H+1,) complex wind-up receptance e.H_n e [rad/Nm] (h_0 static, real).
        wlin: (H+1,) complex linear wind-up response e.H_n P_n [rad] (wlin_0: static mean).
        dh_ds, dwlin_ds: their derivatives with respect to speed [per rpm].
        lin, dlin: (wlin, h) and (dwlin_ds, dh_ds) with wlin on the real layout, packed for the
            compiled kernels.
    """

    speed_rpm: float
    omega: float
    h: np.ndarray
    wlin: np.ndarray
    dh_ds: np.ndarray
    dwlin_ds: np.ndarray
    lin: tuple = ()
    dlin: tuple = ()


@dataclass
class HBMPoint:
    """One periodic steady state of the wind-up (SI; speed in rpm).

    Attributes:
        speed_rpm: engine speed.
        x: (2H+1,) real unknowns [w_0, Re w_n, Im w_n] [rad].
        windup_orders: (H+1,) complex c_n of the wind-up, ``w = Re(sum c_n exp(i n psi/2))`` [rad]
            (same convention as newmark.SimulationResult.windup_orders).
        summary: OrderSummary (3rd and 1.5th order amplitude, max/min deviation, mean - theta).
        residual: max |r_n| at convergence [rad]; iterations: Newton iterations used.
        stable: Floquet stability (None until computed); multipliers: Floquet multipliers of the
            full linearized driveline over one 720 deg cycle (rigid-body pair excluded).
        branch: branch id in a sweep; kind: 'main', 'subharmonic' or 'harmonic'.
        tangent_speed: d(speed)/d(arc) of the continuation tangent (changes sign at a fold).
        forced_order_1_5: |wlin_3|, the linear (directly forced) 1.5th-order wind-up [rad].
    """

    speed_rpm: float
    x: np.ndarray
    windup_orders: np.ndarray
    summary: OrderSummary
    residual: float
    iterations: int
    stable: bool | None = None
    multipliers: np.ndarray | None = None
    max_multiplier: float = float('nan')
    branch: int = 0
    kind: str = 'main'
    tangent_speed: float = float('nan')
    forced_order_1_5: float = float('nan')

    @property
    def order_3(self) -> float:
        return self.summary.order_3

    @property
    def order_1_5(self) -> float:
        return self.summary.order_1_5

    def subharmonic_amplitude(self) -> float:
        """rms of the n = 3, 9, 15, 21 wind-up harmonics [rad] (zero on a 120-deg-periodic
        state)."""
        c = self.windup_orders
        return float(np.sqrt(np.sum(np.abs(c[[n for n in SUB_HARMONICS if n < len(c)]]) ** 2)))

    def as_dict(self) -> dict:
        d = {'speed_rpm': float(self.speed_rpm), 'branch': int(self.branch), 'kind': self.kind,
             'stable': None if self.stable is None else bool(self.stable)}
        d.update({k: v for k, v in self.summary.as_dict().items() if k != 'mean'})
        d['mean'] = float(self.summary.mean)
        d['max_multiplier'] = float(self.max_multiplier)
        d['forced_order_1_5'] = float(self.forced_order_1_5)
        return d
