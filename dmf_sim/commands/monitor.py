"""``dmf-sim monitor [--namespace /truck1]``: live terminal view of a running driveline_node.

Reads what the node publishes for people (no 1 kHz stream): ``/diagnostics`` (speed, load,
wind-up, DMF region, lag, overruns, the DMF monitor's alarms), ``<ns>/driveline/dmf_orders``
(per engine cycle: live orders, region shares, predicted state, live minus predicted, alarms) and
``<ns>/driveline/dmf_predicted`` (the predicted stable states, latched). Refreshes ``--rate``
times a second with ``rich`` (``--plain``: text frames, for logs and tests); Ctrl-C ends it.
``--once`` prints one frame as soon as the node's diagnostics arrived; ``--frames N`` stops after
N frames that show the node (however long discovery took); ``--duration S`` stops after S seconds.
"""
from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

from dmf_sim.commands._options import check_wait
from dmf_sim.commands._ros import NodeSelector, select_node
from dmf_sim.core.errors import ConfigError, NoResponseError
from dmf_sim.core.json_out import write_json
from dmf_sim.live.health import LEVEL_NAMES as LEVELS, STATUS_SUFFIX as SIM_STATUS
from dmf_sim.monitor.messages import MONITOR_NAME as MONITOR_STATUS

__all__ = ['NAME', 'HELP', 'STYLES', 'STALE_S', 'add_arguments', 'Status', 'MonitorView',
           'render_plain', 'render_rich', 'run']

NAME = 'monitor'
HELP = ('Live terminal view of a running driveline_node: speed, load, wind-up, live and '
        'predicted orders, DMF region, lag and alarms (needs rclpy)')
STYLES = {0: 'green', 1: 'yellow', 2: 'bold red', 3: 'dim'}
STALE_S = 3.0                           # diagnostics older than this [s] are shown as stale


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--namespace', default='', metavar='NS',
                        help="the node's namespace, e.g. /truck1 or truck1 (default: none); "
                             '/diagnostics statuses of nodes in other namespaces are ignored')
    parser.add_argument('--node', default='', metavar='NAME',
                        help='only /diagnostics statuses of this node: its full name '
                             '(/truck1/driveline_node, implies the namespace) or its name in '
                             '--namespace (default: any node in the namespace)')
    parser.add_argument('--rate', type=float, default=4.0, metavar='HZ',
                        help='screen refreshes per second (default 4)')
    parser.add_argument('--plain', action='store_true',
                        help='print text frames instead of the live rich view')
    end = parser.add_mutually_exclusive_group()
    end.add_argument('--once', action='store_true',
                     help='print one frame once the node answered, then exit')
    end.add_argument('--frames', type=int, metavar='N',
                     help='exit after N frames that show the node (the frames before its first '
                          'diagnostics do not count)')
    end.add_argument('--duration', type=float, metavar='S', help='exit after S seconds')
    parser.add_argument('--timeout', type=float, default=15.0, metavar='S',
                        help='with --once or --frames: seconds to wait for the node (default 15)')
    end.add_argument('--foxglove-layout', type=Path, metavar='FILE',
                     help='write the Foxglove layout for this node (--namespace/--node: its '
                          'topics, its health status selected by its full name) to the new '
                          'FILE and exit; needs no running node')


# ------------------------------------------------------------------------------------------------
# The view (no ROS): what the messages said, and the lines shown
# ------------------------------------------------------------------------------------------------

@dataclass
class Status:
    """One DiagnosticStatus as received: level, name, message, key -> value text."""

    level: int
    name: str
    message: str
    values: dict[str, str]
    hardware_id: str = ''

    @classmethod
    def from_msg(cls, st) -> 'Status':
        level = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
        return cls(level, st.name, st.message, {kv.key: kv.value for kv in st.values},
                   st.hardware_id)

    @property
    def node(self) -> str:
        """Full name of the node that published it: its hardware_id (the node's fully
        qualified name), else the name's part before ':'."""
        if self.hardware_id.startswith('/'):
            return self.hardware_id
        return self.name.split(':', 1)[0].strip()


