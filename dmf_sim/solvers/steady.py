"""Every steady state at one operating point, and how likely the driveline settles in each
(``dmf-sim steady``).

1. The states: a full harmonic balance sweep over a small speed window around the operating
   point (dmf_sim.solvers.hbm: continuation, Floquet stability, branch switching, deflated Newton
   seeds, Newmark shots), evaluated exactly at the speed; 120 deg twins are one state with its
   multiplicity (when the cylinders fire alike: with faults that make them differ, states are
   told apart by their harmonics, phases included; dmf_sim.solvers.hbm.faulted). Where no
   periodic state is stable, a long Newmark run says what happens instead
   (dmf_sim.solvers.nonperiodic).
2. Basins of attraction: N initial states around the static equilibrium — wind-up offsets and
   rates drawn uniformly in [-A, A] / 2 and [-Omega A, Omega A] / 2 along each of the two modes
   with the most strain energy in the DMF (:func:`dmf_modes`, Omega their angular frequency) —
   are integrated by Newmark until the cycle-to-cycle change settles. Each run is matched to a
   state by its order amplitudes (with unlike cylinders by its complex orders); a settled run
   that matches none is polished by harmonic balance Newton and added (found by time
   integration). The share of runs per state is reported with a
   95 % Wilson score interval.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from dmf_sim.core.errors import ConfigError, ConvergenceError
from dmf_sim.physics.loads import DrivelineExcitation
from dmf_sim.solvers.hbm import CondensedHBM, HBMOptions, HBMPoint, SweepOptions, sweep
from dmf_sim.solvers.hbm.faulted import fingerprints
from dmf_sim.solvers.hbm.unknowns import to_real
from dmf_sim.solvers.newmark import SimulationOptions, simulate
from dmf_sim.solvers.nonperiodic import NonPeriodicResult
from dmf_sim.solvers.stability import FlexibleModes, FloquetAnalyzer

__all__ = ['Z_95', 'MATCH_HARMONICS', 'BasinOptions', 'wilson_interval', 'SteadyState',
           'SteadyStateSet', 'find_steady_states', 'dmf_modes']

Z_95 = 1.959963984540054      # two-sided 95 % normal quantile (Wilson interval)
MATCH_HARMONICS = 12          # half orders compared when matching a run to a state (to 6th order)


@dataclass(frozen=True)
class BasinOptions:
    """samples: initial states (0: no basin estimate); amplitude_rad: A, half-range of the random
    wind-up offset (None: twice the largest 3rd-order amplitude, at least 0.02 rad); seed: random
    generator seed; max_cycles: engine cycles per run; dt: Newmark step [s]; steady_tol: the
    run's cycle-to-cycle change that counts as settled (coarser than for an accurate steady
    state: the run only tells where it goes, the state is the harmonic balance one); match_tol:
    relative order-amplitude distance under which a run belongs to a state."""

    samples: int = 200
    amplitude_rad: float | None = None
    seed: int = 0
    max_cycles: int = 200
    dt: float = 1e-4
    steady_tol: float = 1e-3
    match_tol: float = 0.03


def wilson_interval(k: int, n: int) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion k / n."""
    if n <= 0:
        return 0.0, 1.0
    p = k / n
    den = 1.0 + Z_95 ** 2 / n
    centre = (p + Z_95 ** 2 / (2 * n)) / den
    half = Z_95 * math.sqrt(p * (1 - p) / n + Z_95 ** 2 / (4 * n * n)) / den
    return max(0.0, centre - half), min(1.0, centre + half)


