"""Every compiled kernel of the solvers in one table: the entry point, its readable reference
twin, the parity case that holds them to each other with its tolerance, and the kernel group that
loads it.

A kernel (:func:`dmf_sim.core.compiled.jit`) called from Python is an *entry point*
(:class:`Kernel`): its group's ``warm_up`` must load it (the group's ``kernels()`` list is
:func:`entry_points` of this table), and its ``case`` compares it with ``reference`` (the numpy
path it replaces, or the Python loop whose decisions it repeats) to ``rel_tol``. A kernel only
called from other kernels is a *helper* (:data:`HELPERS`): it is compiled with its callers.

Adding a kernel is one entry here and, if no existing case covers it, one case builder in
``test/support/kernel_cases.py`` (the builders make test problems, which the package does not
import; the table names them). From this table

1. ``test/solvers/test_kernel_registry.py`` checks that every compiled function of the solver
   modules is an entry point or a helper, that every entry point's reference exists, and that
   every group's ``warm_up`` loads each of its entry points (a sweep after it compiles nothing
   new: ``test/solvers/hbm/test_hbm_compiled.py``);
2. ``test/solvers/test_kernel_parity.py`` runs every case, compiled against reference to the
   tolerance of the entries naming it, and fails for an entry whose case has no builder; its
   tests carry the ``parity`` marker, so ``pytest -m parity`` runs every kernel against its
   reference.

Names are strings (``module:attribute``, ``module:Class.method``) so that reading the table
imports nothing; :func:`resolve` imports one.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass

__all__ = ['Kernel', 'KERNELS', 'HELPERS', 'SWEEP', 'TIME_INTEGRATION', 'BITWISE', 'REL_TOL',
           'entry_points', 'resolve']

SWEEP = 'sweep'
"""The group of harmonic balance, continuation and stability kernels
(:data:`dmf_sim.solvers.hbm.warm.SWEEP`)."""
TIME_INTEGRATION = 'time integration'
"""The group of the Newmark step (:data:`dmf_sim.live.warm.TIME_INTEGRATION`)."""

_K = 'dmf_sim.solvers.hbm.kernels'
_C = 'dmf_sim.solvers.hbm.continuation_kernels'
_L = 'dmf_sim.solvers.hbm.linear_kernels'
_S = 'dmf_sim.solvers.step_control'
_HBM = 'dmf_sim.solvers.hbm.condensed:CondensedHBM'
_CONT = 'dmf_sim.solvers.continuation'
BITWISE = 0.0
"""The tolerance of a kernel that must give the reference's bits."""
REL_TOL = 1e-10
"""The tolerance of a kernel whose operations round differently from its numpy reference:
relative to the largest magnitude of each compared output."""
FRICTION_TOL = 1e-9
"""The tolerance of the kernels with friction and end stops: their law (a tanh of the wind-up
rate, a secant over each step) rounds differently from numpy's."""


@dataclass(frozen=True)
class Kernel:
    """One compiled entry point.

    Attributes:
        kernel: ``module:name`` of the compiled function (a numba dispatcher).
        reference: ``module:name`` of its readable twin ('' for the step-control decisions,
            which are the only version: the Python loop calls them compiled).
        case: the name of the parity case comparing the kernel with the reference (a builder
            in ``test/support/kernel_cases.py``; entries sharing a case share its tolerance).
        rel_tol: how far the kernel's outputs may lie from the reference's, relative to the
            largest magnitude of each output (:data:`BITWISE`: the same bits).
        group: the kernel group whose ``warm_up`` loads it.
    """

    kernel: str
    reference: str
    case: str
    rel_tol: float
    group: str = SWEEP


