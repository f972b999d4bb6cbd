"""``dmf-sim fault REQUEST [--namespace /truck1]``: inject a fault into a running node;
``dmf-sim fault --clear``: end every fault.

REQUEST is a fault in the grammar of :mod:`dmf_sim.physics.faults` (YAML flow style), e.g.
``'{kind: misfire, cylinders: [3]}'`` or a list of them. It is checked here first (the grammar:
kinds, fields, ranges, NaN, windows; one line and exit 2), then published on the node's
``faults/inject`` (std_msgs/String) with a ``request_id`` the node applies once, until the node
has acknowledged it (as ``dmf-sim setpoint`` delivers setpoints). The node checks it against its
driveline and its other faults (cylinders, stages, overlaps) and refuses a bad one with its
reason (logged, counted in ``/diagnostics``: ``fault_last_refused``); what it applied appears on
``faults/active`` and ``faults/ground_truth``.

``--clear`` calls the node's ``~/clear_faults`` service (std_srvs/Trigger) and prints its answer.
"""
from __future__ import annotations

import argparse
import math
import os
import socket
import time

from dmf_sim.core.errors import ConfigError, NoResponseError

__all__ = ['NAME', 'HELP', 'add_arguments', 'check', 'run']

NAME = 'fault'
HELP = ("Inject a fault into a running driveline_node ('{kind: misfire, cylinders: [3]}', "
        'YAML flow) or --clear them all (needs rclpy)')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('request', nargs='?', metavar='REQUEST',
                        help="the fault(s) in YAML flow style, e.g. '{kind: misfire, cylinders: "
                             "[3]}' or '{kind: weak_cylinder, cylinder: 5, factor: 0.7, "
                             "duration_s: 10}'")
    parser.add_argument('--clear', action='store_true',
                        help='end every fault now (the node\'s ~/clear_faults service)')
    parser.add_argument('--namespace', default='', metavar='NS',
                        help="the node's namespace, e.g. /truck1 (default: none)")
    parser.add_argument('--node', default='driveline_node', metavar='NAME',
                        help="the node's name, for --clear (default driveline_node)")
    parser.add_argument('--timeout', type=float, default=10.0, metavar='S',
                        help='seconds to wait for the node (default 10)')


def check(args: argparse.Namespace) -> str:
    """The request's text with a request id, as published (one-line ConfigError for a bad
    request or option); '' for --clear."""
    import yaml

    from dmf_sim.core.paths import parse_yaml
    from dmf_sim.live.faults import REQUEST_ID
    from dmf_sim.physics.faults import parse_request

    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise ConfigError(f'--timeout must be > 0 s, got {args.timeout!r}')
    if args.clear:
        if args.request is not None:
            raise ConfigError('give a REQUEST or --clear, not both')
        return ''
    if not args.request:
        raise ConfigError("give a REQUEST, e.g. '{kind: misfire, cylinders: [3]}', or --clear")
    spec = parse_yaml(args.request, 'REQUEST')
    parse_request(spec, 'REQUEST')          # the grammar; the node checks its driveline
    if not isinstance(spec, (dict, list)) or not spec:
        raise ConfigError('REQUEST: must be a fault mapping or a list of them')
    first = spec if isinstance(spec, dict) else spec[0]
    first[REQUEST_ID] = f'{socket.gethostname()}-{os.getpid()}-{time.time_ns()}'
    return yaml.safe_dump(spec, default_flow_style=True, sort_keys=False,
                          width=math.inf).strip()


def run(args: argparse.Namespace) -> int:
    from dmf_sim.commands._ros import (
        check_namespace,
        publish_until_acked,
        reliable_qos,
        ros_session,
        wait_for_subscribers,
    )

    text = check(args)
    ns = check_namespace(args.namespace)
    with ros_session('dmf_sim_fault', args.namespace) as (rclpy, node, executor):
        if args.clear:
            from std_srvs.srv import Trigger
            name = f'{ns}/{args.node.strip("/")}/clear_faults'
            client = node.create_client(Trigger, name)
            if not client.wait_for_service(timeout_sec=args.timeout):
                raise NoResponseError(f'no service {name} within {args.timeout:g} s (is '
                                      'driveline_node running with this ROS_DOMAIN_ID, '
                                      'namespace and name?)')
            future = client.call_async(Trigger.Request())
            executor.spin_until_future_complete(future, timeout_sec=args.timeout)
            if not future.done():
                raise NoResponseError(f'{name} did not answer within {args.timeout:g} s')
            print(f'{name}: {future.result().message}')
            return 0
        from std_msgs.msg import String

        pub = node.create_publisher(String, 'faults/inject', reliable_qos())
        start = time.monotonic()
        wait_for_subscribers([pub], executor, args.timeout)
        publish_until_acked([(pub, String(data=text))],
                            args.timeout - (time.monotonic() - start), 'fault request')
        n = pub.get_subscription_count()
        print(f'{pub.topic_name}: {text} delivered to {n} subscriber{"s" if n != 1 else ""}; '
              'the node checks it against its driveline (a refusal: its log, /diagnostics '
              'fault_last_refused); applied faults: faults/active, faults/ground_truth')
    return 0