@dataclass
class SteadyState:
    """One steady state: the HBM point (orders, Fig. 13 quantities, stability), its
    multiplicity (120 deg twins), how it was found, and its basin estimate."""

    point: HBMPoint
    multiplicity: int = 1
    found_by: str = ''
    hits: int = 0
    forced_ratio: float | None = None

    @property
    def kind(self) -> str:
        """'1.5th order' or '3rd order' (the larger share); with cylinders that do not fire alike
        (``forced_ratio`` set: they force the 1.5th order directly) '1.5th order' where it
        exceeds ``forced_ratio`` x its directly forced level (a resonance, as the sweep's
        humps), else 'forced'."""
        p = self.point
        if self.forced_ratio is not None:
            return ('1.5th order' if p.order_1_5 > self.forced_ratio * p.forced_order_1_5
                    else 'forced')
        return '1.5th order' if p.order_1_5 > 0.2 * p.order_3 else '3rd order'

    def as_dict(self, samples: int, all_orders: bool = False) -> dict:
        """The state's numbers; ``orders_rad``: the wind-up's orders that are multiples of the
        1.5th (every half order to the 12th with ``all_orders``, as a faulted engine excites
        them)."""
        p = self.point
        lo, hi = wilson_interval(self.hits, samples)
        d = {'kind': self.kind, 'stable': None if p.stable is None else bool(p.stable),
             'multiplicity': int(self.multiplicity), 'found_by': self.found_by,
             'max_multiplier': float(p.max_multiplier)}
        d.update(p.summary.as_dict())
        d['orders_rad'] = {f'{n / 2:g}': float(abs(c)) for n, c in enumerate(p.windup_orders)
                           if n > 0 and (all_orders or n % 3 == 0) and n <= 24}
        if samples:      # an unstable state attracts nothing: no basin (not a share of 0)
            d['basin'] = ({'hits': int(self.hits), 'share': self.hits / samples,
                           'ci95': [lo, hi]} if p.stable is not False else None)
        return d


@dataclass
class SteadyStateSet:
    """All steady states at one operating point (SI; speed in rpm)."""

    speed_rpm: float
    load: float
    states: list[SteadyState]
    non_periodic: list[NonPeriodicResult] = field(default_factory=list)
    samples: int = 0
    amplitude_rad: float = 0.0
    rate_rad_s: float = 0.0
    unsettled: int = 0
    seconds: float = 0.0
    faults: object = None          # the FaultSet of the search (None: healthy)

    @property
    def stable(self) -> list[SteadyState]:
        return [s for s in self.states if s.point.stable]

    def as_dict(self) -> dict:
        lo, hi = wilson_interval(self.unsettled, self.samples)
        faulted = {'faults': self.faults.text()} if self.faults else {}
        return {'speed_rpm': self.speed_rpm, 'load': self.load, **faulted,
                'seconds': self.seconds,
                'n_stable': len(self.stable),
                'states': [s.as_dict(self.samples, bool(self.faults)) for s in self.states],
                'non_periodic': [r.as_dict() for r in self.non_periodic],
                'basin_sampling': {'samples': self.samples,
                                   'windup_offset_range_rad': [-self.amplitude_rad,
                                                               self.amplitude_rad],
                                   'windup_rate_range_rad_s': [-self.rate_rad_s, self.rate_rad_s],
                                   'unsettled': self.unsettled,
                                   'unsettled_share': (self.unsettled / self.samples
                                                       if self.samples else 0.0),
                                   'unsettled_ci95': [lo, hi] if self.samples else None},
                'units': 'wind-up quantities in rad, positive when the engine drives'}


def _fingerprint(c: np.ndarray, symmetric: bool = True) -> np.ndarray:
    """The first MATCH_HARMONICS + 1 wind-up orders a run is matched on: their amplitudes when
    the cylinders fire alike (a run on a 120 deg shifted twin matches the state), else the
    complex orders (a state another phase away is another state)."""
    k = min(len(c), MATCH_HARMONICS + 1)
    c = np.asarray(c)[:k]
    return np.abs(c) if symmetric else c


