"""Namespaces that reach a bag (``dmf-sim run --namespace``) follow ROS 2's rules
(rmw_validate_namespace, after rcl's normalization of a relative name): a name no ROS node
could publish under is refused in one line naming the option, before anything is written."""
from __future__ import annotations

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
