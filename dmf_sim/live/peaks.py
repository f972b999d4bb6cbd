"""The extremes of a transient: peak wind-up (both signs), the DMF torque there and the end stops.

What ``dmf-sim run`` reports in its summary, what the node's health gives since its start or its
last ``~/reset`` and what a design study's load steps measure (``dmf_sim.design.transient``), in
one place. :class:`WindupPeaks` observes the wind-up of every recorded step (the samples, every
``stride``-th Newmark step) and, where the integrator gives them, the wind-up's extremes over
every step (:attr:`dmf_sim.solvers.newmark.NewmarkIntegrator.windup_extremes`): the peaks do not
depend on the output rate (without them a 60 Hz 3rd order's crest is missed by up to 2 % of its
amplitude at 1 kHz, by all of it at a rate below the order's):

* ``peak_windup_rad``: the smallest and the largest wind-up [rad] (negative: coast side);
* ``peak_dmf_torque_nm``: the spring's torque T(w) [Nm] at those two wind-ups (the spring is
  monotone, so these are the extremes of the spring torque; the same quantity as the design
  metric ``max_dmf_torque``);
* with end stops (the spring's ``stop_angles_rad``: (coast < 0, drive > 0) wind-ups, None when
  the spring has none): ``travel_margin_rad``, the smallest distance of the wind-up to a stop
  (negative: beyond it), and ``stop_contacts``, how often the wind-up went from inside to beyond
  a stop. Without stops the two are not reported (no stop, no contact, no margin).
* with the spring's end-stop law (``spring.stops``, doc/theory.md eq. 8b) the contacts are the
  Newmark kernel's, counted at every step (:meth:`WindupPeaks.observe_law`), and
  ``peak_stop_torque_nm`` is the largest contact torque |T_s| [Nm]: the impact;
* with arc-spring friction (eq. 8a) ``friction_heat_j``: the friction's work [J], its heat.

A driveline without a DMF has no wind-up and no DMF torque: the peak fields are left out (only
``since_s`` remains), as the end-stop fields are without stops, and :func:`peaks_text` says so.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['WindupPeaks', 'stop_angles', 'peaks_text', 'NO_EXTREMES', 'merge_extremes']

NO_EXTREMES = (math.nan,) * 4
"""(smallest wind-up, its time, largest wind-up, its time) before any step."""


def merge_extremes(a: tuple, b: tuple) -> tuple:
    """The wind-up extremes (smallest [rad], its time [s], largest [rad], its time [s]) of two
    stretches of steps together; a stretch without steps is all nan."""
    lo = a if not b[0] < a[0] and not math.isnan(a[0]) else b
    hi = a if not b[2] > a[2] and not math.isnan(a[2]) else b
    return (lo[0], lo[1], hi[2], hi[3])


def stop_angles(spring) -> tuple[float, float] | None:
    """The end stops of ``spring`` as (coast < 0, drive > 0) wind-ups [rad], or None (no spring,
    or a spring without stops)."""
    stops = getattr(spring, 'stop_angles_rad', None) if spring is not None else None
    return None if stops is None else (float(stops[0]), float(stops[1]))


class WindupPeaks:
    """Running extremes of the wind-up (module docstring), since construction or :meth:`reset`.

    Args:
        spring: the DMF spring (``PiecewiseLinearSpring``) or None (a driveline without DMF).
        t_s: the simulated time [s] the peaks start at: samples recorded before it are left out
            of the wind-up's extremes (a later time leaves out a settling from static
            equilibrium); the kernel's figures (:meth:`observe_law`) count from construction.
    """

    def __init__(self, spring, t_s: float = 0.0) -> None:
        self.spring = spring
        self.reset(t_s)

    def reset(self, t_s: float = 0.0) -> None:
        """Forget the peaks; the next ones start at simulated time ``t_s`` [s] (the samples
        before it are left out; the kernel's figures of :meth:`observe_law` count from now)."""
        self.since_s = float(t_s)
        self.lo = self.hi = math.nan
        self.t_lo = self.t_hi = math.nan
        self.torque_lo = self.torque_hi = math.nan
        self.contacts = 0
        self.margin = math.inf
        self._beyond = False
        self.law_contacts = 0
        self.peak_stop_torque = 0.0
        self.friction_heat = 0.0

    def observe_law(self, contacts: int, heat_j: float, peak_stop_torque_nm: float) -> None:
        """Take one chunk's figures of the kernel (every step, not only the recorded ones):
        end-stop ``contacts`` begun in it, the friction's work ``heat_j`` [J] and the largest
        contact torque |T_s| [Nm] (eq. 8a-8b)."""
        self.law_contacts += int(contacts)
        self.friction_heat += float(heat_j)
        self.peak_stop_torque = max(self.peak_stop_torque, float(peak_stop_torque_nm))

    def set_spring(self, spring) -> None:
        """The spring from now on (a new DMF: the torques at later peaks use it)."""
        self.spring = spring

    @property
    def observed(self) -> bool:
        return not math.isnan(self.lo)

    def _torque(self, w: float) -> float:
        return float(self.spring.torque(w)) if self.spring is not None else math.nan

    def observe(self, windup: np.ndarray, t: np.ndarray, extremes: tuple | None = None
                ) -> None:
        """Take the wind-ups [rad] recorded at times ``t`` [s] (one chunk, in time order), those
        from :attr:`since_s` on, and the chunk's ``extremes`` over every step (smallest wind-up
        [rad], its time [s], largest, its time: :func:`merge_extremes`' layout; None or nan: the
        samples alone), each where its time is from :attr:`since_s` on."""
        after = np.asarray(t) >= self.since_s
        if not after.all():
            windup, t = np.asarray(windup)[after], np.asarray(t)[after]
        chunk = NO_EXTREMES
        if len(windup):
            i_lo, i_hi = int(np.argmin(windup)), int(np.argmax(windup))
            chunk = (float(windup[i_lo]), float(t[i_lo]), float(windup[i_hi]), float(t[i_hi]))
        if extremes is not None:
            lo, t_lo, hi, t_hi = extremes
            steps = (lo if t_lo >= self.since_s else math.nan, t_lo,
                     hi if t_hi >= self.since_s else math.nan, t_hi)
            chunk = merge_extremes(chunk, steps)
        lo, t_lo, hi, t_hi = chunk
        if math.isnan(lo) and math.isnan(hi):
            return
        if not math.isnan(lo) and not self.lo <= lo:       # NaN (first chunk) or a new minimum
            self.lo, self.t_lo, self.torque_lo = lo, t_lo, self._torque(lo)
        if not math.isnan(hi) and not self.hi >= hi:
            self.hi, self.t_hi, self.torque_hi = hi, t_hi, self._torque(hi)
        stops = stop_angles(self.spring)
        if stops is not None:
            coast, drive = stops
            self.margin = min(self.margin, drive - self.hi, self.lo - coast)
            if len(windup):
                beyond = (windup >= drive) | (windup <= coast)
                entries = int(np.count_nonzero(beyond[1:] & ~beyond[:-1]))
                self.contacts += entries + int(bool(beyond[0]) and not self._beyond)
                self._beyond = bool(beyond[-1])

    def as_dict(self) -> dict:
        """The JSON/summary form: ``peak_windup_rad`` [min, max], ``peak_dmf_torque_nm`` [at
        min, at max], their times ``peak_windup_t_s``, ``since_s``; with end stops also
        ``travel_margin_rad`` and ``stop_contacts`` (module docstring); without a DMF only
        ``since_s``."""
        if self.spring is None:
            return {'since_s': self.since_s}
        out = {'peak_windup_rad': [self.lo, self.hi],
               'peak_dmf_torque_nm': [self.torque_lo, self.torque_hi],
               'peak_windup_t_s': [self.t_lo, self.t_hi], 'since_s': self.since_s}
        if stop_angles(self.spring) is not None:
            out['travel_margin_rad'] = self.margin if self.observed else math.nan
            law = getattr(self.spring, 'stops', None) is not None
            out['stop_contacts'] = self.law_contacts if law else self.contacts
            if law:
                out['peak_stop_torque_nm'] = self.peak_stop_torque
        if getattr(self.spring, 'friction', None) is not None:
            out['friction_heat_j'] = self.friction_heat
        return out


def peaks_text(d: dict) -> str:
    """One line for people from :meth:`WindupPeaks.as_dict` (or a run summary holding its keys):
    ``peak wind-up -0.0512 .. 0.3021 rad, DMF torque -558 .. 3601 Nm`` and the end stops'
    margin and contacts where the spring has stops; ``no DMF: no wind-up, no DMF torque``
    without one."""
    if 'peak_windup_rad' not in d:
        return 'no DMF: no wind-up, no DMF torque'
    (w_lo, w_hi), (t_lo, t_hi) = d['peak_windup_rad'], d['peak_dmf_torque_nm']
    text = (f'peak wind-up {w_lo:.4f} .. {w_hi:.4f} rad, DMF torque {t_lo:.0f} .. {t_hi:.0f} '
            'Nm')
    if 'stop_contacts' in d:
        text += (f'; end stops: travel margin {d["travel_margin_rad"]:.4f} rad, '
                 f'{d["stop_contacts"]} contacts')
        if d.get('peak_stop_torque_nm') is not None:
            text += f', peak impact {d["peak_stop_torque_nm"]:.0f} Nm'
    if d.get('friction_heat_j') is not None:
        text += f'; friction heat {d["friction_heat_j"]:.1f} J'
    return text
