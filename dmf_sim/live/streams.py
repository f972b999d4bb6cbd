"""The node's published streams (one table): key -> (default topic, ROS type).

Relative topics resolve under the node's namespace. ``driveline_node`` publishes and records
these; ``dmf-sim run`` writes a bag with the same topics and types (the sample streams filled,
the status streams declared), so one reader serves both.
"""
from __future__ import annotations

from dmf_sim.monitor.messages import TOPIC_CYCLE, TOPIC_PREDICTED

STREAMS = {  # key -> (default topic, ROS type)
    'joint_states': ('driveline/joint_states', 'sensor_msgs/msg/JointState'),
    'dmf_windup': ('driveline/dmf_windup', 'std_msgs/msg/Float64'),
    'speed': ('engine/speed', 'std_msgs/msg/Float64'),
    'crank_angle': ('engine/crank_angle', 'std_msgs/msg/Float64'),
    'diagnostics': ('/diagnostics', 'diagnostic_msgs/msg/DiagnosticArray'),
    'dmf_orders': (TOPIC_CYCLE, 'diagnostic_msgs/msg/DiagnosticArray'),
    'dmf_predicted': (TOPIC_PREDICTED, 'diagnostic_msgs/msg/DiagnosticArray'),
}
SAMPLE_STREAMS = ('joint_states', 'dmf_windup', 'speed', 'crank_angle')   # one message each per
                                                                           # sample, this order
STATUS_STREAMS = ('diagnostics', 'dmf_orders', 'dmf_predicted')


def resolved_topics(namespace: str = '') -> dict[str, str]:
    """Stream key -> absolute topic name under ``namespace`` ('' = none), as rclpy resolves
    the relative names (absolute ones stay)."""
    ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
    return {k: (t if t.startswith('/') else f'{ns}/{t}') for k, (t, _) in STREAMS.items()}
