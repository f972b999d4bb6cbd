"""rclpy session for the ``dmf-sim`` commands that talk to a running node (setpoint, fault,
monitor), and the delivery of a command message to it.

rclpy is imported only when a session starts, so ``dmf-sim --help`` and the offline commands
work without ROS. The session uses its own rclpy context and the environment's ROS_DOMAIN_ID /
ROS_AUTOMATIC_DISCOVERY_RANGE, like ``ros2`` commands do.
"""
from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import dataclass

from dmf_sim.core.errors import ConfigError
from dmf_sim.core.names import check_namespace

RELIABLE_DEPTH = 10     # the node's stream QoS: reliable, volatile, keep-last 10
REPEAT_EVERY_S = 0.2    # publish a command again at this interval until acknowledged
ACK_TIMEOUT_S = 5.0     # for the last acknowledgement


@dataclass(frozen=True)
class NodeSelector:
    """Which node's ``/diagnostics`` statuses a command shows: the node's namespace and, if
    given, its fully qualified name. Statuses are matched by the full name of the node that
    published them (its ``hardware_id``), never by the last name segment alone, which is the
    same for every truck (``/truck1/driveline_node``, ``/truck2/driveline_node``)."""

    namespace: str = ''         # '' (root) or '/truck1'
    fqn: str = ''               # '/truck1/driveline_node', or '' = any node in the namespace

    def matches(self, node_fqn: str) -> bool:
        """Whether a status published by node ``node_fqn`` belongs to the selected node."""
        full = '/' + node_fqn.strip().lstrip('/')
        if self.fqn:
            return full == self.fqn
        return full.rsplit('/', 1)[0] == self.namespace

    def describe(self) -> str:
        return self.fqn or f'a node in namespace {self.namespace or "/"}'


def select_node(namespace: str, node: str = '') -> NodeSelector:
    """The node of ``--namespace`` / ``--node``: ``node`` absolute (``/truck1/driveline_node``)
    is the full name and implies its namespace; relative, it is resolved in ``namespace``;
    empty, any node directly in ``namespace``. One-line ConfigError when they disagree."""
    ns = check_namespace(namespace)
    name = (node or '').strip().rstrip('/')
    if not name:
        return NodeSelector(ns, '')
    fqn = name if name.startswith('/') else f'{ns}/{name}'
    node_ns = fqn.rsplit('/', 1)[0]
    if namespace and node_ns != ns:
        raise ConfigError(f'--node {node!r} is not in --namespace {namespace!r} (give one of '
                          'them, or both consistent)')
    return NodeSelector(node_ns, fqn)


def topic(namespace: str, name: str) -> str:
    """Absolute topic of a node-relative name inside ``namespace``."""
    return f'{namespace}/{name}' if not name.startswith('/') else name


@contextmanager
def ros_session(node_name: str, namespace: str = ''):
    """Yield (rclpy, node, executor) on a fresh context; everything is shut down on exit."""
    try:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
    except ImportError as exc:
        raise ConfigError(f'ROS 2 Python packages missing ({exc}); source a Jazzy installation '
                          'or pip install "dmf_sim[ros]"') from None
    ns = check_namespace(namespace)
    ctx = rclpy.context.Context()
    rclpy.init(context=ctx, args=[])
    node = None
    try:
        try:
            node = rclpy.create_node(f'{node_name}_{os.getpid()}', namespace=ns or '/',
                                     context=ctx)
        except Exception as exc:  # noqa: BLE001 - rclpy's InvalidNamespaceException and kin
            raise ConfigError(f'--namespace {namespace!r}: {" ".join(str(exc).split())}') from None
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        try:
            yield rclpy, node, executor
        finally:
            executor.shutdown(timeout_sec=1.0)
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)


UNKNOWN_NODE = '_UNKNOWN_'    # in rmw's node name/namespace until discovery tells them


