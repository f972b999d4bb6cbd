"""``driveline_node``: the live driveline as a ROS 2 node — rclpy plumbing over the ROS-free core.

How to start it: :data:`INVOCATIONS` (``ros2 run``, ``ros2 launch``, ``python -m``). What runs
is :class:`dmf_sim.live.runtime.LiveRuntime` (simulation, tick loop, recording, health); this
module declares the parameters, creates the topics and services, serializes the samples and
spins. Importing it needs no ROS installation (the rclpy imports are guarded).

Topics and services (relative names; without a namespace they resolve as listed) are the
tables of :mod:`dmf_sim.live.streams`; ``driveline_node --help`` prints them (:func:`usage`).

Setpoints are commands: the subscriptions keep all (reliable flow control slows a publisher
that outruns the node instead of dropping its commands), their callbacks only validate, count
and hand the value to the tick thread (no lock), and the last valid setpoint received is the one
applied. Fault requests (:mod:`dmf_sim.live.faults`) on ``faults/inject`` are validated on
arrival and applied between ticks; a bad one is refused with its reason (logged, counted in
/diagnostics).

Stamps: see :class:`dmf_sim.live.pacing.TimeBase` (wall clock at real-time factor 1, re-anchored
when pacing returns to it). Parameters: :mod:`dmf_sim.live.parameters`,
``config/driveline_node.yaml``.
"""
from __future__ import annotations

import array
import sys
import textwrap
import threading
import time

from dmf_sim.core.errors import ConfigError, DmfSimError, one_line
from dmf_sim.core.numbers import fmt_num
from dmf_sim.live.parameters import DMF_PARAMETERS, PARAMETERS, coerce
from dmf_sim.live.stop_signals import StopSignals
from dmf_sim.live.streams import (
    CLOCK,
    DETECTIONS,
    PUBLISHED,
    SENSOR_STREAMS,
    SERVICES,
    STREAMS,
    SUBSCRIPTIONS,
    streams_for,
)
from dmf_sim.transient.live_profile import NodeProfile, check_profile

__all__ = ['EXIT_CONFIG_ERROR', 'DrivelineNode', 'usage', 'main']

EXIT_CONFIG_ERROR = 2

INVOCATIONS = (
    'ros2 run dmf_sim driveline_node [--ros-args --params-file config/driveline_node.yaml '
    '-p k:=v]',
    'ros2 launch dmf_sim driveline.launch.py namespace:=truck1 record:=true',
    'python -m dmf_sim.node [--ros-args ...]',
)
"""How the node is started (``--help``)."""
STOPPING = ('Stop: Ctrl-C or SIGTERM (closes the bag; later SIGINT/SIGTERM are ignored until it '
            'is closed, SIGKILL stops at once); it also stops when the process that started it '
            '(ros2 launch) ends.')

try:
    from builtin_interfaces.msg import Time
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import (
        FloatingPointRange,
        IntegerRange,
        ParameterDescriptor,
        ParameterType,
        SetParametersResult,
    )
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.exceptions import ParameterException
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, String, UInt64MultiArray
    from std_srvs.srv import SetBool, Trigger
    ROS_IMPORT_ERROR: ImportError | None = None
except ImportError as _exc:      # no ROS: PARAMETERS, STREAMS and main()'s message still work
    Node = object
    ROS_IMPORT_ERROR = _exc


def _qos(depth: int = 0, latched: bool = False):
    """Reliable, volatile (``latched``: transient local); keep last ``depth`` (0 = keep all)."""
    history = HistoryPolicy.KEEP_LAST if depth else HistoryPolicy.KEEP_ALL
    durability = DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE
    return QoSProfile(history=history, depth=depth, reliability=ReliabilityPolicy.RELIABLE,
                      durability=durability)


def _stream_qos(stream):
    return _qos(stream.depth, latched=stream.latched)


