"""The options several ``dmf-sim`` commands share, added and checked in one place.

``--config``, ``--engine``, ``--alpha``, ``--theta``, ``--load-set``, ``--load``, ``--speeds`` and
``--harmonics`` mean the same and accept the same values in every command that has them: a
command adds them with the ``add_*`` functions and calls :func:`check_common` first thing in its
``run``; a value out of range is a one-line :class:`~dmf_sim.core.errors.ConfigError` naming the
option and the allowed range.

Every command that writes files adds ``--overwrite`` with :func:`add_overwrite` and checks its
output path with :func:`output` before computing (the one rule of
:mod:`dmf_sim.core.destinations`).
"""
from __future__ import annotations

import math

from dmf_sim.cluster import CONNECT_TIMEOUT_S
from dmf_sim.core.destinations import Destination, claim
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.limits import MAX_WAIT_S, MAX_WORKERS_PER_CPU, max_local_workers
from dmf_sim.physics.engine import DEFAULT_ENGINE, LOAD_LIMITS, LOAD_SETS, load_error
from dmf_sim.physics.spring import STAGE_ANGLE_MAX_RAD, STIFFNESS_FACTOR_MAX

__all__ = ['ALPHA_RANGE', 'THETA_RANGE_RAD', 'LOAD_LIMITS', 'LOAD_SETS', 'HARMONICS_RANGE',
           'MAX_GRID_POINTS', 'MIN_STEP_RPM', 'DEFAULT_CONFIG', 'DEFAULT_ENGINE', 'add_config',
           'add_engine', 'add_alpha', 'add_theta', 'add_load_set', 'add_load', 'add_speeds',
           'add_harmonics', 'check_common', 'check_load', 'check_grid', 'check_harmonics',
           'check_dmf_options',
           'add_cluster', 'check_cluster', 'DEFAULT_CONNECT_TIMEOUT_S', 'OVERWRITE_HELP',
           'add_overwrite', 'output', 'resumable_output', 'check_names', 'check_wait',
           'add_steady_faults', 'steady_faults']

ALPHA_RANGE = (0.0, STIFFNESS_FACTOR_MAX)    # secondary stiffness factor (the spring's bound)
THETA_RANGE_RAD = (0.0, STAGE_ANGLE_MAX_RAD)  # knee angle [rad], lower bound excluded
HARMONICS_RANGE = (6, 64)        # highest half-order index H kept (6 = the 3rd order)
MAX_GRID_POINTS = 2000           # output speed grid points per sweep
MIN_STEP_RPM = 0.5               # finest output speed grid [rpm]
DEFAULT_CONFIG = 'truck_dmf'     # config/truck_dmf.yaml: Table 1 with the DMF
DEFAULT_CONNECT_TIMEOUT_S = CONNECT_TIMEOUT_S    # waiting for a Dask scheduler to answer


def add_config(p, default: str | None = DEFAULT_CONFIG, help_default: str | None = None) -> None:
    p.add_argument('--config', default=default,
                   help='driveline YAML name in config/ or path (default '
                        f'{help_default or default})')


def add_engine(p, default: str | None = DEFAULT_ENGINE, help_default: str | None = None) -> None:
    p.add_argument('--engine', default=default,
                   help='engine YAML or A_n table (CSV/YAML) name in config/ or path (default '
                        f'{help_default or default}; engine_d13_2500nm is the 2500 Nm rating)')


def add_alpha(p, many: bool = False, default: float | None = None,
              help_default: str = 'the YAML value') -> None:
    p.add_argument('--alpha', type=float, nargs='+' if many else None, default=default,
                   help=f'DMF secondary stiffness factor{"s" if many else ""} of the first drive '
                        f'stage, k(1+alpha), in [{ALPHA_RANGE[0]:g}, {ALPHA_RANGE[1]:g}] '
                        f'(default {help_default})')


def add_theta(p, help_default: str = 'the YAML value') -> None:
    p.add_argument('--theta', type=float,
                   help=f'DMF first stiffness change angle [rad] in ({THETA_RANGE_RAD[0]:g}, '
                        f'{THETA_RANGE_RAD[1]:g}] (default {help_default})')


def add_load_set(p, many: bool = False, default=('A',), help_default: str | None = None) -> None:
    if many:
        p.add_argument('--load-set', nargs='+', default=list(default) if default else default,
                       help=f'load sets among {"/".join(LOAD_SETS)} (default '
                            f'{help_default or " ".join(default)})')
    else:
        p.add_argument('--load-set', default=default[0] if default else None,
                       help=f'load set {"/".join(LOAD_SETS)} (default '
                            f'{help_default or default[0]})')


def add_load(p, default: float | None = 1.0, help_default: str | None = None) -> None:
    p.add_argument('--load', type=float, default=default,
                   help=f'torque demand {LOAD_LIMITS[0]:g}..{LOAD_LIMITS[1]:g}: 1 full load, 0 '
                        'none, below 0 engine braking (-1 the full brake of an engine with a '
                        f'brake curve) (default {help_default or f"{default:g}"})')


