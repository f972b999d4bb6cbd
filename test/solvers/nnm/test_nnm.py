"""Non-linear normal modes (paper Fig. 14): linear limit, periodicity in time, scaling, trends."""
import json

import numpy as np
import pytest

from dmf_sim.cli import main
from dmf_sim.physics.modal import modes
from dmf_sim.physics.model import read_driveline, read_model
from dmf_sim.solvers.nnm import (
    ConservativeNNM,
    NNMOptions,
    integrate_physical,
    nnm_branches,
    scaling_check,
    static_state,
    static_windup,
    subsystem_frequencies,
)


@pytest.fixture(scope='module')
def model():
    return read_model('truck_dmf', alpha=2.0)


@pytest.fixture(scope='module')
def result(model):
    return nnm_branches(model, xi_max=10.0)


@pytest.mark.slow
def test_linear_limit_at_xi_one(model, result):
    """At xi -> 1 the NNM frequencies are the linear ones at primary / secondary stiffness."""
    for region in ('primary', 'secondary'):
        f_lin = modes(model, region).frequencies_hz[2]
        br = result.branches[region]
        assert br.xi[0] == pytest.approx(1.0, abs=1e-12)
        assert br.frequency_hz[0] == pytest.approx(f_lin, rel=1e-12)
        assert br.linear_frequency_hz == pytest.approx(f_lin, rel=1e-12)
        # continuous out of the linear limit
        assert br.frequency_at([1.0005])[0] == pytest.approx(f_lin, rel=2e-4)
    assert result.branches['primary'].frequency_hz[0] == pytest.approx(17.88, abs=0.01)
    assert result.branches['secondary'].frequency_hz[0] == pytest.approx(24.66, abs=0.01)


def test_primary_rises_secondary_falls_toward_one_frequency(result):
    xi = np.linspace(1.0, 10.0, 37)
    fp = result.branches['primary'].frequency_at(xi)
    fs = result.branches['secondary'].frequency_at(xi)
    assert np.all(np.isfinite(fp)) and np.all(np.isfinite(fs))
    assert np.all(np.diff(fp) > 0)             # stiffening: static point in the primary region
    assert np.all(np.diff(fs) < 0)             # softening: static point in the secondary region
    gap = fs - fp
    assert np.all(gap > 0) and gap[-1] < 0.5 * gap[0]


