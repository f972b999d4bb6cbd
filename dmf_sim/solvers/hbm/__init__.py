"""Harmonic balance (HBM) of the DMF driveline, condensed onto the DMF wind-up (paper eq. 9-15).

* :mod:`~dmf_sim.solvers.hbm.condensed` — the condensed problem at one speed: residual (eq. 15),
  AFT with analytic Jacobian, Newton (:class:`CondensedHBM`);
* :mod:`~dmf_sim.solvers.hbm.expansion` — every element's motion and torque from a solution;
* :mod:`~dmf_sim.solvers.hbm.point` — its settings and results: :class:`HBMOptions`,
  :class:`LinearParts`, :class:`HBMPoint`;
* :mod:`~dmf_sim.solvers.hbm.sweep` — speed sweeps: pseudo-arc-length continuation, Floquet
  stability, events (:func:`sweep`, :class:`SpeedSweep`);
* :mod:`~dmf_sim.solvers.hbm.branches` — branch switching to 1.5th-order and other coexisting
  branches;
* :mod:`~dmf_sim.solvers.hbm.results` — :class:`SweepResult`, :class:`Branch`, :class:`SweepEvent`;
* :mod:`~dmf_sim.solvers.hbm.unknowns` — the real unknown layout and shift-invariant fingerprints.
* :mod:`~dmf_sim.solvers.hbm.faulted` — steady states with faults (misfiring or weak cylinders,
  DMF faults) and when the shift symmetries hold.
"""
from dmf_sim.solvers.hbm.condensed import CondensedHBM
from dmf_sim.solvers.hbm.point import HBMOptions, HBMPoint, LinearParts
from dmf_sim.solvers.hbm.results import Branch, SweepEvent, SweepResult
from dmf_sim.solvers.hbm.search import SearchOptions
from dmf_sim.solvers.hbm.sweep import SpeedSweep, SweepOptions, sweep
from dmf_sim.solvers.hbm.unknowns import SUB_HARMONICS, to_complex, to_real

__all__ = ['CondensedHBM', 'HBMOptions', 'HBMPoint', 'LinearParts', 'SUB_HARMONICS', 'to_complex',
           'to_real', 'Branch', 'SweepEvent', 'SweepResult', 'SearchOptions', 'SpeedSweep',
           'SweepOptions', 'sweep']
