"""Options and results of the non-linear normal mode computation (paper Fig. 14)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ['TWO_PI', 'REGIONS', 'NNMOptions', 'NNMBranch', 'FlatBranch', 'NNMResult']

TWO_PI = 2.0 * np.pi
REGIONS = ('primary', 'secondary')


@dataclass(frozen=True)
class NNMOptions:
    """Numerical settings.

    Attributes:
        n_harmonics: H, highest harmonic of the base frequency kept.
        n_grid: grid intervals on the half period used to bracket the knee crossings.
        tol: corrector tolerance on max|r| relative to the knee distance d.
        step, step_min, step_max: arc-length steps (unknowns scaled by d, Omega by the linear
            mode).
        max_steps: safety limit of continuation steps per branch.
        xi_stop: continuation stops once xi exceeds this (default: 1.5 * xi_max of the caller).
        tongue_share: a point is on a flat branch (tongue) when one harmonic n >= 2 carries more
            than this share of the time-averaged kinetic energy; it is on the backbone when the
            fundamental carries at least 1 - tongue_share.
    """

    n_harmonics: int = 20
    n_grid: int = 1024
    tol: float = 1e-11
    step: float = 0.02
    step_min: float = 1e-6
    step_max: float = 0.02
    max_steps: int = 4000
    xi_stop: float | None = None
    tongue_share: float = 0.25


@dataclass
class NNMBranch:
    """One NNM branch, points ordered along the continuation (arc length).

    Attributes:
        region: 'primary' or 'secondary': where the static wind-up lies.
        mode: index of the linear mode the branch starts from (modal.modes order, 0 = rigid).
        windup_static: static wind-up w_s [rad]; distance: |theta - w_s| [rad].
        linear_frequency_hz: the start mode's frequency at K_lin [Hz]; e_nl: E_nl [J].
        xi: (p,) E / E_nl; frequency_hz: (p,) base frequency Omega / 2 pi [Hz]; energy: (p,) E [J].
        coefficients: (p, H+1) wind-up deviation cosine coefficients a_n [rad].
        shares: (p, H+1) share of each harmonic in the time-averaged kinetic energy.
        residual: (p,) max|r| at convergence [rad].
        segment: (p,) continuation piece: 0, 1, ... along the backbone (a new piece starts past a
            tongue cut at xi_stop); -1 - k: the far side of the tongue that ended piece k, traced
            from the restart point back up to xi_stop (reversed, so it runs down into piece k + 1).
    """

    region: str
    mode: int
    windup_static: float
    distance: float
    linear_frequency_hz: float
    e_nl: float
    xi: np.ndarray
    frequency_hz: np.ndarray
    energy: np.ndarray
    coefficients: np.ndarray
    shares: np.ndarray
    residual: np.ndarray
    segment: np.ndarray
    tongue_share: float = 0.25

    @property
    def dominant_harmonic(self) -> np.ndarray:
        """(p,) harmonic carrying most kinetic energy (1 on the backbone)."""
        return self.shares.argmax(axis=1)

    @property
    def tongue_harmonic(self) -> np.ndarray:
        """(p,) harmonic n >= 2 with the largest kinetic-energy share, or 0 where no harmonic
        n >= 2 carries more than ``tongue_share`` (the point is not on a flat branch)."""
        if self.shares.shape[1] <= 2:
            return np.zeros(len(self.xi), int)
        n = self.shares[:, 2:].argmax(axis=1) + 2
        return np.where(self.shares[np.arange(len(n)), n] > self.tongue_share, n, 0)

    @property
    def backbone(self) -> np.ndarray:
        """Boolean mask of the backbone points: the fundamental carries most of the kinetic
        energy (near a flat branch a point can be both: the branch bends into the tongue)."""
        return self.shares[:, 1] >= 0.5

    def frequency_at(self, xi) -> np.ndarray:
        """Backbone frequency [Hz] at the given xi: linear interpolation at the first crossing of
        xi on the backbone (near a flat branch the backbone is two-valued: the crossing where the
        fundamental's kinetic-energy share is largest wins). NaN where xi is not reached."""
        xi = np.atleast_1d(np.asarray(xi, float))
        out = np.full(xi.shape, np.nan)
        ok = self.backbone & (self.segment >= 0)
        pair = ok[:-1] & ok[1:] & (self.segment[:-1] == self.segment[1:])
        x0, x1 = self.xi[:-1], self.xi[1:]
        f0, f1 = self.frequency_hz[:-1], self.frequency_hz[1:]
        for j, v in enumerate(xi):
            tol = 1e-9 * max(abs(v), 1.0)
            hit = np.flatnonzero(pair & (np.minimum(x0, x1) <= v + tol)
                                 & (np.maximum(x0, x1) >= v - tol))
            if len(hit):
                purity = np.minimum(self.shares[hit, 1], self.shares[hit + 1, 1])
                i = hit[int(np.argmax(purity))]
                w = 0.0 if x1[i] == x0[i] else min(max((v - x0[i]) / (x1[i] - x0[i]), 0.0), 1.0)
                out[j] = f0[i] + w * (f1[i] - f0[i])
        return out

@dataclass
class FlatBranch:
    """A flat branch (internal-resonance tongue) of an NNM branch."""

    region: str
    # n: n * base frequency ~ subsystem resonance (the figure's label)
    harmonic: int
    frequency_hz: float           # base frequency on the tongue (median) [Hz]
    xi_min: float
    xi_max: float
    subsystem: str                # 'front' or 'rear' of the DMF
    subsystem_frequency_hz: float
    resonance_hz: float           # nearest linear resonance of the whole driveline at K_lin
    clamped_frequency_hz: float   # nearest natural frequency with the DMF wind-up clamped

    def as_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                for k, v in self.__dict__.items()}