@dataclass
class MonitorView:
    """The latest of each message and the lines to show (see :meth:`rows`)."""

    node: NodeSelector = field(default_factory=NodeSelector)
    sim: Status | None = None
    monitor: Status | None = None
    cycle: Status | None = None
    predicted: list[Status] = field(default_factory=list)
    intervals_scored: int = 0
    last_alarm: Status | None = None
    alarms_seen: int = 0
    received: dict[str, float] = field(default_factory=dict)

    def on_diagnostics(self, statuses, now: float) -> None:
        for st in statuses:
            if not self.node.matches(st.node):
                continue
            if st.name.endswith(SIM_STATUS):
                self.sim = st
                self.received['sim'] = now
            elif st.name.endswith(MONITOR_STATUS):
                self.monitor = st
                self.received['monitor'] = now

    def on_cycle(self, statuses, now: float) -> None:
        if statuses:
            self.cycle = statuses[0]
            self.received['cycle'] = now

    def on_detections(self, statuses, now: float) -> None:
        """The live misfire detector's statuses (one per scored firing interval)."""
        for st in statuses:             # the node's own topic (namespaced), as on_cycle
            self.intervals_scored += 1
            if st.values.get('alarm') == 'true':
                self.alarms_seen += 1
                self.last_alarm = st
            self.received['detections'] = now

    def on_predicted(self, statuses, now: float) -> None:
        self.predicted = list(statuses)
        self.received['predicted'] = now

    @property
    def has_data(self) -> bool:
        return self.sim is not None

    def rows(self, now: float) -> list[tuple[str, str, int]]:
        """(label, text, level) lines; level picks the colour (0 OK .. 3 stale/none)."""
        out: list[tuple[str, str, int]] = []
        if self.sim is None:
            return [('node', f'waiting for /diagnostics of {self.node.describe()} ...', 3)]
        v = self.sim.values
        age = now - self.received['sim']
        out.append(('node', f'{self.sim.name.split(":", 1)[0]}  {LEVELS.get(self.sim.level)}  '
                    f'{self.sim.message}'
                    + (f'  (diagnostics {age:.0f} s old)' if age > STALE_S else ''),
                    self.sim.level if age <= STALE_S else 3))
        out.append(('time', f'sim {_num(v, "sim_time_s", "{:.1f}")} s  real-time factor '
                    f'{_num(v, "real_time_factor", "{:.3f}")}  lag '
                    f'{_num(v, "lag_ms", "{:.2f}")} ms (p99 {_num(v, "lag_p99_ms", "{:.2f}")} ms)'
                    f'  overruns '
                    f'{v.get("overruns", "?")}', 0))
        out.append(('speed', f'{_num(v, "speed_rpm", "{:.1f}")} rpm (setpoint '
                    f'{v.get("speed_setpoint_rpm", "?")} rpm)   load {_num(v, "load", "{:.3f}")} '
                    f'(setpoint {v.get("load_setpoint", "?")})', 0))
        out.append(('wind-up', f'{_num(v, "windup_rad", "{:+.5f}")} rad   DMF region '
                    f'{v.get("dmf_region", "?")}   secondary share '
                    f'{_num(v, "dmf_secondary_fraction", "{:.0%}")}   knee crossings '
                    f'{v.get("knee_crossings", "?")}', 0))
        out += self._cycle_rows()
        out += self._prediction_rows()
        out.append(self._detector_row())
        level, text = 0, 'none'
        for st in (self.monitor, self.cycle):
            if st is not None and st.values.get('alarms'):
                level, text = st.level, st.message
                break
        if self.monitor is None and self.cycle is None:
            level, text = 3, 'no DMF monitor on this node (no driveline/dmf_orders yet)'
        out.append(('alarms', text, level))
        return out

    def _cycle_rows(self) -> list[tuple[str, str, int]]:
        if self.cycle is None:
            return [('orders', 'no engine cycle analysed yet (topic driveline/dmf_orders)', 3)]
        c = self.cycle.values
        shares = ', '.join(f'{k[6:].replace("_", " ")} {float(x):.0%}' for k, x in c.items()
                           if k.startswith('share_') and float(x) > 0)
        rows = [('cycle', f'#{_num(c, "cycle", "{:.0f}")} at {_num(c, "speed_rpm", "{:.1f}")} rpm'
                 f', load {_num(c, "load", "{:.3f}")}   regions: {shares}', 0),
                ('orders', f'3rd {_num(c, "order_3_rad", "{:.5f}")} rad   1.5th '
                 f'{_num(c, "order_1_5_rad", "{:.5f}")} rad   max/min dev '
                 f'{_num(c, "max_deviation_rad", "{:+.5f}")}/'
                 f'{_num(c, "min_deviation_rad", "{:+.5f}")} rad', self.cycle.level),
                ('mean', f'mean {_num(c, "mean_rad", "{:.5f}")} rad   mean - theta '
                 f'{_num(c, "mean_minus_theta_rad", "{:+.5f}")} rad   theta - static '
                 f'{_num(c, "theta_minus_static_rad", "{:+.5f}")} rad', 0)]
        if c.get('predicted_applies') == 'true':
            rows.append(('vs predicted', f'3rd {_num(c, "predicted_order_3_rad", "{:.5f}")} '
                         f'(live - predicted {_num(c, "order_3_minus_predicted_rad", "{:+.5f}")})'
                         f'   1.5th {_num(c, "predicted_order_1_5_rad", "{:.5f}")} (live - '
                         f'predicted {_num(c, "order_1_5_minus_predicted_rad", "{:+.5f}")}) rad',
                         0))
        return rows

    def _detector_row(self) -> tuple[str, str, int]:
        if not self.intervals_scored:
            return ('misfires', 'no firing interval scored (topic faults/detections: parameters '
                    'sensors and monitor)', 3)
        text = f'{self.intervals_scored} firing intervals scored, {self.alarms_seen} alarms'
        if self.last_alarm is None:
            return ('misfires', text, 0)
        a = self.last_alarm.values
        return ('misfires', f'{text}; last: cylinder {a.get("cylinder", "?")} at '
                f'{_num(a, "tdc_time_s", "{:.3f}")} s, crank angle '
                f'{_num(a, "tdc_crank_angle_rad", "{:.2f}")} rad, score '
                f'{_num(a, "score", "{:.2f}")}', self.last_alarm.level)

    def _prediction_rows(self) -> list[tuple[str, str, int]]:
        if not self.predicted:
            return [('predicted', 'no prediction received (topic driveline/dmf_predicted)', 3)]
        head, states = self.predicted[0], self.predicted[1:]
        rows = [('predicted', head.message, head.level)]
        for st in states:
            s = st.values
            rows.append(('', f'{s.get("kind", "")}: 3rd {_num(s, "order_3_rad", "{:.5f}")} rad, '
                         f'1.5th {_num(s, "order_1_5_rad", "{:.5f}")} rad, mean - theta '
                         f'{_num(s, "mean_minus_theta_rad", "{:+.5f}")} rad', 0))
        return rows


