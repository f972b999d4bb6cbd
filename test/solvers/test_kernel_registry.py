"""The kernel registry (dmf_sim/solvers/kernel_registry.py) is complete and true: every compiled
function of the solvers is listed, each entry point's reference twin exists, and each group's
warm-up loads exactly the entry points the registry gives it (the parity cases the entries name:
test_kernel_parity.py)."""
from __future__ import annotations

import importlib
import pkgutil

import pytest

import dmf_sim.solvers
from dmf_sim.solvers import kernel_registry
from dmf_sim.solvers.kernel_registry import HELPERS, KERNELS, entry_points, resolve


def compiled_functions() -> set[str]:
    """``module:name`` of every numba dispatcher defined in a module of dmf_sim.solvers."""
    from numba.core.registry import CPUDispatcher
    found = set()
    for info in pkgutil.walk_packages(dmf_sim.solvers.__path__, 'dmf_sim.solvers.'):
        module = importlib.import_module(info.name)
        for name, obj in vars(module).items():
            if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == info.name:
                found.add(f'{info.name}:{name}')
    return found


def test_every_compiled_function_of_the_solvers_is_registered():
    listed = [k.kernel for k in KERNELS] + list(HELPERS)
    assert len(listed) == len(set(listed))                   # each once
    found = compiled_functions()
    assert len(found) > 40
    assert set(listed) == found, (set(listed) - found, found - set(listed))


@pytest.mark.parametrize('entry', KERNELS, ids=lambda k: k.kernel.split(':')[1])
def test_an_entry_point_has_its_reference(entry):
    assert hasattr(resolve(entry.kernel), 'py_func')          # a compiled kernel
    if entry.reference:
        assert callable(resolve(entry.reference))
    else:                        # the one version: only the step control has none
        assert entry.kernel.startswith('dmf_sim.solvers.step_control:')


def test_the_groups_load_the_registered_entry_points():
    """The sweep group's list is the registry's; the time-integration group's list starts with
    the registry's Newmark kernels; after a group's warm-up each of them is loaded."""
    from dmf_sim.live.warm import TIME_INTEGRATION
    from dmf_sim.solvers.hbm.warm import SWEEP
    for group in (SWEEP, TIME_INTEGRATION):
        mine = entry_points(group.name)
        assert mine and tuple(group.kernels()[:len(mine)]) == mine
        group.warm_up()
        assert all(len(k.signatures) >= 1 for k in mine), group.name
    assert kernel_registry.SWEEP == SWEEP.name
    assert kernel_registry.TIME_INTEGRATION == TIME_INTEGRATION.name
