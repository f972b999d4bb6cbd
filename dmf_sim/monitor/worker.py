"""The node's DMF monitor without ROS: live orders, prediction, alarms, off the real-time path.

One :class:`LiveMonitor` per node. The tick thread hands it the published samples
(:meth:`LiveMonitor.add_samples`, a few microseconds: :meth:`CycleOrderTracker.collect`); the
order analysis of completed cycles (~1 ms each) and the harmonic-balance prediction at the
setpoint (:func:`dmf_sim.monitor.prediction.predict_states`, 5 ms .. 0.3 s) and, with the tooth
wheels around the DMF on, the live misfire detector (:mod:`dmf_sim.monitor.misfire`, a few ms per
engine cycle: :meth:`LiveMonitor.add_sensors`) run in worker processes
(``worker='process'``, default: no GIL shared with the tick thread; ``niceness`` can lower
their scheduling priority) or threads (``worker='thread'``). :meth:`LiveMonitor.poll`, called
from the node's loop, returns what finished: per-cycle reports (the cycle, live minus predicted,
alarms, the message content) and a new prediction when the setpoint's changed. Predictions are
cached per operating point (speed and load rounded, load set, spring, the persistent faults
acting: :meth:`LiveMonitor.set_faults`). ``benchmarks/
bench_monitor.py`` measures the tick thread's lateness with process and thread workers.
"""
from __future__ import annotations

import itertools
import math
import os
import signal
import time
from collections import OrderedDict
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field, replace

import numpy as np

from dmf_sim.analysis.misfire_detector import DEFAULT_THRESHOLD
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.process import blocked_signals, die_with_parent
from dmf_sim.monitor.alarms import AlarmReport, AlarmSettings, evaluate
from dmf_sim.monitor.messages import (
    StatusData,
    cycle_status,
    detection_statuses,
    monitor_status,
    prediction_statuses,
)
from dmf_sim.monitor.misfire import (
    MisfireTracker,
    MisfireWindow,
    analyze_window as analyze_misfires,
    dmf_wheels,
)
from dmf_sim.monitor.orders import CycleOrderTracker, CycleResult, CycleWindow, analyze_window
from dmf_sim.monitor.prediction import (
    Comparison,
    OperatingPoint,
    Prediction,
    compare,
    predict_states,
    solve_prediction,
    steady_part,
)

__all__ = ['WORKER_MODES', 'MONITOR_PARAMETERS', 'MonitorSettings', 'CycleReport',
           'MonitorUpdate', 'LiveMonitor']

WORKER_MODES = ('process', 'thread')
WORKER_IGNORES = (signal.SIGINT, signal.SIGTERM)   # a worker process ends when the node says so
PREDICTION_CACHE_SIZE = 256        # operating points kept
WORKER_MODELS = 4                  # driveline models a worker keeps built
_uid = itertools.count(1)

# Node parameters of the monitor: name -> (default, description, (lo, hi) or None).
MONITOR_PARAMETERS: dict[str, tuple] = {
    'monitor': (True, 'Per-cycle order analysis, prediction and alarms (topics '
                'driveline/dmf_orders, driveline/dmf_predicted)', None),
    'monitor_worker': ('process', "Where the analysis and prediction run: 'process' (worker "
                       "processes, no GIL shared with the tick thread) or 'thread'", None),
    'subharmonic_alarm_rad': (0.005, '1.5th-order wind-up amplitude above which a sub-harmonic '
                              'state counts as present or possible [rad]', (1e-6, 1.0)),
    'end_stop_rad': (0.6, 'DMF end-stop wind-up, both directions [rad] (alarm beyond it)',
                     (1e-3, 3.2)),
    'prediction_speed_step_rpm': (5.0, 'Predictions are computed and cached for the speed '
                                  'setpoint rounded to this step [rpm]', (0.1, 100.0)),
    'prediction_load_step': (0.01, 'Load setpoint rounding for predictions', (1e-4, 0.5)),
    'compare_speed_tolerance_rpm': (10.0, 'Live minus predicted only for cycles within this '
                                    'speed of the prediction [rpm]', (0.1, 500.0)),
    'compare_load_tolerance': (0.02, 'Live minus predicted only for cycles within this load of '
                               'the prediction', (1e-4, 1.0)),
    'misfire_threshold': (DEFAULT_THRESHOLD, 'Live misfire detector (topic faults/detections): '
                          'alarm when a firing interval\'s engine work falls this fraction of '
                          'the mean work below its neighbours', (0.01, 10.0)),
}


