"""ROS 2 messages as CDR bytes for test data (helper, not tests), with rosbags' serializer.

No ROS installation is needed: the message classes come from rosbags' type store for Jazzy.
The bytes equal rclpy's ``serialize_message`` of the same message except for padding bytes,
which rclpy leaves unset and rosbags writes as zeros.
"""
from __future__ import annotations

import numpy as np
from rosbags.typesys import Stores, get_typestore

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
Time = TYPESTORE.types['builtin_interfaces/msg/Time']
Header = TYPESTORE.types['std_msgs/msg/Header']
JointState = TYPESTORE.types['sensor_msgs/msg/JointState']
Float64 = TYPESTORE.types['std_msgs/msg/Float64']
String = TYPESTORE.types['std_msgs/msg/String']
KeyValue = TYPESTORE.types['diagnostic_msgs/msg/KeyValue']
DiagnosticStatus = TYPESTORE.types['diagnostic_msgs/msg/DiagnosticStatus']
DiagnosticArray = TYPESTORE.types['diagnostic_msgs/msg/DiagnosticArray']


def serialize_message(msg) -> bytes:
    """CDR bytes of a message of TYPESTORE (little endian, as rclpy writes)."""
    return bytes(TYPESTORE.serialize_cdr(msg, msg.__msgtype__))


def stamp(ns: int) -> Time:
    """builtin_interfaces/Time of a time [ns]."""
    return Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def joint_state(stamp_ns: int, names, position, velocity=None, effort=None, frame: str = ''):
    """sensor_msgs/JointState stamped ``stamp_ns``; velocity/effort None: zeros."""
    zeros = np.zeros(len(names))
    return JointState(header=Header(stamp=stamp(stamp_ns), frame_id=frame), name=list(names),
                      position=np.asarray(position, np.float64),
                      velocity=zeros if velocity is None else np.asarray(velocity, np.float64),
                      effort=zeros if effort is None else np.asarray(effort, np.float64))
