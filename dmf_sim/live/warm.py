"""Every compiled kernel of the package, in groups (:mod:`dmf_sim.core.kernel_cache`): what
``dmf-sim warm-up`` compiles into numba's cache once per machine, and what a command loads before
its work starts.

* :data:`TIME_INTEGRATION`: the Newmark step and the torque read-out, as the node and ``dmf-sim
  run`` call them (through :class:`~dmf_sim.live.simulation.LiveSimulation`), with the sensors
  (their tracking, their signals, the messages ``dmf-sim run`` writes at once);
* :data:`~dmf_sim.solvers.hbm.warm.SWEEP`: harmonic balance, continuation and Floquet stability;
* :data:`~dmf_sim.bags.warm.BAG_READING`: the MCAP record scanner.
"""
from __future__ import annotations

from dmf_sim.bags.warm import BAG_READING
from dmf_sim.core import kernel_cache
from dmf_sim.core.kernel_cache import KernelGroup
from dmf_sim.solvers.hbm.warm import SWEEP

__all__ = ['TIME_INTEGRATION', 'TIME_INTEGRATION_COMPILE_S', 'GROUPS', 'group', 'warm_up']

TIME_INTEGRATION_COMPILE_S = 15.0
"""Seconds the group took to compile on the 2-core reference machine."""

_CHUNK_STEPS = 25           # a chunk of a few samples: every code path of a real chunk


def _warm_up() -> None:
    """The live core on the shipped truck, without sensors and with them (the kernel's two
    specializations, the sensor signals): the kernels load when it is built; one chunk through
    :meth:`~LiveSimulation.advance` and one through integrate / read_out with a caller's buffers,
    as ``dmf-sim run`` does; sensor messages encoded and packed into records at once, as
    ``dmf-sim run`` writes them."""
    import numpy as np

    from dmf_sim.bags.sensor_messages import encode_sensor_messages
    from dmf_sim.bags.writer import pack_records
    from dmf_sim.live.simulation import LiveSimulation
    from dmf_sim.solvers.newmark import StepRecord
    for sensors in (False, True):
        sim = LiveSimulation.from_config(sensors=sensors)
        sim.advance(_CHUNK_STEPS)
        record = StepRecord.allocate(_CHUNK_STEPS, sim.model.n_dof)
        sim.read_out(sim.integrate(_CHUNK_STEPS, record),
                     np.zeros((_CHUNK_STEPS, 3 * sim.model.n_elements)))
    payload, offsets = encode_sensor_messages(np.zeros((1, 3), np.int64), np.array([[0, 1]]),
                                              np.zeros(1), np.array([0, 1]))
    pack_records(np.zeros(int(offsets[-1]) + 62, np.uint8), np.zeros(2, np.int64),
                 np.zeros((2, 31), np.uint8), payload, offsets)


def _kernels() -> tuple:
    from dmf_sim.bags import sensor_messages
    from dmf_sim.bags.writer import pack_records
    from dmf_sim.core.counter_random import gaussians
    from dmf_sim.live.torques import sparse_outputs
    from dmf_sim.physics.sensor_signals import synthesize
    from dmf_sim.solvers import kernel_registry
    return (*kernel_registry.entry_points(kernel_registry.TIME_INTEGRATION), sparse_outputs,
            synthesize, gaussians, sensor_messages.fill_messages, pack_records)


TIME_INTEGRATION = KernelGroup('time integration', 'the Newmark step and the torque read-out '
                               '(the node, run, steady, runup, the optimizer\'s verification)',
                               _warm_up, _kernels, TIME_INTEGRATION_COMPILE_S)

GROUPS = (SWEEP, TIME_INTEGRATION, BAG_READING)
"""Every group: together, every compiled kernel of the package."""


def group(name: str) -> KernelGroup:
    """The group called ``name``."""
    return next(g for g in GROUPS if g.name == name)


def warm_up(command: str, *names: str) -> None:
    """Load the named groups before ``command``'s work (and its progress bar) starts: one line
    ``dmf-sim COMMAND: compiling the numerical kernels once (...)`` on stderr when they must be
    compiled first (:func:`dmf_sim.core.kernel_cache.warm_up`)."""
    kernel_cache.warm_up([group(n) for n in names], prefix=f'dmf-sim {command}')
