"""Offline transient runs: a speed/load profile through the live core, streamed to a bag
(``dmf-sim run``).

The same equation and stepping as the live node: :class:`dmf_sim.live.simulation.LiveSimulation`
(the compiled Newmark kernel with the speed ramp inside it, excitation phase psi = integral of
omega dt, d'Alembert loads of the reference acceleration balanced at the rear element, the load
ramped step by step with the excitation coefficients, interpolated linearly in time over each
chunk between the profile's speed and load at its ends), driven by
:class:`dmf_sim.transient.follow.ProfileFollower`. Chunks end at every profile row, so the
reference speed is on the table exactly. Samples every ``1 / rate_hz`` s go to a bag with the
node's topics, types, stamps (wall clock at the start + simulated time, as
:class:`dmf_sim.live.pacing.TimeBase`), split files and ``custom_data``
(:class:`dmf_sim.bags.metadata.RunMetadata`, plus the profile's name and the settle from static
equilibrium, :attr:`dmf_sim.transient.profiles.Profile.start_settle_s`), written a chunk at a time
(:meth:`dmf_sim.bags.writer.BagRecorder.write_block`), so memory stays flat whatever the
profile's length. On ``/diagnostics``, the node's health status as the node builds it
(:class:`dmf_sim.live.health.SimulationHealth`, :meth:`dmf_sim.live.health.HealthReport.status`:
speed, load and their setpoints, DMF, solver), at the node's default ``diagnostics_rate`` in
simulated time: chunks also end at each report, which is taken of the chunk's own end state. An
interruption (Ctrl-C) closes the bag: what was simulated is readable.

Faults (``RunOptions.faults``, a schedule file, :func:`dmf_sim.physics.faults.read_schedule`):
the live core follows their :class:`~dmf_sim.physics.faults.FaultTimeline` (times are the
profile's); their ground truth goes into the bag as the node publishes it
(:mod:`dmf_sim.live.faults`: one ``faults/ground_truth`` message per event, ``faults/active``
at the start and whenever the set changes), each written after the chunk it fell in.
With sensors (``RunOptions.sensors``, the default; the driveline YAML's ``sensors:``), the bag
also holds the node's sensor topics, the same layouts and the edge batches per sample period
(:class:`dmf_sim.transient.encode.SensorBlock`).

Two threads (``RunOptions.threads`` 2, the default when the process may use two CPUs, see
:func:`dmf_sim.transient.defaults.default_threads`): the chunks are integrated
(:meth:`LiveSimulation.integrate`, the kernel without the GIL) in a thread of their own, up to
PIPELINE_DEPTH ahead, while this thread reads them out (:meth:`LiveSimulation.read_out`),
encodes and writes; the chunks, their order and every value are those of one thread (1: in
turn). Each thread's CPU time grows when they run side by side on two cores (caches, the GIL
changing hands), so the gain is less than the overlap; doc/performance.md has the figures.
"""
from __future__ import annotations

import contextlib
import math
import queue
import resource
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from dmf_sim.core.destinations import Destination, check_free_space
from dmf_sim.core.errors import ConfigError, OperatingRangeError, one_line
from dmf_sim.core.names import check_namespace
from dmf_sim.core.paths import config_reference
from dmf_sim.live.faults import (
    ACTIVE_STREAM,
    GROUND_TRUTH_STREAM,
    ActiveFaults,
    active_statuses,
    ground_truth_statuses,
)
from dmf_sim.live.health import SimulationHealth
from dmf_sim.live.pacing import TimeBase, publish_stride
from dmf_sim.live.parameters import PARAMETERS
from dmf_sim.live.peaks import WindupPeaks
from dmf_sim.live.recording import run_metadata
from dmf_sim.live.simulation import Integrated, LiveSimulation, Samples
from dmf_sim.live.streams import SAMPLE_STREAMS, resolved_topics, streams_for
from dmf_sim.monitor.messages import StatusData
from dmf_sim.solvers.newmark import StepRecord
from dmf_sim.transient.defaults import CHUNK_RANGE_S, DEFAULT_CHUNK_S, default_threads
from dmf_sim.transient.follow import TIME_EPS_S, ProfileFollower
from dmf_sim.transient.profiles import Profile

