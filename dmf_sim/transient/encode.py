"""The node's sample messages as CDR bytes, a block of samples at a time (numpy, no rclpy).

The node serializes every sample into a ``sensor_msgs/JointState`` (stamp; one name per element;
position = vibratory angle, velocity, effort = transmitted torque) and three ``std_msgs/Float64``
(wind-up [rad], engine speed [rpm], crank angle [rad]) -- see
:data:`dmf_sim.live.streams.SAMPLE_STREAMS`. With fixed element names every message of a stream
has the same length and layout, so a block is a template row repeated with the stamp and the
numbers written in place. The template comes from ``rosbags``' serializer (the readers' decoder)
and the field offsets from :func:`dmf_sim.bags.columns.joint_state_layout`, the layout the fast
reader checks; a test compares the bytes with ``rosbags``' and rclpy's serialization.
"""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from dmf_sim.bags.columns import FLOAT64, JOINT_STATE, joint_state_layout
from dmf_sim.live.simulation import Samples

__all__ = ['SampleEncoder']

_NS_PER_S = 1_000_000_000
_FLOAT64_BYTES = 12            # CDR header 4 + float64 8


def _typestore():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


class SampleEncoder:
    """CDR payloads of the four sample streams for element ``names`` (little-endian CDR, as
    rclpy writes on x86/ARM)."""

    def __init__(self, names: Sequence[str]) -> None:
        store = _typestore()
        js_t = store.types[JOINT_STATE]
        hdr_t = store.types['std_msgs/msg/Header']
        time_t = store.types['builtin_interfaces/msg/Time']
        n = len(names)
        msg = js_t(header=hdr_t(stamp=time_t(sec=0, nanosec=0), frame_id=''), name=list(names),
                   position=np.zeros(n), velocity=np.zeros(n), effort=np.zeros(n))
        self.template = np.frombuffer(bytes(store.serialize_cdr(msg, JOINT_STATE)), np.uint8)
        _, got_names, arrays, total, _ = joint_state_layout(self.template.tobytes())
        if got_names != list(names) or total != len(self.template):
            raise ValueError('unexpected JointState layout')        # a rosbags change: a bug
        self.offsets = {k: off for k, (off, _) in arrays.items()}
        self.n = n
        f64 = store.types[FLOAT64]
        self.float_template = np.frombuffer(bytes(store.serialize_cdr(f64(data=0.0), FLOAT64)),
                                            np.uint8)
        if len(self.float_template) != _FLOAT64_BYTES:
            raise ValueError('unexpected Float64 layout')

    def joint_states(self, stamps_ns: np.ndarray, position: np.ndarray, velocity: np.ndarray,
                     effort: np.ndarray) -> np.ndarray:
        """(rows, size) uint8: one JointState per row."""
        rows = len(stamps_ns)
        out = np.empty((rows, len(self.template)), np.uint8)
        out[:] = self.template
        sec, nsec = np.divmod(np.asarray(stamps_ns, np.int64), _NS_PER_S)
        out[:, 4:8] = sec.astype('<i4').view(np.uint8).reshape(rows, 4)
        out[:, 8:12] = nsec.astype('<u4').view(np.uint8).reshape(rows, 4)
        for key, values in (('position', position), ('velocity', velocity), ('effort', effort)):
            off = self.offsets[key]
            out[:, off:off + 8 * self.n] = np.ascontiguousarray(
                values, dtype='<f8').view(np.uint8).reshape(rows, 8 * self.n)
        return out

    def floats(self, values: np.ndarray) -> np.ndarray:
        """(rows, 12) uint8: one Float64 per row."""
        rows = len(values)
        out = np.empty((rows, _FLOAT64_BYTES), np.uint8)
        out[:, :4] = self.float_template[:4]
        out[:, 4:] = np.ascontiguousarray(values, dtype='<f8').view(np.uint8).reshape(rows, 8)
        return out

    def samples(self, s: Samples, stamps_ns: np.ndarray, topics: dict[str, str]
                ) -> list[tuple[str, np.ndarray]]:
        """(topic, payloads) of the sample streams in the node's order (``topics``: stream key
        -> topic name)."""
        return [(topics['joint_states'],
                 self.joint_states(stamps_ns, s.position, s.velocity, s.effort)),
                (topics['dmf_windup'], self.floats(s.windup)),
                (topics['speed'], self.floats(s.speed_rpm)),
                (topics['crank_angle'], self.floats(s.psi))]