KERNELS: tuple[Kernel, ...] = (
    # the sweep point: AFT residual and Jacobian, Newton, deflated Newton
    Kernel(f'{_K}:residual_jacobian_py', f'{_HBM}.residual_and_jacobian_reference', 'aft',
           REL_TOL),
    Kernel(f'{_K}:harmonics_py', f'{_HBM}.nonlinear_harmonics_reference', 'aft', REL_TOL),
    Kernel(f'{_K}:residual_jacobians_py', f'{_HBM}.residual_speed_derivative',
           'continuation jacobians', REL_TOL),
    # the AFT with arc-spring friction and end stops (called by the kernels above)
    Kernel(f'{_K}:aft_law', f'{_HBM}._nonlinear_reference', 'aft with friction', FRICTION_TOL),
    Kernel(f'{_K}:newton', f'{_HBM}.newton_reference', 'newton', REL_TOL),
    Kernel(f'{_K}:deflated_newton', 'dmf_sim.solvers.hbm.deflation:DeflatedNewton.solve_reference',
           'deflated newton', REL_TOL),
    Kernel(f'{_K}:deflated_newton_first', 'dmf_sim.solvers.hbm.deflation:DeflatedNewton.solve',
           'deflated seeds', BITWISE),
    # the linear parts of the condensed system
    Kernel(f'{_L}:modal_sums', f'{_HBM}._linear_numpy', 'linear parts', REL_TOL),
    Kernel(f'{_L}:linear_parts', f'{_HBM}._linear_numpy', 'linear parts', REL_TOL),
    Kernel(f'{_L}:linear_parts_many_at', f'{_HBM}._linear_parts_many', 'linear parts of a grid',
           BITWISE),
    # the continuation's steps
    Kernel(f'{_C}:tangent', f'{_CONT}:_tangent', 'tangent', REL_TOL),
    Kernel(f'{_C}:corrector_fixed_speed', f'{_CONT}:correct', 'grid corrector', REL_TOL),
    Kernel(f'{_C}:step_fixed_speed', f'{_CONT}:correct_step', 'grid step', BITWISE),
    Kernel(f'{_C}:residual_jacobians_at', f'{_HBM}.residual_and_jacobians', 'off-grid jacobians',
           BITWISE),
    Kernel(f'{_C}:corrector_arclength', f'{_CONT}:correct', 'arc-length corrector', REL_TOL),
    Kernel(f'{_C}:grid_run', f'{_CONT}:continue_branch', 'grid runs', BITWISE),
    # the continuation's step control: one version, called by the loop and by grid_run
    *(Kernel(f'{_S}:{name}', '', 'grid runs', BITWISE)
      for name in ('on_grid', 'grid_step', 'moved_too_far', 'tangent_turn', 'turned_too_far',
                   'after_failure', 'next_step', 'on_bound')),
    # Floquet stability
    Kernel('dmf_sim.solvers.stability_kernel:floquet',
           'dmf_sim.solvers.stability:FloquetAnalyzer.analyze_reference', 'floquet', REL_TOL),
    Kernel('dmf_sim.solvers.stability_kernel:floquet_many',
           'dmf_sim.solvers.stability:FloquetAnalyzer.analyze', 'traced points', BITWISE),
    Kernel('dmf_sim.solvers.stability_kernel:floquet_law_many',
           'dmf_sim.solvers.stability:FloquetAnalyzer.monodromy_law_reference',
           'floquet with friction', FRICTION_TOL),
    Kernel('dmf_sim.solvers.lapack_kernel:eigenvalues_into', 'numpy.linalg:eigvals',
           'eigenvalues', 1e-12),
    # the Newmark step (thousands of steps: the round-off of each accumulates)
    Kernel('dmf_sim.solvers.newmark_kernel:factor',
           'dmf_sim.solvers.newmark_kernel:advance_reference', 'newmark step', 1e-8,
           TIME_INTEGRATION),
    Kernel('dmf_sim.solvers.newmark_kernel:advance_compiled',
           'dmf_sim.solvers.newmark_kernel:advance_reference', 'newmark step', 1e-8,
           TIME_INTEGRATION),
)
"""The compiled entry points of the solvers."""

HELPERS: tuple[str, ...] = (
    *(f'{_K}:{n}' for n in ('aft', 'assemble', 'nonlinear', 'times_h_into', 'times_h_matrix',
                            'residual_jacobian',
                            'speed_derivative', '_newton_start', '_accept', '_log_m',
                            '_log_floor')),
    *(f'dmf_sim.solvers.hbm.dense_kernels:{n}' for n in ('lu_solve', 'max_abs', 'lu_work')),
    *(f'{_L}:{n}' for n in ('engine_at', 'linear_parts_at', 'one_speed_work')),
    f'{_C}:add_step', f'{_C}:_evaluate_scaled', f'{_S}:next_grid',
    'dmf_sim.solvers.stability_kernel:floquet_segments',
    'dmf_sim.solvers.stability_kernel:monodromy_similar',
    *(f'dmf_sim.solvers.stability_kernel:{n}' for n in ('flow_factors', 'flow_apply',
                                                         'flow_real', 'law_steps',
                                                         'monodromy_law')),
    'dmf_sim.solvers.lapack_kernel:dgeev_into',
    'dmf_sim.solvers.francis_qr:hessenberg_eigenvalues',
    *(f'dmf_sim.solvers.newmark_kernel:{n}' for n in ('newmark_constants', 'thomas',
                                                      'knee_between', 'regular_block',
                                                      'law_solve')),
    *(f'dmf_sim.solvers.spring_kernels:{n}' for n in ('region_of', 'primary_range',
                                                      'friction_parts', 'stop_parts',
                                                      'travel_range', 'law_parts',
                                                      'law_active')),
)
"""Compiled functions called only from other kernels (compiled and cached with their callers)."""


def resolve(name: str):
    """The object called ``module:attribute`` (``module:Class.method`` too)."""
    module, _, attr = name.partition(':')
    obj = importlib.import_module(module)
    for part in attr.split('.'):
        obj = getattr(obj, part)
    return obj


def entry_points(group: str) -> tuple:
    """The compiled entry points (numba dispatchers) of ``group``, in table order: what the
    group's ``warm_up`` loads."""
    return tuple(resolve(k.kernel) for k in KERNELS if k.group == group)
