"""Driveline model: YAML validation, rigid merging, J/K/C assembly (eq. 1, 5-6), DMF spring."""
import copy

import numpy as np
import pytest
import yaml

from dmf_sim.core.paths import config_file
from dmf_sim.physics.model import driveline_from_dict, read_driveline, read_model


def raw(name='truck_dmf'):
    return yaml.safe_load(config_file(name).read_text())


def test_table1_loaded_and_merged():
    conv = read_model('truck_conventional')
    dmf = read_model('truck_dmf')
    assert conv.n_elements == dmf.n_elements == 22
    # rigid links: conventional 10,11,13,18,20; DMF 10,12,13,18,20 -> 22 - 5 = 17 DOFs
    assert conv.n_dof == dmf.n_dof == 17
    assert dmf.line.dmf.theta == pytest.approx(0.24)
    assert dmf.spring.k == pytest.approx(10890.0)
    # cumulative ratio at the vehicle: 0.881 * 0.9105 * 2.66
    assert dmf.R[-1] == pytest.approx(0.881 * 0.9105 * 2.66)


def test_every_element_angle_recovered_through_constraints():
    m = read_model('truck_dmf')
    r = m.rigid_mode
    assert r is not None
    np.testing.assert_allclose(m.element_angles(r), 1.0 / m.R, rtol=1e-12)
    q = np.random.default_rng(0).normal(size=m.n_dof)
    phi = m.element_angles(q)
    names = m.names
    for i, el in enumerate(m.line.elements):
        if el.rigid:   # rigid constraint phi_i = phi_{i-1} / r_i holds for every named element
            assert phi[i] == pytest.approx(phi[i - 1] / el.ratio)
    assert names[m.dmf_element] == 'SECONDARY FLYWHEEL'
    # wind-up = primary - secondary (through the ratio)
    assert m.windup(q) == pytest.approx(phi[m.dmf_element - 1] - phi[m.dmf_element])


@pytest.mark.parametrize('name', ['truck_conventional', 'truck_dmf'])
def test_K_C_symmetric_psd_and_energy_consistent(name):
    m = read_model(name)
    for M in (m.K, m.C):
        np.testing.assert_allclose(M, M.T, atol=1e-9 * np.abs(M).max())
        ev = np.linalg.eigvalsh(M)
        assert ev.min() >= -1e-9 * ev.max()
    # rigid rotation deforms nothing: K r = C r = 0 (one rigid-body mode)
    r = m.rigid_mode
    assert np.abs(m.K @ r).max() < 1e-6 * np.abs(m.K).max()
    assert np.abs(m.C @ r).max() < 1e-9 * np.abs(m.C).max()
    # energy: q^T K q / 2 == sum k_i dphi_i^2 / 2 (element equation, eq. 1)
    q = np.random.default_rng(1).normal(size=m.n_dof)
    phi = m.element_angles(q)
    e_el = 0.0
    d_el = 0.0
    for i, el in enumerate(m.line.elements):
        if el.rigid or i == 0:
            continue
        dphi = phi[i] - phi[i - 1] / el.ratio
        e_el += 0.5 * el.stiffness * dphi**2
        d_el += 0.5 * el.damping * dphi**2
    assert 0.5 * q @ m.K @ q == pytest.approx(e_el, rel=1e-10)
    # damping uses c/r^2 on the diagonal like K (eq. 6 misprint fixed)
    assert 0.5 * q @ m.C @ q == pytest.approx(d_el, rel=1e-10)


def test_rigid_merge_equals_limit_of_growing_stiffness():
    from dmf_sim.core.bounds import BOUNDS
    from dmf_sim.physics.modal import modes
    base = raw('truck_conventional')
    merged = modes(driveline_from_dict(base).reduce()).frequencies_hz[:6]
    prev_err = np.inf
    for k in (1e8, 1e9, BOUNDS['stiffness'].hi):      # up to the stiffest a file may hold
        d = copy.deepcopy(base)
        for el in d['elements']:
            if el['stiffness'] == 'rigid':
                el['stiffness'] = k
        f = modes(driveline_from_dict(d).reduce()).frequencies_hz[:6]
        err = np.max(np.abs(f[1:] - merged[1:]) / merged[1:])
        assert err < prev_err
        prev_err = err
    assert prev_err < 1e-4


@pytest.mark.parametrize('mutate, message', [
    (lambda d: d['elements'][3].pop('inertia'), "missing key 'inertia'"),
    (lambda d: d['elements'][3].update(colour='red'), "unknown key 'colour'"),
    (lambda d: d['elements'][3].update(inertia=0.0), "CYL2"),
    (lambda d: d['elements'][3].update(inertia=-1.0),
     "'inertia' must be in (0, 1e+06] kg m^2, got -1.0"),
    (lambda d: d['elements'][14].update(ratio=0),
     "'ratio' must be in [-100, -0.01] or [0.01, 100], got 0.0"),
    (lambda d: d['elements'][5].update(stiffness=-5.0),
     "'stiffness' must be in [0, 1e+10] Nm/rad or 'rigid', got -5.0"),
    (lambda d: d['dmf'].update(element='HUB'), 'rigid element'),
    (lambda d: d['dmf'].update(element='NOPE'), 'unknown element'),
    (lambda d: d['dmf'].update(theta_rad=-0.1), "'theta_rad' must be in (0, 2] rad"),
    (lambda d: d['dmf'].pop('alpha'), "missing key 'alpha'"),
    (lambda d: d.update(wheels=4), "unknown key 'wheels'"),
    (lambda d: d['elements'][3].update(damping=float('nan')),
     "'damping' must be in [0, 1e+06] Nms/rad, got nan"),
])
def test_bad_config_refused_with_one_clear_line(mutate, message):
    d = raw('truck_dmf')
    mutate(d)
    with pytest.raises(ValueError) as exc:
        driveline_from_dict(d)
    text = str(exc.value)
    assert message in text
    assert '\n' not in text


def test_missing_inertia_error_names_element_and_field():
    d = raw('truck_dmf')
    d['elements'][3].pop('inertia')
    with pytest.raises(ValueError, match=r"element 4 \(CYL2\): missing key 'inertia'"):
        driveline_from_dict(d)


def test_alpha_override_and_bad_alpha():
    assert read_driveline('truck_dmf', alpha=3.0).dmf.alpha == 3.0
    with pytest.raises(ValueError, match='alpha'):
        read_driveline('truck_dmf', alpha=-1.0)
    with pytest.raises(ValueError, match='no dmf section'):
        read_driveline('truck_conventional', alpha=1.0)
