"""Driveline loads: cylinder phasing, balanced rear and d'Alembert loads, static equilibrium,
CLI."""
import json
import subprocess
import sys

import numpy as np
import pytest
from support.fake_engine import FakeEngine

from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_model


@pytest.fixture(scope='module')
def real(truck_dmf, engine_d13):
    return DrivelineExcitation(truck_dmf, engine_d13)


def test_rear_load_balances_mean_torque(real, engine_d13):
    m = real.model
    P = real.element_harmonics(1200, 1.0)
    mean_engine = real.mean_engine_torque(1200, 1.0)
    assert mean_engine == pytest.approx(engine_d13.mean_torque(1200, 1.0), rel=1e-9)
    # rear load = - engine mean torque x cumulative ratio
    assert P[0, real.rear_element].real == pytest.approx(-mean_engine * m.R[real.rear_element])
    # balanced: no net work on a rigid rotation
    assert abs(np.real(P[0]) @ (1 / m.R)) < 1e-9 * mean_engine


def test_dalembert_load_is_balanced(real):
    m = real.model
    assert abs(real.dalembert_dof @ m.rigid_mode) < 1e-9 * m.equivalent_inertia


def test_time_signal_matches_eq17(real):
    psi = np.linspace(0, 4 * np.pi, 50)
    p = real.element_loads(psi, 1000, 0.7)
    A = real.engine.coefficients(1000, 0.7)
    n = np.arange(len(A))
    for k, el in enumerate(real.cylinder_elements):
        beta = real.beta[k]
        expected = np.real(np.exp(1j * np.outer(psi - beta, n) / 2) @ A)   # eq. (17)
        np.testing.assert_allclose(p[:, el], expected, atol=1e-9)


def test_static_equilibrium_transmits_mean_torque(real):
    st = real.static_state(1200, 1.0)
    # the DMF carries the whole engine mean torque (series chain)
    assert st.dmf_torque == pytest.approx(real.mean_engine_torque(1200, 1.0), rel=1e-9)
    # default engine (2800 Nm): full load winds the DMF just past the knee, 0.9 load stays below
    assert st.region == 'secondary' and 0.24 < st.windup < 0.25
    part = real.static_state(1200, 0.9)
    assert part.region == 'primary' and 0.22 < part.windup < 0.24
    m = real.model
    assert np.allclose(m.K @ st.q + m.e * m.spring.extra_torque(st.windup),
                       np.real(real.dof_harmonics(1200, 1.0)[0]), atol=1e-6)


def test_static_equilibrium_in_secondary_region():
    L = DrivelineExcitation(read_model('truck_dmf', alpha=2.0), FakeEngine({0: 600.0}))
    st = L.static_state(1000, 1.0)
    assert st.region == 'secondary'
    k, th = 10890.0, 0.24
    assert st.windup == pytest.approx(th + (3600 - k * th) / (3 * k))


def test_cylinder_count_mismatch_refused():
    class Four(FakeEngine):
        n_cylinders = 4
    with pytest.raises(ValueError, match='cylinders'):
        DrivelineExcitation(read_model('truck_dmf'), Four({0: 1.0}))


@pytest.mark.slow
def test_cli_loads_json_and_png(tmp_path):
    out = subprocess.run([sys.executable, '-m', 'dmf_sim.cli', 'loads', '--json', '--speeds',
                          '600', '1200', '100', '--out', str(tmp_path)],
                         capture_output=True, text=True, check=True).stdout
    data = json.loads(out)
    a, b, c = (np.array(data['mean_torque_nm'][s]) for s in 'ABC')
    # B and C give more torque at low speed (Load A's data moved down by 50 / 100 rpm)
    assert np.all(c[:3] > b[:3]) and np.all(b[:3] > a[:3])
    assert np.allclose(a[-2:], c[-2:])
    orders = {o['half_order_index']: o['engine_nm'] for o in data['orders_at_speed']['orders']}
    assert orders[6] == max(orders[n] for n in orders if n > 0)
    assert (tmp_path / 'loads.png').stat().st_size > 1000
    bad = subprocess.run([sys.executable, '-m', 'dmf_sim.cli', 'loads', '--load', '2'],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and '--load 2.0: allowed range -1..1' in bad.stderr
