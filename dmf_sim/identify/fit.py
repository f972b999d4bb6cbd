"""Fit the DMF's spring and damping to a recorded run (``dmf-sim identify``).

**Model.** The bag's driveline, engine and load set (its ``custom_data``, or given; the bag's
driveline with the DMF spring the bag recorded, :attr:`Measurement.stored_spring`) with the DMF
parameters to fit replaced: the design parameter names of :mod:`dmf_sim.design.parameters`
(``k`` primary stiffness [Nm/rad], ``theta`` first drive knee [rad], ``alpha`` first drive stage
factor, ``damping`` [Nms/rad], further ``stages[i].…`` / ``coast_stages[j].…``, the arc-spring
friction's ``friction.torque_nm`` [Nm] and ``friction.speed_coefficient`` [Nm s^2/rad^2]; a
friction the model lacks starts at :data:`FRICTION_START`), every value within the bound of its
physical quantity (:data:`dmf_sim.core.bounds.BOUNDS`).

**Run.** The profile the bag was recorded along (kept whole in the ``custom_data`` of a
``dmf-sim run`` bag), or for a node's recording one rebuilt from what it recorded: the engine
speed and the load of its health statuses every :data:`REBUILT_ROW_S`, read only where the
recorded load is known and settled (:attr:`Measurement.fit_mask`: a load change reaches the
rebuilt profile late). The live core integrates it as ``dmf-sim run`` does
(:func:`dmf_sim.transient.run.follow_profile`, sensors off), and the simulated signal is taken
at the bag's sample times.

**Measurement.** The DMF wind-up (``/driveline/dmf_windup``), or where only the speeds of the
two flywheels were recorded (``--signal speeds``), their difference (the wind-up rate, from
the joint states' velocities). The cycles in which the run settles from static equilibrium
(``settle_s``) are left out.

**Fit.** Least squares of simulated minus measured over the samples,
``min_p sum_i (y_sim,i(p) - y_meas,i)^2`` (scipy's ``least_squares``, trust region reflective,
on the logarithms of the parameters within their bounds: every parameter here is positive and
spans decades), from :attr:`IdentifyOptions.starts` starting points (a Latin hypercube within a
factor :data:`START_SPREAD` of the bag's own values, the first one those values); the best
result is the answer. The starts run on the Dask cluster of :mod:`dmf_sim.cluster` when one is
given (:func:`identify` ``client``), else in turn here.

**Identifiability.** Before the fit, a step in each parameter's logarithm at the model's values
(:func:`identifiability`): a parameter the simulated signal does not change with — a knee, or
the stage beyond it, that the run never reaches — and parameters that change it only together —
the friction's constant and centrifugal parts in a run at one speed — are refused in one line,
naming them and what to do, before anything is written. After the fit, a fitted knee (and the
stage beyond it) that the fitted run never winds up beyond, or without whose stage the fit is
hardly worse (:data:`KNEE_EVIDENCE`), is refused the same way: the check before reads the
starting values, and a knee that the recording never reaches is fitted to the edge of its
wind-up with a small linearized uncertainty (:func:`_refuse_unreached`).

**Uncertainty.** Linearized at the optimum: with J the Jacobian of the residuals in the log
parameters, ``cov = s^2 (J^T J)^-1`` with ``s^2 = sum r_i^2 / (m - n)`` (m samples, n
parameters); the relative standard deviation of a parameter is the square root of its diagonal
entry (log parameters), the correlations from the same matrix. Consecutive samples of a run are
correlated (the residual is coloured noise), so these are lower bounds; the benchmark
(``benchmarks/bench_identify.py``) measures the real error against known parameters.
"""
from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from dmf_sim.core.errors import ConfigError, one_line
from dmf_sim.core.validation import SEED_MAX

__all__ = ['DEFAULT_PARAMETERS', 'SIGNALS', 'START_SPREAD', 'REBUILT_ROW_S', 'MIN_FIT_CYCLES',
           'KNEE_EVIDENCE',
           'PROFILE_SPEED_MATCH', 'IdentifyOptions',
           'Measurement', 'Identification', 'Identifiability', 'read_measurement', 'simulate',
           'identifiability', 'identify', 'fitted_signals']

DEFAULT_PARAMETERS = ('k', 'theta', 'alpha', 'damping')
"""What :func:`identify` fits unless told: the two-step spring and its damping."""
SIGNALS = ('windup', 'speeds')
"""What a fit compares: the wind-up [rad], or the flywheels' relative speed [rad/s]."""
START_SPREAD = 2.0
"""Starting points lie within the bag's value / START_SPREAD .. x START_SPREAD."""
FRICTION_START = {'friction.torque_nm': 20.0, 'friction.speed_coefficient': 1.0e-3}
"""Where a friction parameter starts when the model has none (the fit works on logarithms): a
small sliding torque [Nm] and centrifugal coefficient [Nm s^2/rad^2]."""
LOG_FLOOR = 1e-6
"""The lower end of a parameter whose bound starts at 0, for its logarithm."""
IDENTIFIABLE_STEP = 1e-3
"""Step in a parameter's logarithm of the identifiability check (:func:`identifiability`), as
the fit's own finite differences."""
IDENTIFIABLE_MIN = 1e-9
"""A parameter whose step moves the signal by at most this fraction of the largest move is not
identifiable from the recording: far below any noise, and exactly zero where the run never
reaches what the parameter shapes."""
TIED_MAX = 1e-3
"""Parameters whose normalized effects on the signal have a smallest singular value below this
fraction of the largest act only together in the recording. Measured: the friction's constant
and centrifugal parts in a run at one speed 1.7e-4 (all six parameters 4.5e-5); the benchmark's
separable cases, all six parameters over a range of speeds and loads, 4.0e-2 to 9.4e-2."""
KNEE_EVIDENCE = 9.0
"""A fitted stage must make the fit better than the same fit without it (its stiffness
increment removed) by at least this many times the residual variance s^2 in the residual sum
of squares, else the recording holds no evidence of it (a likelihood-ratio test of one parameter
at 3 sigma). Measured with 0.5 mrad of noise: a run that never reaches the bag's knee (0.34 rad,
wind-up up to 0.296 rad) 0.8-1.4, the fit having put the knee at 0.27-0.296 rad; one crossing it
(0.22 rad) 1.2e7."""
REBUILT_ROW_S = 0.05
"""Row spacing [s] of a profile rebuilt from a recording's speed and load."""
MIN_FIT_CYCLES = 1.0
"""Engine cycles (two revolutions, at the slowest speed of the run) the fitted samples must span
at least: less holds not one period of the 0.5th order, and a fit of a few samples is no fit."""
PROFILE_SPEED_MATCH = 0.01
"""Largest relative difference between a given profile's engine speed and the one the bag
recorded at the same time: beyond it the profile is not the one the bag was recorded along."""
DECIMATE_HZ = 1000.0
"""Samples per simulated second the fit compares at most (a bag's rate above it is thinned):
every sample of a 1 kHz bag. A measurement's noise is independent from sample to sample where
the wind-up is not, so each sample adds information: thinned to 200 Hz, the friction
parameters of a noisy benchmark case came back 4-5 % off instead of 1 %."""


