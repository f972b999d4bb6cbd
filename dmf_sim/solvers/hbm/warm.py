"""Loading (or, the first time on a machine, compiling) every compiled kernel of a sweep in one
call, so that no later first call pays for it: a design-study worker does this when it starts
(the study's worker plugin), ``bench_hbm`` before it times anything; :data:`SWEEP` is the group
``dmf-sim warm-up`` and the sweeping commands load (:mod:`dmf_sim.core.kernel_cache`).
"""
from __future__ import annotations

import time

import numpy as np

from dmf_sim.core.kernel_cache import KernelGroup
from dmf_sim.physics.spring import PiecewiseLinearSpring
from dmf_sim.solvers import kernel_registry, stability_kernel, step_control
from dmf_sim.solvers.hbm.continuation_kernels import (
    RUN_OPTIONS,
    corrector_arclength,
    corrector_fixed_speed,
    grid_run,
    residual_jacobians_at,
    step_fixed_speed,
    tangent,
)
from dmf_sim.solvers.hbm.kernels import (
    aft_law,
    deflated_newton,
    deflated_newton_first,
    harmonics_py,
    newton,
    residual_jacobian_py,
    residual_jacobians_py,
)
from dmf_sim.solvers.hbm.linear_kernels import linear_parts, linear_parts_many_at, modal_sums
from dmf_sim.solvers.hbm.unknowns import to_real
from dmf_sim.solvers.lapack_kernel import eigenvalues_into

__all__ = ['warm_up', 'kernels', 'SWEEP', 'SWEEP_COMPILE_S']