@dataclass(frozen=True)
class MonitorSettings:
    """The monitor's parameters (see :data:`MONITOR_PARAMETERS`; SI, speed in rpm)."""

    subharmonic_alarm_rad: float = MONITOR_PARAMETERS['subharmonic_alarm_rad'][0]
    end_stop_rad: float = MONITOR_PARAMETERS['end_stop_rad'][0]
    prediction_speed_step_rpm: float = MONITOR_PARAMETERS['prediction_speed_step_rpm'][0]
    prediction_load_step: float = MONITOR_PARAMETERS['prediction_load_step'][0]
    compare_speed_tolerance_rpm: float = MONITOR_PARAMETERS['compare_speed_tolerance_rpm'][0]
    compare_load_tolerance: float = MONITOR_PARAMETERS['compare_load_tolerance'][0]
    misfire_threshold: float = MONITOR_PARAMETERS['misfire_threshold'][0]
    worker: str = MONITOR_PARAMETERS['monitor_worker'][0]
    niceness: int = 0             # added to the workers' nice value (see doc/monitoring.md)

    def __post_init__(self) -> None:
        if self.worker not in WORKER_MODES:
            raise ConfigError(f'monitor_worker must be one of {WORKER_MODES}, got {self.worker!r}')
        for name, (_, _, rng) in MONITOR_PARAMETERS.items():
            if rng is None or not hasattr(self, name):
                continue
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and rng[0] <= v <= rng[1]):
                raise ConfigError(f'{name} must be in [{rng[0]:g}, {rng[1]:g}], got {v!r}')

    @property
    def alarms(self) -> AlarmSettings:
        return AlarmSettings(self.subharmonic_alarm_rad, self.end_stop_rad)


# ------------------------------------------------------------------------------------------------
# Worker side (module level: runs in the worker process or thread)
# ------------------------------------------------------------------------------------------------

_MODELS: OrderedDict = OrderedDict()


def _init_worker(niceness: int) -> None:
    # Ctrl-C in a terminal, and `kill -TERM %1` on a `ros2 launch` job, reach the whole process
    # group: the node decides when its workers stop (LiveMonitor.close), a worker must not die
    # of the node's SIGINT or SIGTERM (the node would start a new one while it stops)
    # (started with them blocked, see _Worker: unblocked once ignored)
    for signum in WORKER_IGNORES:
        signal.signal(signum, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, WORKER_IGNORES)
    import multiprocessing
    parent = multiprocessing.parent_process()
    # a crashed node must not leave orphan workers, also when it died while this one started
    die_with_parent(signal.SIGKILL, parent.pid if parent is not None else None)
    if niceness:
        os.nice(niceness)


def _loads(key, payload):
    """The worker's DrivelineExcitation for model ``key`` (built from ``payload`` = (line, engine)
    the first time it is sent)."""
    if payload is not None and key not in _MODELS:
        from dmf_sim.physics.loads import DrivelineExcitation
        line, engine = payload
        _MODELS[key] = DrivelineExcitation(line.reduce(), engine)
        while len(_MODELS) > WORKER_MODELS:
            _MODELS.popitem(last=False)
    _MODELS.move_to_end(key)
    return _MODELS[key]


def _job_ready() -> int:
    """Warm-up job: the worker is up and has imported the solvers."""
    import dmf_sim.solvers.hbm  # noqa: F401
    return os.getpid()


def _job_predict(key, payload, solver, point: OperatingPoint) -> Prediction:
    return solve_prediction(solver, _loads(key, payload), point)


def _job_cycles(key, payload, window: CycleWindow) -> list[CycleResult]:
    loads = _loads(key, payload)
    return analyze_window(window, lambda speed, load: loads.static_state(speed, load).windup)


def _job_misfires(key, payload, window: MisfireWindow) -> list:
    spring = _loads(key, payload).model.spring
    return analyze_misfires(window, None if spring is None else spring.torque)