@dataclass(frozen=True)
class IdentifyOptions:
    """What to fit and how.

    parameters: design parameter names (:mod:`dmf_sim.design.parameters`); signal: one of
    :data:`SIGNALS`; starts: starting points; max_evaluations: simulations per start at most;
    driveline, engine, load_set: the model (None: the bag's); dt: Newmark step [s] (None: the
    bag's); profile: the run's profile (None: the one the bag names, else rebuilt from what it
    recorded); seed: the Latin hypercube's.
    """

    parameters: tuple[str, ...] = DEFAULT_PARAMETERS
    signal: str = 'windup'
    starts: int = 4
    max_evaluations: int = 60
    driveline: str | None = None
    engine: str | None = None
    load_set: str | None = None
    dt: float | None = None
    profile: str | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.signal not in SIGNALS:
            raise ConfigError(f"--signal {self.signal!r}: allowed {', '.join(SIGNALS)}")
        if not 1 <= self.starts <= 1000:
            raise ConfigError(f'--starts {self.starts}: allowed 1..1000')
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) \
                or not 0 <= self.seed <= SEED_MAX:
            raise ConfigError(f'--seed {self.seed}: allowed 0..{SEED_MAX}')
        if not 5 <= self.max_evaluations <= 10000:
            raise ConfigError(f'--max-evaluations {self.max_evaluations}: allowed 5..10000')
        if not self.parameters:
            raise ConfigError('--parameters: give at least one parameter to fit')
        if len(set(self.parameters)) != len(self.parameters):
            raise ConfigError(f'--parameters {",".join(self.parameters)}: a parameter is named '
                              'twice')


@dataclass
class Measurement:
    """What a fit compares with: the bag's signal at its sample times and the run behind it.

    t_s: sample times [s] from the run's start (simulated time); y: the signal; signal: its
    kind; profile: the run's :class:`~dmf_sim.transient.profiles.Profile`; driveline, engine,
    load_set, dt: the model; settle_s: left out from the start [s]; bag: its path;
    rebuilt: the profile was rebuilt from the recorded speed and load; fit_mask: the samples
    the fit may read beyond those (a rebuilt profile's: where the recorded load is known and
    settled), None for all; stored_spring: the DMF spring the bag was recorded with (its
    metadata's ``spring``, ``alpha``, ``theta_rad``: the keywords of
    :func:`dmf_sim.analysis.hbm_overlay.with_stored_spring`), applied to the driveline where it
    is the bag's; None where ``--config`` gives the driveline (its YAML's spring);
    model_until_s, model_until_why: the run time [s] from which the recording is no longer the
    model's run, and what happened there (:func:`_model_until`: the first injected fault that
    changes the driveline, or the node's spring set to other values); the fit reads only the
    samples before it (None: the whole recording is the model's).
    """

    t_s: np.ndarray
    y: np.ndarray
    signal: str
    profile: object
    driveline: str
    engine: str
    load_set: str
    dt: float
    settle_s: float
    bag: str
    rebuilt: bool = False
    fit_mask: np.ndarray | None = None
    stored_spring: dict | None = None
    model_until_s: float | None = None
    model_until_why: str = ''

    @property
    def fitted(self) -> np.ndarray:
        """The samples a fit reads: after the settling, before :attr:`model_until_s`, and in
        :attr:`fit_mask`."""
        keep = self.t_s >= self.settle_s
        if self.model_until_s is not None:
            keep &= self.t_s < self.model_until_s
        return keep if self.fit_mask is None else keep & self.fit_mask


@dataclass
class Identification:
    """The result of :func:`identify` (SI units; ``as_dict`` for JSON).

    values: parameter -> fitted value; initial: parameter -> the bag's own value;
    rel_std: parameter -> relative standard deviation (linearized, a lower bound);
    correlation: the parameters' correlation matrix (rows/columns in ``parameters`` order);
    rms: root mean square of the residual (the signal's unit, over the fitted samples: after
    the settling, thinned to :data:`DECIMATE_HZ`); rms_initial: the same at the bag's own
    values; evaluations: simulations of the fit in all; starts: per start (its values, rms,
    evaluations, status); seconds: wall time; identifiability: the smallest over the largest
    singular value of the parameters' normalized effects on the signal at the bag's own values
    (:class:`Identifiability`: 1 for one parameter, near :data:`TIED_MAX` for a fit that can
    hardly tell them apart).
    """

    parameters: tuple[str, ...]
    values: dict[str, float]
    initial: dict[str, float]
    rel_std: dict[str, float]
    correlation: list[list[float]]
    rms: float
    rms_initial: float
    signal: str
    unit: str
    samples: int
    evaluations: int
    seconds: float
    starts: list[dict] = field(default_factory=list)
    bag: str = ''
    profile: str = ''
    identifiability: float = float('nan')

    def as_dict(self) -> dict:
        return {'bag': self.bag, 'profile': self.profile, 'signal': self.signal,
                'unit': self.unit, 'parameters': list(self.parameters), 'values': self.values,
                'initial': self.initial, 'rel_std': self.rel_std,
                'correlation': self.correlation, 'rms': self.rms,
                'rms_initial': self.rms_initial, 'samples': self.samples,
                'evaluations': self.evaluations, 'seconds': self.seconds,
                'identifiability': self.identifiability, 'starts': self.starts}


