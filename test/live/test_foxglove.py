"""Foxglove: the WebSocket server of dmf_sim.live.foxglove_bridge (a real client connects,
subscribes, decodes the CDR messages) and the shipped layout config/foxglove_layout.json."""
from __future__ import annotations

import asyncio
import json
import re
import struct
from pathlib import Path

import pytest
import websockets
from support.foxglove_client import first_message

from dmf_sim.core.errors import ConfigError
from dmf_sim.live.foxglove_bridge import (
    SUBPROTOCOL,
    FoxgloveBridge,
    foxglove_layout,
    message_definition,
)

REPO = Path(__file__).resolve().parents[2]
LAYOUT = REPO / 'config' / 'foxglove_layout.json'
STREAMS = {'/driveline/dmf_windup': 'std_msgs/msg/Float64',
           '/driveline/dmf_orders': 'diagnostic_msgs/msg/DiagnosticArray'}


def _store():
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def _diag_cdr(store, values: dict) -> bytes:
    """A DiagnosticArray with one status, CDR-serialized (as the node's serialize_message)."""
    T = store.types
    Time = T['builtin_interfaces/msg/Time']
    hdr = T['std_msgs/msg/Header'](stamp=Time(sec=12, nanosec=5), frame_id='')
    kvs = [T['diagnostic_msgs/msg/KeyValue'](key=k, value=v) for k, v in values.items()]
    st = T['diagnostic_msgs/msg/DiagnosticStatus'](level=1, name='n: DMF cycle orders',
                                                  message='m', hardware_id='dmf_sim', values=kvs)
    msg = T['diagnostic_msgs/msg/DiagnosticArray'](header=hdr, status=[st])
    return bytes(store.serialize_cdr(msg, 'diagnostic_msgs/msg/DiagnosticArray'))


async def _client(bridge: FoxgloveBridge, store):
    async with websockets.connect(bridge.url, subprotocols=[SUBPROTOCOL]) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        info = json.loads(await ws.recv())
        assert info['op'] == 'serverInfo' and info['name'] == 'dmf_sim'
        channels = {}
        while len(channels) < len(STREAMS):
            adv = json.loads(await ws.recv())
            assert adv['op'] == 'advertise'
            channels.update({c['topic']: c for c in adv['channels']})
        for topic, msgtype in STREAMS.items():
            c = channels[topic]
            assert (c['encoding'], c['schemaEncoding'], c['schemaName']) == ('cdr', 'ros2msg',
                                                                             msgtype)
            assert c['schema'] == message_definition(msgtype)
        assert 'diagnostic_msgs/KeyValue' in channels['/driveline/dmf_orders']['schema']
        # published before anyone subscribed: goes nowhere
        assert not bridge.has_subscribers('/driveline/dmf_orders')
        bridge.publish('/driveline/dmf_windup', b'\x00\x01\x00\x00' + struct.pack('<d', -1.0), 1)
        subs = {7: '/driveline/dmf_windup', 8: '/driveline/dmf_orders'}
        await ws.send(json.dumps({'op': 'subscribe', 'subscriptions': [
            {'id': i, 'channelId': channels[t]['id']} for i, t in subs.items()]}))
        for _ in range(100):
            if all(bridge.has_subscribers(t) for t in subs.values()):
                break
            await asyncio.sleep(0.02)
        windup = b'\x00\x01\x00\x00' + struct.pack('<d', 0.2345)
        bridge.publish('/driveline/dmf_windup', windup, 1_700_000_000_123_456_789)
        bridge.publish('/driveline/dmf_orders', _diag_cdr(store, {'order_3_rad': '0.0123'}),
                       1_700_000_000_200_000_000)
        got = {}
        while len(got) < 2:
            data = await asyncio.wait_for(ws.recv(), 10)
            assert isinstance(data, bytes) and data[0] == 0x01      # Message Data
            sub_id, log_time = struct.unpack_from('<IQ', data, 1)
            got[subs[sub_id]] = (log_time, data[13:])
        return got


