"""Faults of the virtual truck: their description, validation, schedule and ground truth.

One grammar for every way a fault comes in: a schedule file (``faults: [...]``, beside a
profile in ``dmf-sim run --faults FILE``), the node's string parameters and its
``faults/inject`` topic. A fault is a mapping; the live forms are the same mapping in YAML flow
style, e.g. ``{kind: misfire, cylinders: [3], mode: single}`` or ``{kind: weak_cylinder,
cylinder: 5, factor: 0.7}``.

========================  ======================================================================
kind                      fields (besides the window ``start_s``, ``end_s`` or ``duration_s``)
========================  ======================================================================
``misfire``               ``cylinders`` (1-based list), ``mode`` single (default) | every_cycle |
                          random; random: ``probability`` (per combustion) or ``rate_per_s``,
                          ``seed``; single: ``at_s`` (or ``start_s``), no end
``weak_cylinder``         ``cylinder``, ``factor`` in [0, 1): the combustion torque scaled
``dmf_stiffness``         ``stage`` (1 = the primary stiffness k, 2.. = the drive stages beyond
                          the knees, ``coast_1``.. the coast stages), ``factor`` in (0, 1]
``dmf_broken``            ``stage`` (>= 2 or ``coast_j``): the stage's stiffness increment gone
``dmf_damping``           ``factor`` in [0, 100]: the DMF damping scaled
``sensor_edges``          ``sensor`` (a tooth wheel), ``mode`` missing | extra; missing:
                          ``probability`` (per edge) or ``tooth`` (that tooth every revolution);
                          extra: ``rate_per_s``; ``seed``
``bus_signal``            ``signal`` (a bus signal), ``mode`` stuck | noisy; noisy: ``sigma_rpm``;
                          ``seed``
========================  ======================================================================

Times are simulated seconds. ``start_s`` absent: from the start of a run (schedule) or from now
(live); ``end_s``/``duration_s`` absent: to the end of the run or until cleared. Every refusal
is one line naming the fault (``faults[2] (misfire)``) and the field: unknown keys, NaN, a
cylinder outside 1..n_cyl, a stage the DMF does not have, an unknown sensor or bus signal (when
the caller names the known ones), an inverted window, and windows of the same kind on the same
target that overlap (``misfire`` on one cylinder, ``dmf_stiffness``/``dmf_broken`` on one stage,
...). Two single misfires never overlap: each takes the next combustion not taken yet.

What a fault does:

* combustion (doc/theory.md, "Faults"): cylinder k fires with a combustion factor s_k (1
  healthy, 0 misfire, ``factor`` of a weak cylinder); s_k changes only where fired and motored
  torques agree, at the cylinder's bottom dead centre before its compression stroke: combustion
  m of cylinder k owns the crank-angle window [TDC_km - 180 deg, TDC_km + 540 deg) with TDC_km =
  beta_k + 720 deg m. Its factor is decided when its window opens; a single misfire therefore
  removes exactly one combustion. :meth:`FaultSet.combustion_factors` gives the persistent part
  (every-cycle misfires and weak cylinders), what a periodic steady state sees;
* the DMF: :meth:`FaultSet.apply_to_driveline` returns the driveline with the spring's stages
  changed (the one spring object, :class:`~dmf_sim.physics.spring.PiecewiseLinearSpring`) and the
  DMF damping scaled;
* sensors: parsed and validated here, applied by the sensor signal synthesis
  (:attr:`FaultTimeline.sensor_faults`).

:class:`FaultTimeline` is the ground truth: which faults are active at which time, which
combustion events misfired (random ones reproducible from the seed), every start and end as a
:class:`FaultEvent` (the key/value layout of the ``faults/ground_truth`` statuses is
:meth:`FaultEvent.values`, read back with :func:`event_from_values`).

The package's modules, one concept each: :mod:`~dmf_sim.physics.faults.fault` (the description
and a set of faults), :mod:`~dmf_sim.physics.faults.parse` (the grammar, its validation and
schedule files), :mod:`~dmf_sim.physics.faults.combustion` (combustion windows and factors),
:mod:`~dmf_sim.physics.faults.dmf` (what DMF faults do to the spring) and
:mod:`~dmf_sim.physics.faults.timeline` (the ground truth). Import the names from here.
"""
from dmf_sim.physics.faults.combustion import CYCLE_RAD, WINDOW_OPEN_RAD, combustion_windows
from dmf_sim.physics.faults.dmf import DMF_DAMPING_FACTOR_MAX
from dmf_sim.physics.faults.fault import (
    BUS_MODES,
    COMBUSTION_KINDS,
    DMF_KINDS,
    EDGE_MODES,
    FAULT_KINDS,
    MISFIRE_MODES,
    SENSOR_KINDS,
    Fault,
    FaultSet,
)
from dmf_sim.physics.faults.parse import (
    SEED_MAX,
    FaultSchedule,
    check_overlaps,
    known_sensors,
    parse_fault,
    parse_faults,
    parse_request,
    read_schedule,
)
from dmf_sim.physics.faults.timeline import FaultEvent, FaultTimeline, event_from_values

__all__ = ['FAULT_KINDS', 'COMBUSTION_KINDS', 'DMF_KINDS', 'SENSOR_KINDS', 'MISFIRE_MODES',
           'EDGE_MODES', 'BUS_MODES', 'DMF_DAMPING_FACTOR_MAX', 'SEED_MAX', 'WINDOW_OPEN_RAD',
           'CYCLE_RAD', 'Fault', 'FaultSet', 'FaultSchedule', 'FaultEvent', 'FaultTimeline',
           'known_sensors', 'parse_fault', 'parse_faults', 'parse_request', 'read_schedule',
           'check_overlaps',
           'event_from_values', 'combustion_windows']
