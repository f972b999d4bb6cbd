"""Durability figures of a record, accumulated batch by batch (bounded memory).

Inputs per sample: time [ns], DMF wind-up w [rad] and its rate dw/dt [rad/s], engine speed
[rpm], crank angle psi [rad]. What is counted:

* the spring torque T(w) = k w + g(w) [Nm] (:meth:`PiecewiseLinearSpring.torque`; the viscous
  damper torque c dw/dt is not part of the spring's load): a histogram of the time spent per
  torque bin, rainflow cycles (:class:`StreamingRainflow`) in a range x mean matrix, and the
  Palmgren-Miner damage with the S-N curve, in total and per engine-speed band (a cycle counts
  in the band of the window, ``window_s`` long at most, in which it closed; the residue's half
  cycles, open over the whole record, count in no band: ``damage_residue``);
* time, torque range and mean per spring stage (primary, drive stage i, coast stage j);
* the largest torques (|T|) with time and speed, at least ``largest_separation_s`` apart;
* the power the DMF's viscous damping dissipates, c (dw/dt)^2 [W], averaged per engine cycle
  (720 deg of crank angle; every complete cycle is kept: its start, mean power and mean speed,
  24 bytes, e.g. 1.4 MB for an hour at 2000 rpm), and those per-cycle values averaged over
  ``power_time_s``. With arc-spring friction in the spring (doc/theory.md eq. 8a) its power
  T_f(dw/dt, Omega) dw/dt is added: the real DMF's heat, usually larger than the viscous part
  (both energies are reported apart too); without it (the paper's model) the viscous power alone;
* with end stops (eq. 8b): the contacts (entries beyond a stop, on the samples), the largest
  contact torque |T_s(w, dw/dt)| [Nm] of the samples (the impact), and the power the contact's
  damping dissipates, c_s (dw/dt)^2 while a stop pushes (:meth:`EndStops.damping_power`), added
  to the dissipated power and reported apart (``stop_energy_j``).

A record no driveline can produce is refused (BagError, one line naming the first such sample):
a value that is not finite, an engine speed beyond the ``engine_speed`` bound, a crank angle
beyond :data:`MAX_CRANK_ANGLE_RAD`, or a DMF torque
(the spring's, the damper's c dw/dt, the end stops') beyond the ``torque`` bound of
:data:`dmf_sim.core.bounds.BOUNDS` -- what a diverged simulation writes (a wind-up of 1e251 rad).
Counted, such values would overflow every figure; no damage figure of them means anything.
"""
from __future__ import annotations

import math
from array import array
from dataclasses import dataclass, field

import numpy as np

from dmf_sim.core.bounds import BOUNDS
from dmf_sim.core.errors import BagError
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.durability.rainflow import StreamingRainflow
from dmf_sim.durability.settings import DurabilitySettings
from dmf_sim.physics.orders import CYCLE_RAD

__all__ = ['MAX_GAP_STEPS', 'MAX_CRANK_ANGLE_RAD', 'StageStats', 'DurabilityResult',
           'DurabilityAccumulator']

MAX_GAP_STEPS = 100     # a time step this many median steps long is a gap (paused clock): its
                        # time is not counted

MAX_CRANK_ANGLE_RAD = CYCLE_RAD * 2.0 ** 53
"""Largest crank angle [rad] a record may hold: beyond 2^53 engine cycles a float64 angle no longer
tells one cycle from the next (its spacing exceeds 720 deg), so the power per engine cycle has
no meaning; 1.1e17 rad is 17 million years at 2000 rpm, so only a broken record gets there."""


def _add_counts(store: dict, keys: np.ndarray, weights: np.ndarray) -> None:
    """store[key] += weight, summed per key (keys: int array, or (n, 2) int array)."""
    if len(keys) == 0:
        return
    if keys.ndim == 1:
        uk, inv = np.unique(keys, return_inverse=True)
        sums = np.bincount(inv, weights=weights)
        for k, v in zip(uk.tolist(), sums.tolist()):
            store[k] = store.get(k, 0.0) + v
    else:
        uk, inv = np.unique(keys, axis=0, return_inverse=True)
        sums = np.bincount(inv.ravel(), weights=weights)
        for k, v in zip(map(tuple, uk.tolist()), sums.tolist()):
            store[k] = store.get(k, 0.0) + v