# ---------------------------------------------------------------------------- the measurement
def _rebuilt_profile(series, origin_ns: int, end_ns: int):
    """A profile from a recording's engine speed and the load of its health statuses, from the
    run's start ``origin_ns`` (one sample period before its first sample) to ``end_ns`` (the last
    sample to fit: the run must reach it)."""
    from dmf_sim.analysis.load_timeline import HEALTH_KEYS
    from dmf_sim.transient.profiles import make_profile
    speed, health = series.series.get('speed'), series.health
    if speed is None or len(speed) < 2 or health is None:
        raise ConfigError(f'{series.bag.path}: the bag names no profile (not a dmf-sim run '
                          'bag) and holds no engine speed and health statuses to rebuild one')
    ts = (speed.t_ns - origin_ns) * 1e-9
    end_s = max((end_ns - origin_ns) * 1e-9, float(ts[-1]))
    rows_t = np.arange(0.0, end_s + REBUILT_ROW_S, REBUILT_ROW_S)     # one row at or past it
    hs_t = (health[0] - origin_ns) * 1e-9
    load_col = health[1][:, HEALTH_KEYS.index('load')]
    idx = np.clip(np.searchsorted(hs_t, rows_t, side='right') - 1, 0, len(hs_t) - 1)
    rows = np.column_stack([rows_t, np.interp(rows_t, ts, speed.values), load_col[idx]])
    return make_profile(rows, name='rebuilt', source=str(series.bag.path),
                        where=f'{series.bag.path}: rebuilt profile')


def _cut(profile, end_s: float):
    """``profile`` simulated no further than the recording goes (``end_s`` [s], its last
    sample): a longer ``--profile``, or the whole profile a ``dmf-sim run`` stopped early keeps
    in its metadata."""
    if profile.duration_s <= end_s + REBUILT_ROW_S:
        return profile
    return replace(profile.window(0.0, end_s + REBUILT_ROW_S, name=profile.name),
                   settle_s=profile.settle_s)


def _given_profile(profile, spec: str, series, t_ns: np.ndarray, t_s: np.ndarray):
    """``--profile``, checked against the bag (a one-line ConfigError where it is not the run
    recorded: shorter than the recording, or at another engine speed where the bag recorded
    one)."""
    end = float(t_s[-1])
    if profile.duration_s < end - 1e-9:
        raise ConfigError(f'--profile {spec}: it lasts {profile.duration_s:g} s, the recording '
                          f'{end:g} s: not the profile the bag was recorded along')
    speed = series.series.get('speed')
    if speed is not None and len(speed):
        ts = (speed.t_ns - t_ns[0]) * 1e-9 + (t_s[0])
        want = profile.at(ts)[0]
        off = np.abs(want - speed.values) / np.maximum(np.abs(speed.values), 1.0)
        i = int(np.argmax(off))
        if off[i] > PROFILE_SPEED_MATCH:
            raise ConfigError(f'--profile {spec}: at t = {ts[i]:.3g} s it runs at '
                              f'{want[i]:.0f} rpm, the bag recorded {speed.values[i]:.0f} rpm: '
                              'not the profile the bag was recorded along')
    return profile


def _known_load(series, start_load: float | None, t_ns: np.ndarray, settle_s: float
                ) -> np.ndarray:
    """Which samples (times ``t_ns``) a rebuilt profile reproduces: those in a stretch of known,
    constant load (the bag analysis's :func:`dmf_sim.analysis.load_timeline.load_timeline` of
    the health statuses, the recorded setpoints and the start load) at least ``settle_s`` after
    the stretch began, or in the stretch the recording starts in. A load change shows up in the
    rebuilt profile only at the next health status; the run it simulates differs from the
    recorded one until that transient has decayed."""
    from dmf_sim.analysis.load_timeline import LOAD_TOLERANCE, load_timeline
    tl = load_timeline(series.health, series.load_setpoints, start_load, int(t_ns[0]),
                       int(t_ns[-1]))
    if tl is None:
        return np.ones(len(t_ns), dtype=bool)
    t0, t1, val = tl.t0_ns, tl.t1_ns, tl.value
    began = t0.copy()                  # where each interval's stretch of one known load began
    for i in range(1, len(t0)):
        if (np.isfinite(val[i]) and np.isfinite(val[i - 1]) and t0[i] == t1[i - 1]
                and abs(val[i] - val[i - 1]) <= LOAD_TOLERANCE):
            began[i] = began[i - 1]
    i = np.searchsorted(t0, t_ns, side='right') - 1
    j = np.clip(i, 0, None)
    inside = (i >= 0) & (t_ns < t1[j]) & np.isfinite(val[j])
    return inside & ((began[j] <= t_ns[0]) | (t_ns - began[j] >= settle_s * 1e9))


