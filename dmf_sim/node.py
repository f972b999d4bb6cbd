"""``driveline_node``: the live driveline as a ROS 2 node (thin rclpy shell over dmf_sim.live).

    ros2 run dmf_sim driveline_node [--ros-args --params-file config/driveline_node.yaml -p k:=v]
    python -m dmf_sim.node [--ros-args ...]

Topics (relative names; without a namespace they resolve as listed), all QoS reliable /
volatile / keep-last:

    sub  engine/speed_setpoint   std_msgs/Float64      engine speed setpoint [rpm]    depth 10
    sub  engine/load_setpoint    std_msgs/Float64      load setpoint [0..1]           depth 10
    pub  driveline/joint_states  sensor_msgs/JointState every element: position = vibratory
                                 angle [rad], velocity [rad/s], effort = transmitted torque [Nm]
                                                                                     depth 10
    pub  driveline/dmf_windup    std_msgs/Float64      DMF wind-up [rad]              depth 10
    pub  engine/speed            std_msgs/Float64      engine speed (ramped) [rpm]    depth 10
    pub  engine/crank_angle      std_msgs/Float64      crank angle [rad], continuous  depth 10
    pub  /diagnostics            diagnostic_msgs/DiagnosticArray  health             depth 10
    pub  /clock                  rosgraph_msgs/Clock   simulated time (fast pacing,
                                 real_time_factor != 1, or publish_clock)              depth 1

Services: ``~/reset`` (std_srvs/Trigger): static equilibrium at the current setpoints;
``~/record`` (std_srvs/SetBool): start/stop recording (same as setting parameter ``record``).

Stamps (JointState header, bag log times, /clock) are ``start wall time + simulated time``
(+ any time skipped ahead after an overrun): at real_time_factor 1 they track the wall clock
(minus the reported lag). Pacing and overruns: see :mod:`dmf_sim.live`. Parameters:
:data:`PARAMETERS` and ``config/driveline_node.yaml``.
"""
from __future__ import annotations

import array
import math
import shutil
import signal
import sys
import time
from pathlib import Path

# Parameter table: name -> (default, description, (lo, hi) range or None, read-only).
# alpha and theta get their defaults from the driveline YAML (declared after loading it).
PARAMETERS: dict[str, tuple] = {
    'driveline': ('truck_dmf', 'Driveline YAML: a name in config/ or a path', None, True),
    'engine': ('engine_d13', 'Engine excitation: engine YAML or coefficient table (name or path)',
               None, True),
    'load_set': ('A', "Engine load set: 'A', 'B' or 'C' (B/C shift the low-speed pressure data)",
                 None, False),
    'dt': (1e-4, 'Newmark time step [s]', (1e-6, 1e-2), True),
    'initial_speed_rpm': (1000.0, 'Engine speed at start [rpm]', (100.0, 5000.0), True),
    'initial_load': (0.5, 'Load fraction at start [0..1]', (0.0, 1.0), True),
    'speed_min_rpm': (500.0, 'Lowest accepted speed setpoint [rpm] (within the engine data)',
                      (100.0, 5000.0), False),
    'speed_max_rpm': (2200.0, 'Highest accepted speed setpoint [rpm] (within the engine data)',
                      (100.0, 5000.0), False),
    'speed_ramp_rpm_per_s': (500.0, 'Speed setpoint ramp rate [rpm/s]', (1.0, 1e5), False),
    'load_ramp_per_s': (1.0, 'Load setpoint ramp rate [1/s] (1.0 = 0 to full load in 1 s)',
                        (1e-3, 1e3), False),
    'real_time_factor': (1.0, 'Simulated seconds per wall second; 0 = as fast as possible',
                         (0.0, 100.0), False),
    'pacing': ('realtime', "'realtime' (locked to the wall clock x real_time_factor) or 'fast'",
               None, False),
    'publish_rate': (1000.0, 'Samples per simulated second on every stream [Hz] '
                     '(decimation round(1/(rate*dt)) steps)', (0.1, 1e6), False),
    'max_lag': (0.05, 'Lag (wall minus simulated time) [s] above which an overrun is counted',
                (1e-3, 60.0), False),
    'overrun_policy': ('skip', "On an overrun: 'skip' (skip ahead: drop the backlog, stamps jump "
                       "to the wall clock, the physics continues) or 'catch_up' (integrate the "
                       "backlog, at most max_lag of it per tick)", None, False),
    'publish_clock': (False, 'Publish /clock also at real_time_factor 1 (always in fast mode or '
                      'at another factor)', None, False),
    'diagnostics_rate': (1.0, '/diagnostics rate [Hz of wall time]', (0.1, 100.0), False),
    'record': (False, 'Record the published streams to an MCAP bag (rosbag2 layout)', None, False),
    'bag_path': ('', "Bag directory to create; '' = dmf_bag_<YYYYmmdd_HHMMSS> in the working "
                 'directory. An existing path is never overwritten', None, False),
}
DMF_PARAMETERS = {
    'alpha': ('DMF secondary stiffness factor: secondary stiffness k(1+alpha) (default: '
              'driveline YAML)', (0.0, 50.0)),
    'theta': ('DMF stiffness change angle [rad] (default: driveline YAML)', (0.0, 2.0)),
}
RUNTIME_REBUILD = ('alpha', 'theta', 'load_set')
STREAMS = {  # key -> (default topic, ROS type)
    'joint_states': ('driveline/joint_states', 'sensor_msgs/msg/JointState'),
    'dmf_windup': ('driveline/dmf_windup', 'std_msgs/msg/Float64'),
    'speed': ('engine/speed', 'std_msgs/msg/Float64'),
    'crank_angle': ('engine/crank_angle', 'std_msgs/msg/Float64'),
    'diagnostics': ('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray'),
}
WARN_THROTTLE_S = 1.0
FAST_BUDGET_S = 0.01       # wall time per tick in fast mode ...
FAST_PAUSE_S = 1e-4        # ... then a short pause so callbacks get the lock
EXIT_CONFIG_ERROR = 2


