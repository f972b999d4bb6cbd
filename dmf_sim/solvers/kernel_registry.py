"""Every compiled kernel of the solvers in one table: the entry point, its readable reference
twin, the test that holds them to each other, and the kernel group that loads it.

A kernel (:func:`dmf_sim.core.compiled.jit`) called from Python is an *entry point*
(:class:`Kernel`): its group's ``warm_up`` must load it (the group's ``kernels()`` list is
:func:`entry_points` of this table), and its ``parity`` test compares it with ``reference``
(the numpy path it replaces, or the Python loop whose decisions it repeats). A kernel only called
from other kernels is a *helper* (:data:`HELPERS`): it is compiled with its callers.

Adding a kernel is one entry here; ``test/solvers/test_kernel_registry.py`` checks, from this
table, that

1. every compiled function of the solver modules is an entry point or a helper, and nothing
   listed is missing;
2. every entry point's reference exists, and its parity test exists in the named file;
3. every group's ``warm_up`` loads each of its entry points, and a sweep after it compiles
   nothing new (``test/solvers/hbm/test_hbm_compiled.py``, from :func:`entry_points`);
4. the tests named here carry the ``parity`` marker (set by ``test/conftest.py`` from this
   table), so ``pytest -m parity`` runs every kernel against its reference.

Names are strings (``module:attribute``, ``module:Class.method``) so that reading the table
imports nothing; :func:`resolve` imports one.
"""
from __future__ import annotations

import importlib
from dataclasses import dataclass

__all__ = ['Kernel', 'KERNELS', 'HELPERS', 'SWEEP', 'TIME_INTEGRATION', 'entry_points',
           'resolve']

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
_T_HBM = 'test/solvers/hbm/test_hbm_compiled.py'
_T_FAST = 'test/solvers/hbm/test_sweep_fastpaths.py'
_T_FRICTION = 'test/solvers/hbm/test_friction_hbm.py'


@dataclass(frozen=True)
class Kernel:
    """One compiled entry point.

    Attributes:
        kernel: ``module:name`` of the compiled function (a numba dispatcher).
        reference: ``module:name`` of its readable twin ('' for the step-control decisions,
            which are the only version: the Python loop calls them compiled).
        parity: ``file::test`` holding the kernel to the reference (bitwise, or to the
            tolerance the test states).
        group: the kernel group whose ``warm_up`` loads it.
    """

    kernel: str
    reference: str
    parity: str
    group: str = SWEEP