def _descriptor(name: str, default, spec) -> ParameterDescriptor:
    types = {bool: ParameterType.PARAMETER_BOOL, float: ParameterType.PARAMETER_DOUBLE,
             str: ParameterType.PARAMETER_STRING, int: ParameterType.PARAMETER_INTEGER}
    d = ParameterDescriptor(name=name, type=types[type(default)], description=spec.description,
                            read_only=spec.read_only)
    if spec.range is not None and isinstance(default, int) and not isinstance(default, bool):
        d.integer_range = [IntegerRange(from_value=int(spec.range[0]),
                                        to_value=int(spec.range[1]), step=1)]
    elif spec.range is not None:
        d.floating_point_range = [FloatingPointRange(from_value=float(spec.range[0]),
                                                     to_value=float(spec.range[1]), step=0.0)]
    return d


class StartupFailed(Exception):
    """The node refused its configuration at start-up; the reason is logged, one line naming
    the node (``start-up of /truck1/driveline_node failed: ...``)."""


class DrivelineNode(Node):
    """The rclpy shell: parameters, topics, services; the work is in ``self.runtime``.

    A configuration the node refuses raises :class:`StartupFailed` after logging why; whatever
    the start had opened is closed again (the monitor's workers, Foxglove) and a bag it had
    created is removed (nothing was recorded in it; its ``bag_path`` is free again)."""

    def __init__(self, node_name: str = 'driveline_node') -> None:
        super().__init__(node_name)
        self.fqn = self.get_fully_qualified_name()
        self.runtime = None
        try:
            self._start(node_name)
        except (DmfSimError, ParameterException) as exc:
            self._abandon()
            self.get_logger().error(f'start-up of {self.fqn} failed: {one_line(exc)}')
            self.destroy_node()
            raise StartupFailed(one_line(exc)) from None
        except BaseException:
            self._abandon()
            raise

    def _abandon(self) -> None:
        if self.runtime is not None:
            self.runtime.abandon()

    def _start(self, node_name: str) -> None:
        from dmf_sim.live.runtime import LiveRuntime, read_line

        values = {name: self._declare(name, spec.default, spec)
                  for name, spec in PARAMETERS.items()}
        line = read_line(values['driveline'])
        defaults = (line.dmf.alpha, line.dmf.theta) if line.dmf is not None else (0.0, 0.0)
        for (name, spec), default in zip(DMF_PARAMETERS.items(), defaults):
            if line.dmf is None:
                spec = spec._replace(description=spec.description + '; this driveline has no '
                                     'DMF: not used')
            values[name] = self._declare(name, float(default), spec)

        # the profile before anything starts (the monitor's worker processes among them)
        if reason := check_profile(values['profile'], (values['speed_min_rpm'],
                                                       values['speed_max_rpm']),
                                   dt=values['dt'])[1]:
            raise ConfigError(reason)
        types = {'sensor_msgs/msg/JointState': JointState, 'std_msgs/msg/Float64': Float64,
                 'diagnostic_msgs/msg/DiagnosticArray': DiagnosticArray,
                 'std_msgs/msg/UInt64MultiArray': UInt64MultiArray}
        streams = streams_for(line.sensors if values['sensors'] else None)
        self._pubs = {k: self.create_publisher(types[s.msgtype], s.topic, _stream_qos(s))
                      for k, s in streams.items()}
        self._topics = {k: pub.topic_name for k, pub in self._pubs.items()}
        self._js = JointState()
        self._f64 = Float64()
        self._clock_msg = Clock()
        self._clock_pub = None
        self._answers: list[str] = []
        self.runtime = LiveRuntime(values, line, self, self.get_logger(), node_name=self.fqn,
                                   topics={self._topics[k]: s.msgtype for k, s in streams.items()},
                                   qos={self._topics[k]: s.qos_profile()
                                        for k, s in streams.items()}, streams=streams)
        self._js.name = self.runtime.sim.names
        self._update_clock_publisher()
        self.profile = NodeProfile(self.runtime, self.get_logger())     # parameter 'profile'
        if reason := self.profile.start(values['profile']):
            raise ConfigError(reason)

        inbox = self.runtime.loop.inbox
        for kind in ('speed', 'load'):
            lost = SubscriptionEventCallbacks(
                message_lost=lambda info, k=kind: inbox.count_lost(k, info.total_count_change))
            sub = SUBSCRIPTIONS[f'{kind}_setpoint']
            self.create_subscription(Float64, sub.topic,
                                     lambda msg, k=kind: self._on_setpoint(k, msg.data),
                                     _qos(sub.depth), event_callbacks=lost)
        sub = SUBSCRIPTIONS['fault_inject']
        self.create_subscription(String, sub.topic,
                                 lambda msg: self.runtime.faults.offer(msg.data), _qos(sub.depth))
        self.create_service(Trigger, SERVICES['clear_faults'].name, self._on_clear_faults)
        self.create_service(Trigger, SERVICES['reset'].name, self._on_reset)
        self.create_service(SetBool, SERVICES['record'].name, self._on_record)
        self.add_pre_set_parameters_callback(self._coerce_parameters)
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.get_logger().info(self.runtime.describe())
        for line in self.runtime.ready_lines(self._topics):
            self.get_logger().info(line)

    def _declare(self, name, default, spec):
        try:
            return self.declare_parameter(name, default, _descriptor(name, default, spec)).value
        except ParameterException as exc:
            hint = (' (write floating-point values with a decimal point, e.g. 200.0)'
                    if isinstance(default, float) and "'INTEGER'" in str(exc) else '')
            raise ConfigError(f'parameter {name!r}: {one_line(exc)}{hint}') from None

    # ---- sink of the run loop (tick thread) ---------------------------------------------
    def _emit(self, key: str, msg, log_ns: int) -> None:
        self._emit_raw(key, serialize_message(msg), log_ns)

    def _emit_raw(self, key: str, data: bytes, log_ns: int) -> None:
        """Serialized once: published, recorded, served."""
        self._pubs[key].publish(data)
        rt = self.runtime
        rt.recording.write(self._topics[key], log_ns, data)
        if rt.foxglove is not None:
            rt.foxglove.publish(self._topics[key], data, log_ns)

    def publish_statuses(self, key: str, statuses, stamp_ns: int,
                         sent_ns: int | None = None) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
        msg.status = [s.to_msg(DiagnosticStatus, KeyValue) for s in statuses]
        self._emit(key, msg, (stamp_ns if sent_ns is None else sent_ns)
                   + self.runtime.loop.time.log_offset_ns)

    def publish_samples(self, s, stamps_ns, log_ns) -> None:
        js, f = self._js, self._f64
        stamp = js.header.stamp
        for i in range(len(s)):
            stamp.sec, stamp.nanosec = divmod(int(stamps_ns[i]), 1_000_000_000)
            log = int(log_ns[i])
            js.position = array.array('d', s.position[i].tobytes())
            js.velocity = array.array('d', s.velocity[i].tobytes())
            js.effort = array.array('d', s.effort[i].tobytes())
            self._emit('joint_states', js, log)
            f.data = float(s.windup[i])
            self._emit('dmf_windup', f, log)
            f.data = float(s.speed_rpm[i])
            self._emit('speed', f, log)
            f.data = float(s.psi[i])
            self._emit('crank_angle', f, log)

    def publish_sensors(self, chunk, epoch_ns: int, log_offset_ns: int) -> None:
        for key, log_ns, data in self.runtime.sensor_messages.of(chunk, epoch_ns, log_offset_ns):
            self._emit_raw(key, data, log_ns)

    def publish_held_sensors(self) -> None:
        """Send and record the edges of the batch periods not ended yet (shutdown, before the
        bag closes): the bag keeps every edge of the simulated time."""
        rt = self.runtime
        if rt.sensor_messages is None:
            return
        with rt.lock:
            t = rt.loop.time
            for key, log_ns, data in rt.sensor_messages.held(t.epoch_ns, t.log_offset_ns):
                self._emit_raw(key, data, log_ns)

    def publish_clock(self, stamp_ns: int) -> None:
        if self._clock_pub is not None:
            self._clock_msg.clock = Time(sec=stamp_ns // 1_000_000_000,
                                         nanosec=stamp_ns % 1_000_000_000)
            self._clock_pub.publish(self._clock_msg)

    def _update_clock_publisher(self) -> None:
        """Advertise /clock only while it is published."""
        wanted = self.runtime.loop.clock_on
        if wanted and self._clock_pub is None:
            self._clock_pub = self.create_publisher(Clock, CLOCK.topic, _stream_qos(CLOCK))
        elif not wanted and self._clock_pub is not None:
            self.destroy_publisher(self._clock_pub)
            self._clock_pub = None

    def _publish_diagnostics(self, now: float) -> None:
        rt = self.runtime
        report = rt.health.report(now)
        msg = DiagnosticArray()
        stamp_ns = rt.loop.time.stamp_ns(rt.sim.t)
        msg.header.stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
        msg.status = [report.status(self.fqn).to_msg(DiagnosticStatus, KeyValue)]
        if rt.monitor is not None:                # the DMF monitor: orders, prediction, alarms
            msg.status.append(rt.monitor.diagnostics().to_msg(DiagnosticStatus, KeyValue))
        self._emit('diagnostics', msg, stamp_ns + rt.loop.time.log_offset_ns)
        rt.recording.flush()

    # ---- setpoints and services (executor thread) ---------------------------------------
    def _on_setpoint(self, kind: str, value) -> None:
        inbox = self.runtime.loop.inbox
        if (reason := inbox.offer(kind, value)) and self.runtime.loop.throttle.ready(kind):
            sim = self.runtime.sim
            keep = inbox.last_valid.get(kind, sim.speed_setpoint if kind == 'speed'
                                        else sim.load_setpoint)
            self.get_logger().warning(
                f'rejected {reason}; keeping {fmt_num(keep)}{" rpm" if kind == "speed" else ""}'
                f' ({inbox.rejected[kind]} {kind} setpoints rejected so far)')

    def _on_reset(self, _request, response):
        response.success = True
        response.message = self.runtime.reset()
        return response

    def _on_clear_faults(self, _request, response):
        from dmf_sim.live.faults import FAULT_PARAMETERS
        response.message = self.runtime.clear_faults()
        held = [n for n in FAULT_PARAMETERS if self.get_parameter(n).value]
        if held:        # the parameters show what is active: none now
            self.set_parameters([Parameter(n, Parameter.Type.STRING, '') for n in held])
        response.success = True
        return response

    def _on_record(self, request, response):
        self._answers = []
        result = self.set_parameters([Parameter('record', Parameter.Type.BOOL,
                                                bool(request.data))])[0]
        response.success = bool(result.successful)
        rec = self.runtime.recording
        if not result.successful:
            response.message = result.reason
        elif self._answers:
            response.message = '; '.join(self._answers)
        else:
            response.message = f'recording to {rec.path}' if rec.active else 'not recording'
        return response

    # ---- parameters: pre-set (coerce), on-set (validate), post-set (apply) --------------
    def _coerce_parameters(self, params):
        return [Parameter(p.name, value=coerce(p.name, p.value)) for p in params]

    def _check_parameters(self, params):
        new = {p.name: p.value for p in params}
        reason = (self.profile.check(new['profile']) if 'profile' in new else None
                  ) or self.runtime.check(new)
        if reason:
            self.runtime.discard_pending()
            self.get_logger().warning(f'parameter change refused: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params) -> None:
        with self.runtime.lock:
            self._answers = self.runtime.apply({p.name: p.value for p in params})
            self._answers += [self.profile.apply(p.value) for p in params if p.name == 'profile']
            self._update_clock_publisher()

    # ---- spinning -----------------------------------------------------------------------
    def spin(self, executor, should_stop) -> None:
        """Tick in this (main) thread until ``should_stop()``; ROS callbacks run in an executor
        thread that sleeps in rcl_wait until something arrives."""
        worker = threading.Thread(target=self._serve, args=(executor,), daemon=True,
                                  name='ros-callbacks')
        self.runtime.health.start(time.perf_counter())
        worker.start()
        try:
            self.runtime.loop.run(should_stop, self.runtime.lock, self._publish_diagnostics)
        finally:
            executor.shutdown(timeout_sec=2.0)
            worker.join(timeout=2.0)

    @staticmethod
    def _serve(executor) -> None:
        from rclpy.executors import ExternalShutdownException
        try:
            executor.spin()
        except ExternalShutdownException:
            pass


def usage() -> str:
    """``driveline_node --help``: how to start it, its topics, services and parameters (from
    their tables: :mod:`dmf_sim.live.streams`, :mod:`dmf_sim.live.parameters`), how to stop it."""
    def qos(depth: int, latched: bool = False) -> str:
        return ('latched, ' if latched else '') + (f'depth {depth}' if depth else 'keep all')

    rows = [('pub', st.topic, st.msgtype, qos(st.depth, st.latched),
             f'{st.what}; {PUBLISHED.get(st.per, st.per)}')
            for st in (*STREAMS.values(), *SENSOR_STREAMS.values(), DETECTIONS, CLOCK)]
    rows += [('sub', su.topic, su.msgtype, qos(su.depth), su.what)
             for su in SUBSCRIPTIONS.values()]
    width = max(len(r[1]) for r in rows)
    type_width = max(len(r[2]) for r in rows)
    topics = [f'  {kind}  {topic:{width}s}  {msgtype:{type_width}s}  {q}' + '\n' + textwrap.fill(
        what, 99, initial_indent=' ' * 9, subsequent_indent=' ' * 9)
        for kind, topic, msgtype, q, what in rows]
    services = [f'  {sv.name:15s} {sv.srvtype:22s} {sv.what}' for sv in SERVICES.values()]
    parameters = textwrap.fill(', '.join([*PARAMETERS, *DMF_PARAMETERS]), 99,
                               initial_indent='  ', subsequent_indent='  ')
    return '\n'.join([
        'driveline_node: the live driveline as a ROS 2 node.', '',
        *(f'    {line}' for line in INVOCATIONS), '',
        'Topics (relative names resolve under the node\'s namespace; all reliable):', *topics,
        '', 'Services:', *services, '',
        'Parameters (ros2 param describe /driveline_node NAME; config/driveline_node.yaml):',
        parameters, '', textwrap.fill(STOPPING, 99)])


def main(argv: list[str] | None = None) -> int:
    """Console script ``driveline_node``. Returns the process exit code."""
    args = list(sys.argv if argv is None else argv)
    ros_args = args.index('--ros-args') if '--ros-args' in args else len(args)
    if {'-h', '--help'} & set(args[1:ros_args]):
        print(usage())
        return 0
    if ROS_IMPORT_ERROR is not None:
        print(f'driveline_node: error: ROS 2 Python packages missing '
              f'({one_line(ROS_IMPORT_ERROR)}); source a Jazzy installation or pip install '
              '"dmf_sim[ros]"', file=sys.stderr)
        return EXIT_CONFIG_ERROR
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.signals import SignalHandlerOptions

    node = None

    def log_ignored(line: str) -> None:
        logger = node.get_logger() if node is not None else rclpy.logging.get_logger(
            'driveline_node')
        logger.warning(line)

    # The first SIGINT/SIGTERM, or the end of the launch parent (SIGTERM from Linux), stops the
    # node; later ones are logged and ignored, so nothing interrupts closing the bag.
    signals = StopSignals(log_ignored).install()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # noqa: BLE001 - RCLError: bad --ros-args / params file
        print(f'driveline_node: error: {one_line(exc)}', file=sys.stderr)
        return EXIT_CONFIG_ERROR
    try:
        try:
            node = DrivelineNode()
        except StartupFailed:
            return EXIT_CONFIG_ERROR
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        node.spin(executor, signals.requested.is_set)
        return 0
    finally:
        if node is not None:
            _shut_down(node, signals)
            node.destroy_node()
        rclpy.try_shutdown()
        signals.ignore_until_exit()


def _shut_down(node: DrivelineNode, signals: StopSignals) -> None:
    """Close the runtime (bag first, then monitor and Foxglove) and say why and where the bag
    is. Signals that arrive meanwhile are logged and ignored (:class:`StopSignals`)."""
    log = node.get_logger()
    log.info(f'stopping ({signals.reason})')
    rt = node.runtime
    rec = rt.recording
    if rec.active:
        signals.doing = f'closing the bag {rec.path.absolute()}'
    node.publish_held_sensors()
    closed = rt.close_recording()       # logs 'stopped recording: bag X closed, N messages'
    if closed == 'not recording':
        log.info('stopped; no bag was open' + (f' (last bag: {rec.path.absolute()})'
                                               if rec.path is not None else
                                               ' (record with -p record:=true)'))
    signals.doing = 'stopping (the bag is closed)' if rec.path is not None else 'stopping'
    rt.close_services()


if __name__ == '__main__':
    sys.exit(main())