def _model_until(resolved, series) -> tuple[int, str] | None:
    """(stamp [ns], what) from which the recording is no longer the run of one healthy model,
    None where it is throughout: the first fault of the bag's ground truth that changes the
    driveline's dynamics (a combustion or DMF fault: a sensor's leaves the recorded wind-up as
    it was), or the last health status before one reports another DMF knee (``alpha``,
    ``theta_rad``: the node's spring set while it recorded; the change lies between the two
    statuses)."""
    from dmf_sim.analysis.load_timeline import HEALTH_KEYS
    from dmf_sim.analysis.misfire_detector import event_start_ns, ground_truth_events
    from dmf_sim.physics.faults import SENSOR_KINDS
    found = [(event_start_ns(ev), f'the first injected fault ({ev["fault"].kind})')
             for ev in ground_truth_events(resolved) if ev['fault'].kind not in SENSOR_KINDS]
    found = [f for f in found if f[0] is not None]
    if series.health is not None:
        hs_t, values = series.health
        knee = values[:, [HEALTH_KEYS.index('alpha'), HEALTH_KEYS.index('theta_rad')]]
        known = np.isfinite(knee).all(axis=1)
        hs_t, knee = hs_t[known], knee[known]
        changed = np.flatnonzero((knee != knee[:1]).any(axis=1)) if len(knee) else []
        if len(changed):
            i = int(changed[0])
            found.append((int(hs_t[i - 1]), f'the node\'s spring set from alpha {knee[0, 0]:g}, '
                                            f'theta {knee[0, 1]:g} rad to alpha {knee[i, 0]:g}, '
                                            f'theta {knee[i, 1]:g} rad (its health statuses)'))
    return min(found) if found else None


def _beyond_the_dmf(given, recorded) -> str | None:
    """The first difference of driveline ``given`` from ``recorded`` in what identify does not
    fit (the elements but the DMF element's stiffness and damping, the cylinders, firing phases,
    the rear load element, which element is the DMF), as text; None where there is none."""
    if given.names != recorded.names:
        return (f'elements {", ".join(given.names)}, the bag\'s driveline '
                f'{", ".join(recorded.names)}')
    fitted = given.dmf.element if given.dmf is not None else None
    for mine, theirs in zip(given.elements, recorded.elements):
        for attr in ('ratio', 'stiffness', 'damping', 'inertia'):
            if mine.name == fitted and attr in ('stiffness', 'damping'):
                continue
            if getattr(mine, attr) != getattr(theirs, attr):
                return (f'element {mine.name!r} {attr} {getattr(mine, attr):g}, the bag\'s '
                        f'driveline {getattr(theirs, attr):g}')
    for attr in ('cylinders', 'firing_phases_deg', 'rear_load_element'):
        if getattr(given, attr) != getattr(recorded, attr):
            return f'{attr} {getattr(given, attr)}, the bag\'s driveline {getattr(recorded, attr)}'
    if (recorded.dmf is not None and fitted != recorded.dmf.element):
        return f'DMF element {fitted}, the bag\'s driveline {recorded.dmf.element}'
    return None


def _check_model(options: IdentifyOptions, meta) -> None:
    """The model's options against what the bag recorded (``meta``): ``--load-set`` or
    ``--engine`` other than the bag's is another run, refused in one line (the fit would put
    the difference into the DMF's values), as a ``--config`` other beyond the DMF is
    (:func:`_check_config`). A file the bag names that is not here is not compared: the option
    stands for it."""
    from dmf_sim.core.paths import config_file
    if options.load_set is not None and meta.load_set is not None \
            and options.load_set.upper() != meta.load_set.upper():
        raise ConfigError(f'--load-set {options.load_set}: the bag was recorded with load set '
                          f'{meta.load_set}: identify fits only the DMF, the rest must be the '
                          f'run recorded; leave out --load-set')
    if options.engine is not None and meta.engine is not None:
        try:
            recorded = config_file(meta.engine).read_bytes()
        except (ConfigError, OSError):
            recorded = None
        if recorded is not None and config_file(options.engine).read_bytes() != recorded:
            raise ConfigError(f'--engine {options.engine}: not the engine the bag was recorded '
                              f'with ({meta.engine}): identify fits only the DMF, the rest must '
                              f'be the run recorded; leave out --engine')
    if options.driveline is not None:
        _check_config(options.driveline, meta.driveline)


def _check_config(given: str, named: str | None) -> None:
    """``--config`` ``given`` against the driveline the bag names (``named``, where it is here):
    one that differs beyond the DMF is another driveline, refused in one line (the fit would
    put the difference into the DMF's values)."""
    from dmf_sim.physics.model import read_driveline
    if named is None:
        return
    try:
        recorded = read_driveline(named)
    except (ConfigError, OSError):          # not on this machine: --config stands for it
        return
    line = read_driveline(given)
    if line.dmf is None:                    # no DMF to fit: _model says so
        return
    what = _beyond_the_dmf(line, recorded)
    if what is not None:
        raise ConfigError(f'--config {given}: {what} ({named}): identify fits only the DMF, '
                          f'the rest must be the driveline recorded; leave out --config, or give '
                          f'the bag\'s driveline with other DMF values')


