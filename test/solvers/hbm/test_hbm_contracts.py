"""The parts of the condensed problem and of the sweep read of their host only what their
protocols name (dmf_sim/solvers/hbm: ExpansionHost, StepsHost, SwitchingHost, SearchHost), and
the hosts provide all of it."""
from __future__ import annotations

import types

import pytest


def test_the_hosts_keep_the_contracts_of_their_parts(paper_hbm):
    """The condensed problem is what its expansion and its continuation steps read
    (ExpansionHost, StepsHost), the sweep what its branch switching and full search read
    (SwitchingHost, SearchHost): every member each protocol names exists on the host."""
    from dmf_sim.solvers.hbm import SpeedSweep
    from dmf_sim.solvers.hbm.branches import SwitchingHost
    from dmf_sim.solvers.hbm.continuation_steps import StepsHost
    from dmf_sim.solvers.hbm.expansion import ExpansionHost
    from dmf_sim.solvers.hbm.search import SearchHost
    hb = paper_hbm
    assert isinstance(hb, ExpansionHost) and isinstance(hb, StepsHost)
    assert hb.steps.host is hb
    sw = SpeedSweep(hb)
    assert isinstance(sw, SwitchingHost) and isinstance(sw, SearchHost)
    part = types.SimpleNamespace(**{m: getattr(hb, m) for m in ('model', 'loads', 'load',
                                                                 'factors', 'H', 'dof_loads',
                                                                 'nonlinear_harmonics')})
    assert not isinstance(part, ExpansionHost)         # one member missing (_u0) fails it
    part._u0 = hb._u0
    assert isinstance(part, ExpansionHost)


@pytest.fixture(scope='module')
def paper_hbm():
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.loads import DrivelineExcitation
    from dmf_sim.physics.model import read_model
    from dmf_sim.solvers.hbm import CondensedHBM
    loads = DrivelineExcitation(read_model('truck_dmf', alpha=3.0),
                                read_engine('engine_d13', load_set='A'))
    return CondensedHBM(loads, 1.0)
