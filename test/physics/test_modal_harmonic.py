"""Modes (paper Fig. 12: 18 Hz / 27 Hz) and the linear harmonic response."""
import json
import subprocess
import sys

import numpy as np
import pytest

from dmf_sim.physics.harmonic import harmonic_response, receptance, solve_harmonic
from dmf_sim.physics.modal import modes
from dmf_sim.physics.model import driveline_from_dict, read_model


def test_dmf_second_mode_matches_paper(truck_dmf):
    # paper: 18 Hz at primary stiffness, 27 Hz at k(1 + alpha), alpha = 3
    f_primary = modes(truck_dmf).frequencies_hz
    f_alpha3 = modes(read_model('truck_dmf', alpha=3.0), 'secondary').frequencies_hz
    assert round(f_primary[2]) == 18
    assert round(f_alpha3[2]) == 27


def test_rigid_body_mode_at_zero_and_dmf_lowers_second_mode(truck_dmf):
    conv = modes(read_model('truck_conventional')).frequencies_hz
    dmf = modes(truck_dmf).frequencies_hz
    assert conv[0] == 0.0 and dmf[0] == 0.0
    assert conv[1] > 0 and dmf[1] > 0
    assert dmf[2] < conv[2]          # the problematic second (elastic) mode moves down


def test_mode_shapes_scaled_by_cumulative_ratio():
    res = modes(read_model('truck_conventional'))
    rigid = res.element_shapes[:, 0]
    np.testing.assert_allclose(rigid, 1.0, atol=1e-9)   # rigid mode is flat after scaling
    assert np.all(np.abs(res.element_shapes).max(axis=0) == pytest.approx(1.0))


def test_harmonic_response_equals_dense_solve(truck_dmf):
    m = truck_dmf
    p = np.zeros(m.n_elements, complex)
    p[2:8] = 100 * np.exp(1j * np.arange(6))
    speeds = np.array([700.0, 1234.0])
    r = harmonic_response(m, speeds, 6, p)
    for s, q in zip(speeds, r.q):
        Om = 3 * s * np.pi / 30
        # dense solve of the element-level equations through the constraint matrix
        Z = (m.T.T @ (np.diag([e.inertia for e in m.line.elements]) * -Om**2) @ m.T + m.K
             + 1j * Om * m.C)
        np.testing.assert_allclose(q, np.linalg.solve(Z, m.T.T @ p), rtol=1e-10)
    np.testing.assert_allclose(r.windup, r.q @ m.e)
    # receptance between wind-up directions
    h = receptance(m, [300.0], m.e, m.e)[0]
    assert h == pytest.approx(m.e @ solve_harmonic(m, 300.0, m.e.astype(complex)))


def test_single_dof_analytic():
    d = {'name': 'sdof', 'elements': [
        {'name': 'GROUND', 'ratio': 1, 'stiffness': 0, 'damping': 0, 'inertia': 1e6},
        {'name': 'MASS', 'ratio': 2.0, 'stiffness': 1000.0, 'damping': 3.0, 'inertia': 0.5}]}
    m = driveline_from_dict(d).reduce()
    speeds = np.linspace(100, 3000, 7)
    p = np.array([0.0, 10.0 + 0j])
    r = harmonic_response(m, speeds, 2, p)
    Om = speeds * np.pi / 30
    # huge ground inertia (the largest an element may have): x = p / (k - Om^2 j + i Om c), to
    # the ground's own motion, ~ j r^2 / J_ground = 2e-6 relative
    expected = 10.0 / (1000.0 - Om**2 * 0.5 + 1j * Om * 3.0)
    np.testing.assert_allclose(r.angles[:, 1], expected, rtol=5e-6)
    # transmitted torque through the spring: -(k + i Om c) dphi
    np.testing.assert_allclose(r.spring_torques[:, 1],
                               -(1000 + 1j * Om * 3) * (r.angles[:, 1] - r.angles[:, 0] / 2),
                               rtol=1e-9)


@pytest.mark.slow
def test_cli_modes_json():
    out = subprocess.run([sys.executable, '-m', 'dmf_sim.cli', 'modes', '--variant', 'dmf',
                          '--alpha', '3', '--json'],
                         capture_output=True, text=True, check=True).stdout
    data = json.loads(out)
    f = data['frequencies_hz']
    assert f == sorted(f) and round(f[2]) == 27      # --alpha selects the secondary stiffness
    assert round(data['regions']['primary'][2]) == 18
    conv = json.loads(subprocess.run([sys.executable, '-m', 'dmf_sim.cli', 'modes', '--variant',
                                      'conventional', '--json'],
                                     capture_output=True, text=True, check=True).stdout)
    assert conv['frequencies_hz'][0] == 0.0