__all__ = ['WRITER_NAME', 'CHUNK_SPEED_STEP_RPM', 'CHUNK_LOAD_STEP', 'DEFAULT_SPLIT_S',
           'DEFAULT_DIAGNOSTICS_HZ', 'MEMORY_MARKS', 'BLAS_THREADS', 'BLOCK_ROWS',
           'PIPELINE_DEPTH', 'MERGE_ROWS_S', 'MIN_SAMPLES', 'MESSAGE_OVERHEAD_BYTES',
           'RunOptions', 'RunSummary', 'dt_error', 'build_simulation', 'open_bag', 'bag_bytes',
           'run_profile', 'follow_profile']

WRITER_NAME = 'dmf-sim run'
CHUNK_SPEED_STEP_RPM = 5.0  # ... and a chunk is short enough that the speed moves at most this
CHUNK_LOAD_STEP = 0.02      # ... and the load at most this (gear shifts: ~10 ms chunks)
DEFAULT_SPLIT_S = 60.0      # bag files split every this many simulated seconds (as the node)
DEFAULT_DIAGNOSTICS_HZ = PARAMETERS['diagnostics_rate'].default   # health statuses per
                                                                   # simulated s (as the node)
MEMORY_MARKS = (0.1, 0.5, 1.0)   # fractions of the run where the peak RSS is sampled
BLAS_THREADS = 1            # the torque read-out's small matrix products in one thread: OpenBLAS
                            # threads them past ~64 rows, ~10x slower on a busy 2-core machine
PIPELINE_DEPTH = 3          # integrated chunks in flight between the two threads
MERGE_ROWS_S = 0.01         # profile rows closer than this are merged into one chunk (a chunk
                            # costs ~0.2 ms of its own: one per 1 ms row ran 12x slower than
                            # the kernel); longer while speed and load stay within the steps above
MIN_SAMPLES = 2             # a run records at least this many samples
MESSAGE_OVERHEAD_BYTES = 47  # MCAP bytes per message beside its payload: the message record's
                             # header (31) and its message index entry (16)
BLOCK_ROWS = 1024           # samples gathered per bag chunk (~1.1 MB for the truck model): the
                            # per-chunk cost of encoding and writing is paid once per simulated
                            # s (measured: writing costs ~0.4x the kernel's time, ~0.75x with
                            # 256-row chunks); an interrupted run writes what it gathered


@dataclass
class RunOptions:
    """Model and output settings of a run (SI; speed in rpm).

    driveline, engine, load_set, alpha, theta: the model (names in ``config/`` or paths).
    dt: Newmark step [s]; rate_hz: samples per simulated second in the bag (a whole number of
    steps per sample); chunk_s: simulated time per chunk; split_s: bag file split [s];
    diagnostics_hz: health statuses on /diagnostics per simulated second;
    write: False integrates without writing (for timing); namespace: topics under it;
    threads: 1 integrates and writes in turn, 2 integrates the next chunks in a thread of its own
    while this one reads out and writes the last ones (the same bag, byte for byte); default
    :func:`~dmf_sim.transient.defaults.default_threads`. faults: a fault schedule file (YAML
    ``faults: [...]``) or None; sensors: the driveline's sensor signals in the bag (False: none,
    at no cost).
    """

    driveline: str = 'truck_dmf'
    engine: str = 'engine_d13'
    load_set: str = 'A'
    alpha: float | None = None
    theta: float | None = None
    dt: float = 1e-4
    rate_hz: float = 1000.0
    chunk_s: float = DEFAULT_CHUNK_S
    split_s: float = DEFAULT_SPLIT_S
    diagnostics_hz: float = DEFAULT_DIAGNOSTICS_HZ
    write: bool = True
    namespace: str = ''
    threads: int = field(default_factory=default_threads)
    faults: str | None = None
    sensors: bool = True

    def __post_init__(self) -> None:
        self.namespace = check_namespace(self.namespace, 'namespace')