def add_speeds(p, default=(600.0, 2000.0, 10.0), what: str = 'speed range and output grid step'
               ) -> None:
    p.add_argument('--speeds', type=float, nargs=3, default=list(default),
                   metavar=('FROM', 'TO', 'STEP'),
                   help=f'{what} [rpm] (default {" ".join(f"{v:g}" for v in default)}; at most '
                        f'{MAX_GRID_POINTS} grid points, STEP >= {MIN_STEP_RPM:g})')


def add_harmonics(p, default: int = 24) -> None:
    p.add_argument('--harmonics', type=int, default=default,
                   help=f'highest half-order index H kept, {HARMONICS_RANGE[0]}..'
                        f'{HARMONICS_RANGE[1]} (default {default} = the {default / 2:g}th engine '
                        'order)')


def add_steady_faults(p) -> None:
    """``--faults FILE|SPEC``: the persistent faults of a steady state (sweep, steady)."""
    p.add_argument('--faults', metavar='FILE|SPEC',
                   help='persistent faults of the steady state: a fault schedule file (YAML '
                        'faults: [...]) or faults in YAML flow style, e.g. "{kind: misfire, '
                        'cylinders: [1], mode: every_cycle}" or a [list]; every_cycle misfires, '
                        'weak_cylinder and dmf_stiffness/dmf_broken/dmf_damping, without time '
                        'windows (a single or random misfire, a window or a sensor fault is '
                        'refused: dmf-sim run --faults takes those)')


def steady_faults(value: str | None, line):
    """The FaultSet of ``--faults FILE|SPEC`` (text starting with '{' or '[' is a SPEC, anything
    else a schedule file), validated against the driveline ``line`` and refused in one line
    unless every fault has a steady state (:func:`dmf_sim.solvers.hbm.faulted.steady_faults`);
    None without faults."""
    if value is None:
        return None
    from dmf_sim.physics.faults import FaultSet, parse_faults, read_schedule
    from dmf_sim.solvers.hbm.faulted import steady_faults as checked
    if value.lstrip().startswith(('{', '[')):
        return checked(FaultSet(parse_faults(value, '--faults', line=line)), '--faults')
    schedule = read_schedule(value, line=line)
    return checked(FaultSet(schedule.faults), f'--faults {schedule.source}')


def check_grid(lo: float, hi: float, step: float, engine=None, option: str = '--speeds') -> None:
    """Refuse a speed grid that is empty, too fine, too long or outside the engine data."""
    if not (all(map(math.isfinite, (lo, hi, step))) and hi > lo and step >= MIN_STEP_RPM):
        raise ConfigError(f'{option} FROM TO STEP: need finite TO > FROM and STEP >= '
                          f'{MIN_STEP_RPM:g} rpm (got {lo:g} {hi:g} {step:g})')
    n = (hi - lo) / step + 1
    if n > MAX_GRID_POINTS:
        raise ConfigError(f'{option} {lo:g} {hi:g} {step:g}: {n:.0f} grid points, allowed at most '
                          f'{MAX_GRID_POINTS} (use a larger STEP)')
    rng = getattr(engine, 'speed_range_rpm', None)
    if rng is not None and not (rng[0] <= lo and hi <= rng[1]):
        raise ConfigError(f'{option} {lo:g} {hi:g}: engine data covers {rng[0]:g}..{rng[1]:g} rpm')


def check_load(engine, load: float | None, option: str = '--load') -> None:
    """Refuse ``load`` (of ``option``) where ``engine`` does not accept it: a negative load for
    an engine without a brake curve (one line, :func:`dmf_sim.physics.engine.load_error`).
    :func:`check_common` has checked the widest range before the engine is loaded."""
    if load is not None and (reason := load_error(engine, load, option)):
        raise ConfigError(reason)


def check_harmonics(h: int, option: str = '--harmonics', lo_hi=HARMONICS_RANGE) -> None:
    lo, hi = lo_hi
    if not lo <= h <= hi:
        raise ConfigError(f'{option}={h}: allowed range {lo}..{hi} (the 3rd order is n = 6)')


def check_dmf_options(alphas, theta) -> None:
    """``--alpha`` values and ``--theta`` within the ranges the node's parameters accept."""
    for a in alphas:
        if not (math.isfinite(a) and ALPHA_RANGE[0] <= a <= ALPHA_RANGE[1]):
            raise ConfigError(f'--alpha {a:g}: allowed range '
                              f'{ALPHA_RANGE[0]:g}..{ALPHA_RANGE[1]:g}')
    if theta is not None and not (math.isfinite(theta)
                                  and THETA_RANGE_RAD[0] < theta <= THETA_RANGE_RAD[1]):
        raise ConfigError(f'--theta {theta:g}: allowed range ({THETA_RANGE_RAD[0]:g}, '
                          f'{THETA_RANGE_RAD[1]:g}] rad')


