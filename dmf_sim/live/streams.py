"""The node's interface as tables: published streams (topic, message type, offered QoS), the
subscriptions and the services, each with what it carries.

Relative topics resolve under the node's namespace. The table serves every place that must
agree: ``driveline_node`` creates its publishers from it; the recorder writes the same offered
QoS into the bag (``metadata.yaml`` ``offered_qos_profiles`` and the MCAP channel metadata,
:meth:`Stream.qos_profile`) and starts each recording and split with the latched messages; the
Foxglove server resends the latched ones to a client that subscribes later; ``dmf-sim run``
writes a bag with the same topics, types and QoS (the sample streams filled, the status streams
declared), so one reader serves both.

All streams are reliable. Samples keep the last :data:`STREAM_DEPTH` messages for a subscriber
that falls behind, status arrays :data:`DIAGNOSTICS_DEPTH`; the prediction is latched
(transient-local, depth 1): a subscriber that joins later gets the latest one at once. The
faults' ground truth (:mod:`dmf_sim.live.faults`) is latched too: ``faults/ground_truth`` one
message per event, the last :data:`GROUND_TRUTH_DEPTH` for a late joiner (the bag has all);
``faults/active`` the set of active faults, depth 1.

The subscriptions (:data:`SUBSCRIPTIONS`, setpoints and fault requests) are commands: reliable and
keep-all. ``/clock`` (:data:`CLOCK`) is advertised only while it is published and not recorded.
``driveline_node --help`` prints these tables (:func:`dmf_sim.node.usage`).

:data:`STREAMS` is what every node publishes. The sensors depend on the driveline
(:mod:`dmf_sim.physics.sensors`): :func:`streams_for` adds theirs — ``edges/<wheel>`` (edge
batches, ``sensors/<wheel>/edges``) and ``bus/<signal>`` (``vehicle_bus/<signal>``), layouts in
:mod:`dmf_sim.bags.sensor_messages`, and ``misfire_detections`` (``faults/detections``, the
monitor's live misfire detector, :mod:`dmf_sim.monitor.misfire`) — and every place that must
agree takes that table.
"""
from __future__ import annotations

from typing import Any, NamedTuple

from dmf_sim.bags.sensor_messages import BUS_TYPE, EDGES_TYPE, bus_topic, edge_topic
from dmf_sim.core.names import check_namespace
from dmf_sim.monitor.messages import TOPIC_CYCLE, TOPIC_DETECTIONS, TOPIC_PREDICTED

__all__ = ['DIAGNOSTICS_DEPTH', 'GROUND_TRUTH_DEPTH', 'LATCHED_DEPTH', 'SAMPLE_STREAMS',
           'STATUS_STREAMS', 'STREAMS', 'STREAM_DEPTH', 'PUBLISHED', 'CLOCK', 'Stream',
           'SENSOR_STREAMS', 'DETECTIONS', 'Subscription', 'SUBSCRIPTIONS', 'Service', 'SERVICES',
           'edge_key', 'bus_key', 'sensor_streams', 'streams_for', 'resolved_topics']

STREAM_DEPTH = 100          # 0.1 s of samples at 1 kHz for a subscriber that falls behind
DIAGNOSTICS_DEPTH = 10      # status arrays (1 Hz health, one per engine cycle)
LATCHED_DEPTH = 1           # the latest prediction, the active faults
GROUND_TRUTH_DEPTH = 100    # fault events a late joiner gets (starts, ends, misfires)


