"""``dmf-sim setpoint --speed RPM [--load L] [--namespace /truck1]``: setpoints to a live node;
``dmf-sim setpoint --profile FILE``: a speed/load profile played in real time.

Publishes std_msgs/Float64 on ``<namespace>/engine/speed_setpoint`` [rpm] and
``<namespace>/engine/load_setpoint`` [-1..1] (the node's subscriptions), the way
``ros2 topic pub`` would, but first waits until the node's subscription has matched this
publisher so the message is not lost, and repeats it until every subscriber has acknowledged it
(setpoints are idempotent; the node's reader can discover this publisher seconds after this
publisher discovered it, and acknowledges only from then on). Exit 0 when delivered to every
subscriber; one line and exit 2 when no node subscribes or acknowledges within ``--timeout``.
Before sending, the speeds (``--speed``, every row of ``--profile``) are checked against the
limits of each node that subscribes (its parameters ``speed_min_rpm``/``speed_max_rpm``, read
with its parameter service as ``ros2 param get`` does): a speed outside them is refused in one
line naming it and the limits, exit 2, and nothing is sent. A node whose parameters cannot be
read is named on stderr and the setpoints are sent unchecked; the node refuses a speed outside
its limits itself (counted in its /diagnostics, ``rejected_setpoints``, and logged).

``--profile``: once the node subscribes, the profile (a file, a packaged name or a ``ramp:``
spec, as ``dmf-sim run`` takes) is published interpolated at
:data:`dmf_sim.transient.live_profile.PLAYER_RATE_HZ` over wall-clock time (the node ramps
toward each value at its ``speed_ramp_rpm_per_s``), the last row until acknowledged. For a node
in fast pacing use the node's own ``profile`` parameter instead (it follows simulated time).
"""
from __future__ import annotations

import argparse
import math
import sys
import time

from dmf_sim.commands._options import LOAD_LIMITS, check_wait
from dmf_sim.core.errors import ConfigError, OperatingRangeError
from dmf_sim.core.limits import MAX_WAIT_S

__all__ = ['NAME', 'HELP', 'add_arguments', 'check', 'run']

NAME = 'setpoint'
HELP = ('Send an engine speed [rpm] and/or load [-1..1] setpoint to a running driveline_node '
        '(waits until its subscription matched; needs rclpy)')


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--speed', type=float, metavar='RPM', help='engine speed setpoint [rpm]')
    parser.add_argument('--load', type=float, metavar='L',
                        help='load setpoint, the torque demand -1..1: 1 full load, 0 none, '
                             'below 0 engine braking (the node refuses it for an engine '
                             'without a brake curve); ramped at the node\'s load_ramp_per_s')
    parser.add_argument('--profile', metavar='FILE',
                        help='play a speed/load profile in real time: CSV/YAML file, packaged '
                             'name (truck_road_cycle), ramp:FROM:TO:RATE[:LOAD[:SETTLE]] or '
                             'step:SPEED:FROM:TO:RISE[:HOLD[:SETTLE]] (a fast step reaches the '
                             'node at its load_ramp_per_s; its profile parameter follows it as '
                             'given)')
    parser.add_argument('--namespace', default='', metavar='NS',
                        help="the node's namespace, e.g. /truck1 or truck1 (default: none)")
    parser.add_argument('--timeout', type=float, default=10.0, metavar='S',
                        help=f'seconds to wait for the node (default 10, at most {MAX_WAIT_S:g})')


def check(args: argparse.Namespace) -> list[tuple[str, float, str]]:
    """(topic name relative to the namespace, value, text) per setpoint; one-line errors."""
    if args.profile is not None and (args.speed is not None or args.load is not None):
        raise ConfigError('give either --profile FILE or --speed/--load, not both')
    if args.profile is not None:
        from dmf_sim.transient.profiles import read_profile
        prof = read_profile(args.profile)
        speed, load = (float(v) for v in prof.at(0.0))
        args.profile_data = prof
        check_wait(args.timeout)
        return [('engine/speed_setpoint', speed, f'{speed:g} rpm'),
                ('engine/load_setpoint', load, f'load {load:g}')]
    if args.speed is None and args.load is None:
        raise ConfigError('give --speed RPM and/or --load L, or --profile FILE')
    out = []
    if args.speed is not None:
        if not (math.isfinite(args.speed) and args.speed > 0):
            raise ConfigError(f'--speed must be a finite speed > 0 rpm, got {args.speed!r}')
        out.append(('engine/speed_setpoint', float(args.speed), f'{args.speed:g} rpm'))
    if args.load is not None:
        lo, hi = LOAD_LIMITS
        if not (math.isfinite(args.load) and lo <= args.load <= hi):
            raise ConfigError(f'--load must be in [{lo:g}, {hi:g}], got {args.load!r}')
        out.append(('engine/load_setpoint', float(args.load), f'load {args.load:g}'))
    check_wait(args.timeout)
    return out