def _as_list(value) -> list:
    if value is None:
        return []
    return list(value) if isinstance(value, (list, tuple)) else [value]


def check_names(args) -> None:
    """``--config`` and ``--engine`` given as an empty name: refused (not the default)."""
    for option in ('config', 'engine'):
        value = getattr(args, option, None)
        if isinstance(value, str) and not value.strip():
            raise ConfigError(f'--{option}: empty name (give a name in config/ or a path, or '
                              'leave the option out for the default)')


def check_common(args) -> None:
    """Check every shared option ``args`` has (``--config``, ``--engine``, ``--alpha``,
    ``--theta``, ``--load``, ``--load-set``, ``--speeds``, ``--harmonics``): one-line errors
    with the allowed range. The output path is checked by :func:`output`."""
    check_names(args)
    alphas = _as_list(getattr(args, 'alpha', None))
    check_dmf_options(alphas, getattr(args, 'theta', None))
    load = getattr(args, 'load', None)
    if load is not None and not (math.isfinite(load) and LOAD_LIMITS[0] <= load <= LOAD_LIMITS[1]):
        raise ConfigError(f'--load {load!r}: allowed range {LOAD_LIMITS[0]:g}..{LOAD_LIMITS[1]:g}')
    for s in _as_list(getattr(args, 'load_set', None)):
        if s not in LOAD_SETS:
            raise ConfigError(f'--load-set {s!r}: allowed {", ".join(LOAD_SETS)}')
    speeds = getattr(args, 'speeds', None)
    if speeds is not None:
        check_grid(*speeds)
    h = getattr(args, 'harmonics', None)
    if h is not None:
        check_harmonics(h)


OVERWRITE_HELP = ("replace the output an earlier run of this command left at the output path "
                  "(only the files it wrote there; anything else there is refused). Without it "
                  "the output path must be new or an empty directory")


def add_overwrite(p) -> None:
    """``--overwrite``: the same option and help in every command that writes files."""
    p.add_argument('--overwrite', action='store_true', help=OVERWRITE_HELP)


def output(args, command: str, path=None, *, option: str = '--out', kind: str = 'dir',
           resume: bool = False, resume_option: str | None = None, owned=None) -> Destination:
    """The output path of ``command`` (``path``, default ``args.out``) checked under the one
    rule of :mod:`dmf_sim.core.destinations`, before anything is computed."""
    return claim(args.out if path is None else path, command, option=option,
                 overwrite=args.overwrite, kind=kind, resume=resume,
                 resume_option=resume_option, owned=owned)


def resumable_output(args, command: str) -> Destination:
    """``--out`` of a command that continues its earlier output there with ``--resume``."""
    if args.resume and args.overwrite:
        raise ConfigError('--resume continues the output in --out and --overwrite replaces it: '
                          'give one of them')
    return output(args, command, resume=args.resume, resume_option='--resume')


def check_wait(seconds: float, option: str = '--timeout') -> float:
    """A wait for something to answer: > 0 and at most :data:`MAX_WAIT_S`."""
    if not (math.isfinite(seconds) and 0 < seconds <= MAX_WAIT_S):
        raise ConfigError(f'{option} must be a finite number > 0 s and at most {MAX_WAIT_S:g} s, '
                          f'got {seconds!r}')
    return float(seconds)


def add_cluster(p) -> None:
    """``--scheduler``, ``--workers``, ``--connect-timeout``: where a Dask command runs."""
    p.add_argument('--scheduler', metavar='ADDRESS',
                   help='use an existing Dask cluster, e.g. tcp://HOST:8786 (default: a local '
                        'cluster on this machine)')
    p.add_argument('--workers', type=int,
                   help='worker processes of the local cluster (default: one per core; at most '
                        f'{MAX_WORKERS_PER_CPU} per core)')
    p.add_argument('--connect-timeout', type=float, default=DEFAULT_CONNECT_TIMEOUT_S,
                   help=f'seconds to wait for --scheduler to answer (default '
                        f'{DEFAULT_CONNECT_TIMEOUT_S:g}, at most {MAX_WAIT_S:g})')


def check_cluster(args) -> None:
    """One-line errors for the options of :func:`add_cluster` (and a command's ``--local``,
    which runs without Dask)."""
    limit = max_local_workers()
    if args.workers is not None and not 1 <= args.workers <= limit:
        raise ConfigError(f'--workers {args.workers}: allowed 1..{limit} on this machine '
                          f'({MAX_WORKERS_PER_CPU} per usable CPU)')
    if args.workers is not None and args.scheduler:
        raise ConfigError('--workers sizes the local cluster; with --scheduler the cluster '
                          'brings its own workers (leave out one of them)')
    if getattr(args, 'local', False) and (args.workers is not None or args.scheduler):
        raise ConfigError('--local runs without Dask: leave out --workers and --scheduler')
    check_wait(args.connect_timeout, '--connect-timeout')