def warm_up() -> float:
    """Load (or compile) every compiled kernel of a sweep point —
    :mod:`dmf_sim.solvers.hbm.kernels`, :mod:`~dmf_sim.solvers.hbm.continuation_kernels`,
    :mod:`~dmf_sim.solvers.hbm.linear_kernels`, :mod:`dmf_sim.solvers.stability_kernel` and the
    eigenvalue call of one point (:mod:`dmf_sim.solvers.lapack_kernel`) — on a tiny problem
    with the argument types of the real ones. Returns the seconds it took."""
    t0 = time.perf_counter()
    H, M = 2, 8
    n = 2 * H + 1
    phi = 2.0 * np.pi * np.arange(M) / M
    harm = np.arange(1, H + 1)
    E = np.hstack([np.ones((M, 1)), np.cos(np.outer(phi, harm)), -np.sin(np.outer(phi, harm))])
    weights = np.full(n, 2.0 / M)
    weights[0] = 1.0 / M
    m_all = np.arange(n)
    aft_mats = (E, weights, np.cos(np.outer(phi, m_all)), np.sin(np.outer(phi, m_all)))
    sp = PiecewiseLinearSpring.two_step(1.0, 0.5, 1.0)
    spring = (*sp.arrays(), int(sp.primary_index), sp.law_array())
    h = np.full(H + 1, 0.5 + 0.1j)
    x0 = np.zeros(n)
    x0[1] = 1.0
    lin = (x0.copy(), h, 1.0)
    dlin = (x0.copy(), h)
    out = np.empty(n)
    residual_jacobian_py(x0, lin, aft_mats, spring, True)
    residual_jacobians_py(x0, lin, dlin, aft_mats, spring)
    harmonics_py(x0, 1.0, aft_mats, spring, True)
    aft_law(x0, 1.0, aft_mats, spring, np.empty(2 * n), np.empty((n, n)), True)
    newton(x0, lin, aft_mats, spring, (1e-10, 5, 8, 0.5), out)
    deflated_newton(x0, np.zeros((1, n)), lin, aft_mats, spring, 1e-10,
                    np.array([2.0, 1.0, 1e-2, 5.0, 0.125, 6.0]), out)
    deflated_newton_first(x0[None], 0, np.zeros((1, n)), lin, aft_mats, spring, 1e-10,
                          np.array([2.0, 1.0, 1e-2, 5.0, 0.125, 6.0]), out)
    corrector_fixed_speed(x0, 1.0, lin, dlin, aft_mats, spring, 1e-10, 3, out, np.empty(n),
                          np.empty((n, n)), np.empty(n))
    t1 = np.zeros(n + 1)
    t1[n] = 1.0
    tangent(np.eye(n), np.ones(n), t1, 1.0, 1.0, np.empty(n + 1))
    step_fixed_speed(t1, t1, 1.0, 1.0, lin, dlin, aft_mats, spring, 1e-10, 3, np.empty(n + 1),
                     np.empty(n + 1), np.empty(n), np.empty((n, n)), np.empty(n))
    m = 2
    for K in (1, 2):     # one speed: h[:, 1:] is C-contiguous; a batch: it is not (two layouts)
        modal_sums(np.ones(K), np.ones(H), np.array([-1.0 + 1j, -1.0 - 1j]),
                   np.ones((H + 1, m), dtype=complex)[1:], np.ones(m, dtype=complex),
                   np.empty((K, H), dtype=complex), np.empty((K, H), dtype=complex),
                   np.empty((K, H + 1), dtype=complex)[:, 1:],
                   np.empty((K, H + 1), dtype=complex)[:, 1:])
        A = np.ones((K, H + 1), dtype=complex)
        linear_parts(np.ones(K), np.ones(H), np.array([-1.0 + 1j, -1.0 - 1j]),
                     np.ones((H + 1, m), dtype=complex)[1:], np.ones(m, dtype=complex), A, A,
                     np.ones(K), np.ones(K), 1.0, np.empty((K, H + 1), dtype=complex),
                     np.empty((K, H + 1), dtype=complex), np.empty((K, H + 1), dtype=complex),
                     np.empty((K, H + 1), dtype=complex), np.empty((K, n)), np.empty((K, n)))
    # the arc-length corrector and the off-grid linear parts with the engine query
    table = (np.array([0.0, 1.0, 2.0]), np.ones((3, H + 1), dtype=complex),
             np.ones(3, dtype=bool), np.zeros(H + 1, dtype=complex), 0.0, 0.0)
    statics = (1.0, 1.0, 1.0)
    modal = (np.ones(H), np.array([-1.0 + 1j, -1.0 - 1j]),
             np.ascontiguousarray(np.ones((H + 1, m), dtype=complex)[1:]),
             np.ones(m, dtype=complex), 1.0)
    residual_jacobians_at(x0, 1.0, 0.05, table, statics, modal, aft_mats, spring)
    K = 2
    linear_parts_many_at(np.ones(K), 0.05, table, statics, modal,
                         *[np.empty((K, H + 1), dtype=complex) for _ in range(7)],
                         np.empty((K, n)), np.empty((K, n)), np.empty(K, dtype=np.int64))
    y1 = np.zeros(n + 1)
    y1[n] = 1.0
    corrector_arclength(y1, y1.copy(), 1.0, 1.0, 1e-10, 2, 0.05, table, statics, modal,
                        aft_mats, spring, np.empty(n + 1), np.empty(n), np.empty((n, n)),
                        np.empty(n))
    opts = np.ones(len(RUN_OPTIONS))
    grid_run(1.0, y1, t1, 1.0, 0.0, 2.0, opts, 3, 3, True, 1, (0.05, table, statics, modal),
             aft_mats, spring, (np.empty((1, n)), np.empty(1), np.empty((1, n + 1)),
                                np.empty(1, dtype=np.int64), np.empty(1),
                                np.empty(1, dtype=np.bool_)))
    ns = 2
    W = np.zeros((2, 2, ns, ns))
    W[:, :] = np.eye(ns)
    c = np.zeros(H + 1, dtype=complex)
    c[1] = 1.0
    fl_args = (spring[0], spring[3], 1, np.array([[1, 2], [1, 2]], dtype=np.int64),
               -np.ones((2, ns)), np.ones((2, ns)), W)
    stability_kernel.floquet(c, E @ to_real(c, H), 1.0, *fl_args)
    stability_kernel.floquet_many(c[None], (E @ to_real(c, H))[None], np.ones(1), *fl_args,
                                  np.empty(1, dtype=np.int64), np.empty(1, dtype=np.int64),
                                  np.empty(1), np.empty((1, ns)), np.empty((1, ns)),
                                  np.empty(1, dtype=np.int64))
    # the monodromies with friction and end stops and their multipliers (the spring's law
    # array, a uniform grid)
    grid = np.zeros((1, 4))
    stability_kernel.floquet_law_many(grid, grid, np.ones(1), np.ones(1), *spring,
                                      *fl_args[3:], np.ones((2, ns)), np.ones((2, ns)),
                                      np.ones((2, ns)), 1.0, np.ones((2, 2)), 0.0,
                                      W[0].copy(), W[0].copy(),
                                      np.empty((1, ns, ns)), np.empty((1, ns)),
                                      np.empty((1, ns)), np.empty(1, dtype=np.int64))
    # the multipliers of one point analyzed alone (stability.eigenvalues calls it from Python)
    eigenvalues_into(np.eye(ns), np.empty(ns), np.empty(ns))
    # the continuation loop's step control, called from Python with these types
    step_control.on_grid(1.0, 1.0)
    step_control.grid_step(1.0, 1.0, 1.0, 0.0, 2.0, 1.0, 1.0, 1.0, 0.2)
    step_control.moved_too_far(0.1, 1.0, 0.5, 1e-4)
    step_control.turned_too_far(step_control.tangent_turn(1.0), True, 1.0, 0.6, 1e-4)
    step_control.after_failure(1.0, 0.5, True, 1e-4)
    step_control.next_step(1.0, 2, 3, 1e-4, 1.0)
    step_control.on_bound(1.0, 0.0, 2.0)
    return time.perf_counter() - t0



def kernels() -> tuple:
    """The entry points :func:`warm_up` loads (numba dispatchers): the sweep group of
    :mod:`dmf_sim.solvers.kernel_registry`."""
    return kernel_registry.entry_points(kernel_registry.SWEEP)


SWEEP_COMPILE_S = 40.0
"""Seconds :func:`warm_up` took to compile on the 2-core reference machine (the field report's
first sweep: 35 s of 40 compiling)."""

SWEEP = KernelGroup('sweep', 'harmonic balance, continuation, Floquet stability (sweep, steady, '
                    'runup, paper, design, optimize, the monitor\'s prediction)', warm_up,
                    kernels, SWEEP_COMPILE_S)