class Stream(NamedTuple):
    """One published stream: default topic (relative to the node's namespace unless it starts
    with '/'), ROS type, history depth, latched (transient-local durability), and when it is
    published: per ``'sample'`` (publish_rate), ``'diagnostics'`` (diagnostics_rate),
    ``'cycle'`` (per engine cycle), ``'setpoint'`` (when the setpoint changes), ``'fault'``
    (when a fault starts or ends, a combustion misfires), ``'edges'`` (per edge-batch period,
    when a tooth wheel has edges), ``'bus'`` (when a bus value is delivered) or ``'clock'``
    (with the samples, while /clock is on); what it carries, for people."""

    topic: str
    msgtype: str
    depth: int
    latched: bool = False
    per: str = 'sample'
    what: str = ''

    def qos_profile(self) -> dict[str, Any]:
        """The offered QoS in rosbag2's form (reliable, keep-last ``depth``)."""
        from dmf_sim.bags.writer import qos_profile
        return qos_profile(self.depth, transient_local=self.latched)


_DIAG = 'diagnostic_msgs/msg/DiagnosticArray'
_F64 = 'std_msgs/msg/Float64'
STREAMS: dict[str, Stream] = {
    'joint_states': Stream('driveline/joint_states', 'sensor_msgs/msg/JointState', STREAM_DEPTH,
                           what='every element: position = vibratory angle [rad], velocity '
                                '[rad/s], effort = transmitted torque [Nm]'),
    'dmf_windup': Stream('driveline/dmf_windup', _F64, STREAM_DEPTH, what='DMF wind-up [rad]'),
    'speed': Stream('engine/speed', _F64, STREAM_DEPTH, what='engine speed (ramped) [rpm]'),
    'crank_angle': Stream('engine/crank_angle', _F64, STREAM_DEPTH,
                          what='crank angle [rad], continuous'),
    'diagnostics': Stream('/diagnostics', _DIAG, DIAGNOSTICS_DEPTH, per='diagnostics',
                          what='health: one status per node (and the monitor)'),
    'dmf_orders': Stream(TOPIC_CYCLE, _DIAG, DIAGNOSTICS_DEPTH, per='cycle',
                         what='live orders of each engine cycle, against the prediction; alarms'),
    'dmf_predicted': Stream(TOPIC_PREDICTED, _DIAG, LATCHED_DEPTH, latched=True,
                            per='setpoint', what='the HBM prediction at the setpoint'),
    'fault_ground_truth': Stream('faults/ground_truth', _DIAG, GROUND_TRUTH_DEPTH, latched=True,
                                 per='fault', what='one status per fault start or end and per '
                                                   'misfired combustion'),
    'fault_active': Stream('faults/active', _DIAG, LATCHED_DEPTH, latched=True, per='fault',
                           what='the faults acting now'),
}
SAMPLE_STREAMS = ('joint_states', 'dmf_windup', 'speed', 'crank_angle')   # one message each per
                                                                           # sample, this order
STATUS_STREAMS = ('diagnostics', 'dmf_orders', 'dmf_predicted', 'fault_ground_truth',
                  'fault_active')
CLOCK = Stream('/clock', 'rosgraph_msgs/msg/Clock', LATCHED_DEPTH, per='clock',
               what='simulated time; advertised only while pacing is fast, real_time_factor '
                    '!= 1 or publish_clock is set')
"""/clock: not in :data:`STREAMS` (not recorded; advertised only while published)."""
PUBLISHED = {'sample': 'every sample (publish_rate)', 'diagnostics': 'diagnostics_rate',
             'cycle': 'per engine cycle', 'setpoint': 'when the setpoint changes',
             'fault': 'per fault event',
             'edges': 'a batch per edge-batch period with edges (sensors.edge_batch_s)',
             'bus': 'when the bus delivers a value', 'clock': 'with the samples'}