def read_measurement(bag, options: IdentifyOptions = IdentifyOptions()) -> Measurement:
    """The signal of ``bag`` to fit, with the run and model behind it (one-line
    :class:`~dmf_sim.core.errors.ConfigError` / BagError when the bag lacks what is needed)."""
    from dmf_sim.analysis.series import SignalSpec, read_bag_series
    from dmf_sim.bags.layout import resolve_bag
    from dmf_sim.core.paths import config_file
    from dmf_sim.transient.profiles import profile_from_table, read_profile

    resolved = resolve_bag(bag)
    meta = resolved.run_metadata
    specs = ([SignalSpec.parse('windup')] if options.signal == 'windup' else
             [SignalSpec.parse('velocity:PRIMARY FLYWHEEL'),
              SignalSpec.parse('velocity:SECONDARY FLYWHEEL')])
    series = read_bag_series(resolved, signals=specs)
    got = [series.series.get(s.label) for s in specs]
    if any(g is None or len(g) < 10 for g in got):
        raise ConfigError(f'{resolved.path}: no {options.signal} signal to fit '
                          f'({", ".join(s.label for s in specs)}: not recorded or empty)')
    if options.signal == 'windup':
        t_ns, y = got[0].t_ns, got[0].values
    else:
        n = min(len(got[0]), len(got[1]))
        t_ns, y = got[0].t_ns[:n], got[1].values[:n] - got[0].values[:n]
    if np.ptp(y) == 0.0:           # a driveline without a DMF records a wind-up of zeros
        what, unit = (('wind-up', 'rad') if options.signal == 'windup' else
                      ('flywheel speed difference', 'rad/s'))
        raise ConfigError(f'{resolved.path}: the recorded {what} does not vary ({y[0]:g} {unit} '
                          f'throughout): nothing to fit (recorded with '
                          f'{meta.driveline or "a driveline the bag does not name"}: one without '
                          f'a DMF records no wind-up); give a recording of a driveline with a '
                          f'DMF')
    profile, rebuilt = None, False
    if options.profile is not None:
        profile = read_profile(options.profile)
    elif meta.profile_table is not None:    # a dmf-sim run bag: the run's own profile
        profile = profile_from_table(meta.profile_table,
                                     f'{resolved.path}: the profile in its metadata')
    elif meta.profile is not None:
        try:
            profile = read_profile(meta.profile)
        except ConfigError:                 # a file of the recording machine: not here
            pass
    for what, given, named, option in (('driveline', options.driveline, meta.driveline,
                                        '--config'),
                                       ('engine', options.engine, meta.engine, '--engine')):
        if given is None and named is not None:
            try:
                config_file(named)
            except ConfigError as exc:
                raise ConfigError(f'{resolved.path}: the {what} the bag was recorded with, '
                                  f'{named}, is not here ({one_line(exc)}); give it with '
                                  f'{option}') from None
    _check_model(options, meta)
    rate = meta.publish_rate_hz or 1000.0
    t_s = (t_ns - t_ns[0]) * 1e-9 + 1.0 / rate        # the first sample: one period in
    period_ns = int(round(1e9 / rate))
    if options.profile is not None:
        profile = _given_profile(profile, options.profile, series, t_ns, t_s)
    until = _model_until(resolved, series)
    fit_mask = None
    if profile is not None:
        profile = _cut(profile, float(t_s[-1]))
    else:
        profile = _rebuilt_profile(series, int(t_ns[0]) - period_ns, int(t_ns[-1]) + period_ns)
        rebuilt = True
        fit_mask = _known_load(series, meta.load, t_ns, profile.start_settle_s)
    return Measurement(
        t_s=t_s, y=np.asarray(y, float), signal=options.signal, profile=profile,
        driveline=options.driveline or meta.driveline or 'truck_dmf',
        engine=options.engine or meta.engine or 'engine_d13',
        load_set=options.load_set or meta.load_set or 'A',
        dt=options.dt or meta.dt_s or 1e-4,
        settle_s=float(meta.settle_s if meta.settle_s is not None
                       else profile.start_settle_s),
        bag=str(resolved.path), rebuilt=rebuilt, fit_mask=fit_mask,
        stored_spring=(None if options.driveline is not None else
                       {'spring': meta.spring, 'alpha': meta.alpha, 'theta_rad': meta.theta_rad}),
        model_until_s=(None if until is None else
                       float((until[0] - t_ns[0]) * 1e-9 + 1.0 / rate)),
        model_until_why='' if until is None else until[1])


# ---------------------------------------------------------------------------- the model
@dataclass
class _Model:
    """The base driveline and engine of a measurement, and the parameters' objects."""

    base: object
    engine: object
    params: list
    speed_limits: tuple[float, float]


def _model(meas: Measurement, names: Sequence[str]) -> _Model:
    from dmf_sim.analysis.hbm_overlay import with_stored_spring
    from dmf_sim.design.parameters import check_parameter_set, parse_parameter
    from dmf_sim.physics.engine import read_engine
    from dmf_sim.physics.model import read_driveline
    base = read_driveline(meas.driveline)
    if meas.stored_spring is not None:
        try:
            base = with_stored_spring(base, **meas.stored_spring)
        except (ConfigError, KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f'{meas.bag}: the DMF spring stored in the bag is invalid '
                              f'({one_line(exc)}); give the driveline with --config') from None
    if base.spring is None:
        raise ConfigError(f'driveline {meas.driveline}: has no DMF spring to identify')
    engine = read_engine(meas.engine, load_set=meas.load_set)
    lo, hi = getattr(engine, 'speed_range_rpm', (0.0, math.inf))
    if not math.isfinite(hi):
        hi = float(np.max(meas.profile.speed_rpm)) * 2
    params = [parse_parameter(n, '--parameters') for n in names]
    for p in params:
        stages = {'stages': base.spring.drive, 'coast_stages': base.spring.coast}.get(p.side)
        if stages is not None and p.index >= len(stages):
            raise ConfigError(f'--parameters {p.name}: the spring of the bag has '
                              f'{len(stages)} {p.side.replace("_", " ")}')
    check_parameter_set(params, base, '--parameters')     # one quantity under two names
    return _Model(base, engine, params, (float(lo), float(hi)))


def _check_run(meas: Measurement, model: _Model) -> None:
    """The run checked as ``dmf-sim run`` checks a profile (one-line errors naming it): its
    speeds within the engine data, its loads torque demands the engine accepts, no load change
    faster than one Newmark step."""
    meas.profile.check_runnable(model.speed_limits, model.engine, meas.dt,
                                dt_what="the Newmark step: --dt, else the bag's")


