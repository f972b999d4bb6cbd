"""Every compiled kernel of the kernel registry (dmf_sim/solvers/kernel_registry.py) against its
reference: one test per parity case the registry names (the builders: test/support/
kernel_cases.py), each output compared to the tolerance the registry entries state; and a case
for every entry."""
from __future__ import annotations

import pytest
from support.kernel_cases import CASES, Problems, assert_parity

from dmf_sim.solvers.kernel_registry import KERNELS

pytestmark = pytest.mark.parity

NAMED = sorted({k.case for k in KERNELS})


@pytest.fixture(scope='module')
def problems():
    return Problems()


def tolerance(case: str) -> float:
    """The tolerance the registry states for ``case`` (the same for every entry naming it)."""
    (tol,) = {k.rel_tol for k in KERNELS if k.case == case}
    return tol


def test_every_entry_has_a_case_with_one_tolerance():
    missing = sorted({f'{k.kernel} -> {k.case!r}' for k in KERNELS if k.case not in CASES})
    assert not missing, f'kernel registry entries without a parity case: {missing}'
    assert set(CASES) == set(NAMED), set(CASES) - set(NAMED)     # no case left unused
    for case in NAMED:
        tols = {k.rel_tol for k in KERNELS if k.case == case}
        assert len(tols) == 1 and 0.0 <= min(tols) < 1e-6, (case, tols)


@pytest.mark.parametrize('case', [c for c in NAMED if c in CASES])
def test_kernel_equals_reference(case, problems):
    tol = tolerance(case)
    n = 0
    for pair in CASES[case](problems):
        assert_parity(pair.kernel, pair.reference, tol, pair.label)
        n += 1
    assert n > 0