class StartupError(Exception):
    """A bad configuration: reported as one line, exit code 2."""


def _one_line(exc: BaseException) -> str:
    return ' '.join(str(exc).split()) or type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    """Console script ``driveline_node``. Returns the process exit code."""
    argv = list(sys.argv if argv is None else argv)
    stop = {'flag': False}

    def on_signal(signum, _frame):
        stop['flag'] = True
        # a second SIGINT/SIGTERM falls through to the default action
        signal.signal(signum, signal.SIG_DFL)

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)

    try:
        import rclpy
        from rclpy.exceptions import ParameterException
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions
        node_class = _node_class()
    except ImportError as exc:
        print(f'driveline_node: error: ROS 2 Python packages missing ({_one_line(exc)}); source '
              'a Jazzy installation or pip install "dmf_sim[ros]"', file=sys.stderr)
        return EXIT_CONFIG_ERROR

    try:
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:  # noqa: BLE001 - RCLError: bad --ros-args / params file
        print(f'driveline_node: error: {_one_line(exc)}', file=sys.stderr)
        return EXIT_CONFIG_ERROR
    node = None
    try:
        try:
            node = node_class()
        except (StartupError, ParameterException, ValueError, OSError) as exc:
            rclpy.logging.get_logger('driveline_node').error(f'start-up failed: {_one_line(exc)}')
            return EXIT_CONFIG_ERROR
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        node.spin(executor, lambda: stop['flag'])
        return 0
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()


_NODE_CLASS = None


def _node_class():
    """The rclpy node class, defined on first use: importing dmf_sim.node (e.g. for
    :data:`PARAMETERS`) needs no ROS installation."""
    global _NODE_CLASS
    if _NODE_CLASS is None:
        _NODE_CLASS = _define_node_class()
    return _NODE_CLASS


