"""The live node's ROS-free core without DDS: a log and a sink that keep what they get, a clock
that moves when told, a simulation and a run loop made of them (helpers)."""
from __future__ import annotations

from dmf_sim.live.pacing import Pacer
from dmf_sim.live.run_loop import RunLoop
from dmf_sim.live.simulation import LiveSimulation


class ListLog:
    """info/warning/error into a list of (level, text)."""

    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def info(self, msg):
        self.lines.append(('info', msg))

    def warning(self, msg):
        self.lines.append(('warning', msg))

    def error(self, msg):
        self.lines.append(('error', msg))

    def text(self, level: str | None = None) -> str:
        return '\n'.join(t for lv, t in self.lines if level in (None, lv))


class ListSink:
    """The run loop's output: every sample's stamp, log time, time and crank angle."""

    def __init__(self) -> None:
        self.stamps, self.logs, self.t, self.psi, self.clock = [], [], [], [], []
        self.sensors = []

    def publish_samples(self, s, stamps_ns, log_ns):
        self.stamps += stamps_ns.tolist()
        self.logs += log_ns.tolist()
        self.t += s.t.tolist()
        self.psi += s.psi.tolist()

    def publish_clock(self, stamp_ns):
        self.clock.append(stamp_ns)

    def publish_sensors(self, chunk, epoch_ns, log_offset_ns):
        self.sensors.append((chunk, epoch_ns, log_offset_ns))


class StatusSink:
    """The live runtime's output by stream key: the statuses published (stamp, list), samples
    counted, sensors dropped; ``events()`` the faults' ground truth events in order."""

    def __init__(self) -> None:
        self.statuses: dict[str, list] = {}
        self.sent: dict[str, list] = {}          # the send stamps, by stream key
        self.samples = 0
        self.last_stamp = 0

    def publish_samples(self, s, stamps_ns, log_ns):
        self.samples += len(s)
        self.last_stamp = int(stamps_ns[-1])

    def publish_clock(self, stamp_ns):
        pass

    def publish_sensors(self, chunk, epoch_ns, log_offset_ns):
        pass

    def publish_statuses(self, key, statuses, stamp_ns, sent_ns=None):
        self.statuses.setdefault(key, []).append((stamp_ns, list(statuses)))
        self.sent.setdefault(key, []).append(stamp_ns if sent_ns is None else sent_ns)

    def events(self) -> list[dict]:
        from dmf_sim.monitor.messages import values_of
        from dmf_sim.physics.faults import event_from_values
        out = []
        for _, statuses in self.statuses.get('fault_ground_truth', []):
            assert len(statuses) == 1            # one message per event
            s = statuses[0]
            out.append(event_from_values(s.message, values_of(s)))
        return out


class FakeClock:
    """Monotonic [s] and wall [ns] clocks that move only when told (or by ``auto`` per read)."""

    def __init__(self, wall0_s: float = 1_700_000_000.0) -> None:
        self.now = 0.0
        self.wall0 = wall0_s
        self.auto = 0.0

    def __call__(self) -> float:
        self.now += self.auto
        return self.now

    def wall_ns(self) -> int:
        return int(round((self.wall0 + self.now) * 1e9))


def new_sim(**kw) -> LiveSimulation:
    return LiveSimulation.from_config('truck_dmf', 'engine_d13', 'A', **kw)


def new_loop(sim=None, **kw):
    clock, sink, log = FakeClock(), ListSink(), ListLog()
    sim = sim or new_sim()
    loop = RunLoop(sim, Pacer(sim.dt, 1.0, max_lag=0.05), sink, log, clock=clock,
                   wall_clock_ns=clock.wall_ns, **kw)
    loop.start()
    return loop, clock, sink, log