def test_foxglove_server_streams_cdr_messages_a_client_decodes():
    store = _store()
    bridge = FoxgloveBridge(STREAMS, port=0)
    try:
        assert bridge.port > 0
        got = asyncio.run(_client(bridge, store))
    finally:
        bridge.close()
    t, payload = got['/driveline/dmf_windup']
    assert t == 1_700_000_000_123_456_789
    assert store.deserialize_cdr(payload, 'std_msgs/msg/Float64').data == 0.2345
    t, payload = got['/driveline/dmf_orders']
    msg = store.deserialize_cdr(payload, 'diagnostic_msgs/msg/DiagnosticArray')
    assert t == 1_700_000_000_200_000_000
    assert msg.status[0].values[0].key == 'order_3_rad'
    assert msg.status[0].values[0].value == '0.0123' and msg.status[0].level == 1


def test_foxglove_refuses_other_subprotocols_and_bad_settings():
    bridge = FoxgloveBridge(STREAMS, port=0)

    async def old_client():
        async with websockets.connect(bridge.url, subprotocols=['foxglove.websocket.v1']):
            pass
    try:
        with pytest.raises(Exception, match='400|sec-websocket-protocol|InvalidStatus'):
            asyncio.run(old_client())
        with pytest.raises(ConfigError, match='foxglove server on 127.0.0.1'):
            FoxgloveBridge(STREAMS, port=bridge.port)          # the port is taken
    finally:
        bridge.close()
    with pytest.raises(ConfigError, match='absolute'):
        FoxgloveBridge({'driveline/dmf_windup': 'std_msgs/msg/Float64'}, port=0)
    with pytest.raises(ConfigError, match='unknown message type'):
        FoxgloveBridge({'/x': 'no_msgs/msg/Nothing'}, port=0)
    with pytest.raises(ConfigError, match='foxglove_port'):
        FoxgloveBridge(STREAMS, port=70000)


# ------------------------------------------------------------------------------------------------
# The layout
# ------------------------------------------------------------------------------------------------

def _panel_ids(tree) -> list[str]:
    if isinstance(tree, str):
        return [tree]
    return _panel_ids(tree['first']) + _panel_ids(tree['second'])