@dataclass
class NNMResult:
    """Both branches of one NNM family (paper Fig. 14) and the reference frequencies."""

    driveline: str
    alpha: float
    theta: float
    mode: int
    branches: dict[str, NNMBranch]
    linear_frequencies_hz: dict[str, np.ndarray]
    subsystem_frequencies_hz: dict[str, np.ndarray]
    clamped_frequencies_hz: np.ndarray
    flat_branches: list[FlatBranch] = field(default_factory=list)
    n_harmonics: int = 0

    def as_dict(self, xi_max: float | None = None) -> dict:
        out = {
            'driveline': self.driveline, 'alpha': self.alpha, 'theta_rad': self.theta,
            'mode': self.mode,
            'n_harmonics': self.n_harmonics,
            'linear_frequencies_hz': {r: [float(f) for f in v]
                                      for r, v in self.linear_frequencies_hz.items()},
            'subsystem_frequencies_hz': {r: [float(f) for f in v]
                                         for r, v in self.subsystem_frequencies_hz.items()},
            'clamped_frequencies_hz': [float(f) for f in self.clamped_frequencies_hz],
            'flat_branches': [fb.as_dict() for fb in self.flat_branches],
            'branches': {},
        }
        for name, br in self.branches.items():
            m = np.ones(len(br.xi), bool) if xi_max is None else br.xi <= xi_max
            out['branches'][name] = {
                'region': br.region, 'windup_static_rad': br.windup_static,
                'distance_rad': br.distance,
                'linear_frequency_hz': br.linear_frequency_hz, 'e_nl_J': br.e_nl,
                'xi': [float(v) for v in br.xi[m]],
                'frequency_hz': [float(v) for v in br.frequency_hz[m]],
                'segment': [int(v) for v in br.segment[m]],
                'fundamental_share': [float(v) for v in br.shares[m, 1]],
                'tongue_harmonic': [int(v) for v in br.tongue_harmonic[m]],
            }
        return out
