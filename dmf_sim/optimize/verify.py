"""Verifying optimized designs in the time domain (Newmark).

For a design's worst value of an objective (the speed and condition where the harmonic-balance
metrics put it), :func:`verify_worst` runs

* shots: steady-state Newmark runs at that speed from several initial states (the static
  equilibrium and offsets of the wind-up and its rate along the two modes with the most strain
  energy in the DMF, ``dmf_sim.solvers.steady.dmf_modes``), and
* run-ups: slow speed ramps through a window around that speed (inside the study's speed
  range), up to it and down to it (the live node's
  equation: excitation phase = integral of the speed, d'Alembert loads), each started from a
  settled state at the window's end,

and takes the objective's quantity per engine cycle (``dmf_sim.analysis.cycle_orders``): the
wind-up's 1.5th / 3rd order, or the 3rd-order torque into the torque element (``ReducedModel.
transmitted_torques`` of the recorded states). The shots' largest value is the time-domain worst
value compared with the harmonic-balance one; the run-ups' largest value near the speed is
reported beside it, over the cycles within half a grid step of the speed (a ramp passes
coexisting states one way up and another way down, and it sees peaks between grid speeds).

The transient objectives (peak wind-up or DMF torque in the study's load steps,
:mod:`dmf_sim.design.transient`) are time-domain values already: :func:`verify_transient` runs a
design's load steps again with the verification's finer Newmark step (``VerifySettings.dt``)
and compares: the step-refinement check of the study's value. The road cycle's objectives
(friction heat, peak DMF torque; ``conditions.road_cycle``) are checked the same way: the cycle
run again at the finer step.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from dmf_sim.design.parameters import design_driveline
from dmf_sim.physics.orders import ORDER_1_5, ORDER_3

__all__ = ['VERIFIABLE', 'TRANSIENT_VERIFIABLE', 'VerifySettings', 'Check', 'TransientCheck',
           'verify_design', 'verify_worst', 'verify_transient', 'verification_extremes',
           'verification_lines']

VERIFIABLE = {'worst_order_1_5': ('windup', ORDER_1_5), 'worst_order_3': ('windup', ORDER_3),
              'worst_torque_3': ('torque', ORDER_3)}
"""Objectives the time domain can check: (signal, half-order index)."""


TRANSIENT_VERIFIABLE = ('transient_windup', 'transient_dmf_torque', 'cycle_friction_heat',
                        'cycle_dmf_torque')
"""Time-domain objectives (load steps, road cycle) checked by step refinement
(:func:`verify_transient`)."""


@dataclass(frozen=True)
class VerifySettings:
    """dt [s]: Newmark step (<= 5e-5 s resolves the 1.5th-order resonance to < 0.5 %);
    offsets: initial wind-up offsets as multiples of the amplitude scale (0: the static
    equilibrium), each also with the opposite rate; amplitude_min_rad: smallest amplitude scale;
    max_cycles / steady_tol: the shots' settling; window_rpm, ramp_rpm_per_s: the run-ups."""

    dt: float = 5e-5
    offsets: tuple[float, ...] = (0.0, 1.0, -1.0)
    amplitude_min_rad: float = 0.02
    max_cycles: int = 200
    steady_tol: float = 1e-4
    eval_cycles: int = 4
    window_rpm: float = 30.0
    ramp_rpm_per_s: float = 10.0
    run_ups: bool = True


@dataclass
class Check:
    """One objective of one design: HBM worst value vs time domain at its speed and condition."""

    design_id: int
    objective: str
    condition: str
    speed_rpm: float
    hbm: float
    time_domain: float
    run_up: float
    shots: list[float] = field(default_factory=list)
    settled: int = 0

    @property
    def rel_diff(self) -> float:
        """|shots - HBM| / |HBM|: the steady states at the grid speed against harmonic
        balance."""
        return abs(self.time_domain - self.hbm) / abs(self.hbm) if self.hbm else math.nan

    @property
    def run_up_rel_diff(self) -> float:
        """(run-ups - HBM) / |HBM|, signed: what slow ramps through the speed see within half
        a grid step of it, against the harmonic-balance worst value at the grid speed (NaN
        without run-ups)."""
        return (self.run_up - self.hbm) / abs(self.hbm) if self.hbm else math.nan

    def as_dict(self) -> dict:
        return {**asdict(self), 'rel_diff': self.rel_diff,
                'run_up_rel_diff': self.run_up_rel_diff}


