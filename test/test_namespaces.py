"""ROS namespaces given by a user (``--namespace`` of setpoint, monitor, analyze, durability,
run): written one way and checked by ROS's rules in one function,
:func:`dmf_sim.core.validation.ros_namespace`. ``ros2 launch ... namespace:=t1`` runs the node in
``/t1``; ``dmf-sim monitor --namespace t1`` used to be refused."""
from __future__ import annotations

import importlib.util

import pytest

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.validation import NAMESPACE_MAX_LENGTH, ros_namespace
from dmf_sim.live.streams import resolved_topics

GOOD = {'': '', '/': '', 't1': '/t1', '/t1': '/t1', 'fleet/t1': '/fleet/t1', '/_x/y_2': '/_x/y_2',
        '/' + 'a' * (NAMESPACE_MAX_LENGTH - 1): '/' + 'a' * (NAMESPACE_MAX_LENGTH - 1)}
BAD = {'t1/': "ends with '/'", '/a//b': "empty token", '1t': 'starts with a digit',
       '/a/2b': 'starts with a digit', 't-1': 'characters other', 'é': 'characters other',
       ' t1': 'characters other', '/' + 'a' * NAMESPACE_MAX_LENGTH: 'longer than'}


def test_namespaces_as_launch_and_rclpy_take_them():
    for text, expected in GOOD.items():
        assert ros_namespace(text) == expected
    for text, why in BAD.items():
        with pytest.raises(ConfigError, match=f"^--namespace '{text}' is not a ROS namespace: "
                                              f'.*{why}'):
            ros_namespace(text)
    assert resolved_topics('t1')['dmf_windup'] == '/t1/driveline/dmf_windup'      # dmf-sim run
    assert resolved_topics('')['dmf_windup'] == '/driveline/dmf_windup'


@pytest.mark.skipif(importlib.util.find_spec('rclpy') is None, reason='needs rclpy (ros extra)')
def test_the_rules_are_rclpys():
    """Every case against rclpy's own validate_namespace (relative ones made absolute, as
    launch_ros does before it passes ``__ns``)."""
    from rclpy.exceptions import InvalidNamespaceException
    from rclpy.validate_namespace import validate_namespace

    for text in [*GOOD, *BAD]:
        absolute = text if text.startswith('/') else '/' + text
        try:
            validate_namespace(absolute)
            ros_ok = True
        except InvalidNamespaceException:
            ros_ok = False
        assert ros_ok == (text in GOOD), text