def _num(values: dict, key: str, fmt: str) -> str:
    """A value formatted as a number, or the raw text ('?' when missing)."""
    text = values.get(key)
    if text is None:
        return '?'
    try:
        x = float(text)
    except ValueError:
        return text
    return fmt.format(x) if math.isfinite(x) else text


def render_plain(view: MonitorView, now: float) -> str:
    width = max(len(label) for label, _, _ in view.rows(now)) + 1
    return '\n'.join(f'{label:<{width}} {text}' for label, text, _ in view.rows(now))


def render_rich(view: MonitorView, now: float, title: str):
    from rich.table import Table

    table = Table(title=title, show_header=False, expand=True, box=None, padding=(0, 1))
    table.add_column(style='bold cyan', no_wrap=True)
    table.add_column()
    for label, text, level in view.rows(now):
        table.add_row(label, text, style=STYLES.get(level, ''))
    return table


# ------------------------------------------------------------------------------------------------
# ROS
# ------------------------------------------------------------------------------------------------

def run(args: argparse.Namespace) -> int:
    from dmf_sim.commands._ros import reliable_qos, ros_session, topic
    from dmf_sim.monitor.messages import TOPIC_CYCLE, TOPIC_DETECTIONS, TOPIC_PREDICTED

    if not (math.isfinite(args.rate) and 0.1 <= args.rate <= 50):
        raise ConfigError(f'--rate must be in [0.1, 50] Hz, got {args.rate!r}')
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise ConfigError(f'--duration must be a finite number > 0 s, got {args.duration!r}')
    if args.frames is not None and args.frames < 1:
        raise ConfigError(f'--frames must be >= 1, got {args.frames!r}')
    check_wait(args.timeout)
    view = MonitorView(node=select_node(args.namespace, args.node))
    if args.foxglove_layout is not None:
        return _write_layout(args.foxglove_layout, view.node)
    with ros_session('dmf_sim_monitor', view.node.namespace) as (rclpy, node, executor):
        from diagnostic_msgs.msg import DiagnosticArray

        ns = node.get_namespace().rstrip('/')
        title = f'dmf-sim monitor  {view.node.fqn or ns or "/"}  (Ctrl-C to quit)'

        def sub(name, handler, latched=False):
            node.create_subscription(
                DiagnosticArray, name,
                lambda msg: handler([Status.from_msg(s) for s in msg.status], time.monotonic()),
                reliable_qos(latched=latched))

        sub('/diagnostics', view.on_diagnostics)
        sub(topic(ns, TOPIC_CYCLE), view.on_cycle)
        sub(topic(ns, TOPIC_PREDICTED), view.on_predicted, latched=True)
        sub(topic(ns, TOPIC_DETECTIONS), view.on_detections)
        try:
            return _loop(args, view, executor, title)
        except KeyboardInterrupt:
            return 0