@pytest.mark.slow
def test_periodic_solutions_return_after_one_period(model, result):
    """Full DOF state recovered from the HBM solution, integrated over one period in time
    (scipy DOP853, restart at each knee crossing), returns to its start."""
    for region in ('primary', 'secondary'):
        br = result.branches[region]
        solver = ConservativeNNM(model, br.windup_static)
        picks = [int(np.argmin(np.abs(np.where(br.backbone, br.xi, np.inf) - x)))
                 for x in (2.0, 6.0)]
        tongue = np.flatnonzero((br.tongue_harmonic > 0) & (br.xi < 10))
        if len(tongue):
            picks.append(int(tongue[len(tongue) // 2]))
        for i in picks:
            a, W = br.coefficients[i], 2 * np.pi * br.frequency_hz[i]
            x0, v0 = solver.initial_state(a, W)
            assert model.e @ x0 == pytest.approx(a.sum(), rel=1e-9)      # wind-up recovered
            err = solver.periodicity_error(a, W)
            ctrl = solver.periodicity_error(a, W, period_factor=1.001)
            assert err < 1e-3, (region, i, br.xi[i], err)
            assert ctrl > 5 * err


@pytest.mark.slow
def test_time_integration_error_shrinks_with_harmonics(model):
    errs = []
    for H in (10, 40):
        s = ConservativeNNM(model, static_windup(model, 'primary'),
                            options=NNMOptions(n_harmonics=H, step_max=0.1))
        br = s.branch(xi_stop=4.5)
        i = int(np.argmin(np.abs(br.xi - 4.0)))
        errs.append(s.periodicity_error(br.coefficients[i], 2 * np.pi * br.frequency_hz[i]))
    assert errs[1] < 0.1 * errs[0]
    assert errs[1] < 2e-4


def test_frequency_converged_in_harmonics(model):
    f = []
    for H in (15, 30):
        s = ConservativeNNM(model, static_windup(model, 'secondary'),
                            options=NNMOptions(n_harmonics=H, step_max=0.1))
        f.append(s.branch(xi_stop=3.2).frequency_at([1.5, 3.0]))
    np.testing.assert_allclose(f[0], f[1], rtol=1e-5)


@pytest.mark.slow
def test_scaling_claim_frequency_independent_of_theta_and_distance(model):
    """Paper: for fixed alpha and xi the frequency does not depend on theta (nor on the static
    wind-up's distance to the knee). HBM for other (theta, d), and the scaled reference orbit
    integrated on the full non-linear driveline with its own static load."""
    sc = scaling_check(model, xi_values=(2.0, 4.0), cases=((0.12, 0.1), (0.5, 0.9)))
    for region, v in sc.items():
        assert v['max_relative_spread'] < 1e-9
        assert v['max_time_domain_error'] < 1e-3
        assert v['min_control_error'] > 5 * v['max_time_domain_error']
        for row in v['rows']:
            np.testing.assert_allclose(row['xi_scaled_orbit'],
                                       sc[region]['rows'][0]['xi_scaled_orbit'], rtol=1e-9)


@pytest.mark.slow
def test_static_state_holds_the_requested_windup(model):
    for ws in (0.1, 0.4):
        q_s, P0 = static_state(model, ws)
        assert model.e @ q_s == pytest.approx(ws, rel=1e-10)
        assert abs(model.rigid_mode @ P0) < 1e-9 * np.abs(P0).max()
        # equilibrium of the full non-linear chain: it stays put
        q1, v1 = integrate_physical(model, P0, q_s, np.zeros_like(q_s), 0.05)
        assert np.abs(q1 - q_s).max() < 1e-9 * max(abs(ws), 1)


def test_residual_jacobian_and_exact_force_harmonics(model):
    s = ConservativeNNM(model, static_windup(model, 'primary'), options=NNMOptions(n_harmonics=8))
    rng = np.random.default_rng(1)
    a = np.zeros(9)
    a[0], a[1] = 0.01, 0.3
    a[2:6] = 0.01 * rng.normal(size=4)
    W = 1.07 * s.omega_lin
    r, Ja, rW = s.residual_and_jacobians(a, W)
    eps = 1e-7
    Jfd = np.array([(s.residual(a + eps * e, W) - s.residual(a - eps * e, W)) / (2 * eps)
                    for e in np.eye(9)]).T
    np.testing.assert_allclose(Ja, Jfd, atol=1e-7)
    rWfd = (s.residual(a, W * (1 + 1e-7)) - s.residual(a, W * (1 - 1e-7))) / (2e-7 * W)
    np.testing.assert_allclose(rW, rWfd, atol=1e-9)
    # exact Galerkin harmonics vs a very fine sampled FFT
    N = 1 << 16
    tau = 2 * np.pi * np.arange(N) / N
    g = s.force.value(np.cos(np.outer(tau, np.arange(9))) @ a)
    G = np.fft.rfft(g) / N
    fs = 2 * G.real[:9]
    fs[0] /= 2
    np.testing.assert_allclose(s.force.harmonics(a), fs, atol=1e-5 * np.abs(fs).max())


def test_flat_branches_sit_at_subsystem_resonances(model, result):
    assert result.flat_branches, 'expected at least one flat branch'
    subs = subsystem_frequencies(model)
    assert subs['front'].min() > 100 and subs['rear'].min() < 20
    for fb in result.flat_branches:
        assert fb.harmonic >= 2
        assert (abs(fb.harmonic * fb.frequency_hz - fb.subsystem_frequency_hz)
                < 0.02 * fb.subsystem_frequency_hz)
        assert abs(fb.harmonic * fb.frequency_hz - fb.resonance_hz) < 0.01 * fb.resonance_hz
    regions = {fb.region for fb in result.flat_branches}
    assert regions == {'primary', 'secondary'}


def test_coast_knee_and_errors():
    line = read_driveline('truck_dmf', alpha=2.0)
    coast = line.with_dmf(coast_stages=[(0.1, 1.0)]).reduce()
    s = ConservativeNNM(coast, 0.12, options=NNMOptions(step_max=0.1))
    assert len(s.force.beta) == 2
    br = s.branch(xi_stop=3.0)
    i = int(np.argmin(np.abs(br.xi - 2.5)))
    assert s.periodicity_error(br.coefficients[i], 2 * np.pi * br.frequency_hz[i]) < 1e-3
    with pytest.raises(ValueError, match='alpha = 0'):
        ConservativeNNM(read_model('truck_dmf', alpha=0.0), 0.1)
    with pytest.raises(ValueError, match='no dmf'):
        nnm_branches(read_model('truck_conventional'))
    with pytest.raises(ValueError, match='on a knee'):
        ConservativeNNM(read_model('truck_dmf'), 0.24)


@pytest.mark.slow
def test_cli_writes_csv_json_png(tmp_path, capsys):
    out = tmp_path / 'nnm'
    assert main(['nnm', '--alpha', '2', '--xi-max', '4', '--harmonics', '12', '--json',
                 '--out', str(out)]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data['alpha'] == 2.0 and data['summary']['xi'][0] == 1.0
    fp, fs = data['summary']['primary'], data['summary']['secondary']
    assert fp[0] == pytest.approx(17.88, abs=0.01) and fs[0] == pytest.approx(24.66, abs=0.01)
    assert fp[-1] > fp[0] and fs[-1] < fs[0]
    for name in ('nnm.csv', 'nnm.json', 'nnm.png'):
        assert (out / name).stat().st_size > 0
    header = (out / 'nnm.csv').read_text().splitlines()[0].split(',')
    assert header[:4] == ['region', 'segment', 'xi', 'frequency_hz']
    assert main(['nnm', '--xi-max', '0.5']) == 2


def test_the_command_says_what_the_modes_leave_out(capsys):
    """A friction DMF's NNMs are those of its elastic spring: the command says so."""
    from dmf_sim.cli import main
    from dmf_sim.commands.nnm import left_out
    from dmf_sim.physics.model import read_model

    assert left_out(read_model('truck_dmf').spring) == ''
    text = left_out(read_model('truck_dmf_friction').spring)
    assert 'friction' in text and 'end stops' in text
    assert main(['nnm', '--config', 'truck_dmf_friction', '--xi-max', '1.5']) == 0
    assert f'left out: {text}' in capsys.readouterr().out
