"""The parameters of ``driveline_node`` (names, defaults, ranges, descriptions), without ROS.

The node declares each with a ``ParameterDescriptor`` built from :data:`PARAMETERS` (and
:data:`DMF_PARAMETERS`, whose defaults come from the driveline YAML); ``config/
driveline_node.yaml`` lists the same values. Read-only parameters are fixed at start-up.

Run-time changes go through three steps, as in ros2/demos' ``set_parameters_callback``:
:func:`coerce` (pre-set: an integer given for a floating-point parameter, as ``ros2 param set
/driveline_node speed_ramp_rpm_per_s 1000`` sends it, becomes a float), then validation and then
application (:class:`dmf_sim.live.runtime.LiveRuntime` ``check`` / ``apply``).
"""
from __future__ import annotations

from typing import Any, NamedTuple

from dmf_sim.live.faults import FAULT_PARAMETERS
from dmf_sim.live.foxglove_bridge import FOXGLOVE_PARAMETERS
from dmf_sim.live.pacing import OVERRUN_POLICIES
from dmf_sim.live.run_loop import PACING_MODES
from dmf_sim.monitor.worker import MONITOR_PARAMETERS
from dmf_sim.physics.engine import LOAD_LIMITS
from dmf_sim.physics.spring import STAGE_ANGLE_MAX_RAD, STIFFNESS_FACTOR_MAX

__all__ = ['ParameterSpec', 'PARAMETERS', 'MONITOR_SETTINGS', 'DMF_PARAMETERS', 'FLOAT_PARAMETERS',
           'coerce', 'choice_reason']


class ParameterSpec(NamedTuple):
    """default (its type is the parameter's type), description, (lo, hi) range or None,
    read-only (fixed after start-up)."""

    default: Any
    description: str
    range: tuple[float, float] | None = None
    read_only: bool = False