@dataclass
class TransientCheck:
    """One transient objective of one design: the study's value (Newmark at the study's step
    ``dt_s``) against the same load steps at the verification's finer step ``refined_dt_s``."""

    design_id: int
    objective: str
    condition: str
    study_value: float
    refined: float
    dt_s: float
    refined_dt_s: float

    @property
    def rel_diff(self) -> float:
        """|refined - study| / |study|."""
        return (abs(self.refined - self.study_value) / abs(self.study_value)
                if self.study_value else math.nan)

    def as_dict(self) -> dict:
        return {**asdict(self), 'rel_diff': self.rel_diff}


def _design(study, row: dict):
    """(the study's evaluation context, the driveline of a design's summary row)."""
    from dmf_sim.design.evaluate import StudyContext
    ctx = StudyContext.from_study(study)
    return ctx, design_driveline(study.base,
                                 ctx.design_values([row[v] for v in study.variable_names]))


def verify_transient(problem, row: dict, settings: VerifySettings | None = None
                     ) -> list[TransientCheck]:
    """The step-refinement checks of a design's time-domain objectives (module docstring)."""
    from dmf_sim.design.transient import (
        CYCLE,
        LOAD_STEP_DT_S,
        cycle_metrics,
        cycle_summary,
        step_metrics,
        transient_summary,
    )
    s = settings or VerifySettings()
    study = problem.study
    wanted = [o for o in study.objectives if o in TRANSIENT_VERIFIABLE
              and row.get(o) is not None and np.isfinite(row[o])]
    if not wanted:
        return []
    _, line = _design(study, row)
    refined: dict = {}
    if study.load_steps and any(o not in CYCLE for o in wanted):
        results = [step_metrics(line, study.engines[step.load_set], step, dt=s.dt)
                   for step in study.load_steps]
        refined.update(transient_summary(study.load_steps, results))
    cycle = study.road_cycle
    if cycle is not None and any(o in CYCLE for o in wanted):
        refined.update(cycle_summary(cycle, cycle_metrics(line, study.engines[cycle.load_set],
                                                          cycle, dt=s.dt)))
    return [TransientCheck(int(row['design_id']), o,
                           str(row.get(f'{o}_condition') or (cycle.label if o in CYCLE else '')),
                           float(row[o]), float(refined[o]), LOAD_STEP_DT_S, s.dt)
            for o in wanted if o in refined]


def verify_design(problem, row: dict, settings: VerifySettings | None = None) -> list[Check]:
    """Time-domain checks of every verifiable objective of a design's summary row."""
    s = settings or VerifySettings()
    study = problem.study
    ctx, line = _design(study, row)
    out = []
    for obj in study.objectives:
        if obj not in VERIFIABLE or row.get(obj) is None or not np.isfinite(row[obj]):
            continue
        cond = next(c for c in study.conditions if c.label == row[f'{obj}_condition'])
        out.append(verify_worst(line, study.engines[cond.load_set], cond.load,
                                float(row[f'{obj}_rpm']), obj, float(row[obj]),
                                ctx.settings.torque_element, s, row['design_id'], cond.label,
                                study.speeds_rpm))
    return out


def verify_worst(line, engine, load: float, speed_rpm: float, objective: str, hbm_value: float,
                 torque_element: int, s: VerifySettings, design_id: int = -1,
                 condition: str = '', speeds_rpm: tuple[float, float, float] | None = None
                 ) -> Check:
    """The time-domain check of one worst value (see the module docstring); ``speeds_rpm``:
    the study's speed grid (from, to, step): the run-ups stay inside it."""
    lo_s, hi_s, step_rpm = speeds_rpm or (0.0, math.inf, 10.0)
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.solvers.newmark import SimulationOptions, simulate
    from dmf_sim.solvers.steady import dmf_modes
    signal, n = VERIFIABLE[objective]
    loads = DrivelineExcitation(line.reduce(), engine)
    model = loads.model
    q_s = loads.static_state(speed_rpm, load).q
    modes = dmf_modes(model, 2)
    amp = max(s.amplitude_min_rad, 2.0 * hbm_value if signal == 'windup' else 0.0)
    shots, settled = [], 0
    for off in s.offsets:
        dq, dv = np.zeros_like(q_s), np.zeros_like(q_s)
        for shape, om in modes:
            dq += off * amp / len(modes) * shape
            dv -= off * om * amp / len(modes) * shape
        r = simulate(loads, speed_rpm, load, initial=(q_s + dq, dv),
                     options=SimulationOptions(dt=s.dt, max_cycles=s.max_cycles,
                                               steady_tol=s.steady_tol,
                                               eval_cycles=s.eval_cycles))
        settled += bool(r.steady)
        shots.append(float(np.max(_cycle_values(r, model, signal, n, torque_element))))
    run_up = math.nan
    if s.run_ups:
        vals = []
        a, b = max(speed_rpm - s.window_rpm, lo_s), min(speed_rpm + s.window_rpm, hi_s)
        for start, end in ((a, b), (b, a)):
            if start == speed_rpm:          # the worst speed at the grid's end: one way only
                continue
            first = simulate(loads, start, load,
                             options=SimulationOptions(dt=s.dt, max_cycles=s.max_cycles,
                                                       steady_tol=s.steady_tol, eval_cycles=1))
            init = (first.q[-1], first.v[-1])
            t_end = abs(end - start) / s.ramp_rpm_per_s
            r = simulate(loads, start, load, t_end=t_end, target_speed_rpm=end,
                         ramp_rpm_per_s=s.ramp_rpm_per_s, initial=init,
                         options=SimulationOptions(dt=s.dt))
            v, speeds = _cycle_values(r, model, signal, n, torque_element, with_speed=True)
            near = (np.abs(speeds - speed_rpm) <= step_rpm / 2.0) & (speeds >= lo_s) \
                & (speeds <= hi_s)
            if near.any():
                vals.append(float(np.max(v[near])))
        run_up = max(vals) if vals else math.nan
    return Check(int(design_id), objective, condition, float(speed_rpm), float(hbm_value),
                 float(max(shots)), run_up, shots, settled)