SPEED_LIMITS = ('speed_min_rpm', 'speed_max_rpm')     # the node's parameters [rpm]


def check_speed_limits(args: argparse.Namespace, limits: tuple[float, float], fqn: str) -> None:
    """OperatingRangeError (one line, exit 2) if ``--speed`` or a row of ``--profile`` lies
    outside node ``fqn``'s ``limits`` [rpm]."""
    lo, hi = limits
    what = f"node {fqn}'s speed_min_rpm/speed_max_rpm"
    profile = getattr(args, 'profile_data', None)
    if profile is not None:
        profile.check_speed_range(lo, hi, what)
    elif args.speed is not None and not lo <= args.speed <= hi:
        raise OperatingRangeError(f'--speed {args.speed:g} rpm is outside {what} '
                                  f'[{lo:g}, {hi:g}] rpm; nothing sent')


def _warn(why: str) -> None:
    print(f'dmf-sim setpoint: warning: {why}; sending unchecked (the node refuses a speed '
          'outside its limits)', file=sys.stderr)


def _check_nodes(args, node, executor, speed_topic: str, timeout_s: float) -> None:
    """:func:`check_speed_limits` against every node subscribing to ``speed_topic``."""
    from dmf_sim.commands._ros import get_parameters, subscriber_nodes

    nodes = subscriber_nodes(node, executor, speed_topic, timeout_s)
    if not nodes:
        _warn(f'discovery did not name the node subscribing to {speed_topic} within '
              f'{timeout_s:g} s')
    for fqn in nodes:
        values = get_parameters(node, executor, fqn, list(SPEED_LIMITS), timeout_s)
        if isinstance(values, dict) and None in values.values():
            values = f'{fqn} does not declare {" and ".join(SPEED_LIMITS)}'
        if isinstance(values, str):
            _warn(f'cannot read the speed limits of {fqn} ({values})')
            continue
        check_speed_limits(args, (float(values[SPEED_LIMITS[0]]),
                                  float(values[SPEED_LIMITS[1]])), fqn)


def run(args: argparse.Namespace) -> int:
    from dmf_sim.commands._ros import (
        ACK_TIMEOUT_S,
        publish_until_acked,
        reliable_qos,
        ros_session,
        wait_for_subscribers,
    )

    setpoints = check(args)
    with ros_session('dmf_sim_setpoint', args.namespace) as (rclpy, node, executor):
        from std_msgs.msg import Float64

        pubs = [(node.create_publisher(Float64, name, reliable_qos()), value, text)
                for name, value, text in setpoints]
        end = time.monotonic() + args.timeout
        wait_for_subscribers([p for p, _, _ in pubs], executor, args.timeout)
        speed_pubs = [p for p, _, _ in pubs if p.topic_name.endswith('/engine/speed_setpoint')]
        if speed_pubs:
            _check_nodes(args, node, executor, speed_pubs[0].topic_name,
                         max(end - time.monotonic(), ACK_TIMEOUT_S))
        left = max(end - time.monotonic(), ACK_TIMEOUT_S)
        if getattr(args, 'profile_data', None) is not None:
            _play(args.profile_data, pubs, executor, Float64)
            pubs = [(p, v, f'{v:g} rpm' if 'speed' in p.topic_name else f'load {v:g}')
                    for (p, _, _), v in zip(pubs, args.profile_data.at(
                        args.profile_data.duration_s))]
            left = args.timeout
        publish_until_acked([(p, Float64(data=v)) for p, v, _ in pubs], left, 'setpoint')
        for pub, _, text in pubs:
            n = pub.get_subscription_count()
            print(f'{pub.topic_name}: {text} delivered to {n} subscriber{"s" if n != 1 else ""}')
    return 0


def _play(profile, pubs, executor, Float64) -> None:
    """Publish the profile's setpoints in real time (see the module docstring)."""
    from dmf_sim.transient.live_profile import ProfilePlayer

    player = ProfilePlayer(profile, time.monotonic())
    print(f'playing profile {profile.name}: {profile.duration_s:g} s, '
          f'{profile.speed_rpm.min():g}-{profile.speed_rpm.max():g} rpm', flush=True)
    now = time.monotonic()
    while not player.done(now):
        values = player.setpoints(now)
        for (pub, _, _), v in zip(pubs, values):
            pub.publish(Float64(data=v))
        executor.spin_once(timeout_sec=max(player.next_time(now) - time.monotonic(), 0.0))
        now = time.monotonic()