def test_layout_is_a_foxglove_layout_of_the_node_s_topics_and_keys():
    """The layout file as Foxglove exports/imports it (configById + mosaic layout tree): every
    panel in the tree is configured, every message path names a topic the node publishes with
    the right type, and every key filter a key the monitor's messages carry."""
    from types import SimpleNamespace

    from dmf_sim.live.streams import streams_for
    from dmf_sim.monitor.alarms import AlarmReport
    from dmf_sim.monitor.messages import (
        TOPIC_CYCLE,
        TOPIC_DETECTIONS,
        TOPIC_PREDICTED,
        cycle_status,
        detection_statuses,
        monitor_status,
        prediction_statuses,
        values_of,
    )
    from dmf_sim.monitor.misfire import Detection
    from dmf_sim.monitor.prediction import OperatingPoint, PredictedState, Prediction
    from dmf_sim.node import STREAMS as NODE_STREAMS
    from dmf_sim.physics.model import read_driveline
    from dmf_sim.physics.orders import OrderSummary

    layout = json.loads(LAYOUT.read_text())
    assert set(layout) >= {'configById', 'layout', 'globalVariables', 'userNodes',
                           'playbackConfig'}
    ids = _panel_ids(layout['layout'])
    assert sorted(ids) == sorted(layout['configById'])
    kinds = {i.split('!')[0] for i in ids}
    assert kinds >= {'Plot', 'DiagnosticSummary', 'DiagnosticStatusPanel'}
    # the virtual truck's panels: the bus speeds beside the true speed, the active faults,
    # their ground truth and the crank tooth edges
    every_path = json.dumps(layout['configById'])
    for topic in ('/vehicle_bus/engine_speed', '/vehicle_bus/gearbox_input_speed',
                  '/vehicle_bus/output_shaft_speed', '/faults/active', '/faults/ground_truth',
                  '/sensors/crank/edges', '/faults/detections'):
        assert f'"{topic}' in every_path, topic

    sensors = read_driveline('truck_dmf').sensors          # the node's default sensors
    topics = {'/' + t.lstrip('/'): msgtype for t, msgtype in
              [(v[0], v[1]) for v in streams_for(sensors).values()]}
    assert set(NODE_STREAMS) < set(streams_for(sensors))
    topics['/' + TOPIC_CYCLE] = topics['/' + TOPIC_PREDICTED] = \
        'diagnostic_msgs/msg/DiagnosticArray'
    # keys the messages really carry (built by the same functions as the node)
    summ = OrderSummary(0.01, 0.002, 0.02, -0.02, 0.2, 0.0, 0.19, 0.2)
    cyc = SimpleNamespace(index=1, speed_rpm=1000.0, load=0.5, summary=summ,
                          max_windup=0.22, min_windup=0.18,
                          values=lambda: {'cycle': 1.0, 'speed_rpm': 1000.0, 'load': 0.5,
                                          'order_3_rad': 0.01, 'order_1_5_rad': 0.002,
                                          'mean_rad': 0.2, 'max_windup_rad': 0.22,
                                          'min_windup_rad': 0.18, 'max_deviation_rad': 0.02,
                                          'min_deviation_rad': -0.02,
                                          'mean_minus_theta_rad': 0.0,
                                          'theta_minus_static_rad': 0.01,
                                          'static_windup_rad': 0.19, 'cycle_duration_s': 0.12,
                                          'share_primary': 1.0, 'share_secondary': 0.0})
    pred = Prediction(OperatingPoint(1000.0, 0.5, 'A', None),
                      (PredictedState(0.01, 0.002, 0.02, -0.02, 0.2, 0.0, 0.19, 0.01),), 0.1)
    keys = {'/' + TOPIC_CYCLE: set(values_of(cycle_status('n', cyc, None, pred,
                                                          AlarmReport(0, ())))),
            '/' + TOPIC_PREDICTED: set().union(*(values_of(s) for s in
                                                 prediction_statuses('n', pred, 2.5, 0.24))),
            '/' + TOPIC_DETECTIONS: set(values_of(detection_statuses(
                'n', [Detection(1, 3, 2, 31.4, 1200.0, -0.9, True)])[0]))}
    diag_keys = {'speed_rpm', 'speed_setpoint_rpm', 'load', 'load_setpoint', 'windup_rad',
                 'lag_ms', 'lag_p99_ms', 'real_time_factor'}   # the node's health status

    paths = []
    for pid, cfg in layout['configById'].items():
        kind = pid.split('!')[0]
        if kind == 'Plot':
            assert cfg['paths'], pid
            paths += [p['value'] for p in cfg['paths']]
        elif kind in ('DiagnosticSummary', 'DiagnosticStatusPanel'):
            assert topics[cfg['topicToRender']] == 'diagnostic_msgs/msg/DiagnosticArray'
        elif kind == 'RawMessages':
            paths.append(cfg['topicPath'])
    assert len(paths) >= 8
    # the node's health status is picked by its hardware_id, the node's fully qualified name:
    # a layout variable, and the Diagnostic Status panel selects it (it
    # selected 'dmf_sim', which no status carries); `dmf-sim foxglove-layout` for other names
    assert layout['globalVariables'] == {'node': '/driveline_node'}
    published = {monitor_status('/driveline_node', AlarmReport(0, ()), None, None, {}).hardware_id,
                 cycle_status('/driveline_node', cyc, None, pred, AlarmReport(0, ())).hardware_id}
    assert published == {'/driveline_node'}
    assert layout['configById']['DiagnosticStatusPanel!dmfdiag']['selectedHardwareId'] in \
        published
    for path in paths:
        m = re.match(r'^(/[\w/]+?)(\.|$)(.*)$', path)
        assert m and m.group(1) in topics, path
        topic, rest = m.group(1), m.group(3)
        if topics[topic] == 'std_msgs/msg/Float64':
            assert rest in ('data', ''), path
        elif topics[topic] == 'diagnostic_msgs/msg/DiagnosticArray' and rest:
            km = re.fullmatch(r'status(?:\[0\]|\[:\]|\[:\]\{hardware_id==\$node\})'
                              r'\.values\[:\]\{key=="(\w+)"\}\.value', rest)
            assert km, path
            key = km.group(1)
            allowed = keys.get(topic, diag_keys)
            assert key in allowed, path


