"""The node's published streams (one table): topic, message type and offered QoS of each.

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
"""
from __future__ import annotations

from typing import Any, NamedTuple

from dmf_sim.core.names import check_namespace
from dmf_sim.monitor.messages import TOPIC_CYCLE, TOPIC_PREDICTED

__all__ = ['DIAGNOSTICS_DEPTH', 'GROUND_TRUTH_DEPTH', 'LATCHED_DEPTH', 'SAMPLE_STREAMS',
           'STATUS_STREAMS', 'STREAMS', 'STREAM_DEPTH', 'Stream', 'resolved_topics']

STREAM_DEPTH = 100          # 0.1 s of samples at 1 kHz for a subscriber that falls behind
DIAGNOSTICS_DEPTH = 10      # status arrays (1 Hz health, one per engine cycle)
LATCHED_DEPTH = 1           # the latest prediction, the active faults
GROUND_TRUTH_DEPTH = 100    # fault events a late joiner gets (starts, ends, misfires)


class Stream(NamedTuple):
    """One published stream: default topic (relative to the node's namespace unless it starts
    with '/'), ROS type, history depth, latched (transient-local durability), and when it is
    published: per ``'sample'`` (publish_rate), ``'diagnostics'`` (diagnostics_rate),
    ``'cycle'`` (per engine cycle), ``'setpoint'`` (when the setpoint changes) or ``'fault'``
    (when a fault starts or ends, a combustion misfires)."""

    topic: str
    msgtype: str
    depth: int
    latched: bool = False
    per: str = 'sample'

    def qos_profile(self) -> dict[str, Any]:
        """The offered QoS in rosbag2's form (reliable, keep-last ``depth``)."""
        from dmf_sim.bags.writer import qos_profile
        return qos_profile(self.depth, transient_local=self.latched)


_DIAG = 'diagnostic_msgs/msg/DiagnosticArray'
_F64 = 'std_msgs/msg/Float64'
STREAMS: dict[str, Stream] = {
    'joint_states': Stream('driveline/joint_states', 'sensor_msgs/msg/JointState', STREAM_DEPTH),
    'dmf_windup': Stream('driveline/dmf_windup', _F64, STREAM_DEPTH),
    'speed': Stream('engine/speed', _F64, STREAM_DEPTH),
    'crank_angle': Stream('engine/crank_angle', _F64, STREAM_DEPTH),
    'diagnostics': Stream('/diagnostics', _DIAG, DIAGNOSTICS_DEPTH, per='diagnostics'),
    'dmf_orders': Stream(TOPIC_CYCLE, _DIAG, DIAGNOSTICS_DEPTH, per='cycle'),
    'dmf_predicted': Stream(TOPIC_PREDICTED, _DIAG, LATCHED_DEPTH, latched=True,
                            per='setpoint'),
    'fault_ground_truth': Stream('faults/ground_truth', _DIAG, GROUND_TRUTH_DEPTH, latched=True,
                                 per='fault'),
    'fault_active': Stream('faults/active', _DIAG, LATCHED_DEPTH, latched=True, per='fault'),
}
SAMPLE_STREAMS = ('joint_states', 'dmf_windup', 'speed', 'crank_angle')   # one message each per
                                                                           # sample, this order
STATUS_STREAMS = ('diagnostics', 'dmf_orders', 'dmf_predicted', 'fault_ground_truth',
                  'fault_active')


def resolved_topics(namespace: str = '') -> dict[str, str]:
    """Stream key -> absolute topic name under ``namespace`` ('' = none), as rclpy resolves
    the relative names (absolute ones stay)."""
    ns = check_namespace(namespace, 'namespace')
    return {k: (s.topic if s.topic.startswith('/') else f'{ns}/{s.topic}')
            for k, s in STREAMS.items()}
