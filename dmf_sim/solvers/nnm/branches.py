"""Both NNM branches of Fig. 14 (static point in the primary and in the secondary region), their
flat branches, and the theta-scaling check of the paper."""
from __future__ import annotations

import numpy as np
import scipy.linalg

from dmf_sim.physics.modal import stiffness_matrix
from dmf_sim.physics.model import ReducedModel
from dmf_sim.solvers.nnm.conservative import ConservativeNNM
from dmf_sim.solvers.nnm.results import REGIONS, TWO_PI, FlatBranch, NNMOptions, NNMResult
from dmf_sim.solvers.nnm.subsystems import (
    clamped_frequencies,
    require_dmf,
    static_windup,
    subsystem_frequencies,
)
from dmf_sim.solvers.nnm.time_domain import energy_norm, integrate_physical, static_state

__all__ = ['nnm_branches', 'scaling_check']


def _flat_branches(result: NNMResult, xi_max: float | None) -> list[FlatBranch]:
    subs = result.subsystem_frequencies_hz
    cl = result.clamped_frequencies_hz
    lin = result.linear_frequencies_hz
    out = []
    for name, br in result.branches.items():
        tn = br.tongue_harmonic
        idx = np.flatnonzero(tn > 0)
        if not len(idx):
            continue
        # runs of consecutive points on the same harmonic
        cut = np.flatnonzero((np.diff(idx) > 1) | (np.diff(tn[idx]) != 0)) + 1
        for g in np.split(idx, cut):
            n = int(tn[g[0]])
            if xi_max is not None and br.xi[g].min() > xi_max:
                continue
            f = float(np.median(br.frequency_hz[g]))
            best = None
            for sub, fr in subs.items():
                if len(fr):
                    j = int(np.argmin(np.abs(fr - n * f)))
                    if best is None or abs(fr[j] - n * f) < abs(best[1] - n * f):
                        best = (sub, float(fr[j]))
            jc = int(np.argmin(np.abs(cl - n * f)))
            fl = lin[br.region][lin[br.region] > 0]
            jl = int(np.argmin(np.abs(fl - n * f)))
            out.append(FlatBranch(region=br.region, harmonic=n, frequency_hz=f,
                                  xi_min=float(br.xi[g].min()), xi_max=float(br.xi[g].max()),
                                  subsystem=best[0], subsystem_frequency_hz=best[1],
                                  resonance_hz=float(fl[jl]), clamped_frequency_hz=float(cl[jc])))
    # merge tongues of the same harmonic at the same frequency visited twice (up and back down)
    merged: list[FlatBranch] = []
    for fb in sorted(out, key=lambda x: (x.region, x.harmonic, x.frequency_hz)):
        if merged and merged[-1].region == fb.region and merged[-1].harmonic == fb.harmonic and \
                abs(merged[-1].frequency_hz - fb.frequency_hz) < 0.01 * fb.frequency_hz:
            m = merged[-1]
            m.xi_min, m.xi_max = min(m.xi_min, fb.xi_min), max(m.xi_max, fb.xi_max)
            continue
        merged.append(fb)
    return merged


def nnm_branches(model: ReducedModel, *, mode: int = 2, distance: float | None = None,
                 xi_max: float = 10.0, options: NNMOptions | None = None,
                 regions=REGIONS) -> NNMResult:
    """Both NNM branches of linear mode ``mode``: static wind-up ``distance`` [rad] below the knee
    ('primary', frequency rises with xi) and above it ('secondary', frequency falls), each
    continued from xi = 1 to beyond ``xi_max`` (options.xi_stop, default 1.5 xi_max)."""
    require_dmf(model)
    o = options or NNMOptions()
    xi_stop = o.xi_stop if o.xi_stop is not None else 1.5 * xi_max
    branches = {}
    for region in regions:
        solver = ConservativeNNM(model, static_windup(model, region, distance), mode=mode,
                                 options=o)
        branches[region] = solver.branch(xi_stop=xi_stop)
    lin = {}
    for region in REGIONS:
        K = stiffness_matrix(model, region)
        w2 = scipy.linalg.eigh(K, model.J, eigvals_only=True)
        lin[region] = np.sqrt(np.clip(w2, 0.0, None)) / TWO_PI
    res = NNMResult(driveline=model.line.name, alpha=float(model.spring.alpha),
                    theta=float(model.spring.theta),
                    mode=int(mode), branches=branches, linear_frequencies_hz=lin,
                    subsystem_frequencies_hz=subsystem_frequencies(model),
                    clamped_frequencies_hz=clamped_frequencies(model), n_harmonics=o.n_harmonics)
    res.flat_branches = _flat_branches(res, xi_max)
    return res