@dataclass
class RunSummary:
    """What a run did (``--json``)."""

    profile: dict
    bag: str | None
    simulated_s: float
    wall_s: float
    realtime_factor: float        # simulated s per wall s (the loop: integrate, encode, write)
    cpu_s: float                  # the process' CPU time in the loop (threads included)
    samples: int
    messages: int
    rate_hz: float
    dt_s: float
    interrupted: bool
    knee_crossings: int
    solver_resets: int
    threads: int = 1              # 1: integrate and write in turn; 2: integrating thread
    peak_rss_mib: dict = field(default_factory=dict)   # fraction of the run -> peak RSS
    faults: str | None = None     # the fault schedule
    fault_events: int = 0         # ground-truth events (starts, ends, misfires)
    misfires: int = 0             # combustions that misfired
    peaks_after_s: float = 0.0    # the peaks below are over the steps from this time on [s]
    #                               (the profile's settling from static equilibrium left out)
    peak_windup_rad: list | None = None     # [min, max] over every step (a DMF driveline)
    peak_dmf_torque_nm: list | None = None  # spring torque at those wind-ups (a DMF driveline)
    travel_margin_rad: float | None = None  # smallest distance to an end stop (spring with stops)
    stop_contacts: int | None = None        # entries beyond an end stop (spring with stops)
    peak_stop_torque_nm: float | None = None  # largest end-stop contact torque (end-stop law)
    friction_heat_j: float | None = None    # arc-spring friction's work [J] (spring with friction)

    def as_dict(self) -> dict:
        """Every field; the peaks only for a driveline with a DMF, the end-stop fields only
        for a spring that has stops, the friction heat only for one with friction."""
        out = asdict(self)
        for key in ('peak_windup_rad', 'peak_dmf_torque_nm', 'travel_margin_rad',
                    'stop_contacts', 'peak_stop_torque_nm', 'friction_heat_j'):
            if out[key] is None:
                del out[key]
        return out


def _peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0    # KiB on Linux


def _chunk_limit(profile: Profile, segment: int, chunk: int, dt: float) -> int:
    """Steps per chunk in a profile segment: at most ``chunk``, and few enough that speed and
    load move at most CHUNK_SPEED_STEP_RPM / CHUNK_LOAD_STEP (the excitation is interpolated
    linearly in time over a chunk; whatever the sample rate: the chunks, and with them every
    value, do not depend on it)."""
    i = min(max(segment, 0), len(profile) - 2)
    span = profile.t_s[i + 1] - profile.t_s[i]
    seconds = opt_s = chunk * dt
    for delta, step in ((profile.speed_rpm[i + 1] - profile.speed_rpm[i], CHUNK_SPEED_STEP_RPM),
                        (profile.load[i + 1] - profile.load[i], CHUNK_LOAD_STEP)):
        if delta:
            seconds = min(seconds, step * span / abs(delta))
    return max(int(min(seconds, opt_s) / dt), 1)


def dt_error(dt: float, what: str = 'dt') -> str | None:
    """Why ``dt`` [s] is not a Newmark step a run takes, or None: the node's range for its
    ``dt`` parameter, one line naming ``what`` (``--dt`` on the command line)."""
    lo, hi = PARAMETERS['dt'].range
    if isinstance(dt, (int, float)) and math.isfinite(dt) and lo <= dt <= hi:
        return None
    return f'{what} must be within [{lo:g}, {hi:g}] s, got {dt!r}'


