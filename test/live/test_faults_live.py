"""Faults in the live node's ROS-free core: requests by topic, parameter and service, validated
and applied between ticks; a bad request refused with its reason and counted while the node
keeps running; the ground truth and the active set published (ROS over DDS: test_faults_dds.py)."""
from __future__ import annotations

import pytest
from support.live_core import ListLog, StatusSink

from dmf_sim.core.errors import ConfigError
from dmf_sim.live.faults import FAULT_PARAMETERS
from dmf_sim.live.parameters import DMF_PARAMETERS, PARAMETERS
from dmf_sim.live.runtime import LiveRuntime, read_line
from dmf_sim.live.streams import STREAMS, resolved_topics
from dmf_sim.monitor.messages import values_of

NODE = '/driveline_node'


def make(**over):
    values = {name: spec.default for name, spec in PARAMETERS.items()}
    values.update(alpha=2.5, theta=0.24, monitor=False, pacing='fast', initial_speed_rpm=1200.0,
                  initial_load=1.0)
    values.update(over)
    topics = resolved_topics('')
    log, sink = ListLog(), StatusSink()
    rt = LiveRuntime(values, read_line(values['driveline']), sink, log,
                     topics={topics[k]: s.msgtype for k, s in STREAMS.items()}, node_name=NODE)
    rt.loop.start()
    return rt, sink, log


def run_for(rt, seconds: float) -> None:
    end = rt.sim.t + seconds
    while rt.sim.t < end:
        with rt.lock:
            rt.loop.tick(rt.loop.clock())


def test_parameters_in_the_table_and_the_params_file():
    for name in FAULT_PARAMETERS:
        assert PARAMETERS[name].default == '' and PARAMETERS[name].description
    assert not set(FAULT_PARAMETERS) & set(DMF_PARAMETERS)
    assert STREAMS['fault_ground_truth'].latched and STREAMS['fault_ground_truth'].depth == 100
    assert STREAMS['fault_active'].latched and STREAMS['fault_active'].depth == 1


def test_topic_request_single_misfire_ground_truth_and_active(monkeypatch):
    # one 1 ms chunk per tick, however fast the machine: the active set is published per tick,
    # and a tick spanning the whole fault (start, misfire, end) would never show it active
    monkeypatch.setattr('dmf_sim.live.run_loop.FAST_BUDGET_S', 0.0)
    rt, sink, log = make()
    run_for(rt, 0.01)
    # the first tick publishes the (empty) active set: a late joiner learns "none"
    assert sink.statuses['fault_active'][0][1] == []
    assert rt.faults.offer('{kind: misfire, cylinders: [3]}') is None
    run_for(rt, 0.3)
    events = sink.events()
    assert [e['what'] for e in events] == ['start', 'misfire', 'end']
    assert events[1]['cylinder'] == 3 and events[0]['id'] == 1
    assert events[0]['start_ns'] == events[0]['event_ns'] and events[2]['end_ns'] is not None
    actives = [[values_of(s)['id'] for s in st] for _, st in sink.statuses['fault_active']]
    assert actives[0] == [] and ['1'] in actives and actives[-1] == []
    assert rt.faults.received == 1 and rt.faults.refused == 0


@pytest.mark.parametrize('request_text,words', [
    ('{kind: misfire, cylinders: [7]}', ["'cylinders[0]'", '1..6']),
    ('{kind: dmf_stiffness, stage: 4, factor: 0.5}', ["'stage'", 'does not exist']),
    ('{kind: weak_cylinder, cylinder: 2, factor: .nan}', ["'factor'"]),
    ('{kind: misfire, cylinders: [1], mode: every_cycle, start_s: 5, end_s: 4}', ["'end_s'"]),
    ('{kind: misfire, cylinders: [1], when: now}', ["unknown key 'when'"]),
    ('not yaml: [', ['invalid YAML']),
    ('', ['empty request']),
])
def test_bad_topic_request_refused_node_keeps_running(request_text, words):
    rt, sink, log = make()
    run_for(rt, 0.01)
    steps = rt.sim.steps
    reason = rt.faults.offer(request_text)
    assert reason and all(w in reason for w in words), reason
    assert reason.startswith('faults/inject')
    run_for(rt, 0.05)
    assert rt.sim.steps > steps                             # still running
    assert rt.faults.refused == 1 and any('refused' in m for lv, m in log.lines
                                          if lv == 'warning')
    report = rt.health.report(rt.loop.clock())
    assert report.values['fault_requests_refused'] == '1'
    assert 'fault request(s) refused' in report.message and report.level >= 1
    assert 'fault_ground_truth' not in sink.statuses