def _write_layout(path: Path, node: NodeSelector) -> int:
    """``--foxglove-layout FILE``: the shipped layout for this node, never overwriting."""

    from dmf_sim.live.foxglove_bridge import DEFAULT_NODE, foxglove_layout

    fqn = node.fqn or f'{node.namespace}{DEFAULT_NODE}'
    if path.exists() or path.is_symlink():
        raise ConfigError(f'--foxglove-layout {path} exists already; not overwriting it')
    try:
        write_json(path, foxglove_layout(fqn), indent=2)
    except OSError as exc:
        raise ConfigError(f'--foxglove-layout {path}: {exc.strerror or exc}') from None
    print(f'wrote {path}: Foxglove layout for {fqn} (Layouts > Import from file)')
    return 0


def _loop(args, view: MonitorView, executor, title: str) -> int:
    period = 1.0 / args.rate
    start = time.monotonic()
    if args.once or args.frames is not None:
        _wait_for_node(args, view, executor, start)
    if args.once:
        # give the per-cycle and prediction topics a moment to arrive too
        settle = time.monotonic() + min(1.0, args.timeout)
        while time.monotonic() < settle and (view.cycle is None or not view.predicted):
            executor.spin_once(timeout_sec=0.05)
        if args.plain:
            print(render_plain(view, time.monotonic()))
        else:
            from rich.console import Console
            Console().print(render_rich(view, time.monotonic(), title))
        return 0
    stop = None if args.duration is None else start + args.duration

    def more(shown: int) -> bool:
        return ((stop is None or time.monotonic() < stop)
                and (args.frames is None or shown < args.frames))

    if args.plain:
        frame = 0
        while more(frame):
            _spin_for(executor, period)
            frame += 1
            print(f'--- frame {frame} t={time.monotonic() - start:.2f} s', flush=True)
            print(render_plain(view, time.monotonic()), flush=True)
        return 0
    from rich.console import Console
    from rich.live import Live

    console = Console()
    with Live(render_rich(view, time.monotonic(), title), console=console,
              refresh_per_second=args.rate, transient=False) as live:
        frame = 0
        while more(frame):
            _spin_for(executor, period)
            frame += 1
            live.update(render_rich(view, time.monotonic(), title))
    return 0


def _wait_for_node(args, view: MonitorView, executor, start: float) -> None:
    """Spin until the node's diagnostics arrived (``--once``, ``--frames``), at most --timeout."""
    end = start + args.timeout
    while not view.has_data:
        if time.monotonic() > end:
            raise NoResponseError(f'no /diagnostics from {view.node.describe()} within '
                                  f'{args.timeout:g} s (is driveline_node running there '
                                  'with this ROS_DOMAIN_ID?)')
        executor.spin_once(timeout_sec=0.05)


def _spin_for(executor, seconds: float) -> None:
    end = time.monotonic() + seconds
    while (left := end - time.monotonic()) > 0:
        executor.spin_once(timeout_sec=min(left, 0.05))