@dataclass
class StageStats:
    time_s: float = 0.0
    torque_min_nm: float = math.inf
    torque_max_nm: float = -math.inf
    torque_sum: float = 0.0        # time-weighted [Nm s]


@dataclass
class DurabilityResult:
    """What :class:`DurabilityAccumulator` found (SI; speed in rpm)."""

    duration_s: float
    samples: int
    settings: DurabilitySettings
    damage: float
    damage_per_hour: float
    cycles: float
    reversals: int
    torque_hist: dict                  # torque bin index -> time [s]
    rainflow: dict                     # (range bin, mean bin) -> cycles
    damage_by_band: dict               # speed band index -> damage of the cycles closed there
    damage_residue: float              # the residue's half cycles (open over the whole record)
    time_by_band: dict                 # speed band index -> time [s]
    stages: dict                       # stage name -> StageStats
    largest: list                      # [(|T|, T, t_s, speed_rpm)], largest first
    power_t_s: np.ndarray              # start of each power bin (power_time_s long) [s]
    power_w: np.ndarray                # mean of the per-cycle powers in the bin [W]
    power_speed_rpm: np.ndarray
    cycle_t_s: np.ndarray              # start of each complete engine cycle [s]
    cycle_power_w: np.ndarray          # its mean damping power [W]
    cycle_speed_rpm: np.ndarray        # its mean engine speed [rpm]
    power_mean_w: float
    power_max_cycle_w: float
    energy_j: float
    torque_min_nm: float
    torque_max_nm: float
    damping_nms: float
    notes: list = field(default_factory=list)
    friction_energy_j: float = 0.0     # of energy_j, the arc-spring friction's [J]
    has_friction: bool = False
    stop_energy_j: float = 0.0         # of energy_j, the end-stop contacts' damping [J]
    stop_contacts: int | None = None   # end-stop contacts (spring with stops)
    peak_stop_torque_nm: float | None = None

    def _power_note(self) -> str:
        parts = ['viscous DMF damping c (dw/dt)^2']
        if self.has_friction:
            parts.append('the arc-spring friction T_f dw/dt')
        if self.stop_contacts is not None:
            parts.append("the end stops' contact damping c_s (dw/dt)^2")
        text = ' plus '.join(parts)
        return text if self.has_friction else (text + ' of the model; the spring has no '
                                               'arc-spring friction')

    def as_dict(self) -> dict:
        s = self.settings
        band = s.speed_bin_rpm
        return {
            'duration_s': self.duration_s, 'samples': self.samples,
            'sn_curve': s.sn.as_dict(),
            'sn_curve_is_placeholder': s.sn.placeholder,
            'damage': self.damage, 'damage_per_hour': self.damage_per_hour,
            'damage_residue': self.damage_residue,
            'hours_to_failure': (1.0 / self.damage_per_hour if self.damage_per_hour > 0
                                 else None),
            'rainflow_cycles': self.cycles, 'reversals': self.reversals,
            'torque_nm': {'min': self.torque_min_nm, 'max': self.torque_max_nm},
            'stages': {name: {'time_s': st.time_s,
                              'time_fraction': st.time_s / self.duration_s
                              if self.duration_s else 0.0,
                              'torque_min_nm': st.torque_min_nm, 'torque_max_nm': st.torque_max_nm,
                              'torque_mean_nm': st.torque_sum / st.time_s if st.time_s else None}
                       for name, st in self.stages.items()},
            'speed_bands': [{'speed_from_rpm': k * band, 'speed_to_rpm': (k + 1) * band,
                             'time_s': self.time_by_band.get(k, 0.0),
                             'damage': self.damage_by_band.get(k, 0.0)}
                            for k in sorted(set(self.time_by_band) | set(self.damage_by_band))],
            'largest_torques': [{'torque_nm': tq, 't_s': t, 'speed_rpm': sp}
                                for _, tq, t, sp in self.largest],
            'dissipated_power': {'mean_w': self.power_mean_w,
                                 'max_cycle_mean_w': self.power_max_cycle_w,
                                 'engine_cycles': len(self.cycle_power_w),
                                 'energy_j': self.energy_j,
                                 'damping_nms_per_rad': self.damping_nms,
                                 'viscous_energy_j': (self.energy_j - self.friction_energy_j
                                                      - self.stop_energy_j),
                                 'friction_energy_j': self.friction_energy_j,
                                 'stop_energy_j': (self.stop_energy_j
                                                   if self.stop_contacts is not None else None),
                                 'note': self._power_note()},
            'end_stops': ({'contacts': self.stop_contacts,
                           'peak_impact_torque_nm': self.peak_stop_torque_nm}
                          if self.stop_contacts is not None else None),
            'torque_histogram': {'bin_nm': s.torque_bin_nm,
                                 'bins': [[k * s.torque_bin_nm, v]
                                          for k, v in sorted(self.torque_hist.items())]},
            'rainflow_matrix': {'range_bin_nm': s.range_bin_nm, 'mean_bin_nm': s.mean_bin_nm,
                                'cells': [[r * s.range_bin_nm, m * s.mean_bin_nm, c]
                                          for (r, m), c in sorted(self.rainflow.items())]},
            'notes': self.notes,
        }