PARAMETERS: dict[str, ParameterSpec] = {
    'driveline': ParameterSpec('truck_dmf', 'Driveline YAML: a name in config/ or a path',
                               None, True),
    'engine': ParameterSpec('engine_d13', 'Engine excitation: engine YAML or coefficient table '
                            '(name or path)', None, True),
    'load_set': ParameterSpec('A', "Engine load set: 'A', 'B' or 'C' (B/C shift the low-speed "
                              'pressure data)'),
    'dt': ParameterSpec(1e-4, 'Newmark time step [s]', (1e-6, 1e-2), True),
    'initial_speed_rpm': ParameterSpec(1000.0, 'Engine speed at start [rpm]', (100.0, 5000.0),
                                       True),
    'initial_load': ParameterSpec(0.5, 'Torque demand at start: 1 full load, 0 none, -1 the '
                                  "engine's full brake (an engine with a brake curve; else "
                                  '0..1)', LOAD_LIMITS, True),
    'speed_min_rpm': ParameterSpec(500.0, 'Lowest accepted speed setpoint [rpm] (within the '
                                   'engine data)', (100.0, 5000.0)),
    'speed_max_rpm': ParameterSpec(2200.0, 'Highest accepted speed setpoint [rpm] (within the '
                                   'engine data)', (100.0, 5000.0)),
    'speed_ramp_rpm_per_s': ParameterSpec(500.0, 'Speed setpoint ramp rate [rpm/s]', (1.0, 1e5)),
    'load_ramp_per_s': ParameterSpec(1.0, 'Load setpoint ramp rate [1/s] (1.0 = 0 to full load '
                                     'in 1 s; 10 = a tip-in 0 -> 1 in 0.1 s)', (1e-3, 1e3)),
    'real_time_factor': ParameterSpec(1.0, 'Simulated seconds per wall second; 0 = as fast as '
                                      'possible', (0.0, 100.0)),
    'pacing': ParameterSpec('realtime', "'realtime' (locked to the wall clock x "
                            "real_time_factor) or 'fast'"),
    'publish_rate': ParameterSpec(1000.0, 'Samples per simulated second on every stream [Hz]; '
                                  '1/(rate*dt) must be a whole number of steps', (0.1, 1e6)),
    'max_lag': ParameterSpec(0.05, 'Lag (wall minus simulated time) [s] above which an overrun '
                             'is counted', (1e-3, 60.0)),
    'overrun_policy': ParameterSpec('skip', "On an overrun: 'skip' (skip ahead: drop the "
                                    'backlog, stamps jump to the wall clock, the physics '
                                    "continues) or 'catch_up' (integrate the backlog, at most "
                                    'max_lag of it per tick)'),
    'publish_clock': ParameterSpec(False, 'Publish /clock also at real_time_factor 1 (always in '
                                   'fast mode or at another factor)'),
    'diagnostics_rate': ParameterSpec(1.0, '/diagnostics rate [Hz of wall time]', (0.1, 100.0)),
    'record': ParameterSpec(False, 'Record the published streams to an MCAP bag (rosbag2 '
                            'layout)'),
    'bag_path': ParameterSpec('', "Bag directory to create; '' = dmf_bag_<YYYYmmdd_HHMMSS> in "
                              'the working directory. An existing path is never overwritten; '
                              'missing parents are created. Set while recording: applies to '
                              'the next recording'),
    'profile': ParameterSpec('', "Speed/load profile to follow from now on: a CSV/YAML file "
                             '(time_s, speed_rpm, load), a packaged name (truck_road_cycle) or '
                             "ramp:FROM:TO:RATE[:LOAD[:SETTLE]]; '' = none. Overrides the "
                             'setpoint topics while it runs; the last row holds after it'),
    'sensors': ParameterSpec(True, 'Publish (and record) the driveline\'s sensors: tooth-wheel '
                             'edge batches on sensors/<wheel>/edges, bus speeds on '
                             'vehicle_bus/<signal> (the driveline YAML\'s sensors section); '
                             'false: none, at no cost', None, True),
    'bag_max_duration_s': ParameterSpec(60.0, 'Split recordings into MCAP files of this many '
                                        'seconds (as ros2 bag record --max-bag-duration); '
                                        'applies to the next recording', (1.0, 86400.0)),
}
# The monitor's and the Foxglove server's parameters, defined beside what they configure
# (dmf_sim.monitor.worker, dmf_sim.live.foxglove_bridge); which of them are fixed at start-up:
_FIXED = ('monitor', 'monitor_worker', 'foxglove_port', 'foxglove_host')
PARAMETERS.update({name: ParameterSpec(default, text, rng, name in _FIXED)
                   for name, (default, text, rng) in {**MONITOR_PARAMETERS,
                                                      **FOXGLOVE_PARAMETERS}.items()})
MONITOR_SETTINGS = tuple(n for n in MONITOR_PARAMETERS if n != 'monitor')
# one string parameter per fault kind (dmf_sim.live.faults): the faults it holds, '' = none
PARAMETERS.update({name: ParameterSpec('', text) for name, (_, text) in FAULT_PARAMETERS.items()})

DMF_PARAMETERS: dict[str, ParameterSpec] = {   # default: from the driveline YAML
    'alpha': ParameterSpec(None, 'DMF secondary stiffness factor: secondary stiffness '
                           'k(1+alpha) (default: driveline YAML)', (0.0, STIFFNESS_FACTOR_MAX)),
    'theta': ParameterSpec(None, 'DMF stiffness change angle [rad] (default: driveline YAML)',
                           (0.0, STAGE_ANGLE_MAX_RAD)),
}
FLOAT_PARAMETERS = frozenset([name for name, s in PARAMETERS.items()
                              if isinstance(s.default, float)] + list(DMF_PARAMETERS))


def coerce(name: str, value):
    """The value to set for ``name``: integers become floats for floating-point parameters
    (bools stay bools, so a wrong type is still refused by its type check)."""
    if name in FLOAT_PARAMETERS and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


def choice_reason(name: str, value) -> str | None:
    """Why ``value`` is not allowed for a parameter with a fixed set of choices, or None."""
    allowed = {'pacing': PACING_MODES, 'overrun_policy': OVERRUN_POLICIES}.get(name)
    if allowed is not None and value not in allowed:
        return f'{name} must be one of {allowed}, got {value!r}'
    return None
