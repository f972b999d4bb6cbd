"""The steady states of one design at one condition, on the study's speed grid.

:func:`grid_states` turns a harmonic-balance sweep (every branch, every point, with Floquet
stability) into one flat set of states per grid speed: a branch point on the grid speed is taken
as it is; a branch stretch that passes a grid speed between two points (near turning points,
where continuation steps along the arc) is interpolated linearly, with the stability of the
nearer point. The 120-deg-shifted twin of a 1.5th-order state is the same physical state; the
sweep keeps one of them. This flat form is what the metrics read, whatever solver made it.

:func:`order_torques` gives the torque harmonic transmitted into one element for many solution
points at once: the DOF harmonic ``q_n = H_n (P_n - e g_n)`` (hbm eq. 10-13) from one batched
solve, ``g_n`` by the same alternating frequency-time pass as the solver, and the torque from
:meth:`ReducedModel.transmitted_torques` applied to the real and imaginary parts (the torque read-
out is linear once the DMF's non-linear torque is given). It equals
``CondensedHBM.torque_harmonics(point)[n, element]`` (tested) at a fraction of its cost, which
solves all H harmonics of the whole chain for one point.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.physics.orders import ORDER_3

__all__ = ['SAME_STATE_REL', 'SAME_STATE_ABS', 'GridStates', 'speed_grid', 'grid_states',
           'order_torques']

_ON_GRID_RPM = 1e-6       # a point this close to a grid speed [rpm] is on it
SAME_STATE_REL = 0.02     # states closer than this (relative) at one speed are the same state
SAME_STATE_ABS = 1e-7     # ... plus this [rad]


@dataclass
class GridStates:
    """States at grid speeds (one entry per state; several per speed where states coexist).

    Attributes:
        grid: (n_grid,) the speed grid [rpm].
        grid_index: index into ``grid`` of every state; speed_rpm its speed.
        Repeated visits of one state (see ``_distinct``) are merged.
        stable: Floquet-stable; is_1_5: a 1.5th-order resonance state (sweep criterion).
        order_3, order_1_5, mean, max_dev, min_dev: wind-up quantities [rad] (paper Fig. 13).
        torque_3: 3rd-order torque amplitude into the torque element [Nm] (NaN if unstable or
            non-periodic).
        n_branches: branches the solver found.
        periodic: False for the time-integration envelopes of grid speeds without a stable
            periodic state (the sweep's non-periodic results: averaged orders, max/min
            deviation over many cycles); those entries are not stable states.
    """

    grid: np.ndarray
    grid_index: np.ndarray
    speed_rpm: np.ndarray
    stable: np.ndarray
    is_1_5: np.ndarray
    order_3: np.ndarray
    order_1_5: np.ndarray
    mean: np.ndarray
    max_dev: np.ndarray
    min_dev: np.ndarray
    torque_3: np.ndarray
    n_branches: int
    periodic: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.periodic is None:
            self.periodic = np.ones(len(self.grid_index), dtype=bool)


def speed_grid(lo: float, hi: float, step: float) -> np.ndarray:
    """lo, lo + step, ... up to hi [rpm]."""
    n = int(np.floor((hi - lo) / step + 1e-9))
    return lo + step * np.arange(n + 1)


def grid_states(res, speeds_rpm: tuple[float, float, float], torque_element: int) -> GridStates:
    """Flat grid states of a :class:`~dmf_sim.solvers.hbm.SweepResult` (see the module doc)."""
    lo, hi, step = speeds_rpm
    grid = speed_grid(lo, hi, step)
    refs = []                # (grid index, branch, point a, point b, weight of b)
    for bi, b in enumerate(res.branches):
        S = b.column('speed_rpm')
        k = np.rint((S - lo) / step).astype(int)
        exact = (np.abs(S - (lo + k * step)) < _ON_GRID_RPM) & (k >= 0) & (k < len(grid))
        refs += [(k[j], bi, j, j, 0.0) for j in np.flatnonzero(exact)]
        a, c = S[:-1], S[1:]
        first = np.floor((np.minimum(a, c) - lo) / step + 1e-7).astype(int) + 1
        last = np.ceil((np.maximum(a, c) - lo) / step - 1e-7).astype(int) - 1
        for j in np.flatnonzero(last >= first):
            for g in range(max(first[j], 0), min(last[j], len(grid) - 1) + 1):
                refs.append((g, bi, j, j + 1, (grid[g] - a[j]) / (c[j] - a[j])))
    if not refs:
        empty = np.zeros(0)
        return GridStates(grid, empty.astype(int), empty, empty.astype(bool), empty.astype(bool),
                          empty, empty, empty, empty, empty, empty, len(res.branches))
    gi = np.array([r[0] for r in refs], dtype=int)
    f = np.array([r[4] for r in refs])
    pa = [res.branches[r[1]].points[r[2]] for r in refs]
    pb = [res.branches[r[1]].points[r[3]] for r in refs]

    def col(get):
        va = np.array([get(p) for p in pa], dtype=float)
        vb = np.array([get(p) for p in pb], dtype=float)
        return va + f * (vb - va)

    sa = np.array([bool(p.stable) for p in pa])
    sb = np.array([bool(p.stable) for p in pb])
    stable = np.where(f < 0.5, sa, sb)
    q = {'order_3': col(lambda p: p.summary.order_3),
         'order_1_5': col(lambda p: p.summary.order_1_5),
         'mean': col(lambda p: p.summary.mean),
         'max_dev': col(lambda p: p.summary.max_deviation),
         'min_dev': col(lambda p: p.summary.min_deviation)}
    keep = _distinct(gi, stable, np.column_stack(list(q.values())))
    gi, f, stable = gi[keep], f[keep], stable[keep]
    pa, pb = [pa[i] for i in keep], [pb[i] for i in keep]
    q = {k: v[keep] for k, v in q.items()}
    forced = col(lambda p: p.forced_order_1_5)
    is_1_5 = q['order_1_5'] > np.maximum(res.ratio_1_5 * forced, res.min_1_5)
    # the torque element's 3rd order, only where a stable state needs it
    need = {id(p): p for i in np.flatnonzero(stable) for p in (pa[i], pb[i])}
    pts = list(need.values())
    tq = dict(zip(need, np.abs(order_torques(res.hbm, pts, torque_element)))) if pts else {}
    ta = np.array([tq.get(id(p), np.nan) for p in pa])
    tb = np.array([tq.get(id(p), np.nan) for p in pb])
    torque_3 = np.where(f == 0.0, ta, ta + f * (tb - ta))
    out = GridStates(grid=grid, grid_index=gi, speed_rpm=grid[gi], stable=stable, is_1_5=is_1_5,
                     torque_3=torque_3, n_branches=len(res.branches), **q)
    return _with_nonperiodic(out, res, lo, step)


def _with_nonperiodic(states: GridStates, res, lo: float, step: float) -> GridStates:
    """Append the sweep's time-integration envelopes at grid speeds without a stable periodic
    state (``periodic`` False)."""
    rows = [r for band in getattr(res, 'non_periodic', ()) for r in band.results]
    k = np.rint((np.array([r.speed_rpm for r in rows]) - lo) / step).astype(int)
    on = [(i, r) for i, r in zip(k, rows)
          if 0 <= i < len(states.grid) and abs(r.speed_rpm - states.grid[i]) < _ON_GRID_RPM]
    if not on:
        return states
    gi = np.array([i for i, _ in on], dtype=int)

    def cat(old, new):
        return np.concatenate([old, np.asarray(new, dtype=old.dtype)])

    n = len(on)
    return GridStates(
        grid=states.grid, grid_index=cat(states.grid_index, gi),
        speed_rpm=cat(states.speed_rpm, states.grid[gi]),
        stable=cat(states.stable, np.zeros(n, bool)), is_1_5=cat(states.is_1_5, np.zeros(n, bool)),
        order_3=cat(states.order_3, [r.order_3 for _, r in on]),
        order_1_5=cat(states.order_1_5, [r.order_1_5 for _, r in on]),
        mean=cat(states.mean, [r.mean for _, r in on]),
        max_dev=cat(states.max_dev, [r.max_deviation for _, r in on]),
        min_dev=cat(states.min_dev, [r.min_deviation for _, r in on]),
        torque_3=cat(states.torque_3, np.full(n, np.nan)), n_branches=states.n_branches,
        periodic=cat(states.periodic, np.zeros(n, bool)))


def _distinct(grid_index: np.ndarray, stable: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Indices of the distinct states: at one grid speed, states of equal stability whose
    wind-up quantities (columns of ``values`` [rad]: order_3, order_1_5, mean, max_dev,
    min_dev) agree within SAME_STATE_REL of the oscillation's size are one state (a branch
    that passes the same speed twice on the same solution, e.g. a continuation going round a
    closed loop more than once)."""
    counts = np.bincount(grid_index)
    keep = list(np.flatnonzero(counts[grid_index] == 1))
    for g in np.flatnonzero(counts > 1):
        kept: list[int] = []
        for i in np.flatnonzero(grid_index == g):
            tol = SAME_STATE_REL * np.abs(values[i, [0, 1, 3, 4]]).max() + SAME_STATE_ABS
            if not any(stable[j] == stable[i] and np.abs(values[j] - values[i]).max() <= tol
                       for j in kept):
                kept.append(i)
        keep += kept
    return np.array(sorted(keep), dtype=int)


