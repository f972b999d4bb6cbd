"""ROS namespaces given by a user (``--namespace`` of setpoint, monitor, analyze, durability,
run) are written one way and checked by ROS 2's rules in one function,
:func:`dmf_sim.core.names.check_namespace` (rmw_validate_namespace, after rcl's normalization of a
relative name: ``ros2 launch ... namespace:=t1`` runs the node in ``/t1``). A name no ROS node
could publish under is refused in one line naming the option, before anything is written."""
from __future__ import annotations

import importlib.util

import pytest

from dmf_sim.cli import main as cli_main
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.names import NAMESPACE_MAX_LENGTH, check_namespace


@pytest.mark.parametrize('value, expected', [
    ('', ''), ('/', ''), (None, ''), ('truck1', '/truck1'), ('/truck1', '/truck1'),
    ('/fleet/truck_2', '/fleet/truck_2'), ('_x/Y9', '/_x/Y9'),
    ('/' + 'a' * (NAMESPACE_MAX_LENGTH - 1), '/' + 'a' * (NAMESPACE_MAX_LENGTH - 1)),
])
def test_valid_namespaces_are_made_absolute(value, expected):
    assert check_namespace(value) == expected


@pytest.mark.parametrize('value, why', [
    ('bad//ns', "contains '//'"),
    ('9truck', "token '9truck' starts with a digit"),
    ('/fleet/2nd', "token '2nd' starts with a digit"),
    ('a b', "character ' ' is not allowed"),
    ('truck-1', "character '-' is not allowed"),
    ('/truck1/', "ends with '/'"),
    ('~/x', "character '~' is not allowed"),
    ('/' + 'a' * NAMESPACE_MAX_LENGTH, f'at most {NAMESPACE_MAX_LENGTH}'),
    (3, 'must be text'),
])
def test_invalid_namespaces_are_one_line_naming_the_rule(value, why):
    with pytest.raises(ConfigError) as e:
        check_namespace(value, '--namespace')
    msg = str(e.value)
    assert msg.startswith(f'--namespace {value!r}: ') and why in msg and '\n' not in msg, msg


@pytest.mark.parametrize('ns', ['bad//ns', '9truck', 'a b'])
def test_run_refuses_the_namespace_before_writing(ns, tmp_path, capsys, monkeypatch):
    def no_run(*args, **kwargs):
        raise AssertionError('the run started with an invalid namespace')
    monkeypatch.setattr('dmf_sim.transient.run.run_profile', no_run)
    out = tmp_path / 'bag'
    assert cli_main(['run', 'ramp:800:900:100', '--out', str(out), '--namespace', ns]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and f'--namespace {ns!r}: not a valid ROS 2 namespace' in err
    assert not out.exists()


def test_run_options_hold_the_normalized_namespace():
    from dmf_sim.live.streams import resolved_topics
    from dmf_sim.transient.run import RunOptions
    opt = RunOptions(namespace='truck1')
    assert opt.namespace == '/truck1'
    assert resolved_topics(opt.namespace)['dmf_windup'].startswith('/truck1/')
    with pytest.raises(ConfigError, match="namespace 'bad//ns'"):
        RunOptions(namespace='bad//ns')


@pytest.mark.skipif(importlib.util.find_spec('rclpy') is None, reason='needs rclpy (ros extra)')
def test_the_rules_are_rclpys():
    """Every case against rclpy's own validate_namespace (relative ones made absolute, as
    launch_ros does before it passes ``__ns``)."""
    from rclpy.exceptions import InvalidNamespaceException
    from rclpy.validate_namespace import validate_namespace

    good = ['t1', '/t1', 'fleet/t1', '/_x/y_2', '/' + 'a' * (NAMESPACE_MAX_LENGTH - 1)]
    bad = ['t1/', '/a//b', '1t', '/a/2b', 't-1', 'é', ' t1', '/' + 'a' * NAMESPACE_MAX_LENGTH]
    for text in good + bad:
        try:
            validate_namespace(text if text.startswith('/') else '/' + text)
            ros_ok = True
        except InvalidNamespaceException:
            ros_ok = False
        assert ros_ok == (text in good), text
        try:
            check_namespace(text)
            ours_ok = True
        except ConfigError:
            ours_ok = False
        assert ours_ok == ros_ok, text
