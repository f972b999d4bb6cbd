"""``driveline_node --help`` is built from the node's tables (streams, subscriptions, services,
parameters), not from the prose of its module docstring."""
from __future__ import annotations

import pytest

from dmf_sim import node
from dmf_sim.live.parameters import DMF_PARAMETERS, PARAMETERS
from dmf_sim.live.streams import (
    CLOCK,
    PUBLISHED,
    SENSOR_STREAMS,
    SERVICES,
    STREAMS,
    SUBSCRIPTIONS,
)


def _line_of(text: str, topic: str) -> str:
    return next(line for line in text.splitlines() if f' {topic} ' in line)


@pytest.mark.parametrize('key', sorted(STREAMS))
def test_every_published_stream_is_in_the_usage_with_its_type_and_qos(key):
    st = STREAMS[key]
    line = _line_of(node.usage(), st.topic)
    assert line.split()[:3] == ['pub', st.topic, st.msgtype]
    assert f'depth {st.depth}' in line and ('latched' in line) == st.latched
    assert st.what and PUBLISHED[st.per]


@pytest.mark.parametrize('key', sorted(SENSOR_STREAMS))
def test_the_sensor_streams_are_in_the_usage_with_a_placeholder_name(key):
    st = SENSOR_STREAMS[key]
    assert '<' in st.topic
    line = _line_of(node.usage(), st.topic)
    assert line.split()[:3] == ['pub', st.topic, st.msgtype] and f'depth {st.depth}' in line
    assert st.what and PUBLISHED[st.per]


def test_subscriptions_services_clock_and_parameters_are_in_the_usage():
    text = node.usage()
    for su in SUBSCRIPTIONS.values():
        assert _line_of(text, su.topic).split() == ['sub', su.topic, su.msgtype, 'keep', 'all']
    assert _line_of(text, CLOCK.topic).split()[:3] == ['pub', '/clock', CLOCK.msgtype]
    for sv in SERVICES.values():
        assert sv.name in text and sv.srvtype in text
    words = set(text.replace(',', ' ').split())
    assert set(PARAMETERS) | set(DMF_PARAMETERS) <= words
    assert all(len(line) <= 99 for line in text.splitlines())
    assert all(line in text for line in node.INVOCATIONS)


def test_the_usage_does_not_read_the_module_docstring(monkeypatch):
    before = node.usage()
    monkeypatch.setattr(node, '__doc__', 'prose only')
    assert node.usage() == before


def test_the_live_detector_stream_is_in_the_usage_and_declared_with_tooth_wheels():
    from dmf_sim.live.streams import DETECTIONS, streams_for
    from dmf_sim.physics.model import read_driveline

    line = _line_of(node.usage(), DETECTIONS.topic)
    assert line.split()[:3] == ['pub', DETECTIONS.topic, DETECTIONS.msgtype]
    assert streams_for(read_driveline().sensors)['misfire_detections'] == DETECTIONS
    assert 'misfire_detections' not in streams_for(None)