class _Matcher:
    """Assigns a Newmark result (its wind-up orders) to the nearest known state that is not
    unstable (a run cannot settle on an unstable state: near one it is still drifting)."""

    def __init__(self, states: list[SteadyState], tol: float, symmetric: bool = True):
        self.states = states
        self.tol = tol
        self.symmetric = symmetric

    def match(self, c: np.ndarray) -> SteadyState | None:
        f = _fingerprint(c, self.symmetric)
        best, dist = None, np.inf
        for s in self.states:
            if s.point.stable is False:
                continue
            g = _fingerprint(s.point.windup_orders, self.symmetric)
            n = min(len(f), len(g))
            d = float(np.abs(f[:n] - g[:n]).max()) / max(float(np.abs(g[1:n]).max()), 1e-6)
            if d < dist:
                best, dist = s, d
        return best if dist <= self.tol else None


def find_steady_states(loads: DrivelineExcitation, speed_rpm: float, load: float, *,
                       window_rpm: float = 30.0, hbm_options: HBMOptions | None = None,
                       sweep_options: SweepOptions | None = None,
                       basin: BasinOptions | None = None, progress: bool = False,
                       faults=None) -> SteadyStateSet:
    """Every steady state at ``speed_rpm`` and load fraction ``load`` with basin estimates (see
    the module docstring). ``faults``: a :class:`~dmf_sim.physics.faults.FaultSet` of
    persistent faults (every-cycle misfires, weak cylinders, DMF faults), None: healthy; the
    search and every basin run take them (:func:`dmf_sim.solvers.hbm.sweep`)."""
    t0 = time.perf_counter()
    b = basin or BasinOptions()
    s = float(speed_rpm)
    rng = getattr(loads.engine, 'speed_range_rpm', None)
    lo, hi = s - window_rpm, s + window_rpm
    if rng is not None:
        if not rng[0] <= s <= rng[1]:
            raise ConfigError(f'speed {s:g} rpm: the engine data covers '
                              f'{rng[0]:g}..{rng[1]:g} rpm')
        lo, hi = max(lo, float(rng[0])), min(hi, float(rng[1]))
    step = max(window_rpm / 6.0, 1.0)
    base = sweep_options or SweepOptions()
    opts = replace(base, step_rpm=step)
    if opts.search is not None:
        opts = replace(opts, search=replace(opts.search, seed_step_rpm=step,
                                            nonperiodic_speeds=(s,)))   # the envelope where asked
    res = sweep(loads, load, (lo, hi), hbm_options=hbm_options, options=opts, progress=progress,
                label=f'{s:g} rpm', faults=faults)
    hb: CondensedHBM = res.hbm
    states: list[SteadyState] = []
    for q in res.solutions_at(s):
        mult = next((br.multiplicity for br in res.branches if br.id == q.branch), 1)
        if _same_state(states, q, hb) is None:
            states.append(SteadyState(q, mult, f'harmonic balance (branch {q.branch}: {q.kind})',
                                      forced_ratio=None if hb.symmetric else opts.ratio_1_5))
    nonper = [r for band in res.non_periodic for r in band.results if abs(r.speed_rpm - s) < 1e-6]
    out = SteadyStateSet(s, float(load), states, nonper, faults=res.faults)
    if b.samples > 0:
        _basins(out, hb, hb.loads, b, progress,       # the loads of the faulted model, if any
                None if hb.symmetric else opts.ratio_1_5)
    out.states.sort(key=lambda st: (not st.point.stable, -st.hits, st.point.order_1_5))
    out.seconds = time.perf_counter() - t0
    return out


def _same_state(states: list[SteadyState], q, hb: CondensedHBM) -> SteadyState | None:
    """The state of ``states`` the harmonic-balance point ``q`` is (its fingerprints within
    1e-4 of its largest harmonic: the same solution up to the solver's tolerance), or None."""
    f = fingerprints(q.x, hb.H, hb.symmetric)
    return next((st for st in states
                 if np.abs(fingerprints(st.point.x, hb.H, hb.symmetric) - f).max()
                 <= 1e-6 + 1e-4 * np.abs(q.x).max()), None)