def _define_node_class():
    from builtin_interfaces.msg import Time
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import (FloatingPointRange, ParameterDescriptor, ParameterType,
                                    SetParametersResult)
    from rclpy.exceptions import ParameterException
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64
    from std_srvs.srv import SetBool, Trigger

    from dmf_sim.live import (OVERRUN_POLICIES, PACING_MODES, LagStats, LiveSimulation, Pacer,
                              publish_stride)

    stream_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                            reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.VOLATILE)
    clock_qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                           reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.VOLATILE)
    ptypes = {bool: ParameterType.PARAMETER_BOOL, float: ParameterType.PARAMETER_DOUBLE,
              str: ParameterType.PARAMETER_STRING}

    def descriptor(name, default, text, rng, read_only):
        d = ParameterDescriptor(name=name, type=ptypes[type(default)], description=text,
                                read_only=read_only)
        if rng is not None:
            d.floating_point_range = [FloatingPointRange(from_value=float(rng[0]),
                                                         to_value=float(rng[1]), step=0.0)]
        return d

    class DrivelineNode(Node):
        """rclpy shell: parameters, topics, services, pacing loop, recording."""

        def __init__(self, node_name: str = 'driveline_node') -> None:
            super().__init__(node_name)
            log = self.get_logger()
            for name, (default, text, rng, ro) in PARAMETERS.items():
                self._declare(name, default, descriptor(name, default, text, rng, ro))
            p = {name: self.get_parameter(name).value for name in PARAMETERS}

            from dmf_sim.engine import load_engine
            from dmf_sim.model import load_driveline
            try:
                line = load_driveline(p['driveline'])
            except (ValueError, FileNotFoundError) as exc:
                raise StartupError(f"parameter 'driveline' = {p['driveline']!r}: "
                                   f'{_one_line(exc)}') from None
            self._has_dmf = line.dmf is not None
            dmf_defaults = ((line.dmf.alpha, line.dmf.theta) if self._has_dmf else (0.0, 0.0))
            for (name, (text, rng)), default in zip(DMF_PARAMETERS.items(), dmf_defaults):
                if not self._has_dmf:
                    text += '; this driveline has no DMF: not used'
                self._declare(name, float(default), descriptor(name, float(default), text, rng,
                                                               False))
            alpha, theta = self.get_parameter('alpha').value, self.get_parameter('theta').value
            try:
                if self._has_dmf:
                    line = line.with_dmf(alpha=alpha, theta=theta)
                elif (alpha, theta) != (0.0, 0.0):
                    raise ValueError(f'driveline {line.name!r} has no dmf section; '
                                     'alpha/theta do not apply')
            except ValueError as exc:
                raise StartupError(f'alpha/theta: {_one_line(exc)}') from None
            try:
                engine = load_engine(p['engine'], load_set=p['load_set'])
            except (ValueError, FileNotFoundError) as exc:
                raise StartupError(f"parameter 'engine' = {p['engine']!r} / 'load_set' = "
                                   f"{p['load_set']!r}: {_one_line(exc)}") from None
            for name, allowed in (('pacing', PACING_MODES), ('overrun_policy', OVERRUN_POLICIES)):
                if p[name] not in allowed:
                    raise StartupError(f'parameter {name!r} must be one of {allowed}, got '
                                       f'{p[name]!r}')
            try:
                stride = publish_stride(p['publish_rate'], p['dt'])
                self.sim = LiveSimulation(
                    line, engine, dt=p['dt'], speed_rpm=p['initial_speed_rpm'],
                    load=p['initial_load'], speed_ramp_rpm_per_s=p['speed_ramp_rpm_per_s'],
                    load_ramp_per_s=p['load_ramp_per_s'],
                    speed_limits_rpm=(p['speed_min_rpm'], p['speed_max_rpm']), stride=stride)
            except ValueError as exc:
                raise StartupError(_one_line(exc)) from None
            self.pacer = Pacer(p['dt'], self._rtf(p['real_time_factor'], p['pacing']),
                               p['max_lag'], p['overrun_policy'])
            self._publish_clock_param = p['publish_clock']
            self._diag_period = 1.0 / p['diagnostics_rate']
            self._driveline_name, self._engine_name = str(p['driveline']), str(p['engine'])

            # ---- topics and services ----------------------------------------------------
            types = {'sensor_msgs/msg/JointState': JointState, 'std_msgs/msg/Float64': Float64,
                     'diagnostic_msgs/msg/DiagnosticArray': DiagnosticArray}
            self._pubs = {k: self.create_publisher(types[t], topic, stream_qos)
                          for k, (topic, t) in STREAMS.items()}
            self._topics = {k: pub.topic_name for k, pub in self._pubs.items()}
            self._clock_pub = self.create_publisher(Clock, '/clock', clock_qos)
            self.create_subscription(Float64, 'engine/speed_setpoint', self._on_speed, stream_qos)
            self.create_subscription(Float64, 'engine/load_setpoint', self._on_load, stream_qos)
            self.create_service(Trigger, '~/reset', self._on_reset)
            self.create_service(SetBool, '~/record', self._on_record)

            # ---- reusable messages and state --------------------------------------------
            import threading
            self._lock = threading.RLock()
            self._js = JointState()
            self._js.name = self.sim.names
            self._f64 = Float64()
            self._clock_msg = Clock()
            self.lag = LagStats()
            self._recorder = None
            self._bag_path: Path | None = None
            self._record_error = ''
            self.rejected = 0
            self._last_lag = 0.0
            self._wake_late_max = self._tick_max = 0.0    # [s], per diagnostics window
            self._win = None
            self._epoch_ns = 0
            self._next_tick = self._next_diag = 0.0
            self.add_on_set_parameters_callback(self._on_set_parameters)
            if p['record']:
                recorder, reason = self._open_recorder(p['bag_path'])
                if reason:
                    raise StartupError(f'record: {reason}')
                self._install_recorder(recorder)
            else:
                # load the message type store now: the first recording then starts in ~10 ms
                from rosbags.typesys import Stores, get_typestore
                get_typestore(Stores.ROS2_JAZZY)
            log.info(f'{line.name} ({len(self.sim.names)} elements, DMF '
                     f'{"alpha=%g theta=%g rad" % (alpha, theta) if self._has_dmf else "none"}), '
                     f'engine {engine!r}; dt={p["dt"]:g} s, publishing '
                     f'{self._effective_rate():g} Hz, pacing '
                     f'{"fast" if self.pacer.fast else "real time x%g" % self.pacer.rtf}'
                     + (f', recording to {self._bag_path}' if self._recorder else ''))

        # ---- helpers --------------------------------------------------------------------
        def _declare(self, name, default, desc):
            try:
                self.declare_parameter(name, default, desc)
            except ParameterException as exc:
                hint = (' (write floating-point values with a decimal point, e.g. 200.0)'
                        if isinstance(default, float) and "'INTEGER'" in str(exc) else '')
                raise StartupError(f'parameter {name!r}: {_one_line(exc)}{hint}') from None

        @staticmethod
        def _rtf(rtf: float, pacing: str) -> float:
            return 0.0 if pacing == 'fast' else float(rtf)

        def _effective_rate(self) -> float:
            return 1.0 / (self.sim.stride * self.sim.dt)

        def _clock_on(self) -> bool:
            return self._publish_clock_param or self.pacer.fast or self.pacer.rtf != 1.0

        def _stamp(self, ns: int):
            return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)

        def _sim_ns(self, t: float) -> int:
            """Stamp [ns] of simulated time t: start wall time + t + time skipped ahead."""
            return self._epoch_ns + int(round(t * 1e9))

        # ---- main loop ------------------------------------------------------------------
        def spin(self, executor, should_stop) -> None:
            """Tick the simulation in this (main) thread until ``should_stop()``; ROS callbacks
            (setpoints, services, parameters) run in an executor thread that sleeps in rcl_wait
            until something arrives. One re-entrant lock serializes them with the ticks."""
            import gc
            import threading

            sys.setswitchinterval(1e-3)   # the tick thread waits at most ~1 ms for the GIL

            worker = threading.Thread(target=self._serve, args=(executor,), daemon=True,
                                      name='ros-callbacks')
            # Everything allocated so far (numba, rclpy, the model) lives until exit: move it
            # out of the collector's reach so full collections do not stall the ticks.
            gc.collect()
            gc.freeze()
            with self._lock:
                now = time.perf_counter()
                self._epoch_ns = time.time_ns() - int(round(self.sim.t * 1e9))
                self.pacer.anchor(now, self.sim.steps)
                self._next_tick = now
                self._next_diag = now + self._diag_period
                self._win = (now, self.sim.t, time.process_time(), self.sim.steps_secondary,
                             self.sim.steps, self.pacer.overruns, self.rejected,
                             self.sim.solver_resets)
            worker.start()
            try:
                while not should_stop():
                    now = time.perf_counter()
                    if now >= self._next_tick:
                        late = now - self._next_tick
                        with self._lock:
                            self._tick(now)
                        busy = time.perf_counter() - now
                        self._wake_late_max = max(self._wake_late_max, late)
                        self._tick_max = max(self._tick_max, busy)
                    if now >= self._next_diag:
                        with self._lock:
                            self._publish_diagnostics(now)
                        self._next_diag = max(self._next_diag + self._diag_period, now)
                    wait = min(self._next_tick, self._next_diag) - time.perf_counter()
                    if self.pacer.fast:
                        wait = FAST_PAUSE_S  # let the callback thread take the lock
                    if wait > 0:
                        time.sleep(wait)
            finally:
                executor.shutdown(timeout_sec=2.0)
                worker.join(timeout=2.0)

        def _serve(self, executor) -> None:
            from rclpy.executors import ExternalShutdownException
            try:
                executor.spin()
            except ExternalShutdownException:
                pass

        def _tick(self, now: float) -> None:
            sim, pacer = self.sim, self.pacer
            if pacer.fast:
                chunk = sim.stride * max(1, math.ceil(1e-3 / (sim.dt * sim.stride)))
                end = now + FAST_BUDGET_S
                while True:
                    self._publish_samples(sim.advance(chunk))
                    self._publish_clock()
                    if time.perf_counter() >= end:
                        break
                self._next_tick = time.perf_counter()
                return
            plan = pacer.plan(now, sim.steps)
            self._last_lag = plan.lag
            if plan.skipped:
                # skip ahead: published time jumps to the wall clock; the physics (state, crank
                # angle) continues from where it was, as if paused for the skipped interval
                self._epoch_ns += int(round(plan.skipped * pacer.rtf * 1e9))
            if plan.overrun:
                self.get_logger().warning(
                    f'overrun: {plan.lag * 1e3:.1f} ms behind the wall clock (max_lag '
                    f'{pacer.max_lag * 1e3:g} ms); policy {pacer.policy}: '
                    + (f'skipped ahead {plan.skipped * 1e3:.1f} ms' if pacer.policy == 'skip'
                       else 'catching up') + f'; {pacer.overruns} overruns so far',
                    throttle_duration_sec=WARN_THROTTLE_S)
            samples = sim.advance(plan.nsteps)
            rows = len(samples)
            if rows == 1:
                self._publish_samples(samples)
                self.lag.add(time.perf_counter() - pacer.due_wall_scalar(int(samples.step[0])))
            elif rows:
                self._publish_samples(samples)
                self.lag.add(time.perf_counter() - pacer.due_wall(samples.step))
            if self._clock_on():
                self._publish_clock()
            self._next_tick = pacer.next_tick(time.perf_counter(), sim.next_sample_step)

        def _emit(self, key: str, msg, ns: int) -> None:
            data = serialize_message(msg)       # serialized once: published and recorded
            self._pubs[key].publish(data)
            if self._recorder is not None:
                try:
                    self._recorder.write(self._topics[key], ns, data)
                except (OSError, ValueError) as exc:
                    self._recording_failed(exc)

        def _publish_samples(self, s) -> None:
            js, f = self._js, self._f64
            stamp = js.header.stamp
            for i in range(len(s)):
                ns = self._sim_ns(float(s.t[i]))
                stamp.sec, stamp.nanosec = divmod(ns, 1_000_000_000)
                js.position = array.array('d', s.position[i].tobytes())
                js.velocity = array.array('d', s.velocity[i].tobytes())
                js.effort = array.array('d', s.effort[i].tobytes())
                self._emit('joint_states', js, ns)
                f.data = float(s.windup[i])
                self._emit('dmf_windup', f, ns)
                f.data = float(s.speed_rpm[i])
                self._emit('speed', f, ns)
                f.data = float(s.psi[i])
                self._emit('crank_angle', f, ns)

        def _publish_clock(self) -> None:
            self._clock_msg.clock = self._stamp(self._sim_ns(self.sim.t))
            self._clock_pub.publish(self._clock_msg)

        # ---- diagnostics ----------------------------------------------------------------
        def _publish_diagnostics(self, now: float) -> None:
            sim, pacer = self.sim, self.pacer
            (w0, t0, c0, sec0, steps0, ovr0, rej0, res0) = self._win
            wall = max(now - w0, 1e-9)
            rtf = (sim.t - t0) / wall
            cpu = 100.0 * (time.process_time() - c0) / wall
            nsteps = sim.steps - steps0
            sec_frac = (sim.steps_secondary - sec0) / nsteps if nsteps else 0.0
            lw = self.lag.take_window()
            tick_max, late_max = self._tick_max, self._wake_late_max
            self._tick_max = self._wake_late_max = 0.0
            new_overruns = pacer.overruns - ovr0
            new_rejected = self.rejected - rej0
            new_resets = sim.solver_resets - res0
            finite = sim.finite
            self._win = (now, sim.t, time.process_time(), sim.steps_secondary, sim.steps,
                         pacer.overruns, self.rejected, sim.solver_resets)
            ms = (lambda x: 'nan' if not math.isfinite(x) else f'{x * 1e3:.3f}')
            problems = []
            level = DiagnosticStatus.OK
            if not finite or new_resets:
                level = DiagnosticStatus.ERROR
                problems.append(f'solver restarted {new_resets}x (non-finite state)')
            if new_overruns:
                problems.append(f'{new_overruns} overrun(s)')
            if not pacer.fast and lw['n'] and lw['max'] > pacer.max_lag:
                problems.append(f'lag up to {lw["max"] * 1e3:.1f} ms')
            if new_rejected:
                problems.append(f'{new_rejected} setpoint(s) rejected')
            if self._record_error:
                problems.append(f'recording failed: {self._record_error}')
            if problems and level == DiagnosticStatus.OK:
                level = DiagnosticStatus.WARN
            mode = 'fast' if pacer.fast else 'realtime'
            values = {
                'pacing': mode,
                'real_time_factor_target': f'{pacer.rtf:g}' if not pacer.fast else 'max',
                'real_time_factor': f'{rtf:.4f}',
                'sim_time_s': f'{sim.t:.4f}',
                'lag_ms': ms(self._last_lag) if not pacer.fast else 'nan',
                'lag_p50_ms': ms(lw['p50']), 'lag_p99_ms': ms(lw['p99']),
                'lag_max_ms': ms(lw['max']), 'lag_samples': str(lw['n']),
                'lag_p99_ms_total': ms(self.lag.total_percentile(99.0)),
                'lag_max_ms_total': ms(self.lag.max if self.lag.count else float('nan')),
                'max_lag_ms': f'{pacer.max_lag * 1e3:g}',
                'overruns': str(pacer.overruns), 'overrun_policy': pacer.policy,
                'skipped_s': f'{pacer.skipped:.4f}',
                'wall_minus_stamp_s': f'{(time.time_ns() - self._sim_ns(sim.t)) / 1e9:.4f}',
                'cpu_pct': f'{cpu:.1f}',
                'tick_wake_late_max_ms': ms(late_max),
                'tick_busy_max_ms': ms(tick_max),
                'steps': str(sim.steps), 'dt_s': f'{sim.dt:g}',
                'publish_rate_hz': f'{self._effective_rate():g}',
                'speed_rpm': f'{sim.speed:.3f}', 'speed_setpoint_rpm': f'{sim.speed_setpoint:g}',
                'load': f'{sim.load:.4f}', 'load_setpoint': f'{sim.load_setpoint:g}',
                'windup_rad': f'{sim.windup:.6f}', 'dmf_region': sim.region,
                'dmf_secondary_fraction': f'{sec_frac:.4f}',
                'knee_crossings': str(sim.knee_crossings),
                'state_finite': str(finite).lower(), 'solver_resets': str(sim.solver_resets),
                'rejected_setpoints': str(self.rejected),
                'alpha': f'{self.get_parameter("alpha").value:g}',
                'theta_rad': f'{self.get_parameter("theta").value:g}',
                'load_set': str(getattr(sim.engine, 'load_set', '')),
                'recording': str(self._recorder is not None).lower(),
                'bag_path': str(self._bag_path or ''),
                'bag_messages': str(self._recorder.message_count if self._recorder else 0),
            }
            msg = DiagnosticArray()
            ns = self._sim_ns(sim.t)
            msg.header.stamp = self._stamp(ns)
            status = DiagnosticStatus(
                level=level, name=f'{self.get_name()}: driveline simulation', hardware_id='dmf_sim',
                message='; '.join(problems) if problems else
                f'{mode} x{rtf:.3f}, {sim.speed:.0f} rpm, load {sim.load:.2f}, DMF {sim.region}')
            status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
            msg.status = [status]
            self._emit('diagnostics', msg, ns)
            if self._recorder is not None:
                try:
                    self._recorder.flush()
                except OSError as exc:
                    self._recording_failed(exc)

        # ---- setpoints and services -----------------------------------------------------
        def _on_speed(self, msg) -> None:
            with self._lock:
                reason = self.sim.set_speed_setpoint(msg.data)
            if reason:
                self._reject(f'{reason}; keeping {self.sim.speed_setpoint:g} rpm')

        def _on_load(self, msg) -> None:
            with self._lock:
                reason = self.sim.set_load_setpoint(msg.data)
            if reason:
                self._reject(f'{reason}; keeping {self.sim.load_setpoint:g}')

        def _reject(self, text: str) -> None:
            self.rejected += 1
            self.get_logger().warning(f'rejected {text} ({self.rejected} rejected so far)',
                                      throttle_duration_sec=WARN_THROTTLE_S)

        def _on_reset(self, _request, response):
            with self._lock:
                self.sim.reset()
            response.success = True
            response.message = (f'reset to static equilibrium at {self.sim.speed_setpoint:g} rpm, '
                                f'load {self.sim.load_setpoint:g} (t = {self.sim.t:.4f} s)')
            self.get_logger().info(response.message)
            return response

        def _on_record(self, request, response):
            result = self.set_parameters([Parameter('record', Parameter.Type.BOOL,
                                                    bool(request.data))])[0]
            response.success = bool(result.successful)
            if not result.successful:
                response.message = result.reason
            elif self._recorder is not None:
                response.message = f'recording to {self._bag_path}'
            else:
                response.message = 'not recording'
            return response

        # ---- recording ------------------------------------------------------------------
        def _bag_target(self, bag_path: str) -> Path:
            if bag_path:
                return Path(bag_path)
            base = f'dmf_bag_{time.strftime("%Y%m%d_%H%M%S")}'
            path, i = Path(base), 1
            while path.exists():
                path, i = Path(f'{base}_{i}'), i + 1
            return path

        def _check_bag_path(self, bag_path: str) -> str | None:
            if bag_path and (Path(bag_path).exists() or Path(bag_path).is_symlink()):
                return (f'bag path {bag_path} exists already; not overwriting it '
                        '(set another bag_path)')
            return None

        def _open_recorder(self, bag_path: str):
            """Create the bag (slow: call without the lock). Returns (recorder, reason)."""
            if reason := self._check_bag_path(bag_path):
                return None, reason
            from dmf_sim.bag import BagRecorder
            from dmf_sim.run_metadata import RunMetadata
            path = self._bag_target(bag_path)
            sim = self.sim
            spring = sim.model.spring
            custom = RunMetadata(
                driveline=self._driveline_name, engine=self._engine_name,
                load_set=str(getattr(sim.engine, 'load_set', '')),
                alpha=spring.alpha if spring else None, theta_rad=spring.theta if spring else None,
                spring=spring.as_dict() if spring else None,
                load=sim.load, speed_rpm=sim.speed,        # at the start of the recording
                dt_s=sim.dt, publish_rate_hz=self._effective_rate(),
                node=self.get_fully_qualified_name()).to_custom_data()
            try:
                return BagRecorder(path, {self._topics[k]: t for k, (_, t) in STREAMS.items()},
                                   custom_data=custom), None
            except (OSError, ValueError) as exc:
                return None, _one_line(exc)

        def _install_recorder(self, recorder) -> None:
            self._recorder = recorder
            self._bag_path = recorder.path
            self._record_error = ''
            self.get_logger().info(f'recording to {recorder.path}')

        @staticmethod
        def _discard_recorder(recorder) -> None:
            """Remove a bag created for a parameter change that was refused after all."""
            recorder.close()
            shutil.rmtree(recorder.path, ignore_errors=True)

        def _stop_recording(self) -> None:
            rec, self._recorder = self._recorder, None
            if rec is not None:
                try:
                    rec.close()
                    self.get_logger().info(f'bag {rec.path} closed: {rec.message_count} messages')
                except OSError as exc:
                    self.get_logger().error(f'closing bag {rec.path} failed: {_one_line(exc)}')

        def _recording_failed(self, exc: BaseException) -> None:
            self._record_error = _one_line(exc)
            self.get_logger().error(f'recording stopped: {self._record_error}')
            rec, self._recorder = self._recorder, None
            try:
                rec.close()
            except Exception:  # noqa: BLE001 - the bag stays readable up to its last chunk
                pass

        def close(self) -> None:
            """Close the bag (on shutdown: SIGINT/SIGTERM)."""
            with self._lock:
                self._stop_recording()

        # ---- runtime parameter changes --------------------------------------------------
        def _on_set_parameters(self, params):
            new = {p.name: p.value for p in params}
            with self._lock:
                reason = self._validate(new)
            recorder = None
            if reason is None and new.get('record') and self._recorder is None:
                # creating the bag takes ~10 ms: not while holding the lock the ticks need
                recorder, reason = self._open_recorder(
                    new.get('bag_path', self.get_parameter('bag_path').value))
            if reason is None:
                with self._lock:
                    try:
                        reason = self._apply(new, recorder)
                    except ValueError as exc:
                        reason = _one_line(exc)
            if reason:
                if recorder is not None and self._recorder is not recorder:
                    self._discard_recorder(recorder)
                self.get_logger().warning(f'parameter change refused: {reason}')
                return SetParametersResult(successful=False, reason=reason)
            return SetParametersResult(successful=True)

        def _validate(self, new: dict) -> str | None:
            """Cheap checks of a set of new values (read-only and ranges: rclpy checks)."""
            cur = lambda k: new.get(k, self.get_parameter(k).value)  # noqa: E731
            if 'pacing' in new and new['pacing'] not in PACING_MODES:
                return f'pacing must be one of {PACING_MODES}, got {new["pacing"]!r}'
            if 'overrun_policy' in new and new['overrun_policy'] not in OVERRUN_POLICIES:
                return (f'overrun_policy must be one of {OVERRUN_POLICIES}, got '
                        f'{new["overrun_policy"]!r}')
            if 'publish_rate' in new:
                try:
                    publish_stride(new['publish_rate'], self.sim.dt)
                except ValueError as exc:
                    return str(exc)
            if 'speed_min_rpm' in new or 'speed_max_rpm' in new:
                lo, hi = cur('speed_min_rpm'), cur('speed_max_rpm')
                if reason := self.sim.check_speed_limits(lo, hi):
                    return reason
                if not lo <= self.sim.speed_setpoint <= hi:
                    return (f'the current speed setpoint {self.sim.speed_setpoint:g} rpm is '
                            f'outside [{lo:g}, {hi:g}]')
            if 'theta' in new and self._has_dmf and not new['theta'] > 0:
                return f'theta must be > 0 rad, got {new["theta"]!r}'
            if ('alpha' in new or 'theta' in new) and not self._has_dmf:
                return 'this driveline has no DMF; alpha/theta do not apply'
            if 'load_set' in new:
                allowed = getattr(getattr(self.sim.engine, 'config', None),
                                  'load_set_shifts_rpm', None)
                if allowed is not None and new['load_set'] not in allowed:
                    return f'load_set must be one of {sorted(allowed)}, got {new["load_set"]!r}'
            if new.get('record') and self._recorder is None:
                if reason := self._check_bag_path(cur('bag_path')):
                    return reason
            return None

        def _apply(self, new: dict, recorder=None) -> str | None:
            sim, now = self.sim, time.perf_counter()
            if 'alpha' in new or 'theta' in new:
                sim.set_dmf(alpha=new.get('alpha'), theta=new.get('theta'))
                spring = sim.model.spring
                self.get_logger().info(f'DMF rebuilt: alpha={spring.alpha:g}, theta='
                                       f'{spring.theta:g} rad (operating point and state kept)')
            if 'load_set' in new:
                sim.set_load_set(new['load_set'])
            if 'speed_min_rpm' in new or 'speed_max_rpm' in new:
                lo = new.get('speed_min_rpm', self.get_parameter('speed_min_rpm').value)
                hi = new.get('speed_max_rpm', self.get_parameter('speed_max_rpm').value)
                if reason := sim.set_speed_limits(lo, hi):
                    return reason
            if 'speed_ramp_rpm_per_s' in new or 'load_ramp_per_s' in new:
                sim.set_ramps(new.get('speed_ramp_rpm_per_s'), new.get('load_ramp_per_s'))
            if 'publish_rate' in new:
                sim.set_stride(publish_stride(new['publish_rate'], sim.dt))
            if 'real_time_factor' in new or 'pacing' in new:
                rtf = self._rtf(new.get('real_time_factor',
                                        self.get_parameter('real_time_factor').value),
                                new.get('pacing', self.get_parameter('pacing').value))
                self.pacer.set_rate(rtf, now, sim.steps)
                self._next_tick = now
            if 'max_lag' in new:
                self.pacer.max_lag = float(new['max_lag'])
            if 'overrun_policy' in new:
                self.pacer.policy = new['overrun_policy']
            if 'publish_clock' in new:
                self._publish_clock_param = bool(new['publish_clock'])
            if 'diagnostics_rate' in new:
                self._diag_period = 1.0 / float(new['diagnostics_rate'])
                self._next_diag = min(self._next_diag, now + self._diag_period)
            if 'record' in new:
                if not new['record']:
                    self._stop_recording()
                elif recorder is not None and self._recorder is None:
                    self._install_recorder(recorder)
            return None

    return DrivelineNode


if __name__ == '__main__':
    sys.exit(main())
