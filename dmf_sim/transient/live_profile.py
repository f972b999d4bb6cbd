"""Profiles for a running node, ROS-free: the node's ``profile`` parameter
(:class:`NodeProfile`) and ``dmf-sim setpoint --profile`` (:class:`ProfilePlayer`).

* :class:`NodeProfile` follows a profile inside the node: set parameter ``profile`` to a profile
  (file, packaged name, ``ramp:`` or ``step:`` spec,
  :func:`dmf_sim.transient.profiles.read_profile`) and
  the node's speed and load setpoints follow it from that moment of simulated time
  (:class:`ProfileFollower`, called after every published chunk in the tick thread); ``''``
  stops it (the setpoints stay where they are). A profile whose speeds lie outside the node's
  ``speed_min_rpm``/``speed_max_rpm``, a braking load for an engine without a brake curve or a
  load change faster than one Newmark step is refused with the reason. A ``step:`` profile is
  how a fast tip-in reaches the node (the rise as given, down to one step ``dt``); the parameter
  ``load_ramp_per_s`` limits only the setpoint topics (at most 1000/s: 0 -> 1 in 1 ms). While it
  runs, setpoints arriving on the topics are overridden at the next chunk. The DMF monitor hears
  every new segment's setpoints like topic setpoints.
* :class:`ProfilePlayer` says which setpoints to publish at a wall-clock time: the profile
  interpolated at ``publish_hz``; the node ramps toward each at its ``speed_ramp_rpm_per_s``
  (so slopes steeper than that are limited by it).
"""
from __future__ import annotations

from dmf_sim.core.errors import DmfSimError, one_line
from dmf_sim.transient.follow import ProfileFollower
from dmf_sim.transient.profiles import Profile, read_profile

__all__ = ['PLAYER_RATE_HZ', 'check_profile', 'NodeProfile', 'ProfilePlayer']

PLAYER_RATE_HZ = 20.0        # setpoints per wall second from ``dmf-sim setpoint --profile``


def check_profile(value: str, speed_limits_rpm: tuple[float, float], *, engine=None,
                  dt: float | None = None) -> tuple[Profile | None, str | None]:
    """(profile, None) or (None, why ``value`` is refused); '' = no profile. Its speeds within
    the node's ``speed_limits_rpm``, and where given its loads torque demands ``engine`` accepts
    and no load change faster than one Newmark step ``dt`` [s]."""
    if not value:
        return None, None
    try:
        prof = read_profile(value)
        prof.check_runnable(speed_limits_rpm, engine, dt,
                            speed_what="the node's speed_min_rpm/speed_max_rpm",
                            dt_what="the node's dt")
    except (DmfSimError, OSError) as exc:   # the message names the profile (read_profile)
        return None, one_line(exc)
    return prof, None


class NodeProfile:
    """The ``profile`` parameter of a :class:`dmf_sim.live.runtime.LiveRuntime`."""

    def __init__(self, runtime, log) -> None:
        self.rt, self.log = runtime, log
        self.follower: ProfileFollower | None = None
        self._segment = -1
        runtime.loop.observers.append(self._observe)

    def _checked(self, value: str) -> tuple[Profile | None, str | None]:
        sim = self.rt.sim
        return check_profile(value, sim.speed_limits_rpm, engine=sim.engine, dt=sim.dt)

    def check(self, value: str) -> str | None:
        return self._checked(value)[1]

    def start(self, value: str) -> str | None:
        """At start-up: follow ``value`` ('' = none); returns why it is refused, or None."""
        if reason := self.check(value):
            return reason
        if value:
            self.apply(value)
        return None

    def apply(self, value: str) -> str:
        """Start following ``value`` now ('' stops); returns what happened (for the log)."""
        prof, reason = self._checked(value)
        if reason:
            return reason
        with self.rt.lock:
            if self.follower is not None:
                self.follower.finish()
                self.follower = None
            if prof is None:
                msg = 'profile stopped; setpoints from the topics again'
            else:
                self.follower = ProfileFollower(prof, self.rt.sim)
                self._step()
                msg = f'following {self.follower.describe()} from t = {self.rt.sim.t:.3f} s'
        self.log.info(msg)
        return msg

    def _step(self) -> None:
        f = self.follower
        sim = self.rt.sim
        if not f.apply(sim.t):
            self.follower = None
            self.log.info(f'profile {f.profile.name} done at t = {sim.t:.3f} s; holding '
                          f'{sim.speed_setpoint:g} rpm, load {sim.load_setpoint:g}')
        seg = f.segment
        if seg != self._segment:
            self._segment = seg
            for listener in self.rt.loop.setpoint_listeners:
                listener(sim.speed_setpoint, sim.load_setpoint)

    def _observe(self, samples, stamps_ns) -> None:      # tick thread, lock held
        if self.follower is not None:
            self._step()


class ProfilePlayer:
    """Setpoints of ``profile`` over wall-clock time from ``t0`` [s] (monotonic clock)."""

    def __init__(self, profile: Profile, t0: float, rate_hz: float = PLAYER_RATE_HZ) -> None:
        self.profile, self.t0, self.period = profile, float(t0), 1.0 / rate_hz

    def setpoints(self, now: float) -> tuple[float, float]:
        """(speed [rpm], load) due at wall time ``now``."""
        speed, load = self.profile.at(now - self.t0)
        return float(speed), float(load)

    def done(self, now: float) -> bool:
        return now - self.t0 >= self.profile.duration_s

    def next_time(self, now: float) -> float:
        """When to publish next (a period later; the last row exactly)."""
        end = self.t0 + self.profile.duration_s
        nxt = now + self.period
        return end if nxt > end and now < end else nxt