class _Worker:
    """One single-worker executor (a spawned process, or a thread) and the models sent to it.
    A process is started (in ``submit``) with SIGINT and SIGTERM blocked, so the process
    group's signals cannot end it before its initializer ignores them."""

    def __init__(self, mode: str, niceness: int, name: str) -> None:
        self.mode, self.niceness, self.name = mode, niceness, name
        self._sent: set = set()
        self._start()

    def _start(self) -> None:
        if self.mode == 'process':
            import multiprocessing
            self.ex = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context('spawn'),
                                          initializer=_init_worker, initargs=(self.niceness,))
        else:
            self.ex = ThreadPoolExecutor(1, thread_name_prefix=self.name)
        self._sent = set()
        with blocked_signals(WORKER_IGNORES):
            self.ready = self.ex.submit(_job_ready)

    def submit(self, fn, model, *args) -> Future:
        key, line, engine = model
        for attempt in range(2):
            payload = None if key in self._sent else (line, engine)
            try:
                with blocked_signals(WORKER_IGNORES):
                    fut = self.ex.submit(fn, key, payload, *args)
            except BrokenProcessPool:
                if attempt:
                    raise
                self._start()       # the worker died (killed?): start a new one
                continue
            self._sent.add(key)
            return fut
        raise RuntimeError('unreachable')

    def close(self) -> None:
        """Stop at once: queued jobs are cancelled and a worker process is killed, whether it
        runs a job (a prediction takes up to seconds) or is still starting (importing, one to
        three seconds): the node is stopping and wants no more results. A thread finishes
        its job."""
        processes = list((getattr(self.ex, '_processes', None) or {}).values())
        manager = getattr(self.ex, '_executor_manager_thread', None)   # shutdown forgets it
        self.ex.shutdown(wait=False, cancel_futures=True)
        for proc in processes:
            if proc.is_alive():
                proc.kill()
        for proc in processes:
            proc.join()
        self.ex.shutdown(wait=True)
        if manager is not None:
            _forget_exit_wakeup(manager)

    @property
    def pids(self) -> list[int]:
        """The worker processes' ids (none for a thread)."""
        return [p.pid for p in (getattr(self.ex, '_processes', None) or {}).values()]


def _forget_exit_wakeup(manager) -> None:
    """Take a closed pool's manager thread (``manager``) out of concurrent.futures' exit hook.

    The hook (``concurrent.futures.process._python_exit``) wakes every manager thread it still
    knows when the interpreter exits; after a pool whose worker was killed has been shut down,
    the thread's wake-up pipe is closed, and the hook's write to it ends the node with a
    traceback ('Bad file descriptor') although everything was closed in order. The pool is
    finished, so nothing is lost by not waking it."""
    from concurrent.futures import process as cf_process
    wakeups = getattr(cf_process, '_threads_wakeups', None)
    if wakeups is not None:
        wakeups.pop(manager, None)


# ------------------------------------------------------------------------------------------------
# The monitor
# ------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class CycleReport:
    """One completed cycle: its analysis, live minus predicted, alarms and message content."""

    cycle: CycleResult
    comparison: Comparison
    alarms: AlarmReport
    status: StatusData


@dataclass
class MonitorUpdate:
    """What :meth:`LiveMonitor.poll` found finished: cycle reports (in order), when the
    prediction at the setpoint changed, the new prediction and its message content, and the
    firing intervals the misfire detector scored for the first time
    (:class:`dmf_sim.monitor.misfire.Detection`, in order) with their message content."""

    cycles: list[CycleReport] = field(default_factory=list)
    prediction: Prediction | None = None
    prediction_statuses: list[StatusData] = field(default_factory=list)
    detections: list = field(default_factory=list)
    detection_statuses: list[StatusData] = field(default_factory=list)


