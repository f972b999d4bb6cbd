"""With the default engine (2800 Nm rating) and Table 1, the package shows the
paper's phenomena. HBM sweeps (dmf_sim.solvers.hbm, used as a black box) on a 20 rpm grid (the
alpha 2.5
and 3 peaks lie on it; alpha 2's is 1.2 % below the 10 rpm grid's) with the default H = 24 (H = 16
would move the peaks by ~1 % and save little: a sweep takes ~0.3 s), checked against Newmark at
the strongest peak."""
from __future__ import annotations

import numpy as np
import pytest

from dmf_sim.paper.study import stable_peak_1_5
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.physics.model import read_model
from dmf_sim.solvers.hbm import SweepOptions, sweep as run_sweep

pytestmark = pytest.mark.slow     # full sweeps for three alphas and three load sets

GRID = SweepOptions(step_rpm=20.0)
BAND = (720.0, 1080.0)


@pytest.fixture(scope='module')
def engine(engine_d13):
    return engine_d13


@pytest.fixture(scope='module')
def load_a(engine):
    """Full Load A for alpha 2, 2.5, 3 (600-1300 rpm)."""
    return {a: run_sweep(DrivelineExcitation(read_model('truck_dmf', alpha=a), engine), 1.0,
                         (600.0, 1300.0), options=GRID) for a in (2.0, 2.5, 3.0)}


def test_load_a_resonance_in_band_grows_with_alpha(load_a):
    peaks = {a: stable_peak_1_5(res) for a, res in load_a.items()}
    amps = [peaks[a]['order_1_5'] for a in (2.0, 2.5, 3.0)]
    assert amps[0] < amps[1] < amps[2], amps
    top = peaks[3.0]
    assert BAND[0] <= top['speed_rpm'] <= BAND[1]
    assert top['order_1_5'] >= 5.0 * top['forced_order_1_5'], top       # measured 11.8x
    assert top['order_1_5'] > 0.01                                       # 12.4 mrad at 1000 rpm
    # the resonance (1.5th order > 3x its forced level) is stable and lies inside the band
    summ = [d for d in load_a[3.0].subharmonic_summary() if d['peak_stable']]
    assert summ and all(BAND[0] <= d['speed_min_rpm'] and d['speed_max_rpm'] <= BAND[1]
                        for d in summ)
    # outside the band the 1.5th order stays at its directly forced level
    for res in load_a.values():
        for p in res.main().points:
            if not BAND[0] <= p.speed_rpm <= BAND[1]:
                assert p.order_1_5 < 2.5 * max(p.forced_order_1_5, 1e-4), p.speed_rpm


def test_green_line_reads_as_the_paper(load_a):
    """theta - static wind-up: above both black lines far below the knee (primary only), between
    them at the resonance (both regions)."""
    main = load_a[3.0].main()
    low = next(p.summary for p in main.points if p.speed_rpm == 700.0)
    assert low.theta_minus_static > low.max_deviation
    peak = max(main.points, key=lambda p: p.order_1_5).summary
    assert peak.min_deviation < peak.theta_minus_static < peak.max_deviation


def test_load_sets_b_and_c_peak_at_lower_speeds(engine, load_a):
    model = read_model('truck_dmf', alpha=2.5)
    speed = {'A': stable_peak_1_5(load_a[2.5])['speed_rpm']}
    for ls in ('B', 'C'):
        res = run_sweep(DrivelineExcitation(model, engine.with_load_set(ls)), 1.0, (600.0, 1300.0),
                        options=GRID)
        speed[ls] = stable_peak_1_5(res, *BAND)['speed_rpm']
    assert speed['C'] < speed['A'] and speed['B'] < speed['A'], speed   # 880, 940 < 980 rpm


def test_newmark_confirms_the_alpha_3_peak(load_a):
    """Time integration started at the static equilibrium (not on the HBM solution) reaches the
    same steady state at the peak: 1.5th order within 1 % (dt 5e-5 s, see doc/theory.md §5)."""
    from dmf_sim.solvers.newmark import SimulationOptions, simulate
    res = load_a[3.0]
    (hb,) = res.solutions_at(1000.0)
    nm = simulate(res.hbm.loads, 1000.0, 1.0, options=SimulationOptions(dt=5e-5))
    assert nm.steady
    assert nm.summary.order_1_5 == pytest.approx(hb.order_1_5, rel=0.01)
    assert nm.summary.order_3 == pytest.approx(hb.order_3, rel=0.01)
    assert np.isclose(nm.summary.mean, hb.summary.mean, atol=2e-4)