KERNELS: tuple[Kernel, ...] = (
    # the sweep point: AFT residual and Jacobian, Newton, deflated Newton
    Kernel(f'{_K}:residual_jacobian_py', f'{_HBM}.residual_and_jacobian_reference',
           f'{_T_HBM}::test_aft_residual_and_jacobian_equal_reference'),
    Kernel(f'{_K}:harmonics_py', f'{_HBM}.nonlinear_harmonics_reference',
           f'{_T_HBM}::test_aft_residual_and_jacobian_equal_reference'),
    Kernel(f'{_K}:residual_jacobians_py', f'{_HBM}.residual_speed_derivative',
           f'{_T_HBM}::test_continuation_jacobians_equal_reference'),
    # the AFT with arc-spring friction and end stops (called by the kernels above)
    Kernel(f'{_K}:aft_law', f'{_HBM}._nonlinear_reference',
           f'{_T_FRICTION}::test_aft_with_friction_and_stops_equals_reference'),
    Kernel(f'{_K}:newton', f'{_HBM}.newton_reference',
           f'{_T_HBM}::test_newton_equals_reference'),
    Kernel(f'{_K}:deflated_newton', 'dmf_sim.solvers.hbm.deflation:DeflatedNewton.solve_reference',
           f'{_T_HBM}::test_deflated_newton_equals_reference'),
    Kernel(f'{_K}:deflated_newton_first', 'dmf_sim.solvers.hbm.deflation:DeflatedNewton.solve',
           f'{_T_HBM}::test_deflated_seeds_in_one_call_are_the_seeds_one_by_one'),
    # the linear parts of the condensed system
    Kernel(f'{_L}:modal_sums', f'{_HBM}._linear_numpy',
           f'{_T_HBM}::test_linear_parts_equal_reference'),
    Kernel(f'{_L}:linear_parts', f'{_HBM}._linear_numpy',
           f'{_T_HBM}::test_linear_parts_equal_reference'),
    Kernel(f'{_L}:linear_parts_many_at', f'{_HBM}._linear_parts_many',
           f'{_T_FAST}::test_linear_parts_of_a_grid_in_one_kernel_call_equal_the_numpy_batch'),
    # the continuation's steps
    Kernel(f'{_C}:tangent', f'{_CONT}:_tangent',
           f'{_T_HBM}::test_continuation_tangent_equals_reference'),
    Kernel(f'{_C}:corrector_fixed_speed', f'{_CONT}:correct',
           f'{_T_HBM}::test_grid_corrector_equals_reference'),
    Kernel(f'{_C}:step_fixed_speed', f'{_CONT}:correct_step',
           f'{_T_HBM}::test_grid_step_in_one_call_is_corrector_then_tangent'),
    Kernel(f'{_C}:residual_jacobians_at', f'{_HBM}.residual_and_jacobians',
           f'{_T_HBM}::test_off_grid_jacobians_in_one_call_are_the_python_path'),
    Kernel(f'{_C}:corrector_arclength', f'{_CONT}:correct',
           f'{_T_HBM}::test_arc_length_corrector_equals_reference'),
    Kernel(f'{_C}:grid_run', f'{_CONT}:continue_branch',
           f'{_T_HBM}::test_grid_runs_are_the_loops_grid_steps'),
    # the continuation's step control: one version, called by the loop and by grid_run
    *(Kernel(f'{_S}:{name}', '', f'{_T_HBM}::test_grid_runs_are_the_loops_grid_steps')
      for name in ('on_grid', 'grid_step', 'moved_too_far', 'tangent_turn', 'turned_too_far',
                   'after_failure', 'next_step', 'on_bound')),
    # Floquet stability
    Kernel('dmf_sim.solvers.stability_kernel:floquet',
           'dmf_sim.solvers.stability:FloquetAnalyzer.analyze_reference',
           f'{_T_HBM}::test_floquet_multipliers_equal_reference'),
    Kernel('dmf_sim.solvers.stability_kernel:floquet_many',
           'dmf_sim.solvers.stability:FloquetAnalyzer.analyze',
           f'{_T_FAST}::test_points_of_a_traced_branch_made_in_one_batch_equal_one_by_one'),
    Kernel('dmf_sim.solvers.stability_kernel:monodromy_law',
           'dmf_sim.solvers.stability:FloquetAnalyzer.monodromy_law_reference',
           f'{_T_FRICTION}::test_floquet_multipliers_with_friction_are_inside_and_converge'),
    Kernel('dmf_sim.solvers.lapack_kernel:eigenvalues_into', 'numpy.linalg:eigvals',
           'test/solvers/test_eigenvalues.py::test_eigenvalues_equal_numpys'),
    # the Newmark step
    Kernel('dmf_sim.solvers.newmark_kernel:factor',
           'dmf_sim.solvers.newmark_kernel:advance_reference',
           'test/solvers/test_newmark.py::test_kernel_equals_reference_path', TIME_INTEGRATION),
    Kernel('dmf_sim.solvers.newmark_kernel:advance_compiled',
           'dmf_sim.solvers.newmark_kernel:advance_reference',
           'test/solvers/test_newmark.py::test_kernel_equals_reference_path', TIME_INTEGRATION),
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
    'dmf_sim.solvers.stability_kernel:step_law',
    'dmf_sim.solvers.lapack_kernel:dgeev_into',
    'dmf_sim.solvers.francis_qr:hessenberg_eigenvalues',
    *(f'dmf_sim.solvers.newmark_kernel:{n}' for n in ('newmark_constants', 'thomas',
                                                      'knee_between', 'regular_block',
                                                      'law_solve')),
    *(f'dmf_sim.solvers.spring_kernels:{n}' for n in ('region_of', 'law_parts', 'law_active')),
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