def scaling_check(model: ReducedModel, xi_values=(2.0, 5.0), *,
                  cases=((0.24, 0.5), (0.12, 0.1), (0.5, 0.9), (0.05, 0.3)), mode: int = 2,
                  options: NNMOptions | None = None, regions=REGIONS, time_domain: bool = True
                  ) -> dict:
    """The paper's scaling claim: for fixed alpha and xi the frequency does not depend on theta nor
    on the static wind-up's distance d to the knee.

    ``cases`` are (theta [rad], d / theta). Per region and case:
      * frequency_hz: the HBM backbone frequency at ``xi_values`` for that (theta, d);
      * time_domain_error: the reference orbit (theta of ``model``, d = theta / 2) at the backbone
        point nearest each xi, scaled by d / d_ref and started from that case's own static
        equilibrium (engine torque and rear load, full two-step spring, no linearization),
        integrated over the reference period: energy-norm periodicity error (see
        periodicity_error);
      * control_error: the same with the period 0.1 % longer (what a 0.1 % frequency change costs).
    """
    o = options or NNMOptions()
    xi_values = np.asarray(xi_values, float)
    xi_stop = 1.2 * xi_values.max()
    out = {}
    for region in regions:
        ref = ConservativeNNM(model, static_windup(model, region), mode=mode, options=o)
        rb = ref.branch(xi_stop=xi_stop)
        bb = np.flatnonzero(rb.backbone)
        picks = [int(bb[np.argmin(np.abs(rb.xi[bb] - x))]) for x in xi_values]
        rows = []
        for th, frac in cases:
            m = model.line.with_dmf(theta=th).reduce()
            d = frac * th
            ws = static_windup(m, region, d)
            solver = ConservativeNNM(m, ws, mode=mode, options=o)
            br = solver.branch(xi_stop=xi_stop)
            row = {'theta_rad': float(th), 'distance_rad': float(d),
                   'windup_static_rad': float(ws),
                   'frequency_hz': [float(v) for v in br.frequency_at(xi_values)]}
            if time_domain:
                q_s, P0 = static_state(m, ws)
                errs, ctrl, xis = [], [], []
                for i in picks:
                    a, W = rb.coefficients[i], TWO_PI * rb.frequency_hz[i]
                    scale = d / ref.distance
                    x0, v0 = ref.initial_state(a, W)
                    x0 = x0 * scale
                    E = solver.energy(a * scale, W)
                    xis.append(E / solver.e_nl)
                    for fac, store in ((1.0, errs), (1.001, ctrl)):
                        q1, v1 = integrate_physical(m, P0, q_s + x0, v0, fac * TWO_PI / W)
                        store.append(energy_norm(solver.K_lin, m.J, q1 - q_s - x0, v1 - v0, E))
                row.update({'reference_frequency_hz': [float(rb.frequency_hz[i]) for i in picks],
                            'xi_scaled_orbit': [float(v) for v in xis],
                            'time_domain_error': [float(v) for v in errs],
                            'control_error': [float(v) for v in ctrl]})
            rows.append(row)
        F = np.array([r['frequency_hz'] for r in rows])
        spread = float(np.nanmax((F.max(axis=0) - F.min(axis=0)) / F.mean(axis=0)))
        res = {'xi': [float(v) for v in xi_values], 'rows': rows, 'max_relative_spread': spread}
        if time_domain:
            res['max_time_domain_error'] = float(max(max(r['time_domain_error']) for r in rows))
            res['min_control_error'] = float(min(min(r['control_error']) for r in rows))
        out[region] = res
    return out
