"""Pacing of the live simulation against the wall clock, its lag statistics and its time stamps.

ROS-free (used by :mod:`dmf_sim.live.run_loop`; unit-tested without DDS).

* :func:`publish_stride` — Newmark steps between published samples; a rate the step cannot
  divide is refused with the nearest rates that it can.
* :class:`Pacer` — locks simulated time to the wall clock scaled by the real-time factor. On every
  tick the node integrates *up to the wall clock* (``floor((wall - wall0) * rtf / dt)`` steps since
  the anchor, minus the steps already done), so timer jitter never makes the simulation drift:
  a late tick integrates more steps. The lag (wall minus simulated time, in wall seconds) is
  measured at every tick; above ``max_lag`` an *overrun* is counted and the policy applies:

  - ``skip`` (default): skip ahead — the backlog is dropped and the pacing re-anchored at (now,
    current step). The node is live again at once. The physics (state, crank angle) continues
    from where it was, as if paused for the skipped interval; the published time (stamps,
    /clock, bag log times) jumps ahead by it so it stays locked to the wall clock, leaving a gap
    in the stamps. Every skip is counted and its length reported (``skipped_s``).
  - ``catch_up``: the backlog is integrated, at most ``max_lag`` worth of simulated time per
    tick (so the node stays responsive), until the lag is back under ``max_lag``.

* :class:`LagStats` — per-sample lag statistics (window and since start, histogram based).
* :class:`TimeBase` — the published stamps and the bag's log times of simulated time, and the
  re-anchoring to the wall clock when pacing returns to real time (see its docstring).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.numbers import fmt_num

__all__ = ['OVERRUN_POLICIES', 'STRIDE_TOLERANCE', 'NS_PER_S', 'publish_stride',
           'TickPlan', 'Pacer', 'LagStats', 'TimeBase']

OVERRUN_POLICIES = ('skip', 'catch_up')
STRIDE_TOLERANCE = 1e-6     # relative: 1/(rate dt) closer than this to an integer divides
NS_PER_S = 1_000_000_000


def publish_stride(publish_rate_hz: float, dt: float, *, rate_name: str = 'publish_rate',
                   dt_name: str = 'dt') -> int:
    """Newmark steps between published samples, ``1 / (publish_rate * dt)``, an integer >= 1.

    Raises ConfigError if the rate is not positive, faster than one sample per step, or not a
    whole number of steps per sample (e.g. 3000 Hz at dt = 1e-4 s: 3.33 steps); the message
    names the nearest rates that are. ``rate_name`` / ``dt_name``: what the messages call the
    two, as the user set them (the node's parameters by default; ``--rate`` and ``--dt`` of
    ``dmf-sim run``).
    """
    if not (math.isfinite(publish_rate_hz) and publish_rate_hz > 0):
        raise ConfigError(f'{rate_name} must be > 0 Hz, got {publish_rate_hz!r}')
    step_rate = 1.0 / dt
    ratio = step_rate / publish_rate_hz
    if ratio < 1.0 - STRIDE_TOLERANCE:
        raise ConfigError(f'{rate_name} {fmt_num(publish_rate_hz)} Hz is faster than the step '
                          f'rate of {dt_name} = {fmt_num(dt)} s ({fmt_num(step_rate)} Hz): give '
                          f'{rate_name} {fmt_num(step_rate)} Hz or less, or {dt_name} '
                          f'{fmt_num(1.0 / publish_rate_hz)} s or less')
    n = max(int(round(ratio)), 1)
    if abs(ratio - n) > STRIDE_TOLERANCE * ratio:
        lo, hi = math.floor(ratio), math.ceil(ratio)
        raise ConfigError(
            f'{rate_name} {fmt_num(publish_rate_hz)} Hz is not a whole number of steps of '
            f'{dt_name} = {fmt_num(dt)} s ({ratio:.4g} steps per sample); nearest rates: '
            f'{step_rate / lo:.6g} Hz (every {lo} steps) or {step_rate / hi:.6g} Hz '
            f'(every {hi} steps)')
    return n


# ------------------------------------------------------------------------------------------------
# Pacing
# ------------------------------------------------------------------------------------------------

@dataclass
class TickPlan:
    """What one tick integrates: ``nsteps`` steps; ``lag`` [wall s] before integrating;
    ``overrun`` when this tick started a new overrun; ``skipped`` [wall s] dropped by this tick
    (the caller moves its published time ahead by ``skipped * real_time_factor``)."""

    nsteps: int
    lag: float
    overrun: bool = False
    skipped: float = 0.0


class Pacer:
    """Simulated time locked to a scaled wall clock (``real_time_factor``), or as fast as possible.

    Args:
        dt: Newmark step [s].
        real_time_factor: simulated seconds per wall second; 0 = as fast as possible.
        max_lag: lag [wall s] above which a tick counts as an overrun.
        policy: ``'skip'`` or ``'catch_up'`` (module docstring).
    """

    def __init__(self, dt: float, real_time_factor: float = 1.0, max_lag: float = 0.05,
                 policy: str = 'skip') -> None:
        if policy not in OVERRUN_POLICIES:
            raise ConfigError(f'overrun_policy must be one of {OVERRUN_POLICIES}, got {policy!r}')
        self.dt = float(dt)
        self.rtf = float(real_time_factor)
        self.max_lag = float(max_lag)
        self.policy = policy
        self.wall0 = 0.0
        self.step0 = 0
        self.overruns = 0
        self.skipped = 0.0        # wall seconds of backlog dropped (policy 'skip')
        self.behind = False

    @property
    def fast(self) -> bool:
        return self.rtf <= 0.0

    def anchor(self, now: float, steps: int) -> None:
        """Lock simulated step ``steps`` to wall time ``now``."""
        self.wall0 = float(now)
        self.step0 = int(steps)
        self.behind = False

    def set_rate(self, real_time_factor: float, now: float, steps: int) -> None:
        """Change the real-time factor without a jump (re-anchor at the current state)."""
        self.rtf = float(real_time_factor)
        self.anchor(now, steps)

    def due_steps(self, now: float) -> int:
        """Step count the simulation should have reached at wall time ``now``."""
        return self.step0 + int(math.floor((now - self.wall0) * self.rtf / self.dt + 1e-6))

    def due_wall(self, step):
        """Wall time at which simulated step ``step`` (scalar or array) is due."""
        return self.wall0 + (np.asarray(step, dtype=float) - self.step0) * self.dt / self.rtf

    def due_wall_scalar(self, step: int) -> float:
        """:meth:`due_wall` for one step, in plain Python (hot path)."""
        return self.wall0 + (step - self.step0) * self.dt / self.rtf

    def lag(self, now: float, steps: int) -> float:
        """Wall minus simulated time [wall s] (0 in fast mode)."""
        if self.fast:
            return 0.0
        return (now - self.wall0) - (steps - self.step0) * self.dt / self.rtf

    def plan(self, now: float, steps: int) -> TickPlan:
        """Steps to integrate on a real-time tick at wall time ``now`` having done ``steps``."""
        if self.fast:
            raise RuntimeError('plan() is for real-time pacing; fast mode integrates chunks')
        lag = self.lag(now, steps)
        n = max(self.due_steps(now) - steps, 0)
        if lag <= self.max_lag:
            self.behind = False
            return TickPlan(n, lag)
        new = not self.behind
        if new:
            self.overruns += 1
        if self.policy == 'skip':
            self.skipped += lag
            self.anchor(now, steps)
            return TickPlan(0, lag, overrun=True, skipped=lag)
        self.behind = True
        cap = max(int(math.ceil(self.max_lag * self.rtf / self.dt)), 1)
        return TickPlan(min(n, cap), lag, overrun=new)

    def next_tick(self, now: float, next_sample_step: int, min_period: float = 5e-4,
                  max_period: float = 1e-2) -> float:
        """Wall time of the next tick: when the next sample is due, clamped to
        [now + min_period, now + max_period] (ticks keep ramps and excitation fresh)."""
        if self.fast:
            return now
        due = float(self.due_wall(next_sample_step))
        return min(max(due, now + min_period), now + max_period)


class LagStats:
    """Lag statistics [s]: a window (reset on read) and a histogram since start (0.05 ms bins up
    to 1 s, then an overflow bin) for percentiles over the whole run. One entry per published
    sample, plus one per skip-ahead tick (its lag is the overrun: it published nothing)."""

    BIN = 5e-5
    NBINS = 20000

    def __init__(self) -> None:
        self.hist = np.zeros(self.NBINS + 1, dtype=np.int64)
        self.count = 0
        self.max = 0.0
        self._window: list[float] = []

    def add(self, lags) -> None:
        if isinstance(lags, float):   # the usual case: one sample per tick
            x = max(lags, 0.0)
            self.hist[min(int(x / self.BIN), self.NBINS)] += 1
            self.count += 1
            if x > self.max:
                self.max = x
            self._window.append(x)
            return
        lags = np.asarray(lags, dtype=float)
        if lags.size == 0:
            return
        lags = np.maximum(lags.reshape(-1), 0.0)
        idx = np.minimum((lags / self.BIN).astype(np.int64), self.NBINS)
        np.add.at(self.hist, idx, 1)
        self.count += lags.size
        self.max = max(self.max, float(lags.max()))
        self._window.extend(lags.tolist())

    def total_percentile(self, p: float) -> float:
        """p-th percentile [s] since start (bin upper edge; nan if empty)."""
        if self.count == 0:
            return float('nan')
        k = int(np.searchsorted(np.cumsum(self.hist), math.ceil(p / 100.0 * self.count)))
        return (k + 1) * self.BIN if k < self.NBINS else self.max

    def take_window(self) -> dict[str, float]:
        """Stats of the samples since the last call: n, p50, p99, max [s]."""
        if not self._window:
            return {'n': 0, 'p50': float('nan'), 'p99': float('nan'), 'max': float('nan')}
        w = np.asarray(self._window)
        self._window = []
        return {'n': int(w.size), 'p50': float(np.percentile(w, 50)),
                'p99': float(np.percentile(w, 99)), 'max': float(w.max())}


# ------------------------------------------------------------------------------------------------
# Time stamps
# ------------------------------------------------------------------------------------------------

class TimeBase:
    """Stamps [ns] of simulated time: what the node publishes and what it writes to its bag.

    * stamp = ``epoch + t``: the epoch is the wall clock at start minus the simulated time then,
      so at real-time factor 1 the stamps track the wall clock. A skip ahead (overrun policy
      ``skip``) moves the epoch forward by the skipped time (a gap in the stamps).
    * When pacing returns to real time at factor 1 after running at another factor (fast mode,
      or x2, x0.5), the stamps are *re-anchored* to the wall clock (:meth:`reanchor`): after a
      fast spell they jump back by the time gained (27 s after 3 s at x10).
    * bag log time = ``stamp + log_offset``: a backward re-anchoring adds its jump to the offset,
      so the log times of a recording never run backward (rosbag2 players and ``dmf-sim
      analyze`` order messages by log time); :meth:`new_recording` resets the offset, so a new
      bag starts with log time = stamp. Forward jumps (skips) move both alike.
    """

    def __init__(self) -> None:
        self.epoch_ns = 0
        self.log_offset_ns = 0
        self.reanchors = 0
        self.last_jump_s = 0.0

    def start(self, wall_ns: int, t: float) -> None:
        """Stamp of simulated time ``t`` := wall clock ``wall_ns``."""
        self.epoch_ns = int(wall_ns) - int(round(t * 1e9))

    def stamp_ns(self, t: float) -> int:
        return self.epoch_ns + int(round(t * 1e9))

    def stamps_ns(self, t: np.ndarray) -> np.ndarray:
        """:meth:`stamp_ns` of an array of simulated times (int64)."""
        return self.epoch_ns + np.rint(np.asarray(t) * 1e9).astype(np.int64)

    def skip(self, seconds: float) -> None:
        """Published time jumps ahead by ``seconds`` (skip ahead after an overrun)."""
        self.epoch_ns += int(round(seconds * 1e9))

    def reanchor(self, wall_ns: int, t: float) -> float:
        """Stamp of ``t`` := ``wall_ns``; returns the jump [s] (negative = back in time)."""
        jump = int(wall_ns) - self.stamp_ns(t)
        self.epoch_ns += jump
        if jump < 0:
            self.log_offset_ns -= jump
        self.reanchors += 1
        self.last_jump_s = jump / 1e9
        return self.last_jump_s

    def new_recording(self) -> None:
        """A new bag: its log times start equal to the stamps."""
        self.log_offset_ns = 0