def dmf_modes(model, count: int = 2) -> list[tuple[np.ndarray, float]]:
    """The ``count`` flexible modes with the largest share of their strain energy in the DMF
    spring (k (e.phi)^2 / omega^2 for mass-normalized phi; the truck: 7.8 and 17.9 Hz), each as
    (DOF shape scaled to unit wind-up, angular frequency [rad/s])."""
    fm = FlexibleModes(model)
    share = model.spring.k * fm.er ** 2 / np.maximum(fm.lam, 1e-300)
    out = []
    for k in np.argsort(-share)[:count]:
        phi = fm.Phi[:, k]
        out.append((phi / float(model.e @ phi), float(np.sqrt(fm.lam[k]))))
    return out


def _basins(out: SteadyStateSet, hb: CondensedHBM, loads: DrivelineExcitation, b: BasinOptions,
            progress: bool, forced_ratio: float | None = None) -> None:
    s, load = out.speed_rpm, out.load
    model = loads.model
    A = b.amplitude_rad
    if A is None:
        A = max([2.0 * st.point.order_3 for st in out.states] + [0.02])
    if not (math.isfinite(A) and A > 0):
        raise ConfigError(f'basin amplitude {A!r} rad: must be > 0')
    modes = dmf_modes(model, 2)
    omega = max(om for _, om in modes)
    out.samples, out.amplitude_rad, out.rate_rad_s = b.samples, float(A), float(omega * A)
    q_s = loads.static_state(s, load, hb.factors).q
    rng = np.random.default_rng(b.seed)
    matcher = _Matcher(out.states, b.match_tol, hb.symmetric)
    floquet = FloquetAnalyzer(model, modes=hb.modes, compiled=hb.compiled)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=b.samples, desc=f'basins at {s:g} rpm', unit='run', leave=False)
    for _ in range(b.samples):
        dq, dv = np.zeros_like(q_s), np.zeros_like(q_s)
        for shape, om in modes:            # the wind-up offset and rate split over the modes
            dq += rng.uniform(-A, A) / len(modes) * shape
            dv += rng.uniform(-om * A, om * A) / len(modes) * shape
        r = simulate(loads, s, load, initial=(q_s + dq, dv), factors=hb.factors,
                     options=SimulationOptions(dt=b.dt, max_cycles=b.max_cycles,
                                               steady_tol=b.steady_tol))
        if bar is not None:
            bar.update(1)
        if not r.steady:
            out.unsettled += 1
            continue
        st = matcher.match(r.windup_orders)
        if st is None:
            st = _add_from_newmark(out, hb, floquet, r.windup_orders, s, forced_ratio)
        if st is None:
            out.unsettled += 1
        else:
            st.hits += 1
    if bar is not None:
        bar.close()


def _add_from_newmark(out: SteadyStateSet, hb: CondensedHBM, floquet: FloquetAnalyzer,
                      c: np.ndarray, s: float, forced_ratio: float | None = None
                      ) -> SteadyState | None:
    """A settled Newmark run that matches no state: Newton from its orders; the state Newton
    ends on if it is known already, else its stability, and added if stable."""
    x = np.zeros(hb.H + 1, dtype=complex)
    k = min(len(c), hb.H + 1)
    x[:k] = c[:k]
    try:
        q = hb.solve(s, to_real(x, hb.H))
    except ConvergenceError:
        return None
    if (known := _same_state(out.states, q, hb)) is not None:
        return known if known.point.stable else None   # a state known already (its run's
    fr = floquet.analyze(q.windup_orders, s)            # orders were off it by > match_tol)
    q.stable, q.multipliers, q.max_multiplier = fr.stable, fr.multipliers, fr.max_abs
    if not q.stable:
        return None          # the run passed near an unstable state: it had not settled
    q.forced_order_1_5 = float(abs(hb.linear_parts(s).wlin[3])) if hb.H >= 3 else 0.0
    st = SteadyState(q, 1, 'time integration from a random start, polished by Newton',
                     forced_ratio=forced_ratio)
    out.states.append(st)
    return st