def build_simulation(profile: Profile, opt: RunOptions) -> LiveSimulation:
    """The live core at the profile's first row (static equilibrium), speed limits = the
    engine's data range (a profile outside it: one-line OperatingRangeError)."""
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.model import read_driveline

    if reason := dt_error(opt.dt):
        raise ConfigError(reason)
    if not (CHUNK_RANGE_S[0] <= opt.chunk_s <= CHUNK_RANGE_S[1]):
        raise ConfigError(f'chunk_s must be within [{CHUNK_RANGE_S[0]:g}, {CHUNK_RANGE_S[1]:g}]'
                          f' s, got {opt.chunk_s!r}')
    lo_hz, hi_hz = PARAMETERS['diagnostics_rate'].range
    if not (lo_hz <= opt.diagnostics_hz <= hi_hz):
        raise ConfigError(f'diagnostics_hz must be within [{lo_hz:g}, {hi_hz:g}] Hz, got '
                          f'{opt.diagnostics_hz!r}')
    try:
        line = read_driveline(opt.driveline, alpha=opt.alpha, theta=opt.theta)
        engine = read_engine(opt.engine, load_set=opt.load_set)
    except (ValueError, FileNotFoundError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(one_line(exc)) from None
    rng = getattr(engine, 'speed_range_rpm', None)
    lo, hi = (float(rng[0]), float(rng[1])) if rng is not None else (0.0, math.inf)
    profile.check_runnable((lo, hi), engine, opt.dt, speed_what=f'the engine data of {opt.engine}',
                           dt_what='--dt')
    if hasattr(engine, 'warm'):
        engine.warm_up()           # the gas grid now (~0.1 s), not lazily inside the timed loop
    hi_lim = hi if math.isfinite(hi) else float(profile.speed_rpm.max()) * 2
    lo_lim = lo if lo > 0 else float(profile.speed_rpm.min()) / 2
    stride = publish_stride(opt.rate_hz, opt.dt, rate_name='--rate', dt_name='--dt')
    schedule = _schedule(opt.faults, line, profile) if opt.faults else None
    try:
        sim = LiveSimulation(line, engine, dt=opt.dt, speed_rpm=float(profile.speed_rpm[0]),
                             load=float(profile.load[0]), speed_limits_rpm=(lo_lim, hi_lim),
                             stride=stride, sensors=opt.sensors)
    except OperatingRangeError:
        raise
    except ValueError as exc:
        raise ConfigError(one_line(exc)) from None
    if schedule is not None:
        sim.attach_faults(schedule.faults, where=f'{schedule.source}: faults')
    return sim


def _schedule(path: str, line, profile: Profile):
    """The fault schedule of ``path`` for ``line``; a fault that would start after the
    profile's end is refused (one line naming it)."""
    from dmf_sim.physics.faults import read_schedule

    schedule = read_schedule(path, line=line)
    for i, f in enumerate(schedule.faults):
        start = f.window(0.0)[0]
        if start >= profile.duration_s:
            field_name = 'at_s' if f.single else 'start_s'
            raise ConfigError(f"{schedule.source}: faults[{i}] ({f.kind}): field '{field_name}' "
                              f'{start:g} s is not before the end of profile {profile.name} '
                              f'({profile.duration_s:g} s)')
    return schedule


def open_bag(out, sim: LiveSimulation, profile: Profile, opt: RunOptions, rate_hz: float):
    """A new bag with the node's topics and this run's metadata (never overwrites)."""
    from dmf_sim.bags.writer import BagRecorder

    streams = streams_for(sim.line.sensors if sim.live_sensors is not None else None)
    topics = resolved_topics(opt.namespace, streams)
    meta = run_metadata(sim, driveline=config_reference(opt.driveline),
                        engine=config_reference(opt.engine), node=WRITER_NAME,
                        publish_rate_hz=rate_hz)
    custom = replace(meta, profile=profile.name, profile_table=profile.as_table(),
                     settle_s=profile.start_settle_s).to_custom_data()
    return BagRecorder(out, {topics[k]: s.msgtype for k, s in streams.items()},
                       qos={topics[k]: s.qos_profile() for k, s in streams.items()},
                       max_duration_s=opt.split_s, custom_data=custom), topics


class _Health:
    """The node's health status every ``period_s`` of simulated time, built as the node builds
    it (:class:`SimulationHealth`, :meth:`HealthReport.status` under the writer's name), taken
    right after the chunk that reaches the report time is integrated (in the integrating
    thread: the state is the chunk's end state, not that of a chunk integrated ahead)."""

    def __init__(self, sim: LiveSimulation, period_s: float) -> None:
        self.sim, self.period_s = sim, period_s
        self.health = SimulationHealth(sim)
        self.next_s = sim.t + period_s

    def steps_to_next(self) -> int:
        """Newmark steps from now to the next report time."""
        return int(round((self.next_s - self.sim.t) / self.sim.dt))

    def take(self) -> tuple[float, StatusData] | None:
        """(simulated time [s], status) when a report is due now, else None."""
        sim = self.sim
        if sim.t < self.next_s - TIME_EPS_S:
            return None
        self.next_s = max(self.next_s + self.period_s, sim.t + TIME_EPS_S)
        return sim.t, self.health.report(WRITER_NAME).status(WRITER_NAME)


def _merged_row(profile: Profile, t: float, chunk_s: float) -> int:
    """The row a chunk starting at profile time ``t`` [s] ends at: the end of the segment
    holding ``t``; where rows are closer than MERGE_ROWS_S, the last row within MERGE_ROWS_S,
    or further while speed and load stay within CHUNK_SPEED_STEP_RPM / CHUNK_LOAD_STEP of their
    values at ``t`` (at most ``chunk_s`` on)."""
    ts = profile.t_s
    j = profile.segment(t + TIME_EPS_S) + 1
    if ts[j] - t >= MERGE_ROWS_S or j == len(ts) - 1:
        return j
    near = int(np.searchsorted(ts, t + MERGE_ROWS_S + TIME_EPS_S, side='right')) - 1
    far = int(np.searchsorted(ts, t + chunk_s + TIME_EPS_S, side='right')) - 1
    speed, load = profile.at(t)
    ok = ((np.abs(profile.speed_rpm[j:far + 1] - speed) <= CHUNK_SPEED_STEP_RPM)
          & (np.abs(profile.load[j:far + 1] - load) <= CHUNK_LOAD_STEP))
    steady = int(np.argmin(ok)) if not ok.all() else len(ok)
    return max(j, near, j + steady - 1)


def _chunk_plan(profile: Profile, sim: LiveSimulation, follower: ProfileFollower, total: int,
                chunk: int, stop: threading.Event, health: _Health | None) -> Iterator[int]:
    """Steps of each chunk, the follower's setpoints applied before it (the caller integrates
    the chunk before asking for the next one): chunks end at every profile row (rows closer
    than MERGE_ROWS_S merged, :func:`_merged_row`) and health report time and are at most
    ``chunk`` steps and :func:`_chunk_limit` long."""
    done = 0
    next_row = -math.inf
    limit = chunk
    while done < total and not stop.is_set():
        if sim.t >= next_row - TIME_EPS_S:        # a new profile segment
            t = sim.t - follower.t0
            row = _merged_row(profile, t, chunk * sim.dt)
            if follower.apply(sim.t, to_row=row):
                next_row = follower.t0 + float(profile.t_s[row])
            else:
                next_row = math.inf
            limit = (_chunk_limit(profile, follower.segment, chunk, sim.dt)
                     if row == follower.segment + 1 else chunk)
        to_row = (int(round((next_row - sim.t) / sim.dt)) if math.isfinite(next_row)
                  else total)
        to_report = health.steps_to_next() if health is not None else total
        n = min(limit, total - done, max(to_row, 1), max(to_report, 1))
        yield n
        done += n


def _chunk_steps(sim: LiveSimulation, chunk_s: float) -> int:
    """Steps of a full chunk of ``chunk_s`` [s], at least one (not tied to the samples: the
    chunks, and with them the integration, are those of any sample rate)."""
    return max(int(round(chunk_s / sim.dt)), 1)


def follow_profile(sim: LiveSimulation, profile: Profile, chunk_s: float = DEFAULT_CHUNK_S,
                   on_samples: Callable[[Samples], None] | None = None,
                   peaks_after_s: float = 0.0):
    """Integrate ``profile`` with the live core ``sim`` from its state now, in the chunks
    :func:`run_profile` integrates (the same setpoints, excitation updates and values), without
    writing anything: what a design study's load step is (``dmf_sim.design.transient``).
    ``on_samples``: called with each chunk's samples (views, valid during the call; None: no
    read-out at all). Returns the run's :class:`~dmf_sim.live.peaks.WindupPeaks`
    (``sim.peaks``, started afresh), its wind-up extremes over every Newmark step from
    ``peaks_after_s`` [s] into the profile on (the profile's ``start_settle_s``: the settling
    from static equilibrium left out, as :func:`run_profile`'s summary leaves it out; the stop
    contacts, impact and friction heat are the whole profile's, as there)."""
    follower = ProfileFollower(profile, sim)
    chunk = _chunk_steps(sim, chunk_s)
    total = int(round(profile.duration_s / sim.dt))
    record = StepRecord.allocate(chunk // sim.stride + 1, sim.model.n_dof)
    sim.peaks.reset(sim.t + peaks_after_s)
    sim.extremes_from_s = sim.t + peaks_after_s       # the kernel's extremes: the same steps
    for n in _chunk_plan(profile, sim, follower, total, chunk, threading.Event(), None):
        raw = sim.integrate(n, record)
        if on_samples is not None:
            on_samples(sim.read_out(raw))
    follower.finish()
    return sim.peaks


def _integrated(sim: LiveSimulation, plan: Iterator[int], health: _Health | None,
                record: Callable[[], StepRecord]
                ) -> Iterator[tuple[int, Integrated, tuple[float, StatusData] | None]]:
    """Each chunk of ``plan`` integrated into a ``record()``, with the health report due after
    it (or None)."""
    for n in plan:
        raw = sim.integrate(n, record())
        yield n, raw, health.take() if health is not None else None


class _Integrating:
    """The chunks integrated in a thread of their own, up to PIPELINE_DEPTH ahead of the
    caller's read-out and writing (the kernel runs without the GIL, so on two cores the two
    overlap); iterate for (steps, :class:`Integrated`, health report or None), then
    :meth:`release` each record."""

    def __init__(self, sim: LiveSimulation, plan: Iterator[int], health: _Health | None,
                 rows: int, stop: threading.Event) -> None:
        self.sim, self.plan, self.health, self.stop = sim, plan, health, stop
        self.free: queue.Queue = queue.Queue()
        self.ready: queue.Queue = queue.Queue()
        for _ in range(PIPELINE_DEPTH):
            self.free.put(StepRecord.allocate(rows, sim.model.n_dof))
        self.thread = threading.Thread(target=self._run, name='dmf-sim run: integrate',
                                       daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            for item in _integrated(self.sim, self.plan, self.health, self.free.get):
                self.ready.put(item)
        except BaseException as exc:  # noqa: BLE001 - raised again in the caller's thread
            self.ready.put(exc)
        self.ready.put(None)

    def __iter__(self) -> Iterator[tuple[int, Integrated, tuple[float, StatusData] | None]]:
        while (item := self.ready.get()) is not None:
            if isinstance(item, BaseException):
                raise item
            yield item

    def release(self, record: StepRecord) -> None:
        self.free.put(record)

    def close(self) -> None:
        """Stop after the chunk in hand and wait for the thread (the chunks not read are
        dropped)."""
        self.stop.set()
        while self.thread.is_alive():
            try:
                item = self.ready.get(timeout=0.05)
            except queue.Empty:
                continue
            if isinstance(item, tuple):
                self.free.put(item[1].record)
        self.thread.join()


def bag_bytes(sim: LiveSimulation, samples: int, profile: Profile | None = None) -> float:
    """About how many bytes a run's bag of ``samples`` samples takes (the sample messages'
    payloads and MCAP records, and with sensors and ``profile`` theirs at its highest speed;
    the latched messages and the summary are small beside them)."""
    from dmf_sim.bags.sensor_messages import EDGE_HEADER_BYTES, EDGE_ROW_BYTES, FLOAT64_BYTES
    from dmf_sim.transient.encode import SampleEncoder
    per_sample = SampleEncoder(sim.names).sample_bytes
    total = samples * (per_sample + len(SAMPLE_STREAMS) * MESSAGE_OVERHEAD_BYTES)
    if sim.live_sensors is None or profile is None:
        return total
    seconds, rpm = profile.duration_s, float(profile.speed_rpm.max())
    sensors, line = sim.line.sensors, sim.line
    batches = seconds / (sensors.edge_batch_ns(sim.stride * sim.dt) * 1e-9)
    for w in sensors.tooth_wheels:        # every edge; at most one batch per batch period
        edges = w.present_teeth * rpm / 60.0 / abs(sim.model.R[line.index(w.element)]) * seconds
        total += (edges * EDGE_ROW_BYTES
                  + min(edges, batches) * (EDGE_HEADER_BYTES + MESSAGE_OVERHEAD_BYTES))
    for b in sensors.bus_signals:
        total += seconds / b.period_s * (FLOAT64_BYTES + MESSAGE_OVERHEAD_BYTES)
    return total


def run_profile(profile: Profile, out: str | Path | None, options: RunOptions | None = None, *,
                progress: bool = False, destination: Destination | None = None) -> RunSummary:
    """Integrate ``profile`` and stream the samples to bag ``out`` (see the module docstring).

    ``out`` None or ``options.write`` False: integrate and encode nothing (timing). Refused
    before integrating (one line): a rate giving fewer than MIN_SAMPLES samples, a bag larger
    than the free space on its disk. ``destination``: the command's checked output path ``out``
    (:func:`dmf_sim.core.destinations.claim`): the earlier output it replaces counts as free
    space, and is removed only after these checks."""
    opt = options or RunOptions()
    sim = build_simulation(profile, opt)
    rate_hz = 1.0 / (sim.stride * sim.dt)
    write = opt.write and out is not None
    samples_due = int(round(profile.duration_s / sim.dt)) // sim.stride
    if samples_due < MIN_SAMPLES:
        raise ConfigError(f'rate (--rate) {rate_hz:g} Hz gives {samples_due} samples over the '
                          f"profile's {profile.duration_s:g} s; a run records at least "
                          f'{MIN_SAMPLES}: raise the rate')
    if not write:
        return _stream(profile, None, opt, sim, progress)
    check_free_space(out, bag_bytes(sim, samples_due, profile),
                     f'the bag ({samples_due} samples at {rate_hz:g} Hz)',
                     'shorten the profile or lower --rate',
                     freed_bytes=destination.replaced_bytes() if destination else 0)
    with destination.writing() if destination is not None else contextlib.nullcontext():
        return _stream(profile, out, opt, sim, progress)


def _stream(profile: Profile, out, opt: RunOptions, sim: LiveSimulation,
            progress: bool) -> RunSummary:
    """The run itself (:func:`run_profile`): ``out`` None writes nothing."""
    from dmf_sim.transient.encode import EncodedBlock, SampleEncoder, SensorBlock, StatusEncoder

    rate_hz = 1.0 / (sim.stride * sim.dt)
    write = out is not None
    recorder, topics = open_bag(out, sim, profile, opt, rate_hz) if write else (None, {})
    follower = ProfileFollower(profile, sim)
    timebase = TimeBase()
    timebase.start(time.time_ns(), sim.t)
    stride = sim.stride
    chunk = _chunk_steps(sim, opt.chunk_s)
    block = (EncodedBlock(SampleEncoder(sim.names), BLOCK_ROWS, topics, recorder) if write
             else None)
    statuses = StatusEncoder() if write else None
    health = _Health(sim, 1.0 / opt.diagnostics_hz)
    ls = sim.live_sensors
    sensors = (SensorBlock(ls.wheel_names, ls.signal_names, topics,
                           sim.line.sensors.edge_batch_ns(sim.stride * sim.dt),
                           timebase.epoch_ns) if write and ls is not None else None)
    max_rows = chunk // stride + 1
    work = np.zeros((max_rows, 3 * sim.model.n_elements))

    def write_out(final: bool = False) -> None:
        stamps, payloads = block.take() if block is not None else (np.zeros(0, np.int64), [])
        if sensors is None:
            if len(stamps):
                recorder.write_block(stamps, payloads)
            return
        # the sensor messages up to the last sample, interleaved with the samples file by
        # file (each call's messages before the current file's end), so every split file
        # holds its own time span as the node's recording does
        log, topic, payload, offsets = sensors.take(None if final or not len(stamps)
                                                    else int(stamps[-1]))
        i = j = 0
        while i < len(stamps) or j < len(log):
            first = min(stamps[i] if i < len(stamps) else log[j],
                        log[j] if j < len(log) else stamps[i])
            end = recorder.file_end_ns(int(first))
            if end <= first:           # the next call starts a new file at `first`
                end = int(first) + int(opt.split_s * 1e9)
            i2 = int(np.searchsorted(stamps, end, side='left'))
            j2 = int(np.searchsorted(log, end, side='left'))
            if i2 > i:
                recorder.write_block(stamps[i:i2], [(tp, p[i:i2]) for tp, p in payloads])
            if j2 > j:
                recorder.write_messages(log[j:j2], topic[j:j2], sensors.topics, payload,
                                        offsets[j:j2 + 1])
            i, j = i2, j2

    active = ActiveFaults()
    counts = {'events': 0, 'misfires': 0}

    def write_faults(events) -> None:
        """A chunk's ground truth, after its samples (as the node publishes it)."""
        counts['events'] += len(events)
        counts['misfires'] += sum(e.what == 'misfire' for e in events)
        changed = active.update(events)
        if recorder is None or not events:
            return
        write_out()
        for stamp, status in ground_truth_statuses(events, timebase.stamp_ns, WRITER_NAME):
            recorder.write(topics[GROUND_TRUTH_STREAM], stamp, statuses.array(stamp, [status]))
        if changed:
            stamp = int(timebase.stamp_ns([e for e in events if e.what != 'misfire'][-1].t_s))
            recorder.write(topics[ACTIVE_STREAM], stamp, statuses.array(
                stamp, active_statuses(active, timebase.stamp_ns, WRITER_NAME)))

    if recorder is not None and sim.faults is not None:      # the latched "none yet"
        stamp0 = int(timebase.stamp_ns(sim.t))
        recorder.write(topics[ACTIVE_STREAM], stamp0, statuses.array(stamp0, []))
    total = int(round(profile.duration_s / sim.dt))
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=round(profile.duration_s, 3), unit='sim s', desc=f'run {profile.name}',
                   leave=False, bar_format='{l_bar}{bar}| {n:.1f}/{total:.1f} sim s '
                   '[{elapsed}<{remaining}, {rate_fmt}]')
    marks = list(MEMORY_MARKS)
    peaks: dict[str, float] = {}
    done = samples = 0
    interrupted = False
    stop = threading.Event()
    plan = _chunk_plan(profile, sim, follower, total, chunk, stop, health)
    # the summary's peaks leave out the settling from static equilibrium, as analyze, runup and
    # a design's load steps and road cycle do (the contacts, impact and heat are the whole run's)
    t_settled = sim.t + profile.start_settle_s
    settled = WindupPeaks(sim.peaks.spring, t_settled)
    sim.extremes_from_s = t_settled                   # the kernel's extremes: the same steps
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    with threadpool_limits(BLAS_THREADS):
        if opt.threads > 1:
            chunks = _Integrating(sim, plan, health, max_rows, stop)
        else:
            own = StepRecord.allocate(max_rows, sim.model.n_dof)
            chunks = None
        try:
            for n, raw, report in (chunks if chunks is not None
                                   else _integrated(sim, plan, health, lambda: own)):
                s = sim.read_out(raw, work)
                settled.set_spring(sim.peaks.spring)
                settled.observe(s.windup, s.t, raw.windup_extremes)   # from t_settled on
                done += n
                rows = len(s)
                samples += rows
                start = 0
                stamps = timebase.stamps_ns(s.t) if block is not None else None
                if sensors is not None and s.sensors is not None:
                    sensors.add(s.sensors)
                while block is not None and start < rows:
                    k = min(block.free, rows - start)
                    block.add(s, stamps, start, start + k)
                    start += k
                    if block.free == 0:
                        write_out()
                if report is not None and statuses is not None:
                    write_out()             # the samples before it first: files in time order
                    t_report, status = report
                    stamp = timebase.stamp_ns(t_report)
                    recorder.write(topics['diagnostics'], stamp, statuses.array(stamp, [status]))
                if raw.fault_events:
                    write_faults(raw.fault_events)
                if chunks is not None:
                    chunks.release(raw.record)
                if bar is not None:
                    bar.update(n * sim.dt)
                while marks and done >= marks[0] * total:
                    peaks[f'{marks.pop(0):g}'] = round(_peak_rss_mib(), 1)
        except KeyboardInterrupt:
            interrupted = True
        finally:
            if chunks is not None:
                chunks.close()
            if bar is not None:
                bar.close()
            if recorder is not None:
                try:
                    write_out(final=True)   # what was gathered so far, also after Ctrl-C
                finally:
                    recorder.close()
    wall, cpu = time.perf_counter() - t_wall, time.process_time() - t_cpu
    follower.finish()
    simulated = done * sim.dt
    extremes = sim.peaks.as_dict()
    peaks_after_s = 0.0         # a run no longer than its settling: its whole extremes
    if settled.observed and 'peak_windup_rad' in extremes:
        peaks_after_s = profile.start_settle_s
        for key, value in settled.as_dict().items():
            if key in ('peak_windup_rad', 'peak_dmf_torque_nm', 'travel_margin_rad'):
                extremes[key] = value
    return RunSummary(
        profile=profile.as_dict(), bag=str(recorder.path) if recorder is not None else None,
        simulated_s=simulated, wall_s=wall,
        realtime_factor=simulated / wall if wall > 0 else math.inf, cpu_s=cpu, samples=samples,
        messages=recorder.message_count if recorder is not None else 0, rate_hz=rate_hz,
        dt_s=sim.dt, interrupted=interrupted, knee_crossings=sim.knee_crossings,
        solver_resets=sim.solver_resets, threads=opt.threads, peak_rss_mib=peaks,
        faults=opt.faults, fault_events=counts['events'], misfires=counts['misfires'],
        peaks_after_s=peaks_after_s, peak_windup_rad=extremes.get('peak_windup_rad'),
        peak_dmf_torque_nm=extremes.get('peak_dmf_torque_nm'),
        travel_margin_rad=extremes.get('travel_margin_rad'),
        stop_contacts=extremes.get('stop_contacts'),
        peak_stop_torque_nm=extremes.get('peak_stop_torque_nm'),
        friction_heat_j=extremes.get('friction_heat_j'))
