"""What the DMF monitoring topics carry, without ROS: names -> values, ready for a message.

Message type: ``diagnostic_msgs/DiagnosticArray`` for all three (a standard type, so the package
needs no generated interfaces). Each quantity is one ``KeyValue`` (key with its unit suffix,
value as text), because that is what every tool reads by name:

* ``ros2 topic echo`` prints ``key: order_3_rad`` / ``value: '0.0123'`` pairs;
* PlotJuggler's built-in DiagnosticArray parser turns every numeric value into a series
  ``<topic>/<hardware_id>/<status name>/<key>``;
* Foxglove's Plot panel takes ``<topic>.status[0].values[:]{key=="order_3_rad"}.value`` (numeric
  strings are plotted as numbers), its Diagnostics panels show the status level and message.

(``sensor_msgs/JointState`` name/position pairs would keep float64 values, but its parallel
arrays are not addressable by name in Foxglove and print as two unrelated lists in
``topic echo``; one ``Float64`` topic per quantity loses the grouping per cycle.)

Topics (relative to the node's namespace):

* :data:`TOPIC_CYCLE` — per completed engine cycle: :func:`cycle_status` (live orders, region
  shares, cycle speed/load, predicted state and live minus predicted, alarm level/message/flags).
* :data:`TOPIC_PREDICTED` — when the prediction at the setpoint changes (latched:
  transient-local, depth 1): :func:`prediction_statuses` (a summary status, then one status per
  stable state).
* ``/diagnostics`` — one more status, :func:`monitor_status` (alarms, last cycle, prediction).
* :data:`TOPIC_DETECTIONS` — per engine cycle, with the tooth wheels around the DMF on:
  :func:`detection_statuses` (one status per firing interval the live misfire detector scored,
  :mod:`dmf_sim.monitor.misfire`; WARN for an alarm).

The node converts a :class:`StatusData` with :meth:`StatusData.to_msg` (given the message
classes) and stamps the array; clients read values back with :func:`values_of`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from dmf_sim.monitor.alarms import LEVEL_NAMES, OK, WARN, AlarmReport
from dmf_sim.monitor.prediction import QUANTITIES, Comparison, Prediction

__all__ = ['TOPIC_CYCLE', 'TOPIC_PREDICTED', 'TOPIC_DETECTIONS', 'HARDWARE_ID', 'StatusData',
           'format_value', 'cycle_status', 'prediction_statuses', 'monitor_status',
           'detection_statuses', 'values_of']

TOPIC_CYCLE = 'driveline/dmf_orders'
TOPIC_PREDICTED = 'driveline/dmf_predicted'
TOPIC_DETECTIONS = 'faults/detections'
HARDWARE_ID = 'dmf_sim'
CYCLE_NAME = 'DMF cycle orders'
PREDICTION_NAME = 'DMF prediction'
STATE_NAME = 'DMF predicted state'
MONITOR_NAME = 'DMF monitor'
DETECTOR_NAME = 'misfire detector'


def format_value(v) -> str:
    """A value as KeyValue text: floats with 9 significant digits ('nan', 'inf' as such)."""
    if isinstance(v, bool):
        return 'true' if v else 'false'
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return repr(v) if not math.isfinite(v) else f'{v:.9g}'
    return str(v)


@dataclass(frozen=True)
class StatusData:
    """One diagnostic_msgs/DiagnosticStatus without ROS: level (0 OK, 1 WARN, 2 ERROR), name,
    message, hardware_id (the node's fully qualified name: two trucks stay apart) and the
    (key, value text) pairs."""

    level: int
    name: str
    message: str
    values: tuple[tuple[str, str], ...]
    hardware_id: str = HARDWARE_ID

    def to_msg(self, status_cls, key_value_cls):
        """The DiagnosticStatus message (pass ``DiagnosticStatus`` and ``KeyValue``)."""
        return status_cls(level=bytes([self.level]), name=self.name, message=self.message,
                          hardware_id=self.hardware_id,
                          values=[key_value_cls(key=k, value=v) for k, v in self.values])

    def as_dict(self) -> dict[str, str]:
        return dict(self.values)


def _pairs(d: dict) -> tuple[tuple[str, str], ...]:
    return tuple((k, format_value(v)) for k, v in d.items())


def _prediction_values(comparison: Comparison | None, prediction: Prediction | None) -> dict:
    out: dict = {'predicted_states': len(prediction.states) if prediction else 0,
                 'predicted_applies': bool(comparison and comparison.applies)}
    state = comparison.state if comparison is not None else None
    for q in QUANTITIES:
        out[f'predicted_{q}_rad'] = getattr(state, q) if state is not None else math.nan
    for q in QUANTITIES:
        out[f'{q}_minus_predicted_rad'] = (comparison.difference[q] if comparison is not None
                                           else math.nan)
    return out


def cycle_status(node: str, cycle, comparison: Comparison | None,
                 prediction: Prediction | None, report: AlarmReport) -> StatusData:
    """The per-cycle status: the cycle's values (:meth:`CycleResult.values`), the nearest
    predicted state and live minus predicted, the alarms (level, message, ``alarm_*`` flags)."""
    values = dict(cycle.values())
    values.update(_prediction_values(comparison, prediction))
    values.update(report.flags())
    values['alarms'] = ','.join(report.keys)
    s = cycle.summary
    text = report.message or (f'cycle {cycle.index}: 3rd order {s.order_3:.4f} rad, 1.5th order '
                              f'{s.order_1_5:.4f} rad at {cycle.speed_rpm:.0f} rpm')
    return StatusData(report.level, f'{node}: {CYCLE_NAME}', text, _pairs(values), node)


def prediction_statuses(node: str, prediction: Prediction, alpha: float,
                        theta: float) -> list[StatusData]:
    """The prediction message: a summary status (operating point, number of stable states,
    solver time, error), then one status per stable state (its Fig. 13 quantities, kind)."""
    pt = prediction.point
    n = len(prediction.states)
    head = {'speed_rpm': pt.speed_rpm, 'load': pt.load, 'load_set': pt.load_set,
            'alpha': float(alpha), 'theta_rad': float(theta), 'stable_states': n,
            'seconds': prediction.seconds, 'error': prediction.error}
    where = f'{pt.speed_rpm:g} rpm, load {pt.load:g}, Load {pt.load_set}'
    if prediction.error:
        level, text = WARN, f'prediction failed at {where}: {prediction.error}'
    elif n == 0:
        level, text = WARN, f'no stable periodic state predicted at {where}'
    else:
        level, text = OK, f'{n} stable state(s) at {where}'
    out = [StatusData(level, f'{node}: {PREDICTION_NAME}', text, _pairs(head), node)]
    for i, st in enumerate(prediction.states, 1):
        vals = {f'{q}_rad': getattr(st, q) for q in QUANTITIES}
        vals.update({'static_windup_rad': st.static_windup,
                     'theta_minus_static_rad': st.theta_minus_static,
                     'max_windup_rad': st.max_windup, 'min_windup_rad': st.min_windup,
                     'kind': st.kind, 'branch': st.branch, 'max_multiplier': st.max_multiplier,
                     'speed_rpm': pt.speed_rpm, 'load': pt.load})
        out.append(StatusData(OK, f'{node}: {STATE_NAME} {i}/{n}',
                              f'{st.kind or "state"}: 3rd order {st.order_3:.4f} rad, 1.5th '
                              f'order {st.order_1_5:.4f} rad', _pairs(vals), node))
    return out


def monitor_status(node: str, report: AlarmReport, cycle, prediction: Prediction | None,
                   counters: dict) -> StatusData:
    """The status the node adds to ``/diagnostics``: alarm level and messages, the last cycle's
    main quantities, the prediction's summary and the monitor's counters."""
    values: dict = {}
    if cycle is not None:
        v = cycle.values()
        for k in ('cycle', 'speed_rpm', 'load', 'order_3_rad', 'order_1_5_rad', 'mean_rad',
                  'max_windup_rad', 'min_windup_rad', 'theta_minus_static_rad'):
            values[f'cycle_{k}' if not k.startswith('cycle') else k] = v[k]
        values.update({k: s for k, s in v.items() if k.startswith('share_')})
    if prediction is not None:
        values.update({'predicted_speed_rpm': prediction.point.speed_rpm,
                       'predicted_load': prediction.point.load,
                       'predicted_states': len(prediction.states),
                       'predicted_max_order_1_5_rad': max(
                           (s.order_1_5 for s in prediction.states), default=math.nan),
                       'prediction_error': prediction.error})
    values.update(counters)
    values.update(report.flags())
    values['alarms'] = ','.join(report.keys)
    text = report.message or (f'no alarm ({LEVEL_NAMES[OK]})' if cycle is not None
                              else 'waiting for the first engine cycle')
    return StatusData(report.level, f'{node}: {MONITOR_NAME}', text, _pairs(values), node)


def detection_statuses(node: str, detections) -> list[StatusData]:
    """The live misfire detector's message: one status per scored firing interval
    (:class:`dmf_sim.monitor.misfire.Detection`), in crank-angle order; WARN and 'misfire
    cylinder N' for an alarm; ``speed_rpm`` the segment's crank speed and
    ``windup_sensors_rad`` the interval's mean DMF wind-up, both from the tooth edges.
    ``tdc_crank_angle_rad`` is the crank angle of the interval's TDC, as the ground truth
    (``faults/ground_truth``) gives a misfire's."""
    out = []
    for d in detections:
        vals = {'cylinder': d.cylinder, 'combustion': d.combustion,
                'tdc_crank_angle_rad': d.tdc_crank_angle_rad, 'tdc_time_s': d.t_ns * 1e-9,
                'speed_rpm': d.speed_rpm, 'score': d.score, 'alarm': d.alarm,
                'windup_sensors_rad': d.windup_rad}
        text = (f'misfire cylinder {d.cylinder}' if d.alarm
                else f'cylinder {d.cylinder}: no misfire')
        out.append(StatusData(WARN if d.alarm else OK, f'{node}: {DETECTOR_NAME}',
                              f'{text} (score {d.score:.2f})', _pairs(vals), node))
    return out


def values_of(status) -> dict[str, str]:
    """key -> value text of a DiagnosticStatus message (or a :class:`StatusData`)."""
    if isinstance(status, StatusData):
        return status.as_dict()
    return {kv.key: kv.value for kv in status.values}