class DurabilityAccumulator:
    """Feed samples with :meth:`add` (any batch sizes, in time order), then :meth:`finish`.

    Args:
        spring: the DMF spring (:class:`dmf_sim.physics.spring.PiecewiseLinearSpring`).
        damping_nms: the DMF's viscous damping c [Nms/rad].
        settings: S-N curve and bins.
    """

    def __init__(self, spring, damping_nms: float, settings: DurabilitySettings) -> None:
        self.spring = spring
        self.c = float(damping_nms)
        self.s = settings
        self.rf = StreamingRainflow()
        self.torque_hist: dict = {}
        self.rainflow: dict = {}
        self.damage_by_band: dict = {}
        self.time_by_band: dict = {}
        self.stages: dict[str, StageStats] = {}
        self.largest: list = []              # (|T|, T, t, speed), largest first
        self.damage = 0.0
        self.damage_residue = 0.0
        self.cycles = 0.0
        self.duration = 0.0
        self.samples = 0
        self.t_prev: int | None = None
        self.step_ns: float | None = None
        self.tmin, self.tmax = math.inf, -math.inf
        # per engine cycle power
        self._cyc_index: int | None = None
        self._cyc_energy = self._cyc_time = self._cyc_speed = 0.0
        self._cyc_t0 = 0.0
        self._cyc_whole = False              # the current cycle began at a 720 deg boundary
        self.energy = 0.0
        self.cycle_power_max = 0.0
        self._pbins: dict = {}               # power time bin -> [sum of cycle powers, n, speed]
        self._cycles = (array('d'), array('d'), array('d'))   # start [s], power [W], speed [rpm]
        self.t0_ns: int | None = None
        self.notes: list[str] = []
        self._gaps = 0
        self.friction = getattr(spring, 'friction', None)
        self.stops = getattr(spring, 'stops', None)
        self.friction_energy = 0.0
        self.stop_energy = 0.0
        self.stop_contacts = 0
        self.peak_stop_torque = 0.0
        self._beyond = 0                     # the last sample's side: +1 drive stop, -1 coast

    def set_dmf(self, spring, damping_nms: float) -> None:
        """The DMF from the next sample on: ``spring`` and viscous ``damping_nms`` [Nms/rad]
        (a DMF fault of the recording, from its time on; the counts go on)."""
        self.spring = spring
        self.c = float(damping_nms)
        self.friction = getattr(spring, 'friction', None)
        self.stops = getattr(spring, 'stops', None)

    # ---- per batch -------------------------------------------------------------------------
    def _check_physical(self, t_ns, w, wdot, speed_rpm, psi, torque) -> None:
        """Refuse the batch at its first sample no driveline can produce (module docstring)."""
        torque_hi, speed_hi = BOUNDS['torque'].hi, BOUNDS['engine_speed'].hi
        with np.errstate(over='ignore', invalid='ignore'):     # what is refused may overflow
            checks = [
                ('DMF wind-up', w, 'rad', None),
                ('DMF wind-up rate', wdot, 'rad/s', None),
                ('engine speed', speed_rpm, 'rpm', speed_hi),
                ('crank angle', psi, 'rad', MAX_CRANK_ANGLE_RAD),
                ('DMF spring torque', torque, 'Nm', torque_hi),
                ('DMF damper torque c dw/dt', self.c * wdot, 'Nm', torque_hi),
            ]
            if self.stops is not None:
                checks.append(('DMF end-stop torque', self.stops.torque(w, wdot), 'Nm',
                               torque_hi))
            first = None
            for name, x, unit, hi in checks:
                bad = ~np.isfinite(x) if hi is None else ~(np.abs(x) <= hi)
                if bad.any():
                    i = int(np.argmax(bad))
                    if first is None or i < first[0]:
                        first = (i, name, float(x[i]), unit, hi)
        if first is None:
            return
        i, name, value, unit, hi = first
        t_s = (int(t_ns[i]) - self.t0_ns) * 1e-9
        beyond = 'is not finite' if not np.isfinite(value) else f'is beyond {hi:g} {unit}'
        raise BagError(f'the record is not physical from t = {t_s:.3f} s: {name} {value:.4g} '
                       f'{unit} {beyond} (a diverged run?); durability assesses physical '
                       'records only')

    def _weights(self, t_ns: np.ndarray) -> np.ndarray:
        """Time [s] each sample stands for (the step to the next one; gaps not counted)."""
        t_all = t_ns if self.t_prev is None else np.concatenate(([self.t_prev], t_ns))
        d = np.diff(t_all).astype(float)
        if self.step_ns is None and len(d):
            pos = d[d > 0]
            self.step_ns = float(np.median(pos)) if len(pos) else None
        if self.t_prev is None:
            # the first sample's own step: take the next one's
            d = np.concatenate((d[:1] if len(d) else [0.0], d))
        if self.step_ns:
            bad = (d <= 0) | (d > MAX_GAP_STEPS * self.step_ns)
            self._gaps += int(np.count_nonzero(d > MAX_GAP_STEPS * self.step_ns))
            d[bad] = np.where(d[bad] > 0, 0.0, self.step_ns)
        return d * 1e-9

    def add(self, t_ns, w, wdot, speed_rpm, psi) -> None:
        t_ns = np.asarray(t_ns, np.int64)
        if len(t_ns) == 0:
            return
        if self.t0_ns is None:
            self.t0_ns = int(t_ns[0])
        w, wdot = np.asarray(w, float), np.asarray(wdot, float)
        speed_rpm, psi = np.asarray(speed_rpm, float), np.asarray(psi, float)
        with np.errstate(over='ignore', invalid='ignore'):
            torque = self.spring.torque(w)
        self._check_physical(t_ns, w, wdot, speed_rpm, psi, torque)
        dt = self._weights(t_ns)
        self.t_prev = int(t_ns[-1])
        self.samples += len(t_ns)
        self.duration += float(dt.sum())
        self.tmin = min(self.tmin, float(torque.min()))
        self.tmax = max(self.tmax, float(torque.max()))
        s = self.s
        _add_counts(self.torque_hist, np.floor(torque / s.torque_bin_nm).astype(np.int64), dt)
        band = np.floor(speed_rpm / s.speed_bin_rpm).astype(np.int64)
        _add_counts(self.time_by_band, band, dt)
        stage = self.spring.stage(w)
        for st in np.unique(stage).tolist():
            sel = stage == st
            rec = self.stages.setdefault(self.spring.region_name(int(st)), StageStats())
            rec.time_s += float(dt[sel].sum())
            rec.torque_min_nm = min(rec.torque_min_nm, float(torque[sel].min()))
            rec.torque_max_nm = max(rec.torque_max_nm, float(torque[sel].max()))
            rec.torque_sum += float((torque[sel] * dt[sel]).sum())
        power = self.c * wdot * wdot
        if self.friction is not None:        # eq. 8a: its heat joins the viscous one
            friction_power = self.friction.torque(wdot, speed_rpm * RPM_TO_RAD_S) * wdot
            self.friction_energy += float((friction_power * dt).sum())
            power = power + friction_power
        if self.stops is not None:           # eq. 8b: contacts and the largest impact torque
            st = self.stops
            side = (w > st.drive_angle_rad).astype(np.int64) - (w < -st.coast_angle_rad)
            prev = np.concatenate(([self._beyond], side[:-1]))
            self.stop_contacts += int(np.count_nonzero((side != 0) & (side != prev)))
            self._beyond = int(side[-1])
            self.peak_stop_torque = max(self.peak_stop_torque,
                                        float(np.abs(st.torque(w, wdot)).max()))
            stop_power = st.damping_power(w, wdot)
            self.stop_energy += float((stop_power * dt).sum())
            power = power + stop_power
        self.energy += float((power * dt).sum())
        self._cycle_power(t_ns, psi, power, dt, speed_rpm)
        self._windows(t_ns, torque, band, speed_rpm)

    def _windows(self, t_ns, torque, band, speed_rpm) -> None:
        """Rainflow and the largest torques, window by window (a window ends where the speed
        band changes or after ``window_s``)."""
        n = len(t_ns)
        step = self.step_ns or 1.0
        max_len = max(int(self.s.window_s * 1e9 / step), 1)
        cuts = np.flatnonzero(np.diff(band) != 0) + 1
        edges = [0]
        for c in list(cuts) + [n]:
            while c - edges[-1] > max_len:
                edges.append(edges[-1] + max_len)
            edges.append(int(c))
        for a, b in zip(edges[:-1], edges[1:]):
            if b <= a:
                continue
            ranges, means, counts = self.rf.add(torque[a:b])
            self._count(ranges, means, counts, int(band[a]))
            k = a + int(np.argmax(np.abs(torque[a:b])))
            self._keep_largest((abs(float(torque[k])), float(torque[k]),
                                (int(t_ns[k]) - self.t0_ns) * 1e-9, float(speed_rpm[k])))

    def _keep_largest(self, item: tuple) -> None:
        """Keep the ``largest`` biggest |T| events, at least ``largest_separation_s`` apart
        (a bigger one replaces its smaller neighbours)."""
        sep = self.s.largest_separation_s
        near = [x for x in self.largest if abs(x[2] - item[2]) < sep]
        if any(x[0] >= item[0] for x in near):
            return
        keep = [x for x in self.largest if abs(x[2] - item[2]) >= sep] + [item]
        keep.sort(reverse=True)
        self.largest = keep[:self.s.largest]

    def _count(self, ranges, means, counts, band: int | None) -> None:
        if len(ranges) == 0:
            return
        s = self.s
        d = s.sn.damage(ranges, counts)
        self.damage += d
        self.cycles += float(counts.sum())
        if band is None:
            self.damage_residue += d
        else:
            self.damage_by_band[band] = self.damage_by_band.get(band, 0.0) + d
        keys = np.stack((np.floor(ranges / s.range_bin_nm), np.floor(means / s.mean_bin_nm)),
                        axis=1).astype(np.int64)
        _add_counts(self.rainflow, keys, counts)

    def _cycle_power(self, t_ns, psi, power, dt, speed) -> None:
        """Mean dissipated power per engine cycle (720 deg of crank angle)."""
        cyc = np.floor(psi / CYCLE_RAD).astype(np.int64)
        if self._cyc_index is None:          # the record's first cycle: whole if it starts
            self._cyc_index = int(cyc[0])    # at a boundary, else it began before the record
            self._cyc_t0 = (int(t_ns[0]) - self.t0_ns) * 1e-9
            self._cyc_whole = float(psi[0]) % CYCLE_RAD == 0.0
        starts = np.flatnonzero(np.diff(np.concatenate(([self._cyc_index], cyc))) != 0)
        bounds = [0, *starts.tolist(), len(cyc)]
        for a, b in zip(bounds[:-1], bounds[1:]):
            if a > 0:                                 # a new cycle starts at a
                self._close_cycle(complete=self._cyc_whole)
                self._cyc_index = int(cyc[a])
                self._cyc_t0 = (int(t_ns[a]) - self.t0_ns) * 1e-9
                self._cyc_whole = True
            if b > a:
                self._cyc_energy += float((power[a:b] * dt[a:b]).sum())
                self._cyc_time += float(dt[a:b].sum())
                self._cyc_speed += float((speed[a:b] * dt[a:b]).sum())

    def _close_cycle(self, complete: bool = True) -> None:
        if self._cyc_time > 0 and complete:
            p = self._cyc_energy / self._cyc_time
            self.cycle_power_max = max(self.cycle_power_max, p)
            for column, value in zip(self._cycles, (self._cyc_t0, p,
                                                    self._cyc_speed / self._cyc_time)):
                column.append(value)
            k = int(self._cyc_t0 // self.s.power_time_s)
            acc = self._pbins.setdefault(k, [0.0, 0, 0.0])
            acc[0] += p
            acc[1] += 1
            acc[2] += self._cyc_speed / self._cyc_time
        self._cyc_energy = self._cyc_time = self._cyc_speed = 0.0

    # ---- the end ---------------------------------------------------------------------------
    def finish(self) -> DurabilityResult:
        ranges, means, counts = self.rf.finish()
        self._count(ranges, means, counts, None)     # the residue: open over the record
        self._close_cycle(complete=False)      # the last, partial engine cycle is left out
        keys = sorted(self._pbins)
        pt = np.array([k * self.s.power_time_s for k in keys])
        pw = np.array([self._pbins[k][0] / self._pbins[k][1] for k in keys])
        ps = np.array([self._pbins[k][2] / self._pbins[k][1] for k in keys])
        hours = self.duration / 3600.0
        if self._gaps:
            self.notes.append(f'{self._gaps} gap(s) in the time stamps (> {MAX_GAP_STEPS} '
                              'steps): their time is not counted')
        if self.s.sn.placeholder:
            self.notes.append('the S-N curve is a placeholder (config/durability.yaml): the '
                              'damage figures only compare records with each other')
        return DurabilityResult(
            duration_s=self.duration, samples=self.samples, settings=self.s,
            damage=self.damage, damage_residue=self.damage_residue,
            damage_per_hour=self.damage / hours if hours > 0 else 0.0,
            cycles=self.cycles, reversals=self.rf.reversals, torque_hist=self.torque_hist,
            rainflow=self.rainflow, damage_by_band=self.damage_by_band,
            time_by_band=self.time_by_band, stages=self.stages,
            largest=sorted(self.largest, reverse=True), power_t_s=pt, power_w=pw,
            power_speed_rpm=ps, cycle_t_s=np.array(self._cycles[0], dtype=float),
            cycle_power_w=np.array(self._cycles[1], dtype=float),
            cycle_speed_rpm=np.array(self._cycles[2], dtype=float),
            power_mean_w=self.energy / self.duration if self.duration > 0 else 0.0,
            power_max_cycle_w=self.cycle_power_max, energy_j=self.energy,
            torque_min_nm=self.tmin, torque_max_nm=self.tmax, damping_nms=self.c,
            friction_energy_j=self.friction_energy, has_friction=self.friction is not None,
            stop_contacts=self.stop_contacts if self.stops is not None else None,
            peak_stop_torque_nm=self.peak_stop_torque if self.stops is not None else None,
            stop_energy_j=self.stop_energy, notes=self.notes)