def subscriber_nodes(node, executor, topic_name: str, timeout_s: float) -> list[str]:
    """Fully qualified names of the nodes that subscribe to ``topic_name`` (sorted), once
    discovery has told every subscription's node (it may take a moment after the match)."""
    import time

    end = time.monotonic() + timeout_s
    while True:
        infos = node.get_subscriptions_info_by_topic(topic_name)
        names = {f'{i.node_namespace.rstrip("/")}/{i.node_name}' for i in infos}
        if not any(UNKNOWN_NODE in n for n in names) or time.monotonic() > end:
            return sorted(n for n in names if UNKNOWN_NODE not in n)
        executor.spin_once(timeout_sec=0.05)


def get_parameters(node, executor, fqn: str, names: list[str], timeout_s: float
                   ) -> dict | str:
    """The values of parameters ``names`` of node ``fqn`` through its parameter service
    (``<fqn>/get_parameters``, rcl_interfaces/GetParameters, what ``ros2 param get`` calls),
    or why they could not be read (one line)."""
    import time

    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    client = node.create_client(GetParameters, f'{fqn}/get_parameters')
    try:
        if not client.wait_for_service(timeout_sec=timeout_s):
            return f'its parameter service {fqn}/get_parameters did not answer within ' \
                   f'{timeout_s:g} s'
        future = client.call_async(GetParameters.Request(names=list(names)))
        end = time.monotonic() + timeout_s
        while not future.done() and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        if not future.done():
            return f'{fqn}/get_parameters did not answer within {timeout_s:g} s'
        values = [parameter_value_to_python(v) for v in future.result().values]
        if len(values) != len(names):
            return f'{fqn} does not declare {", ".join(names)}'
        return dict(zip(names, values))
    finally:
        node.destroy_client(client)


def reliable_qos(depth: int = RELIABLE_DEPTH, latched: bool = False):
    """QoS matching the node's publishers (reliable, volatile or transient-local)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=(DurabilityPolicy.TRANSIENT_LOCAL if latched
                                  else DurabilityPolicy.VOLATILE))


def wait_for_subscribers(pubs, executor, timeout_s: float) -> None:
    """Spin until every publisher of ``pubs`` has a subscriber (the node's), or raise
    NoResponseError naming the topics nobody subscribes to within ``timeout_s``."""
    import time

    from dmf_sim.core.errors import NoResponseError
    end = time.monotonic() + timeout_s
    while not all(p.get_subscription_count() > 0 for p in pubs):
        if time.monotonic() > end:
            missing = [p.topic_name for p in pubs if p.get_subscription_count() == 0]
            raise NoResponseError(
                f'no node subscribes to {", ".join(missing)} within {timeout_s:g} s (is '
                'driveline_node running with this ROS_DOMAIN_ID and namespace?)')
        executor.spin_once(timeout_sec=0.02)


def publish_until_acked(items, timeout_s: float, what: str = 'message') -> None:
    """Publish each (publisher, message) of ``items`` until every subscriber has acknowledged
    it, then once more (the node's reader may discover this publisher seconds after this
    publisher matched it, and acknowledges samples only from then on; the last one certainly
    reaches a matched reader). The messages must be idempotent (setpoints; fault requests
    carry a request id). NoResponseError after ``timeout_s``."""
    import time

    from rclpy.duration import Duration

    from dmf_sim.core.errors import NoResponseError
    end = time.monotonic() + timeout_s
    acked = False
    while not acked and time.monotonic() < end:
        for pub, msg in items:
            pub.publish(msg)
        acked = all(p.wait_for_all_acked(Duration(seconds=REPEAT_EVERY_S)) for p, _ in items)
    if not acked:
        raise NoResponseError(f'the node did not acknowledge the {what} within {timeout_s:g} s')
    for pub, msg in items:
        pub.publish(msg)
    if not all(p.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S)) for p, _ in items):
        raise NoResponseError(f'the node did not acknowledge the {what}')