def _base_values(model: _Model) -> dict[str, float]:
    """The base driveline's value of each parameter."""
    spring = model.base.spring
    out = {}
    for p in model.params:
        if p.kind == 'k':
            out[p.name] = float(spring.k)
        elif p.kind == 'damping':
            out[p.name] = float(model.base.dmf_element.damping)
        elif p.kind in FRICTION_START:
            friction = model.base.dmf.friction
            value = getattr(friction, p.kind.split('.', 1)[1]) if friction is not None else 0.0
            out[p.name] = float(value) or FRICTION_START[p.kind]
        else:                           # the stage exists: checked by _model
            stages = spring.drive if p.side == 'stages' else spring.coast
            out[p.name] = float(getattr(stages[p.index], p.kind))
    return out


def simulate(meas: Measurement, model: _Model, values: dict[str, float]) -> np.ndarray:
    """The signal of the model with ``values`` at the measurement's sample times."""
    from dmf_sim.design.parameters import design_driveline
    from dmf_sim.live.simulation import LiveSimulation
    from dmf_sim.transient.run import follow_profile
    line = design_driveline(model.base, {p: values[p.name] for p in model.params})
    prof = meas.profile
    sim = LiveSimulation(line, model.engine, dt=meas.dt, speed_rpm=float(prof.speed_rpm[0]),
                         load=float(prof.load[0]), speed_limits_rpm=model.speed_limits,
                         sensors=False)
    ts, ys = [], []
    i_pf = line.names.index('PRIMARY FLYWHEEL') if meas.signal == 'speeds' else 0
    i_sf = line.names.index('SECONDARY FLYWHEEL') if meas.signal == 'speeds' else 0

    def take(s) -> None:
        ts.append(s.t.copy())
        ys.append(s.windup.copy() if meas.signal == 'windup'
                  else s.velocity[:, i_sf] - s.velocity[:, i_pf])
    follow_profile(sim, prof, on_samples=take)
    t, y = np.concatenate(ts), np.concatenate(ys)
    return np.interp(meas.t_s, t, y)


# ---------------------------------------------------------------------------- the fit
def _start_points(initial: np.ndarray, lo: np.ndarray, hi: np.ndarray, n: int,
                  seed: int) -> np.ndarray:
    """``n`` starting points in log space: the bag's own values first, then a Latin
    hypercube within a factor START_SPREAD of them (clipped to the bounds)."""
    from scipy.stats import qmc
    pts = [initial]
    if n > 1:
        u = qmc.LatinHypercube(d=len(initial), seed=seed).random(n - 1)
        spread = math.log(START_SPREAD)
        pts += list(initial + (2 * u - 1) * spread)
    return np.clip(np.array(pts), lo + 1e-9, hi - 1e-9)


def _log_bounds(model: _Model) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = [], []
    for p in model.params:
        b = p.bound
        lo.append(math.log(max(b.lo, LOG_FLOOR)))
        hi.append(math.log(b.hi))
    return np.array(lo), np.array(hi)


def _residual(meas: Measurement, names: tuple[str, ...]):
    """(residual of log parameters x: simulated minus measured over the fitted samples, in
    units of the measured signal's standard deviation; the fitted samples' count, scale): the
    samples after the settling, thinned to :data:`DECIMATE_HZ`."""
    model = _model(meas, names)
    keep = meas.fitted
    if meas.model_until_s is not None and not keep.any() and \
            not (meas.t_s[meas.t_s >= meas.settle_s] < meas.model_until_s).any():
        raise ConfigError(f'{meas.bag}: no sample to fit before {meas.model_until_why} at '
                          f'{meas.model_until_s:.4g} s of the run, after the run\'s settling '
                          f'({meas.settle_s:g} s, left out): identify models one healthy '
                          f'driveline; record a run with a stretch of it after its settling')
    if not keep.any() and meas.fit_mask is None:
        raise ConfigError(f'{meas.bag}: no sample to fit: the recording ends within the run\'s '
                          f'first {meas.settle_s:g} s (its settling, left out); record a longer '
                          f'run')
    if not keep.any():
        raise ConfigError(f'{meas.bag}: no sample to fit: no stretch of the recording holds a '
                          f'known, constant load for more than {meas.settle_s:g} s (the run\'s '
                          f'settling after a change; the load is known from the node\'s health '
                          f'statuses and recorded setpoints); give the profile it followed with '
                          f'--profile, or record longer stretches at one load')
    t_all = meas.t_s[keep]
    cycle_s = 2.0 * 60.0 / float(np.min(meas.profile.at(t_all)[0]))     # two revolutions
    if t_all[-1] - t_all[0] < MIN_FIT_CYCLES * cycle_s:
        raise ConfigError(f'{meas.bag}: {len(t_all)} sample{"s" * (len(t_all) != 1)} to fit over '
                          f'{t_all[-1] - t_all[0]:.3g} s after the run\'s settling ('
                          f'{meas.settle_s:g} s, left out): identify needs at least '
                          f'{MIN_FIT_CYCLES:g} engine cycle ({cycle_s:.3g} s at the run\'s '
                          f'slowest speed); record a longer run')
    step = max(int(round(1.0 / (DECIMATE_HZ * np.median(np.diff(meas.t_s))))), 1)
    keep &= (np.arange(len(keep)) % step) == 0
    t_fit, y_fit = meas.t_s[keep], meas.y[keep]
    sub = replace(meas, t_s=t_fit, y=y_fit, fit_mask=None)
    scale = float(np.std(y_fit)) or 1.0

    def residual(x: np.ndarray, strict: bool = False) -> np.ndarray:
        """``strict``: a model that fails to simulate raises (else it counts as far off)."""
        values = {n: math.exp(v) for n, v in zip(names, x)}
        try:
            return (simulate(sub, model, values) - y_fit) / scale
        except (ConfigError, ValueError, FloatingPointError) as exc:
            if strict:
                raise ConfigError(f'{meas.bag}: the model does not run the recording at '
                                  f'{", ".join(f"{n} {values[n]:.4g}" for n in names)}: '
                                  f'{exc}') from None
            return np.full(len(y_fit), 1e3)              # a failed design: far off
    return residual, len(y_fit), scale


