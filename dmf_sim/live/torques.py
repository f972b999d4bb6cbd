"""Transmitted torques of every element for the live node, as precomputed matrices.

``ReducedModel.transmitted_torques`` (model.py) is the single source of truth; this operator reads
its matrices off it once and applies them to many states at a time (the node's hot path).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from dmf_sim.core.compiled import jit
from dmf_sim.solvers.newmark_kernel import region_of

__all__ = ['TorqueOperator', 'sparse_outputs']

if TYPE_CHECKING:
    from dmf_sim.solvers.newmark import NewmarkIntegrator


def sparse_outputs(rows, q, v, a, w, omega_dot, start, index, weight, dal, knees, slopes, offsets,
                   primary, c, out):
    """``out[r] = [q v a][r] M + omega_dot dal + g(w[r]) c`` for ``rows`` rows, M given by its
    non-zeros per output column j (``index[start[j]:start[j+1]]`` into [q v a], ``weight``):
    ~100 of M's 3366 entries for the truck model, so a row costs ~100 products instead of a
    dense row-matrix product (no copy of q, v, a into one matrix either). ``knees`` empty: a
    linear spring (no g term); ``dal`` empty: no d'Alembert term. g(w) is the spring law on its
    arrays (:meth:`PiecewiseLinearSpring.arrays`, the region as the Newmark kernel finds it)."""
    n = q.shape[1]
    n_out = start.shape[0] - 1
    nk = knees.shape[0]
    has_dal = dal.shape[0] > 0 and omega_dot != 0.0
    x = np.empty(3 * n)
    for r in range(rows):
        for i in range(n):
            x[i] = q[r, i]
            x[n + i] = v[r, i]
            x[2 * n + i] = a[r, i]
        g = 0.0
        if nk > 0:
            k = region_of(w[r], knees, primary)
            g = slopes[k] * w[r] + offsets[k]
        for j in range(n_out):
            acc = 0.0
            for p in range(start[j], start[j + 1]):
                acc += x[index[p]] * weight[p]
            if has_dal:
                acc += omega_dot * dal[j]
            if nk > 0:
                acc += g * c[j]
            out[r, j] = acc


sparse_outputs = jit(sparse_outputs)


class TorqueOperator:
    """``ReducedModel.transmitted_torques`` as precomputed matrices (same result, ~10x faster).

    The transmitted torques are linear in (q, v, a, element loads p) except for the DMF's extra
    torque g(w), which enters at the DMF element and, through the rigid links in front of it,
    linearly again: ``T = q Lq + v Lv + a La + p Lp + g(w) c``. The matrices are read off
    ``transmitted_torques`` itself (columns for unit inputs with g held at zero, and ``c`` for a
    unit g), so the model stays the single source of truth; the tests compare both. g(w) itself
    comes from the spring (dmf_sim.physics.spring).

    Element loads only matter on rigidly linked elements (``Lp``'s non-zero rows). When neither
    the cylinders nor the rear element are among them (the truck models), ``p Lp`` reduces to the
    d'Alembert part ``omega_dot * (dal Lp)`` and the cylinder series need not be evaluated;
    otherwise the integrator's ``element_loads`` is used.

    :meth:`outputs` gives element angles, velocities and torques at once from one matrix product
    ``[q v a] M`` (the live node's hot path).
    """

    def __init__(self, integ: NewmarkIntegrator) -> None:
        model, L = integ.model, integ.loads
        n, m = model.n_dof, model.n_elements
        self.integ = integ
        self.model = model
        f = model.transmitted_torques
        eps = 1e-6
        In, Im = eps * np.eye(n), eps * np.eye(m)
        zn, zm = np.zeros((n, n)), np.zeros((n, m))
        self.Lq = f(In, zn, zn, zm, 0.0) / eps
        self.Lv = f(zn, In, zn, zm, 0.0) / eps
        self.La = f(zn, zn, In, zm, 0.0) / eps
        self.Lp = f(np.zeros((m, n)), np.zeros((m, n)), np.zeros((m, n)), Im, 0.0) / eps
        used = np.abs(self.Lp).max(axis=1) > 0
        self.needs_loads = bool(used[L.cylinder_elements].any() or used[L.rear_element])
        self.dal = L.dalembert_elements @ self.Lp
        # torques of a unit DMF extra torque g (at the DMF element and through rigid links)
        self.spring = model.spring
        self.c = (f(np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(m), 1.0) if self.spring
                  else np.zeros(m))
        # [q v a] (rows x 3n) @ M (3n x 3m) = [angles | velocities | torques without p, g]
        T = model.T.T
        M = np.zeros((3 * n, 3 * m))
        M[:n, :m] = T
        M[n:2 * n, m:2 * m] = T
        M[:n, 2 * m:] = self.Lq
        M[n:2 * n, 2 * m:] = self.Lv
        M[2 * n:, 2 * m:] = self.La
        self.M = M
        self.m = m
        # the same product from M's non-zeros, column by column (:func:`sparse_outputs`): the
        # angles and velocities without the d'Alembert and spring terms, the torques with them
        cols = [np.flatnonzero(M[:, j]) for j in range(3 * m)]
        self._start = np.concatenate([[0], np.cumsum([len(c) for c in cols])]).astype(np.int64)
        self._index = np.concatenate(cols).astype(np.int64)
        self._weight = np.concatenate([M[c, j] for j, c in enumerate(cols)]).astype(float)
        nonlinear = self.spring is not None and not self.spring.is_linear
        knees, slopes, offsets = (self.spring.arrays() if nonlinear
                                  else (np.zeros(0), np.zeros(1), np.zeros(1)))
        self._law = (knees, slopes, offsets, self.spring.primary_index if nonlinear else 0)
        self._c3 = np.concatenate([np.zeros(2 * m), self.c])
        self._dal3 = np.concatenate([np.zeros(2 * m), self.dal])

    def _add_loads(self, out, w, psi, omega_dot: float, loads=None) -> None:
        if self.needs_loads:
            if loads is None:
                loads = self.integ.element_loads(psi, omega_dot)
            out += loads @ self.Lp
        elif omega_dot:
            out += omega_dot * self.dal
        if self.spring is not None and not self.spring.is_linear:
            out += np.multiply.outer(self.spring.extra_torque(w), self.c)

    def __call__(self, q, v, a, w, psi, omega_dot: float) -> np.ndarray:
        """Torques (rows x elements) for states q, v, a, wind-ups w at crank angles psi."""
        out = q @ self.Lq + v @ self.Lv + a @ self.La
        self._add_loads(out, w, psi, omega_dot)
        return out

    def outputs(self, qva, w, psi, omega_dot: float, loads=None):
        """Element angles, velocities and torques (each rows x elements) from ``qva`` =
        [q v a] (rows x 3 n_dof); ``loads``: the rows' element loads when taken earlier (the
        integrator's excitation may have moved on), else computed now where needed."""
        out = qva @ self.M
        m = self.m
        torques = out[:, 2 * m:]
        self._add_loads(torques, w, psi, omega_dot, loads)
        return out[:, :m], out[:, m:2 * m], torques

    def outputs_of(self, q, v, a, w, psi, omega_dot: float, loads=None, out=None,
                   omega_rad_s=None):
        """:meth:`outputs` of the states q, v, a (rows x n_dof each), with ``out`` (rows x 3
        elements) as the result's storage when given: one compiled pass over M's non-zeros
        where the element loads reduce to the d'Alembert part (the truck models; ~10x faster
        than the dense product, equal to it to round-off), else :meth:`outputs`. A spring
        with friction or end stops adds their torque (doc/theory.md eq. 8a-8b) at the rows'
        wind-up rates and reference speeds ``omega_rad_s`` [rad/s] where it acts like g."""
        res = self._outputs_of(q, v, a, w, psi, omega_dot, loads, out)
        sp = self.spring
        if sp is not None and not sp.smooth_elastic and omega_rad_s is not None:
            res[2][:] += np.multiply.outer(
                sp.law_torque(w, v @ self.integ.model.e, omega_rad_s), self.c)
        return res

    def _outputs_of(self, q, v, a, w, psi, omega_dot: float, loads=None, out=None):
        rows, m = q.shape[0], self.m
        if self.needs_loads:
            res = self.outputs(np.hstack([q, v, a]), w, psi, omega_dot, loads)
            if out is None:
                return res
            out = out[:rows]
            for k, part in enumerate(res):
                out[:, k * m:(k + 1) * m] = part
        else:
            out = np.empty((rows, 3 * m)) if out is None else out[:rows]
            knees, slopes, offsets, primary = self._law
            sparse_outputs(rows, q, v, a, w, float(omega_dot), self._start, self._index,
                           self._weight, self._dal3, knees, slopes, offsets, primary, self._c3,
                           out)
        return out[:, :m], out[:, m:2 * m], out[:, 2 * m:]
