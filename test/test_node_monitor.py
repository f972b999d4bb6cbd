"""The DMF monitor and the Foxglove server wired into the running node (issue 15 items 1-3):
per-cycle orders and the latched prediction on their topics, the monitor's status beside the
node's health in /diagnostics, and a Foxglove client receiving the node's own wind-up stream."""
from __future__ import annotations

import asyncio
import json
import socket
import struct
from pathlib import Path

import pytest
import websockets
from dds_peer import NodeProcess, Peer, new_domain


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


async def _foxglove_windup(url: str, topic: str) -> float:
    """Connect as a Foxglove client, subscribe to ``topic`` (std_msgs/Float64), decode one."""
    from dmf_sim.live.foxglove_bridge import SUBPROTOCOL
    async with websockets.connect(url, subprotocols=[SUBPROTOCOL]) as ws:
        channels = {}
        while topic not in channels:
            msg = json.loads(await asyncio.wait_for(ws.recv(), 10))
            if msg['op'] == 'advertise':
                channels.update({c['topic']: c for c in msg['channels']})
        assert channels[topic]['schemaName'] == 'std_msgs/msg/Float64'
        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': 1, 'channelId': channels[topic]['id']}]}))
        while True:
            data = await asyncio.wait_for(ws.recv(), 10)
            if isinstance(data, bytes) and data[0] == 0x01:
                return struct.unpack_from('<d', data, 13 + 4)[0]    # CDR header, then float64


def test_node_publishes_cycle_orders_prediction_and_serves_foxglove(tmp_path: Path):
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    domain, port = new_domain(), _free_port()
    node = NodeProcess(['--ros-args', '-r', '__ns:=/truck7', '-p', 'initial_speed_rpm:=1200.0',
                        '-p', 'initial_load:=1.0', '-p', f'foxglove_port:={port}',
                        '-p', 'monitor_worker:=thread'], tmp_path, domain)
    peer = Peer(domain)
    try:
        peer.subscribe('/truck7/driveline/dmf_orders', DiagnosticArray)
        peer.subscribe('/diagnostics', DiagnosticArray)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        predicted = []
        peer.node.create_subscription(DiagnosticArray, '/truck7/driveline/dmf_predicted',
                                      predicted.append, latched)
        assert peer.spin_until(lambda: peer.counts['/truck7/driveline/dmf_orders'] >= 3, 90), \
            node.output()
        status = peer.last['/truck7/driveline/dmf_orders'].status[0]
        values = {kv.key: kv.value for kv in status.values}
        assert 'truck7' in status.name
        order_3 = float(values['order_3_rad'])
        assert 0.001 < order_3 < 0.05 and float(values['speed_rpm']) == pytest.approx(1200, abs=1)
        assert peer.spin_until(lambda: predicted, 60), node.output()
        pv = {kv.key: kv.value for st in predicted[-1].status for kv in st.values}
        assert any(k.endswith('order_3_rad') for k in pv), pv
        # the monitor's status beside the node's health
        assert peer.spin_until(lambda: any('monitor' in name.lower() or 'DMF' in name
                                           for name in peer.diags if 'driveline simulation'
                                           not in name), 10), list(peer.diags)
        health = peer.diagnostics('/truck7/driveline_node: driveline simulation')
        assert health and health['_hardware_id'] == '/truck7/driveline_node'
        # Foxglove: the node's own wind-up stream over the WebSocket protocol
        w = asyncio.run(_foxglove_windup(f'ws://127.0.0.1:{port}', '/truck7/driveline/dmf_windup'))
        assert 0.0 < w < 0.6
    finally:
        peer.close()
        code = node.stop()
    assert code == 0, node.output()