def order_torques(hb, points, element: int, n: int = ORDER_3) -> np.ndarray:
    """Complex half-order-``n`` torque [Nm] transmitted into ``element`` (index) at each HBM
    point of the condensed problem ``hb`` (a :class:`dmf_sim.solvers.hbm.CondensedHBM`), positive
    when the engine drives; n >= 1. See the module docstring."""
    if n < 1:
        raise ValueError(f'half-order n={n}: needs n >= 1 (the static part is not a harmonic)')
    m = hb.model
    # AFT: harmonics of g(w(psi)), the solver's own pass per point (compiled: no BLAS call,
    # whose threads made the (points x samples) products ~100x slower on a busy 2-core machine)
    G = np.array([hb.nonlinear_harmonics(p.x, speed_rpm=p.speed_rpm) for p in points])
    g = G[:, n] + 1j * G[:, hb.H + n]
    speeds = np.array([p.speed_rpm for p in points])
    L = hb.loads
    pe = np.zeros((len(points), m.n_elements), dtype=complex)
    if n <= L.n_max:             # cylinder torques only (the rear load acts on the mean, n = 0)
        A = L.engine_coefficients_many(speeds, hb.load)
        pe[:, L.cylinder_elements] = L.cylinder_coefficients_for(A)[:, :, n]
    Om = n * speeds * (RPM_TO_RAD_S / 2.0)
    Z = m.K - (Om ** 2)[:, None, None] * m.J + (1j * Om)[:, None, None] * m.C
    q = np.linalg.solve(Z, (pe @ m.T - g[:, None] * m.e)[..., None])[..., 0]
    qd, qdd = (1j * Om)[:, None] * q, -(Om ** 2)[:, None] * q

    def part(f):
        return m.transmitted_torques(f(q), f(qd), f(qdd), f(pe), extra_torque=f(g))[:, element]

    return part(np.real) + 1j * part(np.imag)
