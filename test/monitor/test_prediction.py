"""Prediction at the operating point, live minus predicted, alarms and the monitoring messages'
content (dmf_sim.monitor.prediction, dmf_sim.monitor.alarms, dmf_sim.monitor.messages). No ROS but
one test, which builds the ROS message with the real classes (marker ``ros``)."""
from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
from support.monitor_cycles import cycle as _cycle

from dmf_sim.core.errors import ConfigError, ConvergenceError
from dmf_sim.monitor.alarms import ERROR, OK, WARN, AlarmSettings, evaluate
from dmf_sim.monitor.messages import cycle_status, monitor_status, prediction_statuses, values_of
from dmf_sim.monitor.prediction import (
    QUANTITIES,
    OperatingPoint,
    PredictedState,
    Prediction,
    compare,
    predict_states,
    solve_prediction,
)
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_model
from dmf_sim.physics.orders import OrderSummary
from dmf_sim.solvers.newmark import simulate


@pytest.fixture(scope='module')
def knee_loads(engine_2500):
    """alpha 3, theta 0.2 rad, Load A of the 2500 Nm engine: the 1.5th-order resonance near
    900-1070 rpm at full load, with two stable states at 960 rpm."""
    return DrivelineExcitation(read_model('truck_dmf', alpha=3.0, theta=0.2), engine_2500)


def _point(loads, speed, load=1.0):
    return OperatingPoint.rounded(speed, load, 'A', loads.model.spring, 5.0, 0.01)


@pytest.mark.parametrize('speed', [1200.0, 960.0])
def test_predicted_states_are_where_time_integration_settles(knee_loads, speed):
    """Physics: Newmark from static equilibrium runs to a periodic steady state; it must be one
    of the predicted stable states (HBM and Newmark agree within 1 %, doc/theory.md §6)."""
    pred = solve_prediction(predict_states, knee_loads, _point(knee_loads, speed))
    assert not pred.error and pred.states
    sim = simulate(knee_loads, speed, 1.0)
    assert sim.steady
    s = sim.summary
    near = min(pred.states, key=lambda st: abs(st.order_1_5 - s.order_1_5))
    assert near.order_3 == pytest.approx(s.order_3, rel=0.01)
    assert near.order_1_5 == pytest.approx(s.order_1_5, rel=0.01)
    assert near.mean == pytest.approx(s.mean, abs=1e-4)
    assert near.theta_minus_static == pytest.approx(0.2 - knee_loads.static_state(speed, 1.0)
                                                    .windup)
    if speed == 960.0:
        # inside the resonance: two distinct stable states, both with a large 1.5th order
        assert len(pred.states) >= 2 and min(st.order_1_5 for st in pred.states) > 0.01
    else:
        assert len(pred.states) == 1 and pred.states[0].order_1_5 < 0.005


def _hbm_like(order_1_5, stable=True, mean=0.2, kind='main'):
    summ = OrderSummary(order_3=0.01, order_1_5=order_1_5, max_deviation=0.02,
                        min_deviation=-0.02, mean=mean, mean_minus_theta=mean - 0.2,
                        static_windup=0.19, theta=0.2)
    return SimpleNamespace(summary=summ, stable=stable, kind=kind, branch=0, max_multiplier=0.9)


def _stub_unstable(loads, speed, load):
    return [_hbm_like(0.003, stable=False)]


def _stub_two_copies(loads, speed, load):
    """A state, its 120-deg shifted copy (same quantities), another state, an unstable one."""
    return [_hbm_like(0.012), _hbm_like(0.012), _hbm_like(0.002, mean=0.19),
            _hbm_like(0.004, stable=False)]


def _stub_fails(loads, speed, load):
    raise ConvergenceError('HBM Newton: residual 1e-4 rad after 40 iterations at 920.0 rpm')


def test_states_distinct_stable_only_and_failures_reported(knee_loads):
    pt = _point(knee_loads, 1000.0)
    two = solve_prediction(_stub_two_copies, knee_loads, pt)
    assert [s.order_1_5 for s in two.states] == [0.012, 0.002]
    none = solve_prediction(_stub_unstable, knee_loads, pt)
    assert none.states == () and none.no_stable_state and not none.error
    failed = solve_prediction(_stub_fails, knee_loads, pt)
    assert failed.error.startswith('HBM Newton') and not failed.no_stable_state


def test_operating_point_rounding_is_the_cache_key(knee_loads):
    sp = knee_loads.model.spring
    a = OperatingPoint.rounded(951.9, 0.804, 'A', sp, 5.0, 0.01)
    b = OperatingPoint.rounded(950.4, 0.796, 'A', sp, 5.0, 0.01)
    assert a == b and (a.speed_rpm, a.load) == (950.0, 0.8) and hash(a) == hash(b)
    assert a != OperatingPoint.rounded(950.0, 0.8, 'B', sp, 5.0, 0.01)
    other = read_model('truck_dmf', alpha=2.0, theta=0.2).spring
    assert a != OperatingPoint.rounded(950.0, 0.8, 'A', other, 5.0, 0.01)


def _prediction(*order_1_5, speed=950.0, load=1.0, error=''):
    pt = OperatingPoint(speed, load, 'A', None)
    states = tuple(PredictedState(0.015, a, 0.03, -0.03, 0.1985 + 0.1 * a, 0.1 * a - 0.0015,
                                  0.19, 0.01, 'main') for a in order_1_5)
    return Prediction(pt, states, 0.1, error)


