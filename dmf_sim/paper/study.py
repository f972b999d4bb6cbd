"""The reference paper's study, computed by the package (``dmf-sim paper``).

:class:`PaperStudy` runs what the paper's figures and statements rest on: modes (Fig. 12), the
engine loads (Fig. 8), HBM speed sweeps for several alpha and Loads A/B/C (Figs. 13, 15), a
lower DMF damping, a load scan at fixed speeds (also for a what-if engine with a higher
full-load plateau), pure 3rd-order excitation, non-linear normal modes with the scaling check
(Fig. 14), and time integration of coexisting steady states. :mod:`._paper_claims` turns the
results into one row per claim of the paper; nothing there is typed in, every number comes
from these computations.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from dmf_sim.core.errors import DmfSimError

__all__ = ['ORDER_1_5_HZ_FACTOR', 'MAX_STEPS_PER_BRANCH', 'NEWMARK_DT_S', 'NEWMARK_MAX_CYCLES',
           'StudySettings', 'LoadScan', 'StudyResults', 'OrdersOnly', 'stable_peak_1_5',
           'stable_solutions', 'grid', 'PaperStudy', 'DISTINCT_REL', 'distinct']

ORDER_1_5_HZ_FACTOR = 1.5 / 60.0     # 1.5th order frequency [Hz] per engine speed [rpm]
MAX_STEPS_PER_BRANCH = 1000          # continuation steps per branch (a full sweep needs < 300)
NEWMARK_DT_S = 5e-5                  # coexistence check's step (doc/theory.md §5: dt <= 5e-5 s
NEWMARK_MAX_CYCLES = 300             # at the 1.5th-order resonance)


@dataclass(frozen=True)
class StudySettings:
    """What the study computes (full size by default; :meth:`quick` for the test suite)."""

    engine: str = 'engine_d13'
    driveline: str = 'truck_dmf'
    conventional: str = 'truck_conventional'
    speeds: tuple[float, float, float] = (600.0, 2000.0, 10.0)   # sweep grid [rpm]
    alphas: tuple[float, ...] = (2.0, 2.5, 3.0)                  # Fig. 13
    fig15_alpha: float = 2.5
    load_sets: tuple[str, ...] = ('A', 'B', 'C')                 # Fig. 15
    n_harmonics: int = 24
    band_alpha: float = 3.0                       # the paper's 27 Hz is the alpha = 3 mode
    low_damping_factor: float = 0.1               # "lower damping": the paper says not how much
    low_damping_speeds: tuple[float, float, float] = (600.0, 900.0, 5.0)
    scan_loads: tuple[float, ...] = (0.8, 0.85, 0.9, 0.95, 1.0)
    scan_alphas: tuple[float, ...] = (2.5, 3.0)
    scan_load_sets: tuple[str, ...] = ('A', 'B', 'C')
    scan_speeds: tuple[float, float, float] = (700.0, 1300.0, 20.0)
    what_if_plateau_nm: float = 3000.0            # load scan again with this full-load plateau
    nnm_alpha: float = 2.0                        # Fig. 14
    nnm_xi_max: float = 100.0
    nnm_harmonics: int = 20
    scaling_time_domain: bool = True
    fig8_speeds: tuple[float, ...] = (800.0, 1000.0, 1200.0, 1400.0)

    @classmethod
    def quick(cls, **kw) -> StudySettings:
        """A reduced study (coarser sweeps, smaller load scan, NNMs to xi = 10 with fewer
        harmonics, HBM-only scaling check) for tests: same claims, computed on less."""
        small = dict(speeds=(600.0, 1400.0, 20.0), scan_loads=(0.9, 0.95, 1.0),
                     scan_alphas=(3.0,), scan_load_sets=('A', 'C'),
                     scan_speeds=(900.0, 1080.0, 20.0),
                     low_damping_speeds=(640.0, 840.0, 10.0), nnm_xi_max=10.0, nnm_harmonics=12,
                     scaling_time_domain=False, fig8_speeds=(1000.0, 1400.0))
        return cls(**{**small, **kw})


@dataclass
class LoadScan:
    """Largest stable 1.5th-order wind-up [rad] over speeds, per (load set, alpha) and load."""

    speeds_rpm: np.ndarray
    loads: tuple[float, ...]
    order_1_5: dict[tuple[str, float], dict[float, np.ndarray]] = field(default_factory=dict)
    failures: list[str] = field(default_factory=list)


@dataclass
class StudyResults:
    """Everything the report and the figures need."""

    settings: StudySettings
    theta: float = float('nan')
    knee_torque_nm: float = float('nan')         # k theta of the first drive stage
    full_load_max_nm: float = float('nan')       # highest full-load torque of the engine
    modes_conventional: object = None
    modes_dmf: object = None                     # primary stiffness
    modes_dmf_band: object = None                # secondary stiffness at band_alpha
    mean_torque_speeds: np.ndarray | None = None
    mean_torque: dict = field(default_factory=dict)
    fig8_psi_deg: np.ndarray | None = None
    fig8_torque: dict = field(default_factory=dict)
    sweeps: dict[tuple[float, str], object] = field(default_factory=dict)
    low_damping: dict[str, object] = field(default_factory=dict)   # 'table' / 'lower'
    dmf_damping: dict[str, float] = field(default_factory=dict)
    pure_third: object = None
    scan: LoadScan | None = None
    what_if: LoadScan | None = None
    nnm: object = None
    scaling: dict | None = None
    coexisting: dict | None = None
    seconds: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)     # solver remarks for the report


class OrdersOnly:
    """An engine excitation keeping only some half orders (the others set to zero): the paper's
    "pure third engine order excitation" is ``OrdersOnly(engine, (0, 6))``."""

    def __init__(self, engine, keep) -> None:
        self.engine = engine
        self.n_cylinders, self.n_max = engine.n_cylinders, engine.n_max
        self.firing_phases_deg = engine.firing_phases_deg
        self.speed_range_rpm = engine.speed_range_rpm
        self.mask = np.isin(np.arange(engine.n_max + 1), keep)

    def coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        return np.where(self.mask, self.engine.coefficients(speed_rpm, load), 0.0)

    def mean_torque(self, speed_rpm: float, load: float) -> float:
        return self.engine.mean_torque(speed_rpm, load)

    def full_load_torque(self, speed_rpm: float) -> float:
        return self.engine.full_load_torque(speed_rpm)


def stable_peak_1_5(res, lo: float = -np.inf, hi: float = np.inf) -> dict | None:
    """Largest 1.5th-order wind-up over the stable points of every branch of a SweepResult with
    speed in [lo, hi]: amplitude [rad], speed [rpm], its directly forced level [rad]."""
    best = None
    for b in res.branches:
        for p in b.points:
            if p.stable and lo <= p.speed_rpm <= hi and (best is None
                                                         or p.order_1_5 > best.order_1_5):
                best = p
    if best is None:
        return None
    return {'order_1_5': float(best.order_1_5), 'speed_rpm': float(best.speed_rpm),
            'forced_order_1_5': float(best.forced_order_1_5), 'order_3': float(best.order_3),
            'branch': int(best.branch)}


def stable_solutions(res, speed_rpm: float) -> list:
    """The stable solutions of a sweep at one speed (``SweepResult.solutions_at``)."""
    return [p for p in res.solutions_at(speed_rpm) if p.stable]


def grid(spec: tuple[float, float, float]) -> np.ndarray:
    lo, hi, step = spec
    return np.arange(lo, hi + 0.5 * step, step)


class PaperStudy:
    """Runs the study; ``progress(text)`` is told what happens (stderr in the command)."""

    def __init__(self, settings: StudySettings | None = None,
                 progress: Callable[[str], None] | None = None) -> None:
        self.s = settings or StudySettings()
        self.say = progress or (lambda text: None)
        self.notes: list[str] = []
        self.pairs: list[tuple] = []

    # ---- helpers -------------------------------------------------------------------------------
    def _timed(self, key: str, results: StudyResults, fn, *args):
        t0 = time.perf_counter()
        out = fn(*args)
        results.seconds[key] = round(time.perf_counter() - t0, 3)
        self.say(f'{key}: {results.seconds[key]:.1f} s')
        return out

    def _sweep(self, line, engine, alpha: float, load: float, speeds, **dmf):
        from dmf_sim.physics.loads import DrivelineExcitation
        from dmf_sim.solvers.continuation import ContinuationOptions
        from dmf_sim.solvers.hbm import HBMOptions, SweepOptions, sweep
        loads = DrivelineExcitation(line.with_dmf(alpha=alpha, **dmf).reduce(), engine)
        res = sweep(loads, load, (speeds[0], speeds[1]),
                    hbm_options=HBMOptions(n_harmonics=self.s.n_harmonics),
                    options=SweepOptions(step_rpm=speeds[2]),
                    continuation=ContinuationOptions(max_steps=MAX_STEPS_PER_BRANCH))
        for b in res.branches:
            if len(b.points) > MAX_STEPS_PER_BRANCH:
                self.notes.append(
                    f'{getattr(engine, "name", "engine")}, alpha {alpha:g}, load {load:g}: branch '
                    f'{b.id} ({b.kind}, {b.speed_range[0]:.0f}-{b.speed_range[1]:.0f} rpm) '
                    f'stopped after {MAX_STEPS_PER_BRANCH} continuation steps (a closed branch '
                    'traced round more than once)')
        return res

    # ---- the study -----------------------------------------------------------------------------
    def run(self) -> StudyResults:
        from dmf_sim.physics.engine import read_engine
        from dmf_sim.physics.model import read_driveline
        s = self.s
        r = StudyResults(settings=s)
        self.line = read_driveline(s.driveline)
        r.theta = float(self.line.dmf.theta)
        r.knee_torque_nm = float(self.line.spring.k * r.theta)
        self.engine = read_engine(s.engine)
        r.full_load_max_nm = max(self.engine.full_load_torque(v) for v in grid(s.speeds))
        self._timed('engine data', r, self.engine.warm_up)
        self._timed('modes (Fig. 12)', r, self._modes, r)
        self._timed('engine loads (Fig. 8)', r, self._loads, r)
        self._timed('sweeps (Figs. 13, 15)', r, self._sweeps, r)
        self._timed('lower DMF damping', r, self._low_damping, r)
        self._timed('pure 3rd-order excitation', r, self._pure_third, r)
        r.scan = self._timed('load scan', r, self._scan, self.engine)
        what_if = self._what_if_engine()
        if what_if is not None:
            r.what_if = self._timed(f'load scan, {s.what_if_plateau_nm:g} Nm plateau', r,
                                    self._scan, what_if, ('A',), False)
        self._timed('non-linear normal modes (Fig. 14)', r, self._nnm, r)
        self._timed('coexisting solutions', r, self._coexisting, r)
        r.notes = list(dict.fromkeys(self.notes))
        return r

    def _modes(self, r: StudyResults) -> None:
        from dmf_sim.physics.modal import modes
        from dmf_sim.physics.model import read_model
        r.modes_conventional = modes(read_model(self.s.conventional))
        r.modes_dmf = modes(self.line.reduce(), 'primary')
        r.modes_dmf_band = modes(self.line.with_dmf(alpha=self.s.band_alpha).reduce(), 'secondary')

    def _loads(self, r: StudyResults) -> None:
        from dmf_sim.physics.cycle_torque import mean_torques, torque_before_flywheel
        r.mean_torque_speeds = grid(self.s.speeds)
        engines = {ls: self.engine.with_load_set(ls) for ls in self.s.load_sets}
        r.mean_torque = mean_torques(engines, r.mean_torque_speeds, 1.0)
        r.fig8_psi_deg, r.fig8_torque = torque_before_flywheel(self.engine, self.s.fig8_speeds,
                                                               1.0)

    def _sweeps(self, r: StudyResults) -> None:
        s = self.s
        cases = [(a, 'A') for a in s.alphas] + [(s.fig15_alpha, ls) for ls in s.load_sets]
        for a, ls in dict.fromkeys(cases):
            self.say(f'  sweep alpha = {a:g}, Load {ls}, {s.speeds[0]:g}-{s.speeds[1]:g} rpm')
            r.sweeps[(a, ls)] = self._sweep(self.line, self.engine.with_load_set(ls), a, 1.0,
                                            s.speeds)

    def _low_damping(self, r: StudyResults) -> None:
        s = self.s
        line = self.line
        c = line.dmf_element.damping
        r.dmf_damping = {'table': c, 'lower': s.low_damping_factor * c}
        for key, damping in r.dmf_damping.items():
            r.low_damping[key] = self._sweep(line, self.engine, s.band_alpha, 1.0,
                                             s.low_damping_speeds, damping=damping)

    def _pure_third(self, r: StudyResults) -> None:
        from dmf_sim.physics.orders import ORDER_3
        r.pure_third = self._sweep(self.line, OrdersOnly(self.engine, (0, ORDER_3)),
                                   self.s.band_alpha, 1.0, self.s.speeds)

    def _what_if_engine(self):
        """The engine with its full-load curve scaled to ``what_if_plateau_nm`` (None for a
        coefficient table, which has no curve to scale)."""
        from dmf_sim.core.paths import read_yaml_mapping
        from dmf_sim.physics.engine import engine_from_mapping
        from dmf_sim.physics.engine.config import with_base
        if str(self.engine.source).endswith('.csv'):
            return None
        path, doc = read_yaml_mapping(self.engine.source, 'engine')
        if 'coefficients' in doc:
            return None
        doc, _ = with_base(doc, path)
        curve = doc['full_load_curve']
        f = self.s.what_if_plateau_nm / max(curve['torque_nm'])
        doc = {**doc, 'name': f'{doc["name"]} x {f:.3f}',
               'full_load_curve': {**curve, 'torque_nm': [f * t for t in curve['torque_nm']]}}
        eng = engine_from_mapping(doc, path)
        eng.warm_up()
        return eng

    def _stable_peaks(self, res, speeds, label: tuple, record: bool) -> np.ndarray:
        """Largest stable 1.5th-order wind-up [rad] at each speed; with ``record``, pairs of
        physically different stable solutions there are kept for the coexistence claim."""
        out = np.full(len(speeds), np.nan)
        for i, v in enumerate(speeds):
            sols = stable_solutions(res, float(v))
            if sols:
                out[i] = max(p.order_1_5 for p in sols)
            if record:
                self.pairs += [(distinct(p, q), *label, float(v), p, q, res)
                               for k, p in enumerate(sols) for q in sols[k + 1:]
                               if distinct(p, q) > 0]
        return out

    def _scan(self, engine, load_sets=None, record: bool = True) -> LoadScan:
        s = self.s
        speeds = grid(s.scan_speeds)
        scan = LoadScan(speeds, tuple(s.scan_loads))
        sweep_range = (min(s.speeds[0], s.scan_speeds[0]), s.scan_speeds[1], s.scan_speeds[2])
        for ls in load_sets or s.scan_load_sets:
            for a in s.scan_alphas:
                per_load = {}
                for ld in s.scan_loads:
                    try:
                        res = self._sweep(self.line, engine.with_load_set(ls), a, ld, sweep_range)
                    except DmfSimError as exc:
                        scan.failures.append(f'Load {ls}, alpha {a:g}, load {ld:g}: {exc}')
                        continue
                    per_load[ld] = self._stable_peaks(res, speeds, (a, ls, ld), record)
                scan.order_1_5[(ls, a)] = per_load
        return scan

    def _nnm(self, r: StudyResults) -> None:
        from dmf_sim.solvers.nnm import NNMOptions, nnm_branches, scaling_check
        s = self.s
        model = self.line.with_dmf(alpha=s.nnm_alpha).reduce()
        opts = NNMOptions(n_harmonics=s.nnm_harmonics)
        r.nnm = nnm_branches(model, xi_max=s.nnm_xi_max, options=opts)
        r.scaling = scaling_check(model, options=opts, time_domain=s.scaling_time_domain)

    def _coexisting(self, r: StudyResults) -> None:
        """Speeds where two physically different stable steady states coexist (a 120 deg shifted
        twin of a 1.5th-order state is the same state) in the figure sweeps and the load scan,
        and Newmark from each of the pair that differs most: each stays on its own solution."""
        band = (r.modes_dmf.frequencies_hz[2] / ORDER_1_5_HZ_FACTOR,
                r.modes_dmf_band.frequencies_hz[2] / ORDER_1_5_HZ_FACTOR)
        step = self.s.speeds[2]
        speeds = grid((np.ceil(band[0] / step) * step, band[1], step))
        for (a, ls), res in r.sweeps.items():
            self._stable_peaks(res, speeds, (a, ls, 1.0), True)
        found = sorted(self.pairs, key=lambda t: -t[0])
        r.coexisting = {'pairs': [{'alpha': a, 'load_set': ls, 'load': ld, 'speed_rpm': v,
                                   'order_1_5': (p.order_1_5, q.order_1_5),
                                   'order_3': (p.order_3, q.order_3)}
                                  for _, a, ls, ld, v, p, q, _ in found],
                        'newmark': None}
        if found:
            _, a, ls, ld, v, p, q, res = found[0]
            runs = []
            for sol in (p, q):
                nm = res.hbm.newmark_from(sol, dt=NEWMARK_DT_S, max_cycles=NEWMARK_MAX_CYCLES)
                runs.append({'hbm_order_1_5': float(sol.order_1_5),
                             'newmark_order_1_5': float(nm.summary.order_1_5),
                             'hbm_order_3': float(sol.order_3),
                             'newmark_order_3': float(nm.summary.order_3),
                             'steady': bool(nm.steady), 'cycles': int(nm.cycles)})
            r.coexisting['newmark'] = {'alpha': a, 'load_set': ls, 'load': ld, 'speed_rpm': v,
                                       'runs': runs}


DISTINCT_REL = 0.2
"""Two steady states differ physically when their 1.5th- or 3rd-order wind-up amplitudes differ
by more than this share of the larger one (twins shifted by 120 deg differ by far less)."""


def distinct(p, q) -> float:
    """How much two steady states differ (0 if they count as the same physical state)."""
    gaps = []
    for a, b in ((p.order_1_5, q.order_1_5), (p.order_3, q.order_3)):
        rel = abs(a - b) / max(a, b, 1e-12)
        gaps.append(rel if rel > DISTINCT_REL else 0.0)
    return max(gaps)
