"""Everything ``driveline_node`` runs, without ROS: built from its parameter values, validating
and applying run-time parameter changes.

:class:`LiveRuntime` wires a :class:`dmf_sim.live.simulation.LiveSimulation`, its
:class:`dmf_sim.live.run_loop.RunLoop`, a :class:`dmf_sim.live.recording.RecordingControl` and a
:class:`dmf_sim.live.health.HealthMonitor`. The node supplies the sink (publish + record), a logger
and the resolved topic names, and maps its parameter callbacks onto :meth:`LiveRuntime.check`
(on-set: validate; may create a bag, the only full check that it can be written) and
:meth:`LiveRuntime.apply` (post-set: apply). A bad start-up configuration raises
:class:`dmf_sim.core.errors.ConfigError` with one line naming the parameter.

Threads: the tick thread holds :attr:`LiveRuntime.lock` during every tick; ``check`` and
``apply`` take it too. Setpoints do not: they go through the loop's inbox.
"""
from __future__ import annotations

import threading
from typing import Mapping

from dmf_sim.core.errors import ConfigError, one_line
from dmf_sim.core.numbers import fmt_num
from dmf_sim.live.faults import FAULT_PARAMETERS, LiveFaults
from dmf_sim.live.health import HealthMonitor
from dmf_sim.live.pacing import Pacer, publish_stride
from dmf_sim.live.parameters import MONITOR_SETTINGS, choice_reason
from dmf_sim.live.recording import RecordingControl, run_metadata
from dmf_sim.live.simulation import LiveSimulation

__all__ = ['read_line', 'LiveRuntime']


def read_line(driveline: str):
    """The driveline of parameter ``driveline`` (ConfigError naming the parameter)."""
    from dmf_sim.physics.model import read_driveline
    try:
        return read_driveline(driveline)
    except (ValueError, FileNotFoundError) as exc:
        raise ConfigError(f"parameter 'driveline' = {driveline!r}: {one_line(exc)}") from None


def _rtf(real_time_factor: float, pacing: str) -> float:
    return 0.0 if pacing == 'fast' else float(real_time_factor)


