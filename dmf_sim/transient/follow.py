"""Following a speed/load profile with the live simulation (ROS-free; ``dmf-sim run`` and the
node share it).

:class:`ProfileFollower` turns the profile's segment at the current simulated time into the
live core's setpoints: the speed setpoint is the segment's end speed, its ramp rate the one that
reaches it at the segment's end (so the kernel's exact speed ramp, and with it the excitation
phase psi = integral of omega dt, follows the table piecewise linearly); the load likewise
(:class:`dmf_sim.live.simulation.LiveSimulation` ramps the load every Newmark step). Called before
every chunk; ``dmf-sim run`` also ends its chunks at the profile's rows, so there the speed is on
the table exactly; the node calls it after every published chunk (<= one tick late, ~10 ms of
simulated time at real time, 1 ms in fast mode). After the last row the last setpoints hold and
the ramp rates the simulation had before are restored.
"""
from __future__ import annotations

from dmf_sim.transient.profiles import Profile

__all__ = ['MIN_RAMP_RPM_PER_S', 'MIN_LOAD_RAMP_PER_S', 'TIME_EPS_S', 'ProfileFollower']

MIN_RAMP_RPM_PER_S = 1e-6     # a flat segment still gets a (tiny) positive rate
MIN_LOAD_RAMP_PER_S = 1e-9
TIME_EPS_S = 1e-9             # a simulated time this close to a row counts as at the row (the
                              # stepper's time is a float sum of steps)


class ProfileFollower:
    """Drive ``sim``'s setpoints along ``profile``, starting at simulated time ``t0`` [s]
    (default: the simulation's time now)."""

    def __init__(self, profile: Profile, sim, t0: float | None = None) -> None:
        self.profile = profile
        self.sim = sim
        self.t0 = float(sim.t if t0 is None else t0)
        self._saved = (sim.speed_ramp_rpm_per_s, sim.load_ramp_per_s)
        self.segment = -1       # the profile row segment applied last
        self.done = False

    @property
    def end_s(self) -> float:
        """Simulated time [s] of the profile's last row."""
        return self.t0 + self.profile.duration_s

    def next_row_s(self, t: float) -> float:
        """Simulated time [s] of the next profile row after ``t`` (inf past the end)."""
        return self.t0 + self.profile.next_row_s(t - self.t0 + TIME_EPS_S)

    def apply(self, t: float | None = None, to_row: int | None = None) -> bool:
        """Setpoints for simulated time ``t`` (default: now); False once the profile is over
        (the last row's setpoints hold, the previous ramp rates are restored). ``to_row``: the
        row to reach (default: the end of the segment holding ``t``); the rows before it are
        passed over linearly (``dmf-sim run`` merges rows closer than its shortest chunk)."""
        if self.done:
            return False
        sim = self.sim
        t = float(sim.t if t is None else t)
        tp = t - self.t0 + TIME_EPS_S
        prof = self.profile
        if tp >= prof.duration_s - 1e-12:
            self.finish()
            return False
        i = prof.segment(tp)
        j = i + 1 if to_row is None else max(int(to_row), i + 1)
        t_end = prof.t_s[j]
        left = max(t_end - tp, 1e-12)
        speed, load = float(prof.speed_rpm[j]), float(prof.load[j])
        rate = max(abs(speed - sim.speed) / left, MIN_RAMP_RPM_PER_S)
        load_rate = max(abs(load - sim.load) / left, MIN_LOAD_RAMP_PER_S)
        sim.set_ramps(rate, load_rate)
        if reason := sim.set_speed_setpoint(speed):
            raise ValueError(reason)
        if reason := sim.set_load_setpoint(load):
            raise ValueError(reason)
        self.segment = i
        return True

    def finish(self) -> None:
        """End of the profile (or stopped): setpoints = last row, ramp rates restored."""
        if self.done:
            return
        self.done = True
        sim = self.sim
        sim.set_speed_setpoint(float(self.profile.speed_rpm[-1]))
        sim.set_load_setpoint(float(self.profile.load[-1]))
        sim.set_ramps(*self._saved)

    def progress(self, t: float | None = None) -> float:
        """Fraction of the profile done (0..1)."""
        t = float(self.sim.t if t is None else t)
        d = self.profile.duration_s
        return 1.0 if d <= 0 else min(max((t - self.t0) / d, 0.0), 1.0)

    def describe(self) -> str:
        p = self.profile
        return (f'profile {p.name}: {len(p)} rows, {p.duration_s:g} s, '
                f'{p.speed_rpm.min():g}-{p.speed_rpm.max():g} rpm, load '
                f'{p.load.min():g}-{p.load.max():g}')