@dataclass(frozen=True)
class Identifiability:
    """What a recording can tell about the parameters, from one step in each parameter's
    logarithm at the model's values (:func:`identifiability`).

    flat: the parameters the signal does not change with (a step moves no sample by more than
    :data:`IDENTIFIABLE_MIN` of the largest move: a knee, or the stage beyond it, that the run
    never reaches — the simulation is the same to the bit); tied: the parameters of the
    direction the signal hardly tells (their changes of the signal, normalized, have a smallest
    singular value below :data:`TIED_MAX` of the largest: they act only together, as the
    friction's constant and centrifugal parts at one speed); ratio: that smallest over largest
    singular value (1 for one parameter); rms: the residual's root mean square at those values
    (the signal's unit, over the fitted samples, as :attr:`Identification.rms`)."""

    flat: tuple[str, ...]
    tied: tuple[str, ...]
    ratio: float
    rms: float


def identifiability(meas: Measurement, names: Sequence[str], x: np.ndarray,
                    step: float = IDENTIFIABLE_STEP) -> Identifiability:
    """:class:`Identifiability` of ``names`` at log parameters ``x``: one simulation per
    parameter and one at ``x``, the fit's own residual (forward differences, as its Jacobian).
    The tied direction is the right singular vector of the smallest singular value; a parameter
    belongs to it where its entry is at least a third of the largest. A model that fails to
    simulate at ``x`` is refused (:class:`ConfigError`, with why), not taken for one the
    parameters do not change."""
    residual, _, scale = _residual(meas, tuple(names))
    r0 = residual(x, strict=True)
    rms = scale * math.sqrt(float(np.mean(r0 ** 2)))
    cols = []
    for i in range(len(names)):
        xi = np.array(x, dtype=float)
        xi[i] += step
        cols.append(residual(xi) - r0)
    moves = [float(np.max(np.abs(c))) for c in cols]
    top = max(moves)
    flat = tuple(n for n, m in zip(names, moves) if m <= IDENTIFIABLE_MIN * top)
    live = [i for i, n in enumerate(names) if n not in flat]
    if len(live) < 2:
        return Identifiability(flat, (), 1.0, rms)
    D = np.column_stack([cols[i] / np.linalg.norm(cols[i]) for i in live])
    _, sv, vt = np.linalg.svd(D, full_matrices=False)
    ratio = float(sv[-1] / sv[0])
    v = np.abs(vt[-1])
    tied = tuple(names[i] for i, e in zip(live, v) if e >= v.max() / 3) if ratio < TIED_MAX \
        else ()
    return Identifiability(flat, tied, ratio, rms)


def _refuse_unidentifiable(meas: Measurement, names: Sequence[str],
                           found: Identifiability) -> None:
    """One line for what :func:`identifiability` found the recording cannot tell (nothing if it
    can tell every parameter)."""
    signal = 'wind-up' if meas.signal == 'windup' else 'flywheel speed difference'
    if found.flat:
        fit = [n for n in names if n not in found.flat]
        what = (f'; the wind-up stays within [{meas.y.min():.4g}, {meas.y.max():.4g}] rad'
                if meas.signal == 'windup' else '')
        hint = (f'fit --parameters {",".join(fit)}, or ' if fit else '')
        them = 'it' if len(found.flat) == 1 else 'them'
        raise ConfigError(f'{meas.bag}: {", ".join(found.flat)} cannot be identified from this '
                          f'recording: at the model\'s values the {signal} does not change with '
                          f'{them} (a knee or stage the run never reaches{what}); {hint}record '
                          f'a run that reaches {them}')
    if found.tied:
        speeds = meas.profile.speed_rpm
        raise ConfigError(f'{meas.bag}: {", ".join(found.tied)} cannot be told apart by this '
                          f'recording: at the model\'s values they change the {signal} only '
                          f'together (smallest singular value of their effects {found.ratio:.1e} '
                          f'of the largest, below {TIED_MAX:g}; the run spans '
                          f'{float(np.min(speeds)):.0f}-{float(np.max(speeds)):.0f} rpm); fit '
                          f'fewer of them with --parameters, or record a run that separates '
                          f'them (the friction\'s two parts: a range of speeds)')