_CHECK_KEYS = ('design_id', 'objective', 'condition', 'speed_rpm', 'hbm', 'time_domain', 'run_up')


def verification_extremes(checks: list[dict]) -> dict:
    """The two comparisons of the checks (``Check.as_dict`` rows) a summary reports, each with
    the check it comes from: ``verified_max_rel_diff`` (the largest ``rel_diff``: Newmark shots
    at the grid speed vs harmonic balance) and ``verified_run_up_rel_diff`` (the
    ``run_up_rel_diff`` of largest magnitude, signed: slow run-ups through the speed vs harmonic
    balance); ``verified_shots_worst`` / ``verified_run_ups_worst`` name the checks. Empty
    without checks."""
    shots = [c for c in checks if math.isfinite(c['rel_diff'])]
    ups = [c for c in checks if math.isfinite(c['run_up_rel_diff'])]
    out = {}
    if shots:
        w = max(shots, key=lambda c: c['rel_diff'])
        out.update(verified_max_rel_diff=w['rel_diff'],
                   verified_shots_worst={k: w[k] for k in _CHECK_KEYS})
    if ups:
        w = max(ups, key=lambda c: abs(c['run_up_rel_diff']))
        out.update(verified_run_up_rel_diff=w['run_up_rel_diff'],
                   verified_run_ups_worst={k: w[k] for k in _CHECK_KEYS})
    return out


def verification_lines(summary: dict) -> list[str]:
    """What the time domain says about the harmonic-balance worst values, in words (the
    command's summary and the report): what is compared with what, and where the largest
    difference of each comparison is."""
    lines = []
    n = len(summary.get('verification') or [])
    if 'verified_max_rel_diff' in summary:
        w = summary['verified_shots_worst']
        lines += [f'time domain (Newmark) vs harmonic balance (HBM) at each worst value, {n} '
                  'checks:',
                  f'  steady shots at the worst grid speed: largest difference '
                  f'{100 * summary["verified_max_rel_diff"]:.2f} % (design {w["design_id"]}, '
                  f'{w["objective"]} at {w["speed_rpm"]:g} rpm, {w["condition"]}: '
                  f'{w["time_domain"]:.4g} vs HBM {w["hbm"]:.4g})']
    if 'verified_run_up_rel_diff' in summary:
        w = summary['verified_run_ups_worst']
        lines.append(f'  slow run-ups through that speed (within half a grid step of it): '
                     f'largest difference {100 * summary["verified_run_up_rel_diff"]:+.1f} % '
                     f'(design {w["design_id"]}, {w["objective"]} at {w["speed_rpm"]:g} rpm, '
                     f'{w["condition"]}: {w["run_up"]:.4g} vs HBM {w["hbm"]:.4g}); a ramp '
                     'passes between the grid speeds and is not steady')
    return lines


def _cycle_values(r, model, signal: str, n: int, element: int, with_speed: bool = False):
    """Amplitude of half order ``n`` of the signal per whole engine cycle of a Newmark run."""
    from dmf_sim.analysis.cycle_orders import angle_cycle_orders
    if signal == 'windup':
        x = r.windup
    else:
        a = np.gradient(r.v, r.t, axis=0)
        p = r.integrator.element_loads(r.psi)
        x = model.transmitted_torques(r.q, r.v, a, p)[:, element]
    co = angle_cycle_orders(r.psi, x, t_s=r.t)
    amp = np.abs(co.coeffs[:, n])
    return (amp, co.speed_rpm) if with_speed else amp
