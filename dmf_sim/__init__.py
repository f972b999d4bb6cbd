"""dmf_sim: torsional vibrations of a heavy-truck driveline with a two-step dual mass flywheel.

The public API for scripts and notebooks::

    import dmf_sim as dmf

    excitation = dmf.DrivelineExcitation(dmf.read_model('truck_dmf', alpha=3.0),
                                         dmf.read_engine('engine_d13', load_set='A'))
    res = dmf.sweep(excitation, load=1.0, speed_range=(900.0, 1100.0))   # HBM over speed [rpm]
    for row in res.rows()[:3]:                       # one dict per point, SI units (rad, Nm)
        print(row['speed_rpm'], row['order_3'], row['stable'])

Every name in ``__all__`` is loaded on first use (PEP 562), so ``import dmf_sim`` and
``dmf-sim --help`` stay light: numba is compiled only when a solver is first used, Dask only
when a study runs. Type checkers and editors read the same names from the ``TYPE_CHECKING``
imports below. The layers underneath (``dmf_sim.core``, ``physics``, ``solvers``, ``bags``,
``analysis``, the applications) are documented in the docs site's architecture page;
``dmf_sim.node`` is a thin rclpy shell over the ROS-free core. Names renamed since (e.g.
``load_model`` -> ``read_model``) still work, with a deprecation warning.
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from dmf_sim.core.deprecation import warn_renamed

__version__ = '0.1.0'

# public name -> module that defines it (the one place it lives); the TYPE_CHECKING imports
# below name the same (test/test_api.py checks it)
_API = {
    # model and excitation
    'read_model': 'dmf_sim.physics.model',
    'read_driveline': 'dmf_sim.physics.model',
    'driveline_from_dict': 'dmf_sim.physics.model',
    'Driveline': 'dmf_sim.physics.model',
    'ReducedModel': 'dmf_sim.physics.model',
    'PiecewiseLinearSpring': 'dmf_sim.physics.spring',
    'Stage': 'dmf_sim.physics.spring',
    'read_engine': 'dmf_sim.physics.engine',
    'DrivelineExcitation': 'dmf_sim.physics.loads',
    'modes': 'dmf_sim.physics.modal',
    # solvers
    'simulate': 'dmf_sim.solvers.newmark',
    'SimulationOptions': 'dmf_sim.solvers.newmark',
    'SimulationResult': 'dmf_sim.solvers.newmark',
    'sweep': 'dmf_sim.solvers.hbm',
    'SweepOptions': 'dmf_sim.solvers.hbm',
    'HBMOptions': 'dmf_sim.solvers.hbm',
    'SweepResult': 'dmf_sim.solvers.hbm',
    'find_steady_states': 'dmf_sim.solvers.steady',
    'BasinOptions': 'dmf_sim.solvers.steady',
    'nnm_branches': 'dmf_sim.solvers.nnm',
    'NNMOptions': 'dmf_sim.solvers.nnm',
    # bags and their analysis
    'analyze_bag': 'dmf_sim.analysis.pipeline',
    'AnalysisOptions': 'dmf_sim.analysis.pipeline',
    'read_messages': 'dmf_sim.bags.read',
    # design studies
    'read_study': 'dmf_sim.design.study',
    'run_study': 'dmf_sim.design.runner',
    # errors
    'DmfSimError': 'dmf_sim.core.errors',
    'ConfigError': 'dmf_sim.core.errors',
    'ConfigFileError': 'dmf_sim.core.errors',
    'BagError': 'dmf_sim.core.errors',
    'BagFileError': 'dmf_sim.core.errors',
    'BagExistsError': 'dmf_sim.core.errors',
    'ConvergenceError': 'dmf_sim.core.errors',
    'OperatingRangeError': 'dmf_sim.core.errors',
    'TimeLimitError': 'dmf_sim.core.errors',
    'NoResponseError': 'dmf_sim.core.errors',
    'MissingExtraError': 'dmf_sim.core.errors',
}

_RENAMED = {
    'load_model': 'read_model',
    'load_driveline': 'read_driveline',
    'load_engine': 'read_engine',
    'load_study': 'read_study',
    'DrivelineLoads': 'DrivelineExcitation',
}
"""Old public name -> new one: still served, with a deprecation warning."""

__all__ = ['__version__', *_API]

if TYPE_CHECKING:          # explicit re-exports (`name as name`) for type checkers
    from dmf_sim.analysis.pipeline import (
        AnalysisOptions as AnalysisOptions,
        analyze_bag as analyze_bag,
    )
    from dmf_sim.bags.read import read_messages as read_messages
    from dmf_sim.core.errors import (
        BagError as BagError,
        BagExistsError as BagExistsError,
        BagFileError as BagFileError,
        ConfigError as ConfigError,
        ConfigFileError as ConfigFileError,
        ConvergenceError as ConvergenceError,
        DmfSimError as DmfSimError,
        MissingExtraError as MissingExtraError,
        NoResponseError as NoResponseError,
        OperatingRangeError as OperatingRangeError,
        TimeLimitError as TimeLimitError,
    )
    from dmf_sim.design.runner import run_study as run_study
    from dmf_sim.design.study import read_study as read_study
    from dmf_sim.physics.engine import read_engine as read_engine
    from dmf_sim.physics.loads import DrivelineExcitation as DrivelineExcitation
    from dmf_sim.physics.modal import modes as modes
    from dmf_sim.physics.model import (
        Driveline as Driveline,
        ReducedModel as ReducedModel,
        driveline_from_dict as driveline_from_dict,
        read_driveline as read_driveline,
        read_model as read_model,
    )
    from dmf_sim.physics.spring import (
        PiecewiseLinearSpring as PiecewiseLinearSpring,
        Stage as Stage,
    )
    from dmf_sim.solvers.hbm import (
        HBMOptions as HBMOptions,
        SweepOptions as SweepOptions,
        SweepResult as SweepResult,
        sweep as sweep,
    )
    from dmf_sim.solvers.newmark import (
        SimulationOptions as SimulationOptions,
        SimulationResult as SimulationResult,
        simulate as simulate,
    )
    from dmf_sim.solvers.nnm import NNMOptions as NNMOptions, nnm_branches as nnm_branches
    from dmf_sim.solvers.steady import (
        BasinOptions as BasinOptions,
        find_steady_states as find_steady_states,
    )


def __getattr__(name: str):
    """Import the module behind a public name on first use and cache the name here; an old
    name warns and gives the new one (not cached, so it warns at every place that uses it)."""
    if name in _RENAMED:
        warn_renamed(f'dmf_sim.{name}', f'dmf_sim.{_RENAMED[name]}')
        return __getattr__(_RENAMED[name])
    try:
        module = _API[name]
    except KeyError:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}') from None
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
