"""DMF alarms from the live cycle analysis and the prediction (no ROS).

:func:`evaluate` returns an :class:`AlarmReport`: the overall level (diagnostic_msgs levels:
OK 0, WARN 1, ERROR 2) and the active :class:`Alarm` s, each with a stable key and a one-line
message. The node puts it in ``/diagnostics`` and in the per-cycle message
(:mod:`dmf_sim.monitor.messages`). Alarms:

===========================  ======  =========================================================
key                          level   when
===========================  ======  =========================================================
``subharmonic_present``      WARN    the last cycle's 1.5th-order wind-up amplitude exceeds
                                     ``subharmonic_alarm_rad``
``subharmonic_possible``     WARN    a predicted stable state at this operating point has a
                                     1.5th order above ``subharmonic_alarm_rad`` (a disturbance
                                     can move the DMF onto it)
``end_stop``                 ERROR   the last cycle's wind-up went beyond ``end_stop_rad``
                                     (either direction): the DMF would hit its end stop
``no_stable_state``          WARN    the prediction found no stable periodic state here
``prediction_failed``        WARN    the prediction's solver failed here
===========================  ======  =========================================================
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from dmf_sim.core.errors import ConfigError

__all__ = ['OK', 'WARN', 'ERROR', 'ALARM_KEYS', 'AlarmSettings', 'Alarm', 'AlarmReport',
           'evaluate']

OK, WARN, ERROR = 0, 1, 2          # diagnostic_msgs/DiagnosticStatus levels
ALARM_KEYS = ('subharmonic_present', 'subharmonic_possible', 'end_stop', 'no_stable_state',
              'prediction_failed')
LEVEL_NAMES = {OK: 'OK', WARN: 'WARN', ERROR: 'ERROR'}


@dataclass(frozen=True)
class AlarmSettings:
    """Thresholds [rad]: 1.5th-order amplitude that counts as a sub-harmonic state; the DMF's
    end-stop wind-up (both directions; inf = no end-stop alarm)."""

    subharmonic_alarm_rad: float
    end_stop_rad: float

    def __post_init__(self) -> None:
        for name in ('subharmonic_alarm_rad', 'end_stop_rad'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not math.isnan(v) and v > 0):
                raise ConfigError(f'{name} must be > 0 rad, got {v!r}')


@dataclass(frozen=True)
class Alarm:
    key: str
    level: int
    message: str


@dataclass(frozen=True)
class AlarmReport:
    """Overall level (max over the alarms, OK without) and the active alarms."""

    level: int
    alarms: tuple[Alarm, ...]

    @property
    def keys(self) -> list[str]:
        return [a.key for a in self.alarms]

    @property
    def message(self) -> str:
        """The alarms' messages joined by '; ' ('' without alarm)."""
        return '; '.join(a.message for a in self.alarms)

    def flags(self) -> dict[str, float]:
        """'alarm_<key>' -> 1.0 / 0.0 for every alarm key (plottable)."""
        active = set(self.keys)
        return {f'alarm_{k}': float(k in active) for k in ALARM_KEYS}


def evaluate(settings: AlarmSettings, cycle=None, prediction=None) -> AlarmReport:
    """Alarms of the last completed cycle (:class:`dmf_sim.monitor.orders.CycleResult` or None) and
    the prediction at the current operating point (:class:`dmf_sim.monitor.prediction.Prediction`
    or None)."""
    out: list[Alarm] = []
    thr = settings.subharmonic_alarm_rad
    if cycle is not None:
        a15 = cycle.summary.order_1_5
        if a15 > thr:
            out.append(Alarm('subharmonic_present', WARN,
                             f'1.5th-order sub-harmonic present: {a15:.4f} rad > {thr:g} rad at '
                             f'{cycle.speed_rpm:.0f} rpm'))
        stop = settings.end_stop_rad
        if cycle.max_windup > stop or cycle.min_windup < -stop:
            w = cycle.max_windup if cycle.max_windup > stop else cycle.min_windup
            out.append(Alarm('end_stop', ERROR,
                             f'wind-up {w:.4f} rad beyond the end stop +-{stop:g} rad'))
    if prediction is not None:
        pt = prediction.point
        where = f'{pt.speed_rpm:g} rpm, load {pt.load:g}'
        if prediction.error:
            out.append(Alarm('prediction_failed', WARN,
                             f'prediction failed at {where}: {prediction.error}'))
        elif not prediction.states:
            out.append(Alarm('no_stable_state', WARN,
                             f'no stable periodic state predicted at {where}'))
        else:
            peak = max(s.order_1_5 for s in prediction.states)
            if peak > thr:
                out.append(Alarm('subharmonic_possible', WARN,
                                 f'1.5th-order state possible at {where}: predicted stable '
                                 f'state with {peak:.4f} rad > {thr:g} rad '
                                 f'({len(prediction.states)} stable state(s))'))
    level = max((a.level for a in out), default=OK)
    return AlarmReport(level, tuple(out))