def test_live_minus_predicted_uses_the_nearest_state_at_the_same_point():
    pred = _prediction(0.0178, 0.0162, 0.0012)
    comp = compare(_cycle(order_1_5=0.0163), pred, 10.0, 0.02)
    assert comp.applies and comp.state.order_1_5 == 0.0162
    assert comp.difference['order_1_5'] == pytest.approx(0.0163 - 0.0162)
    assert comp.difference["mean"] == pytest.approx(0.1989 - (0.1985 + 0.00162))
    assert set(comp.difference) == set(QUANTITIES)
    off = compare(_cycle(speed=990.0), pred, 10.0, 0.02)
    assert not off.applies and all(math.isnan(v) for v in off.difference.values())
    assert 'prediction at 950' in off.reason
    assert not compare(_cycle(load=0.9), pred, 10.0, 0.02).applies
    assert compare(_cycle(), _prediction(), 10.0, 0.02).reason == \
        'no stable periodic state predicted here'
    assert compare(_cycle(), None, 10.0, 0.02).reason == 'no prediction yet'


def test_alarms():
    st = AlarmSettings(subharmonic_alarm_rad=0.005, end_stop_rad=0.25)
    calm = evaluate(st, _cycle(order_1_5=0.001, max_dev=0.02), _prediction(0.0012))
    assert calm.level == OK and calm.alarms == () and calm.message == ''
    assert calm.flags() == {f'alarm_{k}': 0.0 for k in ('subharmonic_present',
                            'subharmonic_possible', 'end_stop', 'no_stable_state',
                            'prediction_failed')}
    present = evaluate(st, _cycle(order_1_5=0.0163, max_dev=0.02), _prediction(0.0162, 0.0012))
    assert present.level == WARN
    assert present.keys == ['subharmonic_present', 'subharmonic_possible']
    assert '0.0163 rad > 0.005 rad at 950 rpm' in present.message
    possible = evaluate(st, _cycle(order_1_5=0.0012, max_dev=0.02), _prediction(0.0012, 0.017))
    assert possible.keys == ['subharmonic_possible'] and '0.0170 rad' in possible.message
    stop = evaluate(st, _cycle(order_1_5=0.001, max_dev=0.06), None)
    assert stop.level == ERROR and stop.keys == ['end_stop'] and '0.2589 rad' in stop.message
    coast = evaluate(st, _cycle(order_1_5=0.001, mean=-0.2, min_dev=-0.06), None)
    assert coast.keys == ['end_stop']
    assert evaluate(st, None, _prediction()).keys == ['no_stable_state']
    failed = evaluate(st, None, _prediction(error='no HBM sweep converged'))
    assert failed.keys == ['prediction_failed'] and 'no HBM sweep' in failed.message
    for bad in (0.0, -1.0, math.nan):
        with pytest.raises(ConfigError, match='end_stop_rad'):
            AlarmSettings(0.005, bad)


def _cycle_message():
    """The per-cycle status of a cycle against a two-state prediction, with its inputs."""
    st = AlarmSettings(0.005, 0.25)
    pred = _prediction(0.0178, 0.0162)
    cyc = _cycle()
    comp = compare(cyc, pred, 10.0, 0.02)
    report = evaluate(st, cyc, pred)
    return cycle_status('truck1/driveline_node', cyc, comp, pred, report), cyc, pred, report


def test_messages_carry_every_quantity_by_name():
    msg, cyc, pred, report = _cycle_message()
    v = values_of(msg)
    assert msg.level == WARN and msg.name == 'truck1/driveline_node: DMF cycle orders'
    assert msg.message == report.message
    assert float(v['order_1_5_rad']) == 0.0163 and float(v['share_secondary']) == 0.4
    assert float(v['predicted_order_1_5_rad']) == 0.0162
    assert float(v['order_1_5_minus_predicted_rad']) == pytest.approx(1e-4)
    assert v['predicted_applies'] == 'true' and v['predicted_states'] == '2'
    assert v['alarm_subharmonic_present'] == '1' and v['alarm_end_stop'] == '0'
    assert v['alarms'] == 'subharmonic_present,subharmonic_possible'
    heads = prediction_statuses('n', pred, alpha=3.0, theta=0.2)
    assert len(heads) == 3 and heads[0].level == OK
    assert values_of(heads[0])['stable_states'] == '2'
    assert float(values_of(heads[2])['order_1_5_rad']) == 0.0162
    assert heads[1].name == 'n: DMF predicted state 1/2'
    none = prediction_statuses('n', _prediction(), 3.0, 0.2)
    assert len(none) == 1 and none[0].level == WARN and 'no stable periodic' in none[0].message
    diag = monitor_status('n', report, cyc, pred, {'cycles_analysed': 5})
    dv = values_of(diag)
    assert dv['cycles_analysed'] == '5' and float(dv['cycle_order_1_5_rad']) == 0.0163
    assert float(dv['predicted_max_order_1_5_rad']) == 0.0178


@pytest.mark.ros
def test_ros_message_is_built_from_the_status_data():
    import diagnostic_msgs.msg as dm
    msg = _cycle_message()[0]
    ros = msg.to_msg(dm.DiagnosticStatus, dm.KeyValue)
    assert ros.level == bytes([WARN]) and values_of(ros) == values_of(msg)