"""When a stream is published (:attr:`Stream.per`), for people."""
SENSOR_STREAMS = {
    'edges': Stream(edge_topic('<wheel>'), EDGES_TYPE, STREAM_DEPTH, per='edges',
                    what="the tooth edges of each tooth wheel of the driveline YAML's sensors "
                         '(layout: dmf_sim.bags.sensor_messages); parameter sensors'),
    'bus': Stream(bus_topic('<signal>'), BUS_TYPE, STREAM_DEPTH, per='bus',
                  what="each bus signal of the driveline YAML's sensors: speed [rpm]"),
}
"""The sensors' streams, one per tooth wheel and bus signal (:func:`sensor_streams`): reliable,
keep-last :data:`STREAM_DEPTH` as the samples; the topic names the sensor."""
DETECTIONS = Stream(TOPIC_DETECTIONS, _DIAG, DIAGNOSTICS_DEPTH, per='cycle',
                    what='the live misfire detector on the tooth wheels around the DMF: one '
                         'status per scored firing interval, WARN for an alarm (parameters '
                         'monitor, sensors)')
"""``misfire_detections``: declared with any tooth wheel (:func:`sensor_streams`), published
by the monitor when the driveline has one on each side of the DMF
(:mod:`dmf_sim.monitor.misfire`)."""


class Subscription(NamedTuple):
    """A topic the node subscribes to: relative topic, ROS type, what it takes; reliable,
    keep-all (``depth`` 0), so a command is never dropped."""

    topic: str
    msgtype: str
    what: str
    depth: int = 0


SUBSCRIPTIONS: dict[str, Subscription] = {
    'speed_setpoint': Subscription('engine/speed_setpoint', _F64, 'engine speed setpoint [rpm]'),
    'load_setpoint': Subscription('engine/load_setpoint', _F64,
                                  'engine load setpoint [-1..1], below 0 engine braking'),
    'fault_inject': Subscription('faults/inject', 'std_msgs/msg/String',
                                 'a fault request (YAML flow, dmf_sim.live.faults)'),
}


class Service(NamedTuple):
    """A service of the node: private name (``~/`` is the node's own), ROS type, what it does."""

    name: str
    srvtype: str
    what: str


SERVICES: dict[str, Service] = {
    'reset': Service('~/reset', 'std_srvs/srv/Trigger',
                     'static equilibrium at the current setpoints'),
    'record': Service('~/record', 'std_srvs/srv/SetBool',
                      'start/stop recording (as parameter record)'),
    'clear_faults': Service('~/clear_faults', 'std_srvs/srv/Trigger', 'every fault ends now'),
}


def edge_key(wheel: str) -> str:
    """The stream key of a tooth wheel's edge batches."""
    return f'edges/{wheel}'


def bus_key(signal: str) -> str:
    """The stream key of a bus signal."""
    return f'bus/{signal}'


def sensor_streams(sensors) -> dict[str, Stream]:
    """The streams of a :class:`~dmf_sim.physics.sensors.SensorSet`: each tooth wheel's edge
    batches, each bus signal (:data:`SENSOR_STREAMS` with the sensor's name)."""
    edges, bus = SENSOR_STREAMS['edges'], SENSOR_STREAMS['bus']
    out = {edge_key(w.name): edges._replace(topic=edge_topic(w.name))
           for w in sensors.tooth_wheels}
    out.update({bus_key(b.name): bus._replace(topic=bus_topic(b.name))
                for b in sensors.bus_signals})
    if sensors.tooth_wheels:
        out['misfire_detections'] = DETECTIONS
    return out


def streams_for(sensors=None) -> dict[str, Stream]:
    """The streams of a node or run: :data:`STREAMS`, and those of ``sensors`` (a
    :class:`~dmf_sim.physics.sensors.SensorSet`; None or empty: no sensors)."""
    return {**STREAMS, **sensor_streams(sensors)} if sensors else dict(STREAMS)


def resolved_topics(namespace: str = '', streams: dict[str, Stream] | None = None
                    ) -> dict[str, str]:
    """Stream key -> absolute topic name under ``namespace`` ('' = none), as rclpy resolves
    the relative names (absolute ones stay); ``streams``: default :data:`STREAMS`."""
    ns = check_namespace(namespace, 'namespace')
    return {k: (s.topic if s.topic.startswith('/') else f'{ns}/{s.topic}')
            for k, s in (STREAMS if streams is None else streams).items()}
