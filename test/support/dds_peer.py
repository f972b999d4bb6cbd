"""DDS test helpers: the node as a subprocess, an rclpy peer in the test process, domain IDs.

Every DDS participant of the tests stays on this machine (ROS_AUTOMATIC_DISCOVERY_RANGE=
LOCALHOST) on its own ROS_DOMAIN_ID, taken from DMF_SIM_TEST_DOMAINS ("LO-HI", default 1-100)
so that several test runs on one machine can be given disjoint ranges.
"""
from __future__ import annotations

import itertools
import os
import signal
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

DOMAINS_ENV = 'DMF_SIM_TEST_DOMAINS'
DEFAULT_DOMAINS = '1-100'
START_TIMEOUT = 90.0      # first start compiles/loads the numba kernel
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
_seq = itertools.count(1)


def domain_range() -> tuple[int, int]:
    """(lo, hi) of DMF_SIM_TEST_DOMAINS, inclusive, within ROS's 0..232."""
    text = os.environ.get(DOMAINS_ENV, DEFAULT_DOMAINS)
    try:
        lo, hi = (int(x) for x in text.split('-'))
    except ValueError:
        raise ValueError(f'{DOMAINS_ENV} must look like "1-60", got {text!r}') from None
    if not 0 <= lo <= hi <= 232:
        raise ValueError(f'{DOMAINS_ENV} must lie within 0-232, got {text!r}')
    return lo, hi


def new_domain() -> int:
    """A ROS_DOMAIN_ID in the range, different for consecutive calls of this process."""
    lo, hi = domain_range()
    return lo + (os.getpid() * 11 + 37 * next(_seq)) % (hi - lo + 1)


class NodeProcess:
    """The node as a subprocess (python -m dmf_sim.node or an executable)."""

    def __init__(self, args, cwd: Path, domain: int, exe=None, env=None) -> None:
        self.cmd = list(exe or [sys.executable, '-m', 'dmf_sim.node']) + list(args)
        self.env = dict(env or os.environ, ROS_DOMAIN_ID=str(domain),
                        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
        self.log_path = cwd / f'node_{next(_seq)}.log'
        self._log = open(self.log_path, 'w')
        self.proc = subprocess.Popen(self.cmd, cwd=cwd, env=self.env, stdout=self._log,
                                     stderr=subprocess.STDOUT)

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stop(self, sig=signal.SIGTERM, timeout: float = 30.0) -> int:
        if self.alive():
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=timeout)
        finally:
            self.close()

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(timeout=10)
        self._log.close()

    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text()


class Peer:
    """An rclpy participant in this process, on the node's domain."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.rclpy = rclpy
        self.ctx = rclpy.context.Context()
        rclpy.init(context=self.ctx, domain_id=domain)
        self.node = rclpy.create_node(f'test_peer_{os.getpid()}', context=self.ctx)
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.last: dict = {}
        self.counts: dict = defaultdict(int)
        self.series: dict = defaultdict(list)
        self.diags: dict = {}          # status name -> {key: value, _level, _hardware_id}
        self.qos = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)

    def subscribe(self, topic: str, msg_type, keep: bool = False):
        def cb(msg):
            self.last[topic] = msg
            self.counts[topic] += 1
            if keep:                    # a Float64's value, else the message itself
                self.series[topic].append((time.monotonic(), getattr(msg, 'data', msg)))
            if topic == '/diagnostics':
                for st in msg.status:
                    self.diags[st.name] = {'_level': st.level, '_hardware_id': st.hardware_id,
                                           '_message': st.message,
                                           **{kv.key: kv.value for kv in st.values}}
        return self.node.create_subscription(msg_type, topic, cb, self.qos)

    def spin_until(self, cond, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if cond():
                return True
            self.executor.spin_once(timeout_sec=0.02)
        return bool(cond())

    def spin_for(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def call(self, srv_type, name: str, request, timeout: float = 15.0):
        client = self.node.create_client(srv_type, name)
        assert client.wait_for_service(timeout_sec=timeout), f'service {name} not found'
        fut = client.call_async(request)
        assert self.spin_until(fut.done, timeout), f'{name} timed out'
        self.node.destroy_client(client)
        return fut.result()

    def set_params(self, node_name: str, **values):
        from rcl_interfaces.srv import SetParameters
        from rclpy.parameter import Parameter
        req = SetParameters.Request()
        req.parameters = [Parameter(k, value=v).to_parameter_msg() for k, v in values.items()]
        return self.call(SetParameters, f'/{node_name.lstrip("/")}/set_parameters', req).results

    def diagnostics(self, name: str | None = None) -> dict:
        """The last status of ``name`` (default: the only/first node's)."""
        if name is None:
            return next(iter(self.diags.values()), {})
        return self.diags.get(name, {})

    def publishers(self, topic: str) -> int:
        return len(self.node.get_publishers_info_by_topic(topic))

    def close(self) -> None:
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.ctx)