class LiveMonitor:
    """Live orders, prediction and alarms of one node (see the module docstring).

    Args:
        line: the driveline (:class:`dmf_sim.physics.model.Driveline`, with a DMF).
        engine: the engine.
        settings: :class:`MonitorSettings`.
        node_name: used in the status names.
        solver: the prediction solver (:func:`dmf_sim.monitor.prediction.predict_states` by
        default).
        faults: the faults acting (:meth:`set_faults`), None: healthy.
    """

    def __init__(self, line, engine, settings: MonitorSettings | None = None, *,
                 node_name: str = 'driveline_node', solver=predict_states, faults=None) -> None:
        self.settings = settings or MonitorSettings()
        self.node_name = node_name
        self.solver = solver
        self._uid = next(_uid)
        self._version = 0
        self._model = None
        self.tracker = CycleOrderTracker(line.spring)
        s = self.settings
        self._cycles_worker = _Worker(s.worker, s.niceness, 'dmf-cycles')
        self._predict_worker = _Worker(s.worker, s.niceness, 'dmf-prediction')
        self._cycle_jobs: list[Future] = []
        self._misfire_jobs: list[Future] = []
        self._reported_ns = -1          # the last firing interval reported (its TDC time)
        self._cache: OrderedDict[OperatingPoint, Prediction] = OrderedDict()
        self._job: tuple[OperatingPoint, Future] | None = None
        self._want: OperatingPoint | None = None
        self._want_since = 0.0
        self._published: OperatingPoint | None = None
        self._setpoint: tuple[float, float] | None = None
        self.prediction: Prediction | None = None      # the published one (current point)
        self.last_cycle: CycleResult | None = None
        self.last_report: AlarmReport = evaluate(self.settings.alarms)
        self.counters = {'cycles_analysed': 0, 'predictions_computed': 0,
                         'prediction_latency_s': math.nan, 'worker_failures': 0,
                         'monitor_worker': s.worker}
        self.faults = steady_part(faults)
        self.misfires = self._misfire_tracker(line)
        self.set_model(line, engine)

    # ---- configuration ---------------------------------------------------------------------
    def set_model(self, line, engine) -> None:
        """A new DMF (alpha/theta) or load set: later cycles and predictions use it."""
        if line.spring is None:
            raise ConfigError(f'driveline {line.name!r} has no DMF: nothing to monitor')
        self._version += 1
        self._model = ((self._uid, self._version), line, engine)
        self.spring = line.spring
        # why the prediction is off ('' : on; the harmonic balance models every spring,
        # friction and end stops included)
        self.counters['prediction_off'] = ''
        self.load_set = str(getattr(engine, 'load_set', ''))
        self.tracker.set_spring(line.spring)
        if self._setpoint is not None:
            self.set_setpoint(*self._setpoint)

    def _misfire_tracker(self, line) -> MisfireTracker | None:
        """The live misfire detector's tracker when the driveline has tooth wheels on both
        sides of the DMF and firing phases; else None (nothing detected, said in the status)."""
        names = dmf_wheels(line)
        if names is None or not line.firing_phases_deg:
            self.counters['misfire_detector'] = 'off (no tooth wheels on both DMF sides)'
            return None
        wheels = {w.name: w for w in line.sensors.tooth_wheels}
        self.counters.update({'misfire_detector': f'on ({names[0]}, {names[1]})',
                              'intervals_scored': 0, 'misfire_alarms': 0})
        return MisfireTracker([wheels[n] for n in names], np.radians(line.firing_phases_deg),
                              threshold=self.settings.misfire_threshold)

    def set_faults(self, faults) -> None:
        """The faults acting now (a :class:`~dmf_sim.physics.faults.FaultSet`, e.g. a fault
        timeline's active set; None or empty: healthy): later predictions take their persistent
        part (every-cycle misfires, weak cylinders, DMF faults, held; single and random misfires
        and sensor faults have no steady state of their own), and it is part of the cache key.
        ``line`` stays the configured driveline: the DMF faults are applied by the prediction."""
        self.faults = steady_part(faults)
        if self._setpoint is not None:
            self.set_setpoint(*self._setpoint)

    def set_settings(self, settings: MonitorSettings) -> None:
        """New thresholds / rounding (the worker mode stays as started)."""
        self.settings = replace(settings, worker=self.settings.worker)
        if self.misfires is not None:
            self.misfires.threshold = self.settings.misfire_threshold
        if self._setpoint is not None:
            self.set_setpoint(*self._setpoint)

    def set_setpoint(self, speed_rpm: float, load: float) -> None:
        """The node's speed [rpm] and load setpoints: predict there (cached per point)."""
        self._setpoint = (float(speed_rpm), float(load))
        s = self.settings
        point = OperatingPoint.rounded(speed_rpm, load, self.load_set, self.spring,
                                       s.prediction_speed_step_rpm, s.prediction_load_step,
                                       self.faults)
        if point == self._want or self.counters['prediction_off']:
            return
        self._want, self._want_since = point, time.perf_counter()
        if point not in self._cache and self._job is None:
            self._submit(point)

    def _submit(self, point: OperatingPoint) -> None:
        self._job = (point, self._predict_worker.submit(_job_predict, self._model, self.solver,
                                                        point))

    # ---- samples (tick thread) -------------------------------------------------------------
    def add_samples(self, samples, load: float, stamps_ns=None) -> None:
        """The published samples of a tick (cheap; the analysis runs in the worker)."""
        window = self.tracker.collect(samples, load, stamps_ns)
        if window is not None:
            self._cycle_jobs.append(self._cycles_worker.submit(_job_cycles, self._model, window))

    def add_sensors(self, chunk, t_s: float, psi_rad: float) -> None:
        """A chunk's sensor signals (:class:`~dmf_sim.physics.sensor_signals.SensorChunk`) and
        the crank angle at its end [s, rad] (cheap; once per engine cycle the live misfire
        detector runs in the cycle worker). Nothing without the tooth wheels around the DMF."""
        if self.misfires is None:
            return
        window = self.misfires.add(chunk, t_s, psi_rad)
        if window is not None:
            self._misfire_jobs.append(self._cycles_worker.submit(_job_misfires, self._model,
                                                                 window))

    def reset_sensors(self) -> None:
        """The motion jumped (a reset): the misfire detector starts over."""
        if self.misfires is not None:
            self.misfires.clear()     # simulated time goes on: nothing is reported twice

    # ---- results ---------------------------------------------------------------------------
    def poll(self) -> MonitorUpdate:
        """Finished cycle analyses (in order) and a new prediction at the setpoint, if any."""
        up = MonitorUpdate()
        self._poll_prediction(up)
        while self._cycle_jobs and self._cycle_jobs[0].done():
            fut = self._cycle_jobs.pop(0)
            if fut.exception() is not None:       # the worker died: these cycles are lost
                self.counters['worker_failures'] += 1
                continue
            for cycle in fut.result():
                up.cycles.append(self._report(cycle))
        self._poll_misfires(up)
        return up

    def _poll_misfires(self, up: MonitorUpdate) -> None:
        while self._misfire_jobs and self._misfire_jobs[0].done():
            fut = self._misfire_jobs.pop(0)
            if fut.exception() is not None:       # the worker died: these intervals are lost
                self.counters['worker_failures'] += 1
                continue
            detections, terms = fut.result()
            self.misfires.learned.add(terms)
            for d in detections:
                if d.t_ns > self._reported_ns:
                    self._reported_ns = d.t_ns
                    up.detections.append(d)
        if up.detections:
            self.counters['intervals_scored'] += len(up.detections)
            self.counters['misfire_alarms'] += sum(d.alarm for d in up.detections)
            up.detection_statuses = detection_statuses(self.node_name, up.detections)

    def _poll_prediction(self, up: MonitorUpdate) -> None:
        if self._job is not None and self._job[1].done():
            point, fut = self._job
            self._job = None
            if fut.exception() is not None:       # the worker died: computed again below
                self.counters['worker_failures'] += 1
            else:
                self._cache[point] = fut.result()
                self.counters['predictions_computed'] += 1
            while len(self._cache) > PREDICTION_CACHE_SIZE:
                self._cache.popitem(last=False)
        want = self._want
        if want is None:
            return
        if want not in self._cache:
            if self._job is None:
                self._submit(want)
            return
        self._cache.move_to_end(want)
        if want != self._published:
            self._published = want
            self.prediction = self._cache[want]
            self.counters['prediction_latency_s'] = time.perf_counter() - self._want_since
            up.prediction = self.prediction
            sp = self.spring
            up.prediction_statuses = prediction_statuses(self.node_name, self.prediction,
                                                         sp.alpha, sp.theta)

    def _report(self, cycle: CycleResult) -> CycleReport:
        s = self.settings
        comp = compare(cycle, self.prediction, s.compare_speed_tolerance_rpm,
                       s.compare_load_tolerance)
        report = evaluate(s.alarms, cycle, self.prediction)
        self.last_cycle, self.last_report = cycle, report
        self.counters['cycles_analysed'] += 1
        return CycleReport(cycle, comp, report,
                           cycle_status(self.node_name, cycle, comp, self.prediction, report))

    def diagnostics(self) -> StatusData:
        """The monitor's status for /diagnostics (alarms of the last cycle and prediction)."""
        report = evaluate(self.settings.alarms, self.last_cycle, self.prediction)
        return monitor_status(self.node_name, report, self.last_cycle, self.prediction,
                              self.counters)

    def wait_ready(self, timeout: float | None = None) -> None:
        """Block until both workers are up (the node may call this at start-up)."""
        self._cycles_worker.ready.result(timeout)
        self._predict_worker.ready.result(timeout)

    def wait_idle(self, timeout: float | None = None) -> None:
        """Block until every cycle analysis and misfire window handed in so far is done (the
        next :meth:`poll` returns them): for tests and offline use, never in the tick thread."""
        for fut in list(self._cycle_jobs) + list(self._misfire_jobs):
            fut.exception(timeout)

    @property
    def worker_pids(self) -> list[int]:
        """The ids of the worker processes running now (none with ``worker='thread'``)."""
        return self._cycles_worker.pids + self._predict_worker.pids

    def close(self) -> None:
        """Stop the workers at once (a running job's result is dropped; see ``_Worker.close``)."""
        self._cycles_worker.close()
        self._predict_worker.close()
