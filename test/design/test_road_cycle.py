"""A design study's road cycle and arc-spring friction as design parameters: the harmonic
balance's isolation objective with friction, the friction heat over a window of the packaged
cycle (none without friction, converged in the Newmark step), and one-line refusals."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from dmf_sim.core.errors import ConfigError
from dmf_sim.design import read_study
from dmf_sim.design.evaluate import StudyContext, evaluate_design
from dmf_sim.design.parameters import design_driveline
from dmf_sim.design.transient import LOAD_STEP_DT_S, cycle_metrics
from dmf_sim.optimize.verify import VerifySettings, verify_worst
from dmf_sim.transient.profiles import read_profile

STUDY = {
    'name': 'friction_cycle', 'driveline': 'truck_dmf_friction', 'engine': 'engine_d13',
    'sampling': {'method': 'grid'},
    'variables': {'friction.torque_nm': {'values': [0.0, 80.0]},
                  'friction.speed_coefficient': {'values': [0.0, 3.0e-3]}},
    'conditions': {'load_sets': ['A'], 'loads': [1.0],
                   'speeds_rpm': {'from': 1400, 'to': 1600, 'step': 50},
                   'road_cycle': {'profile': 'truck_road_cycle', 'from_s': 10, 'to_s': 13,
                                  'settle_s': 0.5}},
    'objectives': ['worst_torque_3', 'cycle_friction_heat'],
    'solver': {'harmonics': 8, 'search': False},
}
HEAT_REFINEMENT_REL = 0.05     # friction heat at dt and dt/2 agree within this
HBM_VS_NEWMARK_REL = 0.05      # the 3rd-order torque of the harmonic balance vs the time domain


@pytest.mark.slow
def test_friction_parameters_run_the_harmonic_balance_and_heat_the_dmf():
    study = read_study(copy.deepcopy(STUDY))
    ctx = StudyContext.from_study(study)
    rows = {x: evaluate_design(ctx, i, list(x))[-1]
            for i, x in enumerate([(0.0, 0.0), (80.0, 3.0e-3)])}
    for r in rows.values():
        assert r['status'] == 'ok', r['error']
        assert np.isfinite(r['worst_torque_3']) and r['worst_torque_3'] > 0
    free, rubbing = rows[(0.0, 0.0)], rows[(80.0, 3.0e-3)]
    assert free['cycle_friction_heat'] == 0.0          # no friction, no friction heat
    assert rubbing['cycle_friction_heat'] > 10.0       # [J] in 3 s of launch at 87+ Nm
    # friction changes the steady 3rd-order response the harmonic balance finds
    assert abs(rubbing['worst_torque_3'] / free['worst_torque_3'] - 1) > 0.01
    # the rubbing design's worst 3rd-order torque against Newmark shots at its speed
    line = design_driveline(study.base, ctx.design_values([80.0, 3.0e-3]))
    check = verify_worst(line, study.engines['A'], 1.0, rubbing['worst_torque_3_rpm'],
                         'worst_torque_3', rubbing['worst_torque_3'],
                         study.base.index('INPUT SHAFT'),
                         VerifySettings(dt=1e-4, offsets=(0.0, 1.0), window_rpm=10.0,
                                        max_cycles=150, steady_tol=1e-3),
                         condition='A 1', speeds_rpm=study.speeds_rpm)
    assert check.rel_diff < HBM_VS_NEWMARK_REL
    # the heat converges in the Newmark step
    fine = cycle_metrics(line, study.engines['A'], study.road_cycle, dt=LOAD_STEP_DT_S / 2)
    assert fine['friction_heat_j'] == pytest.approx(rubbing['cycle_friction_heat'],
                                                    rel=HEAT_REFINEMENT_REL)


def test_road_cycle_is_a_window_of_the_profile():
    study = read_study(copy.deepcopy(STUDY))
    cycle, profile = study.road_cycle, read_profile('truck_road_cycle')
    assert cycle.window.duration_s == pytest.approx(3.0)
    t = np.array([0.0, 1.7, 3.0])
    for got, want in zip(cycle.window.at(t), profile.at(t + 10.0)):
        assert got == pytest.approx(want, rel=1e-12)
    assert study.as_dict()['conditions']['road_cycle']['to_s'] == 13.0


@pytest.mark.parametrize('path, value, field', [
    (('conditions', 'road_cycle', 'from_s'), 900.0, 'conditions.road_cycle.from_s'),
    (('conditions', 'road_cycle', 'to_s'), 5.0, 'conditions.road_cycle.to_s'),
    (('conditions', 'road_cycle', 'settle_s'), -1.0, 'conditions.road_cycle.settle_s'),
    (('conditions', 'road_cycle', 'profile'), 'no_such_cycle', 'conditions.road_cycle.profile'),
    (('conditions', 'road_cycle', 'load_set'), 'B', 'conditions.road_cycle.load_set'),
    (('variables', 'friction.torque_nm', 'values'), [-5.0, 1.0], 'friction.torque_nm'),
    (('variables', 'friction.speed_coefficient', 'values'), [0.0, 1.0],
     'friction.speed_coefficient'),
])
def test_bad_road_cycle_or_friction_is_one_line_naming_the_field(path, value, field):
    data = copy.deepcopy(STUDY)
    d = data
    for key in path[:-1]:
        d = d[key]
    d[path[-1]] = value
    with pytest.raises(ConfigError) as err:
        read_study(data)
    text = str(err.value)
    assert '\n' not in text and field in text


def test_cycle_objective_needs_a_road_cycle():
    data = copy.deepcopy(STUDY)
    del data['conditions']['road_cycle']
    with pytest.raises(ConfigError, match=r"objectives\[1\].*conditions.road_cycle"):
        read_study(data)