def test_parameter_every_cycle_then_cleared_and_overlap_refused():
    rt, sink, log = make()
    run_for(rt, 0.01)
    value = '{cylinders: [2], mode: every_cycle}'
    assert rt.check({'fault_misfire': value}) is None
    rt.apply({'fault_misfire': value})
    run_for(rt, 0.35)
    events = sink.events()
    assert [e['what'] for e in events][:1] == ['start']
    assert sum(e['what'] == 'misfire' for e in events) >= 3
    # a topic request on the same cylinder overlaps: refused at the tick, counted
    assert rt.faults.offer('{kind: misfire, cylinders: [2]}') is None   # parsed fine ...
    run_for(rt, 0.01)
    assert rt.faults.refused == 1 and 'overlaps' in rt.faults.last_refused  # ... refused here
    # a bad parameter value: refused with its reason, the fault stays
    reason = rt.check({'fault_misfire': '{cylinders: [0], mode: every_cycle}'})
    assert "'cylinders[0]'" in reason
    assert reason.startswith('fault_misfire')
    assert rt.check({'fault_misfire': '{kind: dmf_damping, factor: 2}'})   # another kind
    # setting it again (the same cylinder) replaces, does not overlap itself
    assert rt.check({'fault_misfire': '{cylinders: [2], mode: every_cycle}'}) is None
    rt.apply({'fault_misfire': ''})
    run_for(rt, 0.2)
    events = sink.events()
    assert events[-1]['what'] in ('end', 'misfire')
    assert [e['what'] for e in events if e['what'] != 'misfire'] == ['start', 'end']
    assert not rt.faults.timeline.active()
    assert rt.sim.integ.factors is None                    # every cylinder fires again


@pytest.mark.parametrize('how', ['parameter', 'clear_service'])
def test_a_dmf_fault_ended_between_ticks_restores_the_spring_at_the_next(how):
    # nothing else on the timeline: the next chunk takes the fault-free path, which must still
    # apply a DMF change made between ticks
    rt, sink, log = make()
    run_for(rt, 0.01)
    k = rt.sim.model.spring.k
    rt.apply({'fault_dmf': '{kind: dmf_stiffness, stage: 1, factor: 0.5}'})
    run_for(rt, 0.01)
    assert rt.sim.model.spring.k == 0.5 * k
    if how == 'parameter':
        rt.apply({'fault_dmf': ''})
    else:
        rt.clear_faults()
    assert rt.faults.timeline.idle
    run_for(rt, 0.001)
    assert rt.sim.model.spring.k == k


def test_dmf_parameter_rebuilds_and_clear_service_ends_all():
    rt, sink, log = make()
    run_for(rt, 0.01)
    k = rt.sim.model.spring.k
    assert rt.check({'fault_dmf': '{kind: dmf_stiffness, stage: 1, factor: 0.5}'}) is None
    rt.apply({'fault_dmf': '{kind: dmf_stiffness, stage: 1, factor: 0.5}'})
    rt.faults.offer('{kind: weak_cylinder, cylinder: 4, factor: 0.5}')
    run_for(rt, 0.05)
    assert rt.sim.model.spring.k == 0.5 * k and rt.sim.line.spring.k == k
    assert len(rt.faults.timeline.active()) == 2
    # alpha changes keep the DMF fault applied
    assert rt.check({'alpha': 3.0}) is None
    rt.apply({'alpha': 3.0})
    assert rt.sim.model.spring.k == 0.5 * k and rt.sim.line.spring.alpha == 3.0
    msg = rt.clear_faults()
    assert msg.startswith('cleared faults')
    run_for(rt, 0.2)
    assert rt.sim.model.spring.k == k and not rt.faults.timeline.active()
    assert rt.values['fault_dmf'] == ''
    ends = [e for e in sink.events() if e['what'] == 'end']
    assert len(ends) == 2
    assert sink.statuses['fault_active'][-1][1] == []


def test_bad_start_up_fault_parameter_is_a_config_error():
    with pytest.raises(ConfigError, match="parameter fault_weak_cylinder.*'cylinder'"):
        make(fault_weak_cylinder='{cylinder: 9, factor: 0.5}')
    rt, sink, _ = make(fault_weak_cylinder='{cylinder: 3, factor: 0.5}')
    run_for(rt, 0.2)
    assert rt.sim.integ.factors is not None and rt.sim.integ.factors[2] == 0.5


def test_table_engine_refuses_combustion_faults_live():
    rt, sink, log = make(engine='engine_table_example.csv', speed_min_rpm=600.0,
                         speed_max_rpm=2000.0)
    run_for(rt, 0.01)
    rt.faults.offer('{kind: misfire, cylinders: [1]}')
    run_for(rt, 0.02)
    assert rt.faults.refused == 1 and 'pressure-model engine' in rt.faults.last_refused
    assert 'pressure-model engine' in rt.check({'fault_misfire': '{cylinders: [1]}'})
    # a DMF fault works with any engine
    assert rt.faults.offer('{kind: dmf_damping, factor: 2}') is None
    run_for(rt, 0.02)
    assert len(rt.faults.timeline.active()) == 1


def test_request_id_applies_a_request_once():
    """A sender repeats a request until it is acknowledged (dmf-sim fault): the node applies
    each request id once."""
    rt, sink, log = make()
    run_for(rt, 0.01)
    for _ in range(3):
        assert rt.faults.offer('{kind: misfire, cylinders: [4], request_id: abc-1}') is None
    assert rt.faults.offer('[{kind: misfire, cylinders: [5], request_id: abc-2}]') is None
    run_for(rt, 0.3)
    mis = [e for e in sink.events() if e['what'] == 'misfire']
    assert sorted(e['cylinder'] for e in mis) == [4, 5]
    assert rt.faults.received == 2 and rt.faults.repeated == 2
    # the id is not part of the fault
    assert 'request_id' not in [e for e in sink.events()][0]['fault'].text()