def _refuse_unreached(meas: Measurement, model: _Model, values: dict[str, float]) -> None:
    """One line for the fitted parameters of a stage the fitted run does not show (nothing if
    it shows every fitted stage): one whose knee no fitted sample winds up beyond, or one
    without which the same fit is worse by less than :data:`KNEE_EVIDENCE` times its residual
    variance (the stage's stiffness increment removed, every other value as fitted). The check
    before the fit (:func:`identifiability`) reads the starting values: where the recording's
    knee lies beyond its largest wind-up but the starting one does not, the fit moves the knee
    to the edge of the wind-up, where a touch of the stage is left, and the linearized
    uncertainty of the knee is small (the recording says only that the knee lies beyond)."""
    from dmf_sim.design.parameters import design_driveline, parse_parameter
    keep = meas.fitted
    sub = replace(meas, t_s=meas.t_s[keep], y=meas.y[keep], fit_mask=None)
    fitted = simulate(sub, model, values)
    windup = (fitted if meas.signal == 'windup' else
              simulate(replace(sub, signal='windup'), model, values))
    rss = float(np.sum((fitted - sub.y) ** 2))
    s2 = rss / max(len(sub.y) - len(model.params), 1)
    spring = design_driveline(model.base, {p: values[p.name] for p in model.params}).spring
    sides = {'stages': (spring.drive, float(np.max(windup))),
             'coast_stages': (spring.coast, -float(np.min(windup)))}
    unreached, knees, worse = [], {}, []
    for side, index in dict.fromkeys((p.side, p.index) for p in model.params if p.side):
        stages, reach = sides[side]
        knee = stages[index].angle_rad
        if reach > knee:                  # reached: is the stage beyond it in the fit at all?
            factor = parse_parameter(f'{side}[{index}].stiffness_factor', '--parameters')
            named = next((p for p in model.params if p.key == factor.key), None)
            alt_model = model if named else replace(model, params=[*model.params, factor])
            previous = stages[index - 1].stiffness_factor if index else 0.0
            alt = simulate(sub, alt_model, {**values, (named or factor).name: previous})
            gain = (float(np.sum((alt - sub.y) ** 2)) - rss) / s2 if s2 > 0 else math.inf
            if gain >= KNEE_EVIDENCE:
                continue
            worse.append(gain)
        unreached += [p.name for p in model.params if (p.side, p.index) == (side, index)]
        knees[f'{-knee if side == "coast_stages" else knee:.5g}'] = None
    if not unreached:
        return
    fit = [p.name for p in model.params if p.name not in unreached]
    hint = f'fit --parameters {",".join(fit)}, or ' if fit else ''
    how = ('never winds up beyond the knee' if not worse else
           f'barely winds up beyond the knee: without the stage beyond it the fit is worse by '
           f'only {max(worse):.2g} s^2 (s^2 its residual variance; {KNEE_EVIDENCE:g} s^2 would '
           f'show the stage)')
    raise ConfigError(f'{meas.bag}: {", ".join(unreached)} cannot be identified from this '
                      f'recording: the fitted run {how} (fitted at {", ".join(knees)} rad; the '
                      f'wind-up of the fitted run stays within [{float(np.min(windup)):.5g}, '
                      f'{float(np.max(windup)):.5g}] rad), so the recording does not tell where '
                      f'the knee lies nor the stage beyond it; {hint}record a run that winds up '
                      f'well beyond it')


def _fit_one(meas: Measurement, names: tuple[str, ...], x0: np.ndarray, lo: np.ndarray,
             hi: np.ndarray, max_evaluations: int) -> dict:
    """One least-squares run from ``x0`` (log parameters): its result as a dict (what a Dask
    worker sends back)."""
    from scipy.optimize import least_squares
    residual, m, scale = _residual(meas, names)
    t0 = time.perf_counter()
    res = least_squares(residual, x0, bounds=(lo, hi), method='trf', x_scale=1.0,
                        diff_step=1e-3, max_nfev=max_evaluations)
    n = len(x0)
    rss = float(np.sum(res.fun ** 2)) * scale ** 2
    s2 = float(np.sum(res.fun ** 2)) / max(m - n, 1)
    try:
        cov = s2 * np.linalg.inv(res.jac.T @ res.jac)
    except np.linalg.LinAlgError:
        cov = np.full((n, n), np.nan)
    return {'x': res.x.tolist(), 'rms': math.sqrt(rss / m), 'cov': cov.tolist(),
            'evaluations': int(res.nfev), 'status': int(res.status),
            'message': str(res.message), 'seconds': time.perf_counter() - t0, 'samples': m}


def identify(bag, options: IdentifyOptions = IdentifyOptions(), *, client=None
             ) -> Identification:
    """Fit ``options.parameters`` to ``bag`` (module docstring): a bag, or a
    :class:`Measurement` read from one (:func:`read_measurement`, e.g. with noise added to its
    signal); ``client``: a ``dask.distributed`` client to run the starts on (None: here, in
    turn)."""
    t0 = time.perf_counter()
    meas = bag if isinstance(bag, Measurement) else read_measurement(bag, options)
    model = _model(meas, options.parameters)
    _check_run(meas, model)
    initial = _base_values(model)
    lo, hi = _log_bounds(model)
    x_init = np.log([initial[n] for n in options.parameters])
    found = identifiability(meas, options.parameters, x_init)
    _refuse_unidentifiable(meas, options.parameters, found)
    starts = _start_points(x_init, lo, hi, options.starts, options.seed)
    args = (meas, tuple(options.parameters))
    if client is None:
        results = [_fit_one(*args, x0, lo, hi, options.max_evaluations) for x0 in starts]
    else:
        futures = [client.submit(_fit_one, *args, x0, lo, hi, options.max_evaluations,
                                 pure=False) for x0 in starts]
        results = client.gather(futures)
    best = min(results, key=lambda r: r['rms'])
    names = options.parameters
    values = {n: math.exp(v) for n, v in zip(names, best['x'])}
    _refuse_unreached(meas, model, values)
    cov = np.array(best['cov'])
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(invalid='ignore', divide='ignore'):
        corr = cov / np.outer(sd, sd)
    return Identification(
        parameters=tuple(names), values=values, initial=initial,
        rel_std={n: float(s) for n, s in zip(names, sd)},
        correlation=[[float(c) for c in row] for row in corr], rms=best['rms'],
        rms_initial=found.rms, signal=meas.signal,
        unit='rad' if meas.signal == 'windup' else 'rad/s', samples=best['samples'],
        evaluations=sum(r['evaluations'] for r in results),
        seconds=time.perf_counter() - t0,
        starts=[{'values': {n: math.exp(v) for n, v in zip(names, r['x'])}, 'rms': r['rms'],
                 'evaluations': r['evaluations'], 'status': r['message']} for r in results],
        bag=meas.bag, profile=getattr(meas.profile, 'name', ''), identifiability=found.ratio)


def fitted_signals(result: Identification, meas: Measurement
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(times [s], measured, fitted, at the starting values) after the settling: what the plot
    of measured against fitted shows."""
    model = _model(meas, result.parameters)
    keep = meas.t_s >= meas.settle_s
    sub = replace(meas, t_s=meas.t_s[keep], y=meas.y[keep])
    return (sub.t_s, sub.y, simulate(sub, model, result.values),
            simulate(sub, model, result.initial))