class LiveRuntime:
    """The live simulation of one node, its loop, recording and health.

    Args:
        values: every parameter value (``PARAMETERS`` plus alpha/theta).
        line: the driveline of ``values['driveline']`` (:func:`read_line`).
        sink: :class:`dmf_sim.live.run_loop.SampleSink`.
        log: info/warning/error logger.
        topics: absolute topic name -> ROS type of every recorded stream.
        node_name: the node's fully qualified name (stored in bags).
        qos: absolute topic name -> offered QoS profile (rosbag2 form,
            :meth:`dmf_sim.live.streams.Stream.qos_profile`): written into bags; the latched
            (transient-local) topics start every recording and are resent to Foxglove clients
            that subscribe later.
        streams: stream key -> :class:`~dmf_sim.live.streams.Stream` of every stream
            (:func:`dmf_sim.live.streams.streams_for`; default :data:`~dmf_sim.live.streams.
            STREAMS`, no sensors).
    """

    def __init__(self, values: Mapping, line, sink, log, *, topics: Mapping[str, str],
                 node_name: str = '/driveline_node',
                 qos: Mapping[str, dict] | None = None, streams=None) -> None:
        from dmf_sim.live.run_loop import RunLoop
        from dmf_sim.live.sensors import SensorMessages
        from dmf_sim.live.streams import STREAMS
        from dmf_sim.physics.engine import read_engine

        p = self.values = dict(values)
        self.streams = dict(STREAMS if streams is None else streams)
        self.log, self.node_name = log, node_name
        self.has_dmf = line.dmf is not None
        try:
            if self.has_dmf:
                line = line.with_dmf(alpha=p['alpha'], theta=p['theta'])
            elif (p['alpha'], p['theta']) != (0.0, 0.0):
                raise ConfigError(f'driveline {line.name!r} has no dmf section; alpha/theta do '
                                  'not apply')
        except ValueError as exc:
            raise ConfigError(f'alpha/theta: {one_line(exc)}') from None
        try:
            engine = read_engine(p['engine'], load_set=p['load_set'])
        except (ValueError, FileNotFoundError) as exc:
            raise ConfigError(f"parameter 'engine' = {p['engine']!r} / 'load_set' = "
                              f"{p['load_set']!r}: {one_line(exc)}") from None
        for name in ('pacing', 'overrun_policy'):
            if reason := choice_reason(name, p[name]):
                raise ConfigError(f'parameter {reason}')
        try:
            stride = publish_stride(p['publish_rate'], p['dt'])
            self.sim = LiveSimulation(
                line, engine, dt=p['dt'], speed_rpm=p['initial_speed_rpm'],
                load=p['initial_load'], speed_ramp_rpm_per_s=p['speed_ramp_rpm_per_s'],
                load_ramp_per_s=p['load_ramp_per_s'],
                speed_limits_rpm=(p['speed_min_rpm'], p['speed_max_rpm']), stride=stride,
                sensors=bool(p.get('sensors', False)))
        except ValueError as exc:
            raise ConfigError(one_line(exc)) from None
        ls = self.sim.live_sensors
        self.sensor_messages = (
            SensorMessages(ls.wheel_names, ls.signal_names,
                           line.sensors.edge_batch_ns(self.sim.stride * self.sim.dt))
            if ls is not None else None)
        pacer = Pacer(p['dt'], _rtf(p['real_time_factor'], p['pacing']), p['max_lag'],
                      p['overrun_policy'])
        self.loop = RunLoop(self.sim, pacer, sink, log, publish_clock=p['publish_clock'],
                            diagnostics_period_s=1.0 / p['diagnostics_rate'])
        self.recording = RecordingControl(topics, log, max_duration_s=p['bag_max_duration_s'],
                                          qos=qos)
        self.health = HealthMonitor(self.loop, self.recording)
        self.faults = self._start_faults(sink, p)
        self.monitor = self._start_monitor(sink) if p['monitor'] and self.has_dmf else None
        self.foxglove = None
        if p['foxglove_port']:
            from dmf_sim.bags.writer import latched_depth
            from dmf_sim.live.foxglove_bridge import FoxgloveBridge, foxglove_hint
            latched = [t for t, profile in (qos or {}).items() if latched_depth([profile])]
            self.foxglove = FoxgloveBridge(topics, host=p['foxglove_host'],
                                           port=int(p['foxglove_port']), latched=latched)
            log.info(foxglove_hint(self.foxglove.url, node_name))
        self.lock = threading.RLock()
        self._pending_recorder = None
        if p['record']:
            recorder, reason = self._prepare_recording(p['bag_path'])
            if reason:
                raise ConfigError(f'record: {reason}')
            self._start_recording(recorder)
        else:
            # load the message type store now: the first recording then starts in ~10 ms
            from rosbags.typesys import Stores, get_typestore
            get_typestore(Stores.ROS2_JAZZY)

    # ---- faults: requests in, ground truth out (dmf_sim.live.faults) ----------------------------
    def _start_faults(self, sink, values: Mapping) -> LiveFaults:
        """The node's faults: the parameters' start-up values applied (a bad one: ConfigError
        naming it), topic requests applied between ticks, the ground truth published after
        each tick."""
        faults = LiveFaults(self.sim, self.log, self.node_name)
        for name in FAULT_PARAMETERS:
            if values.get(name):
                if reason := faults.check_parameter(name, values[name]):
                    raise ConfigError(f'parameter {reason}')
                faults.apply_parameter(name, values[name])
        loop = self.loop
        loop.before_tick.append(faults.apply)
        loop.after_tick.append(lambda: faults.publish(sink, loop.time.stamp_ns,
                                                      self.sim.take_fault_events()))
        self.health.contributors.append(faults.health)
        return faults

    def clear_faults(self) -> str:
        """End every fault now (``~/clear_faults``); the fault parameters become ''."""
        with self.lock:
            msg = self.faults.clear()
            self.values.update(dict.fromkeys(FAULT_PARAMETERS, ''))
        return msg

    # ---- the DMF monitor: live orders, prediction, alarms (dmf_sim.monitor.worker) -------------
    def _monitor_settings(self, values: Mapping):
        from dmf_sim.monitor.worker import MonitorSettings
        return MonitorSettings(worker=values['monitor_worker'],
                               **{k: values[k] for k in MONITOR_SETTINGS if k != 'monitor_worker'})

    def _start_monitor(self, sink):
        from dmf_sim.monitor.worker import LiveMonitor
        sim = self.sim
        monitor = LiveMonitor(sim.line, sim.engine, self._monitor_settings(self.values),
                              node_name=self.node_name)
        monitor.set_setpoint(sim.speed_setpoint, sim.load_setpoint)
        self.loop.setpoint_listeners.append(monitor.set_setpoint)
        acting = [None]          # the faults acting at the last tick

        def observe(samples, stamps_ns) -> None:      # tick thread: a few microseconds
            now = sim.faults.active_set() if sim.faults is not None else None
            if now != acting[0]:         # the prediction follows the faults (their held part)
                acting[0] = now
                monitor.set_faults(now)
            monitor.add_samples(samples, sim.load, stamps_ns)
            up = monitor.poll()
            for report in up.cycles:
                sink.publish_statuses('dmf_orders', [report.status], report.cycle.stamp_ns)
            if up.prediction is not None:
                sink.publish_statuses('dmf_predicted', list(up.prediction_statuses),
                                      int(stamps_ns[-1]))
            if up.detection_statuses:     # about the last interval's TDC, sent now
                sink.publish_statuses('misfire_detections', up.detection_statuses,
                                      self.loop.time.epoch_ns + up.detections[-1].t_ns,
                                      int(stamps_ns[-1]))
        self.loop.observers.append(observe)
        if monitor.misfires is not None and sim.live_sensors is not None:
            self.loop.sensor_observers.append(
                lambda chunk: monitor.add_sensors(chunk, sim.t, sim.psi))
        return monitor

    def describe(self) -> str:
        """One start-up line: model, rates, pacing, recording."""
        sim, spring = self.sim, self.sim.model.spring
        dmf = spring.describe() if spring is not None else 'none'
        pacing = ('fast' if self.loop.pacer.fast
                  else f'real time x{fmt_num(self.loop.pacer.rtf)}')
        text = (f'{sim.line.name} ({len(sim.names)} elements, DMF {dmf}), engine '
                f'{self.values["engine"]!r} load set {self.values["load_set"]}; dt='
                f'{fmt_num(sim.dt)} s, publishing {self.loop.publish_rate_hz:g} Hz, pacing '
                f'{pacing}; recording ' + (str(self.recording.path) if self.recording.active
                                           else 'off'))
        if self.recording.active and not self.recording.splits_supported:
            text += ' (one file: this bag writer does not split, bag_max_duration_s unused)'
        return text

    def ready_lines(self, topics: Mapping[str, str]) -> list[str]:
        """What the node says once it runs: its topics with their rates, where to look, how
        to stop. ``topics``: stream key (:data:`dmf_sim.live.streams.STREAMS`) -> resolved
        topic name."""
        by = {}
        for key, name in topics.items():
            per = self.streams[key].per
            if per in ('cycle', 'setpoint') and self.monitor is None:
                continue
            by.setdefault(per, []).append(name + (' (latched)' if self.streams[key].latched
                                                  else ''))
        rate = 1.0 / self.loop.diagnostics_period_s
        ns = topics['speed'].rsplit('/', 2)[0]
        where = f' --namespace {ns}' if ns else ''
        lines = [f'publishing {", ".join(by["sample"])} at {self.loop.publish_rate_hz:g} Hz '
                 f'(simulated time); {", ".join(by["diagnostics"])} at {rate:g} Hz']
        if self.monitor is not None:
            lines.append(f'DMF monitor: {", ".join(by["cycle"])} per engine cycle, '
                         f'{", ".join(by["setpoint"])} when the setpoint changes')
        lines.append(f'faults: {", ".join(by["fault"])}; inject: dmf-sim fault{where} '
                     "'{kind: misfire, cylinders: [3]}' or the fault_* parameters")
        if 'edges' in by or 'bus' in by:
            every = (f'every {self.sensor_messages.batch_period_ns / 1e6:g} ms'
                     if self.sensor_messages is not None else 'none')
            lines.append(f'sensors: edge batches {", ".join(by.get("edges", ())) or "none"} '
                         f'{every}; bus {", ".join(by.get("bus", ())) or "none"} when '
                         'delivered')
        lines.append(f'look: dmf-sim monitor{where} | ros2 topic hz {topics["speed"]} | set: '
                     f'dmf-sim setpoint{where} --speed 1200 --load 0.8')
        bag = f' (closes the bag {self.recording.path})' if self.recording.active else ''
        lines.append(f'stop: Ctrl-C or SIGTERM{bag}')
        return lines

    # ---- recording --------------------------------------------------------------------------
    def _prepare_recording(self, bag_path: str):
        meta = run_metadata(self.sim, driveline=str(self.values['driveline']),
                            engine=str(self.values['engine']), node=self.node_name,
                            publish_rate_hz=self.loop.publish_rate_hz)
        return self.recording.prepare(bag_path, meta)

    def _start_recording(self, recorder) -> None:
        self.loop.time.new_recording()
        self.recording.start(recorder)

    def close(self) -> str:
        """Stop recording, then the monitor's workers and the Foxglove server (shutdown:
        SIGINT/SIGTERM); returns what happened to the recording. The bag is closed first: it
        is what a SIGKILL during the shutdown would cost (the workers may be busy for a
        prediction, or still starting)."""
        closed = self.close_recording()
        self.close_services()
        return closed

    def close_recording(self) -> str:
        """The first half of :meth:`close`: stop recording (the bag closed); returns what
        happened to it."""
        with self.lock:
            return self.recording.stop()

    def abandon(self) -> None:
        """A start-up that failed after this runtime was built: stop the monitor and Foxglove
        and remove the bag it had created (nothing was recorded in it)."""
        with self.lock:
            self.recording.remove_unused()
            self.close_services()

    def close_services(self) -> None:
        """The second half of :meth:`close`: stop the monitor's workers and Foxglove."""
        with self.lock:
            if self.monitor is not None:
                self.monitor.close()
            if self.foxglove is not None:
                self.foxglove.close()

    def reset(self) -> str:
        """Static equilibrium at the current setpoints (``~/reset``)."""
        with self.lock:
            self.sim.reset()
            if self.monitor is not None:
                self.monitor.reset_sensors()
            sim = self.sim
            msg = (f'reset to static equilibrium at {fmt_num(sim.speed_setpoint)} rpm, load '
                   f'{fmt_num(sim.load_setpoint)} (t = {sim.t:.4f} s); the peak wind-up and DMF '
                   'torque start afresh')
        self.log.info(msg)
        return msg

    # ---- run-time parameter changes ---------------------------------------------------------
    def check(self, new: Mapping) -> str | None:
        """Why the parameter changes ``new`` are refused, or None (on-set callback). Ranges,
        types and read-only are the descriptors' job. A ``record`` that turns recording on
        creates its bag here (without the lock); :meth:`apply` then starts it."""
        with self.lock:
            reason = self._check(new)
        if reason is None and new.get('record') and not self.recording.active:
            recorder, reason = self._prepare_recording(new.get('bag_path',
                                                               self.values['bag_path']))
            self._pending_recorder = recorder
        return reason

    def _check(self, new: Mapping) -> str | None:
        sim = self.sim
        cur = {**self.values, **new}
        for name in ('pacing', 'overrun_policy'):
            if name in new and (reason := choice_reason(name, new[name])):
                return reason
        if 'publish_rate' in new:
            try:
                publish_stride(new['publish_rate'], sim.dt)
            except ConfigError as exc:
                return str(exc)
        if 'speed_min_rpm' in new or 'speed_max_rpm' in new:
            lo, hi = cur['speed_min_rpm'], cur['speed_max_rpm']
            if reason := sim.check_speed_limits(lo, hi):
                return reason
            if not lo <= sim.speed_setpoint <= hi:
                return (f'the current speed setpoint {fmt_num(sim.speed_setpoint)} rpm is '
                        f'outside [{fmt_num(lo)}, {fmt_num(hi)}]')
        if 'alpha' in new or 'theta' in new:
            if not self.has_dmf:
                return 'this driveline has no DMF; alpha/theta do not apply'
            if not cur['theta'] > 0:
                return f'theta must be > 0 rad, got {fmt_num(cur["theta"])}'
            try:
                sim.faulted_line(sim.line.with_dmf(alpha=cur['alpha'], theta=cur['theta']))
            except ValueError as exc:
                return f'alpha/theta: {one_line(exc)}'
        if 'load_set' in new:
            allowed = getattr(getattr(sim.engine, 'config', None), 'load_set_shifts_rpm', None)
            if allowed is not None and new['load_set'] not in allowed:
                return f'load_set must be one of {sorted(allowed)}, got {new["load_set"]!r}'
        if self.monitor is not None and any(k in new for k in MONITOR_SETTINGS):
            try:
                self._monitor_settings(cur)
            except ConfigError as exc:
                return one_line(exc)
        for name in FAULT_PARAMETERS:
            if name in new and (reason := self.faults.check_parameter(name, new[name])):
                return reason
        if new.get('record') and not self.recording.active:
            return self.recording.check(cur['bag_path'])
        return None

    def discard_pending(self) -> None:
        """A prepared bag whose change was refused after all: remove it."""
        if self._pending_recorder is not None:
            self.recording.discard(self._pending_recorder)
            self._pending_recorder = None

    def apply(self, new: Mapping) -> list[str]:
        """Apply accepted changes (post-set callback); returns what they did, for the log and
        the services' answers."""
        with self.lock:
            return self._apply(dict(new))

    def _apply(self, new: dict) -> list[str]:
        sim, loop, msgs = self.sim, self.loop, []
        self.values.update(new)
        cur = self.values
        if 'alpha' in new or 'theta' in new:
            sim.set_dmf(alpha=cur['alpha'], theta=cur['theta'])
            msgs.append(f'DMF rebuilt: alpha={fmt_num(cur["alpha"])}, theta='
                        f'{fmt_num(cur["theta"])} rad (operating point and state kept)')
            self.log.info(msgs[-1])
        if 'load_set' in new:
            sim.set_load_set(new['load_set'])
        for name in FAULT_PARAMETERS:
            if name in new:
                msgs.append(self.faults.apply_parameter(name, new[name]))
        if self.monitor is not None and ({'alpha', 'theta', 'load_set'} & set(new)):
            self.monitor.set_model(sim.line, sim.engine)
        if self.monitor is not None and any(k in new for k in MONITOR_SETTINGS):
            self.monitor.set_settings(self._monitor_settings(cur))
        if 'speed_min_rpm' in new or 'speed_max_rpm' in new:
            sim.set_speed_limits(cur['speed_min_rpm'], cur['speed_max_rpm'])
        if 'speed_ramp_rpm_per_s' in new or 'load_ramp_per_s' in new:
            sim.set_ramps(new.get('speed_ramp_rpm_per_s'), new.get('load_ramp_per_s'))
        if 'publish_rate' in new:
            sim.set_stride(publish_stride(new['publish_rate'], sim.dt))
        if 'real_time_factor' in new or 'pacing' in new:
            if msg := loop.set_rate(_rtf(cur['real_time_factor'], cur['pacing'])):
                msgs.append(msg)
        if 'max_lag' in new:
            loop.pacer.max_lag = float(new['max_lag'])
        if 'overrun_policy' in new:
            loop.pacer.policy = new['overrun_policy']
        if 'publish_clock' in new:
            loop.publish_clock_param = bool(new['publish_clock'])
        if 'diagnostics_rate' in new:
            loop.diagnostics_period_s = 1.0 / float(new['diagnostics_rate'])
            loop.next_diag = min(loop.next_diag, loop.clock() + loop.diagnostics_period_s)
        if 'bag_max_duration_s' in new:
            self.recording.max_duration_s = float(new['bag_max_duration_s'])
        if 'bag_path' in new and new.get('record', True):
            if msg := self.recording.note_bag_path(new['bag_path']):
                msgs.append(msg)
        if 'record' in new:
            if not new['record']:
                msgs.append(self.recording.stop())
            elif self._pending_recorder is not None:
                self._start_recording(self._pending_recorder)
                msgs.append(f'recording to {self.recording.path}')
            self._pending_recorder = None
        return msgs
