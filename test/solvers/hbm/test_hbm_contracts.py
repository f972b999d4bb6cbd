"""The parts of the condensed problem read of their host only what their protocols name
(dmf_sim/solvers/hbm: ExpansionHost, StepsHost), and the host provides all of it; the sweep's
collaborators (branch switching, full search) share the sweep's results."""
from __future__ import annotations

import types

import pytest


def test_the_hosts_keep_the_contracts_of_their_parts(paper_hbm):
    """The condensed problem is what its expansion and its continuation steps read
    (ExpansionHost, StepsHost): every member each protocol names exists on the host."""
    from dmf_sim.solvers.hbm.continuation_steps import StepsHost
    from dmf_sim.solvers.hbm.expansion import ExpansionHost
    hb = paper_hbm
    assert isinstance(hb, ExpansionHost) and isinstance(hb, StepsHost)
    assert hb.steps.host is hb and hb.expansion.host is hb
    part = types.SimpleNamespace(**{m: getattr(hb, m) for m in ('model', 'loads', 'load',
                                                                 'factors', 'H', 'dof_loads',
                                                                 'nonlinear_harmonics')})
    assert not isinstance(part, ExpansionHost)         # one member missing (_u0) fails it
    part._u0 = hb._u0
    assert isinstance(part, ExpansionHost)


def test_the_sweeps_collaborators_share_its_results(paper_hbm):
    """The branch switching and the full search are given the sweep's problem, settings and
    result lists (the same objects: what they append, the sweep returns), and report the time
    limit in the phase they set."""
    from dmf_sim.core.errors import TimeLimitError
    from dmf_sim.solvers.hbm import SpeedSweep
    from dmf_sim.solvers.hbm.sweep import SweepOptions
    sw = SpeedSweep(paper_hbm, SweepOptions(time_limit_s=1.0))
    sb, ss = sw.switching, sw.state_search
    assert sb.hbm is ss.hbm is paper_hbm and sb.options is ss.options is sw.options
    assert sb.branches is ss.branches is sw.branches and sb.events is ss.events is sw.events
    for name in ('non_periodic', 'uncovered', 'not_computed'):
        assert getattr(ss, name) is getattr(sw, name), name
    assert ss.search is sw.search and sb.floquet is ss.floquet is sw.floquet
    ss._set_phase('a phase')
    sw._deadline = -1.0
    with pytest.raises(TimeLimitError, match='during a phase at 1000 rpm'):
        ss.check_time(1000.0)


@pytest.fixture(scope='module')
def paper_hbm():
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_model
    from dmf_sim.solvers.hbm import CondensedHBM
    loads = DrivelineExcitation(read_model('truck_dmf', alpha=3.0),
                                read_engine('engine_d13', load_set='A'))
    return CondensedHBM(loads, 1.0)


def test_a_sweep_over_its_time_limit_never_returns(paper_hbm, monkeypatch):
    """The limit is checked between steps and once more at the end: a sweep whose compiled
    stretches ran past it between two checks raises too (no check inside it fires here)."""
    from dmf_sim.core.errors import TimeLimitError
    from dmf_sim.solvers.hbm import SpeedSweep
    from dmf_sim.solvers.hbm.sweep import SweepOptions
    sw = SpeedSweep(paper_hbm, SweepOptions(time_limit_s=1e-3, search=None))
    checks = []
    real = SpeedSweep.check_time

    def during(self, speed_rpm):            # the checks while sweeping see time to spare
        checks.append(self._phase)
        if self._phase == 'the sweep':
            real(self, speed_rpm)
    monkeypatch.setattr(SpeedSweep, 'check_time', during)
    with pytest.raises(TimeLimitError, match='reached during the sweep at 1600 rpm'):
        sw.run((800.0, 1600.0))
    assert checks[-1] == 'the sweep' and len(checks) > 1
