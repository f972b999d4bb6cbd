"""Non-linear normal modes (NNMs) of the conservative DMF driveline (doc/theory.md §10, Fig. 14).

The driveline without damping and excitation, held at the static equilibrium of a mean torque,
is solved by harmonic balance condensed on the DMF wind-up with exact Galerkin harmonics of the
piecewise-linear spring, and followed in energy from the linear mode by pseudo-arc-length
continuation; the frequency is reported against xi = E / E_nl (eq. 19). The equations are in
:mod:`~dmf_sim.solvers.nnm.conservative`'s docstring.

Modules: :mod:`~dmf_sim.solvers.nnm.conservative` (the condensed problem and one branch),
:mod:`~dmf_sim.solvers.nnm.branches` (both branches of Fig. 14, flat branches, the scaling check),
:mod:`~dmf_sim.solvers.nnm.ramp_force` (exact Galerkin harmonics),
:mod:`~dmf_sim.solvers.nnm.subsystems`,
:mod:`~dmf_sim.solvers.nnm.time_domain`, :mod:`~dmf_sim.solvers.nnm.results`.
"""
from dmf_sim.solvers.nnm.branches import nnm_branches, scaling_check
from dmf_sim.solvers.nnm.conservative import ConservativeNNM
from dmf_sim.solvers.nnm.results import REGIONS, FlatBranch, NNMBranch, NNMOptions, NNMResult
from dmf_sim.solvers.nnm.subsystems import (
           clamped_frequencies,
           static_windup,
           subsystem_frequencies,
)
from dmf_sim.solvers.nnm.time_domain import integrate_chain, integrate_physical, static_state

__all__ = ['nnm_branches', 'scaling_check', 'ConservativeNNM', 'REGIONS', 'FlatBranch',
           'NNMBranch', 'NNMOptions', 'NNMResult', 'clamped_frequencies', 'static_windup',
           'subsystem_frequencies',
           'integrate_chain', 'integrate_physical', 'static_state']