def test_layout_for_a_namespaced_node_moves_its_topics_and_selects_its_health(tmp_path, capsys):
    """The layout for /truck1/driveline_node (``dmf-sim monitor --namespace
    /truck1 --foxglove-layout FILE``)."""
    from dmf_sim.cli import main

    out = tmp_path / 'truck1.json'
    assert main(['monitor', '--namespace', '/truck1', '--foxglove-layout', str(out)]) == 0
    assert json.loads(out.read_text()) == foxglove_layout('/truck1/driveline_node')
    assert main(['monitor', '--node', '/truck1/driveline_node', '--foxglove-layout',
                 str(out)]) == 2                                 # never overwritten
    assert 'exists already' in capsys.readouterr().err
    base, layout = foxglove_layout(), foxglove_layout('/truck1/driveline_node')
    assert base == json.loads(LAYOUT.read_text())          # the shipped file is the default
    assert layout['globalVariables'] == {'node': '/truck1/driveline_node'}
    panel = layout['configById']['DiagnosticStatusPanel!dmfdiag']
    assert panel['selectedHardwareId'] == '/truck1/driveline_node'
    assert panel['topicToRender'] == '/diagnostics'                 # not namespaced
    paths = [p['value'] for cfg in layout['configById'].values() for p in cfg.get('paths', ())]
    assert all(p.startswith(('/truck1/driveline/', '/truck1/engine/', '/diagnostics.',
                             '/truck1/vehicle_bus/', '/truck1/faults/')) for p in paths), paths
    topics = {cfg.get('topicToRender') or cfg.get('topicPath')
              for cfg in layout['configById'].values()} - {None}
    assert topics == {'/diagnostics', '/truck1/driveline/dmf_predicted', '/truck1/faults/active',
                      '/truck1/faults/ground_truth', '/truck1/sensors/crank/edges',
                      '/truck1/faults/detections'}
    assert layout['configById']['RawMessages!dmfpredicted']['topicPath'] == \
        '/truck1/driveline/dmf_predicted'
    with pytest.raises(ConfigError, match='fully qualified ROS node name'):
        foxglove_layout('/truck 1/driveline_node')


def test_a_client_connecting_after_the_latched_message_gets_it():
    """The prediction (latched) was published before the client connected;
    the client gets it as soon as it subscribes, as a late transient-local DDS subscriber."""
    store = _store()
    bridge = FoxgloveBridge(STREAMS, port=0, latched=['/driveline/dmf_orders'])
    try:
        old = _diag_cdr(store, {'order_3_rad': '0.01'})
        new = _diag_cdr(store, {'order_3_rad': '0.02'})
        bridge.publish('/driveline/dmf_orders', old, 5)
        bridge.publish('/driveline/dmf_orders', new, 7)
        _, t, payload = first_message(bridge.url, '/driveline/dmf_orders')
        assert t == 7 and payload == new
        with pytest.raises(ConfigError, match='latched topics'):
            FoxgloveBridge(STREAMS, port=0, latched=['/nope'])
    finally:
        bridge.close()
