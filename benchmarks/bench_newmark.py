"""Benchmark: Newmark kernel speed on the full DMF model vs scipy.integrate.solve_ivp.

Figures printed: steps per second and real-time factor at dt = 1e-4 s (one core, compiled
kernel, numba compile excluded), and the speed-up over solve_ivp on the same case (same start,
same excitation) at the same accuracy: both are compared with a reference run (Newmark at dt/8)
over the same interval; solve_ivp's rtol is tightened until its wind-up error is no larger than
Newmark's at dt.

What arc-spring friction and end stops cost (``config/truck_dmf_friction.yaml``, the paper's DMF
with both; doc/theory.md eq. 8a-8c): ``kernel_friction_slowdown``, the kernel's time per step
with them over without (same case, same steps); ``run_friction_slowdown``, the wall time of
``dmf-sim run --no-write`` of a tip-in (``step:1200:0:1:0.1``, 4.2 s simulated, the node's 1 kHz
samples read out) with them over without, the median of ``--repeat`` alternating runs in this
process; ``realtime_factor_run_friction``: simulated / wall seconds of that run with friction
(the node at 1 kHz keeps real time while it is > 1). Last line: one JSON object.

    python benchmarks/bench_newmark.py [--steps N] [--ivp-seconds S] [--repeat R] [--quick]
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np
from scipy.integrate import solve_ivp

from dmf_sim.physics.engine import read_engine
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_model
from dmf_sim.solvers.newmark import NewmarkIntegrator, StepRecord

SPEED_RPM = 900.0      # 1.5th-order region of the paper (knee crossings happen)
LOAD = 1.0
ALPHA = 3.0
DT = 1e-4


def make_loads() -> DrivelineExcitation:
    return DrivelineExcitation(read_model('truck_dmf', alpha=ALPHA), read_engine('engine_d13'))


def newmark_windup(L, dt: float, t_end: float) -> tuple[np.ndarray, np.ndarray]:
    integ = NewmarkIntegrator(L, dt=dt)
    integ.reset(SPEED_RPM, LOAD)
    n = int(round(t_end / dt))
    rec = StepRecord.allocate(n, L.model.n_dof)
    integ.advance(n, rec, 1)
    return rec.t[:n].copy(), rec.windup[:n].copy()


def ivp_windup(L, t_eval: np.ndarray, rtol: float) -> tuple[np.ndarray, float, int]:
    m = L.model
    integ = NewmarkIntegrator(L, dt=DT)          # for the same start and the same load function
    integ.reset(SPEED_RPM, LOAD)
    omega = integ.omega
    n = m.n_dof
    Jinv = 1.0 / np.diag(m.J)
    sp = m.spring

    def rhs(t, y):
        q, v = y[:n], y[n:]
        P = integ.generalized_load(omega * t)
        f = P - m.C @ v - m.K @ q - m.e * float(sp.extra_torque(m.e @ q))
        return np.concatenate([v, Jinv * f])

    y0 = np.concatenate([integ.q, integ.v])
    t0 = time.perf_counter()
    sol = solve_ivp(rhs, (0.0, t_eval[-1]), y0, method='RK45', rtol=rtol, atol=rtol * 1e-3,
                    t_eval=t_eval)
    wall = time.perf_counter() - t0
    return sol.y[:n].T @ m.e, wall, sol.nfev


FRICTION_CONFIG = 'truck_dmf_friction'
TIP_IN = 'step:1200:0:1:0.1'           # 0 -> 1 -> 0 in 0.1 s at 1200 rpm: sliding and sticking
TIP_IN_QUICK = 'step:1200:0:1:0.1:0.3:0.2'


def kernel_seconds(L, steps: int) -> float:
    """Wall seconds of ``steps`` Newmark steps (recorded at 100 Hz) after a warm-up."""
    integ = NewmarkIntegrator(L, dt=DT)
    integ.reset(SPEED_RPM, LOAD)
    integ.advance(1000, StepRecord.allocate(1000, L.model.n_dof), 1)
    stride = 100
    rec = StepRecord.allocate(steps // stride + 1, L.model.n_dof)
    t0 = time.perf_counter()
    integ.advance(steps, rec, stride)
    return time.perf_counter() - t0


def run_seconds(config: str, profile: str) -> tuple[float, float]:
    """(wall, simulated) seconds of ``dmf-sim run PROFILE --config CONFIG --no-write``."""
    from dmf_sim.transient.profiles import read_profile
    from dmf_sim.transient.run import RunOptions, run_profile
    s = run_profile(read_profile(profile), None,
                    RunOptions(driveline=config, write=False))
    return s.wall_s, s.simulated_s


def friction_cost(steps: int, profile: str, repeat: int) -> dict:
    """The friction figures of the module docstring."""
    import statistics
    plain = make_loads()
    rough = DrivelineExcitation(read_model(FRICTION_CONFIG, alpha=ALPHA),
                                read_engine('engine_d13'))
    k_plain, k_rough = kernel_seconds(plain, steps), kernel_seconds(rough, steps)
    for config in ('truck_dmf', FRICTION_CONFIG):          # compile / load once
        run_seconds(config, profile)
    walls: dict[str, list[float]] = {'truck_dmf': [], FRICTION_CONFIG: []}
    simulated = 0.0
    for _ in range(repeat):
        for config in walls:
            wall, simulated = run_seconds(config, profile)
            walls[config].append(wall)
    w_plain = statistics.median(walls['truck_dmf'])
    w_rough = statistics.median(walls[FRICTION_CONFIG])
    return {'kernel_friction_slowdown': round(k_rough / k_plain, 3),
            'kernel_steps_per_s_friction': round(steps / k_rough),
            'run_friction_slowdown': round(w_rough / w_plain, 3),
            'realtime_factor_run_friction': round(simulated / w_rough, 1),
            'realtime_factor_run_no_friction': round(simulated / w_plain, 1),
            'friction_profile': profile, 'friction_config': FRICTION_CONFIG,
            'friction_repeat': repeat}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--steps', type=int, default=2_000_000,
                    help='Newmark steps timed (default 2e6 = 200 s)')
    ap.add_argument('--ivp-seconds', type=float, default=0.2,
                    help='simulated seconds for the accuracy race')
    ap.add_argument('--repeat', type=int, default=5,
                    help='runs with and without friction (alternating; the medians)')
    ap.add_argument('--quick', action='store_true', help='small sizes (used by the test suite)')
    args = ap.parse_args(argv)
    if args.quick:
        args.steps, args.ivp_seconds, args.repeat = 200_000, 0.05, 1
    os.environ.setdefault('NUMBA_NUM_THREADS', '1')
    L = make_loads()

    # --- raw kernel speed -------------------------------------------------------------
    integ = NewmarkIntegrator(L, dt=DT)
    integ.reset(SPEED_RPM, LOAD)
    rec = StepRecord.allocate(1000, L.model.n_dof)
    integ.advance(1000, rec, 1)                              # compile / warm up
    stride = 100                                           # record at 100 Hz like a light consumer
    rec = StepRecord.allocate(args.steps // stride + 1, L.model.n_dof)
    t0 = time.perf_counter()
    integ.advance(args.steps, rec, stride)
    wall = time.perf_counter() - t0
    steps_per_s = args.steps / wall
    rtf = steps_per_s * DT

    # --- accuracy-matched comparison with solve_ivp -----------------------------------
    T = args.ivp_seconds
    t_ref, w_ref = newmark_windup(L, DT / 8, T)
    t_nm, w_nm = newmark_windup(L, DT, T)
    w_ref_on = np.interp(t_nm, t_ref, w_ref)
    scale = float(np.ptp(w_ref_on))
    err_nm = float(np.max(np.abs(w_nm - w_ref_on))) / scale
    t1 = time.perf_counter()
    newmark_windup(L, DT, T)
    nm_wall = time.perf_counter() - t1
    ivp_wall = err_ivp = rtol_used = nfev = None
    for rtol in (1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        w_ivp, ivp_wall, nfev = ivp_windup(L, t_nm, rtol)
        err_ivp = float(np.max(np.abs(w_ivp - w_ref_on))) / scale
        rtol_used = rtol
        if err_ivp <= err_nm:
            break
    result = {
        'steps_per_s': round(steps_per_s),
        'realtime_factor': round(rtf, 1),
        'dt_s': DT,
        'n_dof': L.model.n_dof,
        'newmark_rel_error': err_nm,
        'solve_ivp_rel_error': err_ivp,
        'solve_ivp_rtol': rtol_used,
        'solve_ivp_nfev': nfev,
        'newmark_seconds': round(nm_wall, 4),
        'solve_ivp_seconds': round(ivp_wall, 3),
        'speedup_vs_solve_ivp': round(ivp_wall / nm_wall, 1),
        'simulated_seconds_compared': T,
        'targets': {'steps_per_s': 1e6, 'realtime_factor': 100, 'speedup_vs_solve_ivp': 50,
                    'run_friction_slowdown_max': 2.0, 'realtime_factor_run_friction_min': 1.0},
    }
    result.update(friction_cost(args.steps, TIP_IN_QUICK if args.quick else TIP_IN,
                                args.repeat))
    print(f'Newmark (numba, 1 core): {steps_per_s:,.0f} steps/s = {rtf:.0f}x real time '
          f'at dt={DT} s')
    print(f'accuracy over {T} s vs dt/8 reference: Newmark {err_nm:.2e}, '
          f'solve_ivp RK45 rtol={rtol_used:g} {err_ivp:.2e}')
    print(f'wall: Newmark {nm_wall*1e3:.1f} ms, solve_ivp {ivp_wall*1e3:.0f} ms '
          f'-> speed-up {ivp_wall/nm_wall:.0f}x')
    r = result
    print(f'friction and end stops ({FRICTION_CONFIG}): kernel x{r["kernel_friction_slowdown"]} '
          f'per step, dmf-sim run {r["friction_profile"]} x{r["run_friction_slowdown"]} '
          f'({r["realtime_factor_run_friction"]:.0f}x real time with them)')
    print(json.dumps(result))
    return result


if __name__ == '__main__':
    main()
