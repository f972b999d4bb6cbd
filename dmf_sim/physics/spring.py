"""The DMF spring: piecewise linear in the wind-up (paper Fig. 2, eq. 3 and 8; doc/theory.md §2).

This module is the only place the spring law is written. Every solver (Newmark kernel and its
reference path, harmonic balance and its Jacobian, Floquet monodromy, non-linear normal modes,
the live torque read-out, modes per region) asks a :class:`PiecewiseLinearSpring` and nothing
else.

Wind-up ``w`` [rad] is the primary minus the secondary angle (through the gear ratio), positive
when the engine drives. The spring has the primary stiffness ``k`` [Nm/rad] around w = 0 and
stages on both sides:

* drive stages at angles ``0 < theta_1 < theta_2 < ...``: beyond ``theta_i`` the stiffness is
  ``k (1 + f_i)``;
* coast stages at ``0 > -thetac_1 > -thetac_2 > ...``: beyond ``-thetac_j`` the stiffness is
  ``k (1 + fc_j)``.

``f`` is the stage's *stiffness factor* (>= 0). The paper's two-step spring (k, theta, alpha) is
one drive stage ``(theta, alpha)``: secondary stiffness ``k (1 + alpha)``.

The full torque is ``T(w) = k w + g(w)``. The linear part ``k w`` (and the DMF damping) lives in
the driveline's K and C; the solvers treat only the *extra torque* ``g`` as non-linear
(eq. 7-8, with the ``(dphi - theta)`` factor the print drops). ``g`` is 0 in the primary region
and linear in every stage: ``g(w) = s_r w + o_r`` in region ``r`` (:attr:`slopes`,
:attr:`offsets`), continuous at the knees. Equivalently it is a sum of ramps (:meth:`ramps`),
``g(w) = sum_i c_i (w - x_i) [side_i (w - x_i) > 0]``.

Regions are numbered two ways:

* ``index`` 0 .. n_knees, ascending in w (what arrays and the numba kernel use):
  ``knees[r-1] < w <= knees[r]`` is region r (ties to the primary side);
* ``stage`` = index - :attr:`primary_index`: 0 primary, +i drive stage i, -j coast stage j.

Beside the elastic law the spring carries the two laws of a DMF as it is built (doc/theory.md §2),
both off unless configured:

* **arc-spring friction** (:class:`ArcFriction`, eq. 8a): the springs slide in a greased channel,
  pressed outward by centrifugal force, so the friction torque on the relative motion is
  ``T_f = (T0 + c_Omega Omega^2) tanh(w_dot / omega_reg)``: ``T0`` [Nm] the constant part,
  ``c_Omega`` [Nm s^2/rad^2] the centrifugal part (Omega [rad/s] the engine speed), a
  Coulomb law regularized over the slip speed ``omega_reg`` [rad/s];
* **end stops** (:class:`EndStops`, eq. 8b): beyond the travel (drive angle, coast angle) the
  spring rests on a very stiff contact of stiffness ``k_s`` [Nm/rad] and damping ``c_s``
  [Nms/rad], ``T_s = max(0, k_s d + c_s d_dot)`` (d >= 0 the penetration; the contact pushes,
  never pulls: Kelvin-Voigt clipped at zero).

Both are torques along the wind-up like ``g`` (:meth:`PiecewiseLinearSpring.law_torque`; compiled
once for every kernel: :mod:`dmf_sim.solvers.spring_kernels`). The time integration takes them
(the Newmark kernel solves its condensed equation with them,
:mod:`dmf_sim.solvers.newmark_kernel`), and so does the harmonic balance (its AFT samples the
wind-up rate from the harmonics, :func:`dmf_sim.solvers.hbm.kernels.aft_law`) with its Floquet
stability (:meth:`dmf_sim.solvers.stability.FloquetAnalyzer.analyze_law`); what the harmonic
balance of the regularized law can claim where the spring sticks: doc/theory.md §7.
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from dmf_sim.core.bounds import BOUNDS
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.validation import bounded

__all__ = ['Stage', 'ArcFriction', 'EndStops', 'PiecewiseLinearSpring', 'STIFFNESS_FACTOR_MAX',
           'STAGE_ANGLE_MAX_RAD', 'LAW_SIZE']

STIFFNESS_FACTOR_MAX = BOUNDS['stiffness_factor'].hi
"""Largest stage stiffness factor [-]: a stage stiffer than 51 k is an end stop, which has its
own contact law (:class:`EndStops`) rather than a stage; from the table of bounds,
:data:`dmf_sim.core.bounds.BOUNDS`."""

STAGE_ANGLE_MAX_RAD = BOUNDS['windup_angle'].hi
"""Largest stage angle [rad] (115 deg: beyond any arc-spring travel of a DMF; the table of
bounds)."""


LAW_SIZE = 7
"""Length of :meth:`PiecewiseLinearSpring.law_array` (the compiled kernels' friction and stops)."""


@dataclass(frozen=True)
class ArcFriction:
    """Arc-spring friction (eq. 8a): ``T_f = (torque_nm + speed_coefficient Omega^2)
    tanh(w_dot / regularization_rad_s)``.

    Attributes:
        torque_nm: constant part T0 [Nm] (>= 0).
        speed_coefficient: centrifugal part c_Omega [Nm s^2/rad^2] (>= 0), Omega the engine
            speed [rad/s].
        regularization_rad_s: slip speed omega_reg [rad/s] (> 0) over which the Coulomb law is
            smoothed: tanh(1) = 76 % of the full torque at w_dot = omega_reg.
    """

    torque_nm: float = 0.0
    speed_coefficient: float = 0.0
    regularization_rad_s: float = 0.05

    def __post_init__(self) -> None:
        object.__setattr__(self, 'torque_nm', bounded(self.torque_nm, 'dmf.friction',
                                                       'torque_nm', 'friction_torque'))
        object.__setattr__(self, 'speed_coefficient',
                           bounded(self.speed_coefficient, 'dmf.friction', 'speed_coefficient',
                                   'friction_speed_coefficient'))
        object.__setattr__(self, 'regularization_rad_s',
                           bounded(self.regularization_rad_s, 'dmf.friction',
                                   'regularization_rad_s', 'friction_regularization'))

    @property
    def active(self) -> bool:
        """Whether the law gives any torque (False: both parts zero)."""
        return self.torque_nm > 0.0 or self.speed_coefficient > 0.0

    def amplitude(self, omega_rad_s):
        """The sliding friction torque T0 + c_Omega Omega^2 [Nm] at engine speed(s) Omega."""
        omega = np.asarray(omega_rad_s, dtype=float)
        return self.torque_nm + self.speed_coefficient * omega * omega

    def torque(self, windup_rate_rad_s, omega_rad_s):
        """Friction torque T_f [Nm] (eq. 8a) at wind-up rate(s) w_dot [rad/s] and engine speed
        Omega [rad/s]; it opposes the relative motion (the same sign as w_dot, acting like g)."""
        return self.amplitude(omega_rad_s) * np.tanh(
            np.asarray(windup_rate_rad_s, dtype=float) / self.regularization_rad_s)


@dataclass(frozen=True)
class EndStops:
    """The spring's end stops (eq. 8b): contact beyond ``drive_angle_rad`` (w > 0) and beyond
    ``-coast_angle_rad``, stiffness ``stiffness`` [Nm/rad], damping ``damping`` [Nms/rad]."""

    drive_angle_rad: float
    coast_angle_rad: float
    stiffness: float
    damping: float = 0.0

    def __post_init__(self) -> None:
        w = 'dmf.end_stops'
        object.__setattr__(self, 'drive_angle_rad', bounded(self.drive_angle_rad, w,
                                                             'drive_angle_rad', 'windup_angle'))
        object.__setattr__(self, 'coast_angle_rad', bounded(self.coast_angle_rad, w,
                                                             'coast_angle_rad', 'windup_angle'))
        object.__setattr__(self, 'stiffness', bounded(self.stiffness, w, 'stiffness',
                                                       'stiffness', positive=True))
        object.__setattr__(self, 'damping', bounded(self.damping, w, 'damping', 'damping'))

    def torque(self, windup_rad, windup_rate_rad_s):
        """Contact torque T_s [Nm] (eq. 8b): ``max(0, k_s d + c_s d_dot)`` beyond the drive stop
        (d = w - drive angle), ``-max(0, k_s d + c_s d_dot)`` beyond the coast stop (d = -w -
        coast angle), 0 between."""
        w = np.asarray(windup_rad, dtype=float)
        wd = np.asarray(windup_rate_rad_s, dtype=float)
        dd = w - self.drive_angle_rad
        dc = -w - self.coast_angle_rad
        drive = np.where(dd > 0, np.maximum(0.0, self.stiffness * dd + self.damping * wd), 0.0)
        coast = np.where(dc > 0, np.maximum(0.0, self.stiffness * dc - self.damping * wd), 0.0)
        return drive - coast

    def damping_power(self, windup_rad, windup_rate_rad_s):
        """Power [W] the contact's damping dissipates (eq. 8b): c_s d_dot^2 while a stop pushes
        (its torque above zero), 0 elsewhere; the contact stiffness' part of T_s w_dot is
        stored and given back, not heat."""
        w = np.asarray(windup_rad, dtype=float)
        wd = np.asarray(windup_rate_rad_s, dtype=float)
        pushing = self.torque(w, wd) != 0.0
        return np.where(pushing, self.damping * wd * wd, 0.0)


@dataclass(frozen=True)
class Stage:
    """One stage of the spring: beyond ``angle_rad`` (drive: w > angle, coast: w < -angle) the
    stiffness is ``k (1 + stiffness_factor)``."""

    angle_rad: float
    stiffness_factor: float


def _check_stages(stages, where: str) -> tuple[Stage, ...]:
    out = []
    prev = 0.0
    for i, st in enumerate(stages):
        a, f = float(st.angle_rad), float(st.stiffness_factor)
        if not (math.isfinite(a) and prev < a <= STAGE_ANGLE_MAX_RAD):
            rule = '> 0 rad' if i == 0 else f'> the previous stage angle {prev:g} rad'
            raise ConfigError(f'{where}[{i}].angle_rad must be finite, {rule} and <= '
                              f'{STAGE_ANGLE_MAX_RAD:g} rad, got {a!r}')
        if not (math.isfinite(f) and 0.0 <= f <= STIFFNESS_FACTOR_MAX):
            raise ConfigError(f'{where}[{i}].stiffness_factor must be finite and in '
                              f'[0, {STIFFNESS_FACTOR_MAX:g}] (stage stiffness k (1 + factor) '
                              f'from k to {1 + STIFFNESS_FACTOR_MAX:g} k), got {f!r}')
        out.append(Stage(a, f))
        prev = a
    return tuple(out)


class PiecewiseLinearSpring:
    """Piecewise-linear DMF spring of primary stiffness ``k`` [Nm/rad] with drive and coast stages.

    Args:
        k: primary stiffness [Nm/rad] (> 0).
        drive: drive stages (:class:`Stage`), angles strictly increasing.
        coast: coast stages, angles (magnitudes) strictly increasing.
    """

    def __init__(self, k: float, drive=(), coast=(), friction: ArcFriction | None = None,
                 stops: EndStops | None = None) -> None:
        self.k = bounded(k, 'dmf', 'k', 'stiffness', positive=True)
        self.drive = _check_stages(drive, 'dmf.stages')
        self.coast = _check_stages(coast, 'dmf.coast_stages')
        #: arc-spring friction (eq. 8a) or None: none
        self.friction = friction if friction is not None and friction.active else None
        #: end stops (eq. 8b) or None: the spring law holds at any wind-up
        self.stops = stops
        if stops is not None:
            for side, angle, stages in (('drive', stops.drive_angle_rad, self.drive),
                                        ('coast', stops.coast_angle_rad, self.coast)):
                last = stages[-1].angle_rad if stages else 0.0
                if angle <= last:
                    raise ConfigError(
                        f'dmf.end_stops: field \'{side}_angle_rad\' must be beyond the last '
                        f'{side} stage angle {last:g} rad (in ({last:g}, '
                        f'{STAGE_ANGLE_MAX_RAD:g}] rad), got {angle!r}')
            self.stop_angles_rad = (-stops.coast_angle_rad, stops.drive_angle_rad)
        nc = len(self.coast)
        self.primary_index = nc
        knees = [-s.angle_rad for s in reversed(self.coast)] + [s.angle_rad for s in self.drive]
        self.knees = np.array(knees, dtype=float)
        slopes = ([k * s.stiffness_factor for s in reversed(self.coast)] + [0.0]
                  + [k * s.stiffness_factor for s in self.drive])
        self.slopes = np.array(slopes, dtype=float)
        # offsets from continuity of g at the knees, g = 0 in the primary region
        off = np.zeros(len(slopes))
        for r in range(nc + 1, len(slopes)):          # drive side, outward
            x = self.knees[r - 1]
            off[r] = (self.slopes[r - 1] * x + off[r - 1]) - self.slopes[r] * x
        for r in range(nc - 1, -1, -1):               # coast side, outward
            x = self.knees[r]
            off[r] = (self.slopes[r + 1] * x + off[r + 1]) - self.slopes[r] * x
        self.offsets = off
        # region lookup: a wind-up exactly at a coast knee belongs to the primary (inner) side,
        # exactly at a drive knee too: count coast knees <= w and drive knees < w
        self._coast_knees = self.knees[:nc]
        self._drive_knees = self.knees[nc:]
        for a in (self.knees, self.slopes, self.offsets, self._coast_knees, self._drive_knees):
            a.setflags(write=False)
        #: True when no stage changes the stiffness (g = 0 everywhere); the spring is immutable
        self.is_linear = not np.any(self.slopes)

    #: The end stops as (coast < 0, drive > 0) wind-ups [rad], or None: no end stop (this
    #: spring law holds at any wind-up). Read by the transient peaks (dmf_sim.live.peaks: travel
    #: margin and stop contacts); set from :attr:`stops`.
    stop_angles_rad: tuple[float, float] | None = None

    # ---- construction shorthands -------------------------------------------------------------
    @classmethod
    def two_step(cls, k: float, theta: float, alpha: float, theta_coast: float | None = None,
                 alpha_coast: float = 0.0) -> 'PiecewiseLinearSpring':
        """The paper's two-step spring: knee ``theta`` [rad], secondary stiffness k (1 + alpha);
        optionally a coast knee at ``-theta_coast`` with stiffness k (1 + alpha_coast)."""
        coast = () if theta_coast is None else (Stage(theta_coast, alpha_coast),)
        return cls(k, (Stage(theta, alpha),), coast)

    def replace(self, *, k: float | None = None, drive=None, coast=None
                ) -> 'PiecewiseLinearSpring':
        """A copy with some of k, drive, coast replaced (friction and end stops kept)."""
        return PiecewiseLinearSpring(self.k if k is None else k,
                                     self.drive if drive is None else drive,
                                     self.coast if coast is None else coast,
                                     self.friction, self.stops)

    def with_first_stage(self, *, theta: float | None = None,
                         alpha: float | None = None) -> 'PiecewiseLinearSpring':
        """The paper's (theta, alpha) shorthand applied to the first drive stage (created if the
        spring has none; later stages must stay beyond the new theta)."""
        if theta is None and alpha is None:
            return self
        if theta is not None and not (math.isfinite(theta) and theta > 0):
            raise ConfigError(f'dmf: theta must be finite and > 0 rad (first drive stage angle), '
                              f'got {theta!r}')
        if alpha is not None and not (math.isfinite(alpha) and alpha >= 0):
            raise ConfigError(f'dmf: alpha must be finite and >= 0 '
                              '(first drive stage stiffness factor), '
                              f'got {alpha!r}')
        if theta is not None:
            self._check_theta(float(theta))
        if self.drive:
            first = self.drive[0]
            new = Stage(first.angle_rad if theta is None else float(theta),
                        first.stiffness_factor if alpha is None else float(alpha))
            return self.replace(drive=(new,) + self.drive[1:])
        if theta is None or alpha is None:
            raise ConfigError('dmf: the spring has no drive stage; give both theta and alpha')
        return self.replace(drive=(Stage(float(theta), float(alpha)),))

    def _check_theta(self, theta: float) -> None:
        """The shorthand's knee must stay before the spring's next drive stage and its drive end
        stop: refused naming the shorthand (the API's and the node's ``theta``, the commands'
        ``--theta``) and what it would pass, not the file's field it would then contradict."""
        limits = [(st.angle_rad, f'the next drive stage at {st.angle_rad:g} rad '
                   f'(dmf.stages[{i}].angle_rad)') for i, st in enumerate(self.drive[1:2], 1)]
        if self.stops is not None:
            a = self.stops.drive_angle_rad
            limits.append((a, f'the drive end stop at {a:g} rad (dmf.end_stops.drive_angle_rad)'))
        for angle, what in limits:
            if theta >= angle:
                raise ConfigError(f'theta {theta:g} rad (--theta {theta:g}) moves the first drive '
                                  f'knee to or past {what}: give theta below {angle:g} rad')

    # ---- description -------------------------------------------------------------------------
    @property
    def theta(self) -> float:
        """First drive knee [rad] (the paper's theta; inf without drive stages)."""
        return self.drive[0].angle_rad if self.drive else math.inf

    @property
    def alpha(self) -> float:
        """Stiffness factor of the first drive stage (the paper's alpha; 0 without stages)."""
        return self.drive[0].stiffness_factor if self.drive else 0.0

    @property
    def n_regions(self) -> int:
        return len(self.slopes)

    def stage_of_index(self, index):
        return np.asarray(index) - self.primary_index

    def region_name(self, stage: int) -> str:
        """'primary', 'secondary' (first drive stage), 'drive stage i', 'coast', 'coast stage
        j'."""
        stage = int(stage)
        if stage == 0:
            return 'primary'
        if stage == 1:
            return 'secondary'
        if stage > 1:
            return f'drive stage {stage}'
        return 'coast' if stage == -1 else f'coast stage {-stage}'

    def primary_bounds(self) -> tuple[float, float]:
        """(lower, upper) wind-up [rad] of the primary region (-inf / inf without stages)."""
        p = self.primary_index
        lo = float(self.knees[p - 1]) if p > 0 else -math.inf
        hi = float(self.knees[p]) if p < len(self.knees) else math.inf
        return lo, hi

    def linear_bounds(self) -> tuple[float, float]:
        """(lower, upper) wind-up [rad] between which the spring's elastic law and end stops
        add nothing to k w: the primary region (:meth:`primary_bounds`) cut at the end stops
        (eq. 8b) where the spring has them. Friction (eq. 8a) acts at any wind-up and bounds
        nothing here."""
        lo, hi = self.primary_bounds()
        if self.stops is not None:
            lo = max(lo, -float(self.stops.coast_angle_rad))
            hi = min(hi, float(self.stops.drive_angle_rad))
        return lo, hi

    def stage_stiffness(self, stage: int) -> float:
        """Extra stiffness dg/dw [Nm/rad] in the region of ``stage`` (0 in the primary region)."""
        return float(self.slopes[int(stage) + self.primary_index])

    def stages(self) -> list[int]:
        """All stage numbers, ascending in w."""
        return list(range(-len(self.coast), len(self.drive) + 1))

    def ramps(self) -> list[tuple[float, float, float]]:
        """g as a sum of ramps: (knee x [rad], slope increment c [Nm/rad], side) with
        ``g(w) = sum c (w - x) [side (w - x) > 0]`` (side +1 drive, -1 coast)."""
        out = []
        prev = 0.0
        for st in self.drive:
            s = self.k * st.stiffness_factor
            out.append((st.angle_rad, s - prev, 1.0))
            prev = s
        prev = 0.0
        for st in self.coast:
            s = self.k * st.stiffness_factor
            out.append((-st.angle_rad, s - prev, -1.0))
            prev = s
        return [r for r in out if r[1] != 0.0]

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(knees, slopes, offsets) as contiguous float64 arrays for compiled kernels."""
        return (np.ascontiguousarray(self.knees), np.ascontiguousarray(self.slopes),
                np.ascontiguousarray(self.offsets))

    def as_dict(self) -> dict:
        out = {'k': self.k,
               'stages': [{'angle_rad': s.angle_rad, 'stiffness_factor': s.stiffness_factor}
                          for s in self.drive],
               'coast_stages': [{'angle_rad': s.angle_rad, 'stiffness_factor': s.stiffness_factor}
                                for s in self.coast]}
        if self.friction is not None:
            out['friction'] = {'torque_nm': self.friction.torque_nm,
                               'speed_coefficient': self.friction.speed_coefficient,
                               'regularization_rad_s': self.friction.regularization_rad_s}
        if self.stops is not None:
            out['end_stops'] = {'drive_angle_rad': self.stops.drive_angle_rad,
                                'coast_angle_rad': self.stops.coast_angle_rad,
                                'stiffness': self.stops.stiffness,
                                'damping': self.stops.damping}
        return out

    def describe(self) -> str:
        """One line for people: the paper's ``alpha=.. theta=.. rad`` for a two-step spring,
        every stage (angle rad x stiffness factor) otherwise; friction and end stops appended
        when the spring has them."""
        if len(self.drive) == 1 and not self.coast:
            text = f'alpha={self.alpha:g} theta={self.theta:g} rad'
        elif not self.drive and not self.coast:
            text = f'linear k={self.k:g} Nm/rad'
        else:
            st = ', '.join(f'{s.angle_rad:g} rad: +{s.stiffness_factor:g}k' for s in self.drive)
            co = ', '.join(f'-{s.angle_rad:g} rad: +{s.stiffness_factor:g}k' for s in self.coast)
            text = f'k={self.k:g} Nm/rad, drive stages [{st}], coast stages [{co}]'
        if self.friction is not None:
            f = self.friction
            text += (f', friction {f.torque_nm:g} Nm + {f.speed_coefficient:g} Omega^2 '
                     f'(omega_reg {f.regularization_rad_s:g} rad/s)')
        if self.stops is not None:
            text += (f', end stops -{self.stops.coast_angle_rad:g} .. '
                     f'{self.stops.drive_angle_rad:g} rad')
        return text

    def __repr__(self) -> str:
        st = ', '.join(f'{s.angle_rad:g}:{s.stiffness_factor:g}' for s in self.drive)
        co = ', '.join(f'{s.angle_rad:g}:{s.stiffness_factor:g}' for s in self.coast)
        return f'PiecewiseLinearSpring(k={self.k:g}, drive=[{st}], coast=[{co}])'

    def __eq__(self, other) -> bool:
        return (isinstance(other, PiecewiseLinearSpring) and self.k == other.k
                and self.drive == other.drive and self.coast == other.coast
                and self.friction == other.friction and self.stops == other.stops)

    def __hash__(self) -> int:
        return hash((self.k, self.drive, self.coast, self.friction, self.stops))

    # ---- friction and end stops (eq. 8a, 8b) -------------------------------------------------
    @property
    def has_friction(self) -> bool:
        """Whether the spring has arc-spring friction (eq. 8a)."""
        return self.friction is not None

    @property
    def smooth_elastic(self) -> bool:
        """True when the spring is its elastic law alone (no friction, no end stops): the
        solvers then take their elastic paths (exact region by region)."""
        return self.friction is None and self.stops is None

    def law_torque(self, w, w_dot, omega_rad_s):
        """Friction plus end-stop torque [Nm] along the wind-up (eq. 8a + 8b) at wind-up(s) w
        [rad], wind-up rate(s) w_dot [rad/s] and engine speed Omega [rad/s]; 0 without them.
        The full DMF torque is ``torque(w) + law_torque(...)`` plus the element's viscous
        damping c w_dot."""
        out = np.zeros(np.broadcast(np.asarray(w), np.asarray(w_dot)).shape)
        if self.friction is not None:
            out = out + self.friction.torque(w_dot, omega_rad_s)
        if self.stops is not None:
            out = out + self.stops.torque(w, w_dot)
        return out if out.ndim else float(out)

    def law_array(self) -> np.ndarray:
        """Friction and end stops for compiled kernels, float64[:data:`LAW_SIZE`]:
        [T0 Nm, c_Omega Nm s^2/rad^2, omega_reg rad/s, coast stop (< 0) rad, drive stop rad,
        k_s Nm/rad (0: no stops), c_s Nms/rad]; all zero but omega_reg = 1 without them."""
        f, st = self.friction, self.stops
        return np.array([f.torque_nm if f else 0.0, f.speed_coefficient if f else 0.0,
                         f.regularization_rad_s if f else 1.0,
                         -st.coast_angle_rad if st else 0.0, st.drive_angle_rad if st else 0.0,
                         st.stiffness if st else 0.0, st.damping if st else 0.0])

    # ---- the law -----------------------------------------------------------------------------
    def region_index(self, w):
        """Region index 0..n_knees of wind-up(s) w (ascending in w; ties to the primary side)."""
        w = np.asarray(w, dtype=float)
        idx = np.searchsorted(self._drive_knees, w, side='left')
        if self.primary_index:
            idx = idx + np.searchsorted(self._coast_knees, w, side='right')
        return idx if idx.ndim else int(idx)

    def stage(self, w):
        """Stage number of wind-up(s) w: 0 primary, +i drive stage i, -j coast stage j."""
        return self.region_index(w) - self.primary_index

    def region(self, w: float) -> str:
        """Region name of one wind-up (:meth:`region_name`)."""
        return self.region_name(self.stage(float(w)))

    def extra_torque(self, w):
        """Non-linear part g(w) [Nm] of the spring torque (array or scalar wind-up [rad])."""
        return self.extra_torque_and_stiffness(w)[0]

    def extra_stiffness(self, w):
        """Tangent dg/dw [Nm/rad]."""
        return self.slopes[self.region_index(w)]

    def extra_torque_and_stiffness(self, w) -> tuple[np.ndarray, np.ndarray]:
        """(g(w) [Nm], dg/dw [Nm/rad]) with one region lookup (the AFT's hot path)."""
        w = np.asarray(w, dtype=float)
        r = self.region_index(w)
        s = self.slopes[r]
        return s * w + self.offsets[r], s

    def torque(self, w):
        """Full spring torque T(w) = k w + g(w) [Nm]."""
        return self.k * np.asarray(w, dtype=float) + self.extra_torque(w)

    def stiffness(self, w):
        """Full tangent stiffness dT/dw [Nm/rad]."""
        return self.k + self.extra_stiffness(w)

    @cached_property
    def _g_at_knees(self) -> np.ndarray:
        """g at each knee [Nm] (from the region below it; g is continuous)."""
        return self.slopes[:-1] * self.knees + self.offsets[:-1]

    @cached_property
    def _g_at_knees_list(self) -> list[float]:
        return self._g_at_knees.tolist()

    @cached_property
    def _lists(self) -> tuple[list[float], list[float], list[float]]:
        """(knees, slopes, offsets) as lists of Python floats (scalar look-ups)."""
        return self.knees.tolist(), self.slopes.tolist(), self.offsets.tolist()

    @cached_property
    def _energy_constants(self) -> np.ndarray:
        """Per region: constant C_r with G(w) = s_r w^2 / 2 + o_r w + C_r, G(0) = 0 (G' = g)."""
        s, o, x = self.slopes, self.offsets, self.knees
        C = np.zeros(len(s))
        p = self.primary_index
        for r in range(p + 1, len(s)):
            xr = x[r - 1]
            C[r] = ((0.5 * s[r - 1] * xr**2 + o[r - 1] * xr + C[r - 1])
                    - (0.5 * s[r] * xr**2 + o[r] * xr))
        for r in range(p - 1, -1, -1):
            xr = x[r]
            C[r] = ((0.5 * s[r + 1] * xr**2 + o[r + 1] * xr + C[r + 1])
                    - (0.5 * s[r] * xr**2 + o[r] * xr))
        return C

    def extra_energy(self, w):
        """Potential energy [J] of g alone (G(0) = 0, G' = g)."""
        w = np.asarray(w, dtype=float)
        r = self.region_index(w)
        return 0.5 * self.slopes[r] * w**2 + self.offsets[r] * w + self._energy_constants[r]

    def energy(self, w):
        """Potential energy of the full spring [J] for wind-up w (zero at w = 0)."""
        return 0.5 * self.k * np.asarray(w, dtype=float) ** 2 + self.extra_energy(w)

    # ---- inverses ----------------------------------------------------------------------------
    def windup_for_torque(self, torque: float) -> float:
        """Inverse of T(w): the static wind-up [rad] carrying ``torque`` [Nm] (T is monotone)."""
        Tk = self.k * self.knees + self._g_at_knees
        r = int(np.searchsorted(Tk, torque, side='left'))
        return float((torque - self.offsets[r]) / (self.k + self.slopes[r]))

    def solve_condensed(self, w_lin: float, h: float) -> float:
        """Solve ``w + h g(w) = w_lin`` for w (h >= 0 a flexibility [rad/Nm]), exactly.

        ``F(w) = w + h g(w)`` is increasing and linear per region: find the region whose image
        holds ``w_lin`` and invert there (Newton's method on the piecewise-linear g converges in
        one step from inside the right region)."""
        # scalar arithmetic on lists (the same IEEE operations as the array form, without its
        # per-call overhead: a sweep calls this at every point)
        knees, slopes, offsets = self._lists
        images = [kn + h * gk for kn, gk in zip(knees, self._g_at_knees_list)]
        r = bisect.bisect_left(images, w_lin)     # = np.searchsorted(images, w_lin, 'left')
        return float((w_lin - h * offsets[r]) / (1.0 + h * slopes[r]))
