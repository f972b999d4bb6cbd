"""One row per claim of the reference paper, computed from a :class:`StudyResults`.

Each :class:`Claim` holds the paper's words, the package's numbers (formatted from the study, never
typed in), whether the package reproduces the claim (yes / partly / no, by the criteria named in
the module constants), and, where it disagrees or only partly agrees, why.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from dmf_sim.paper.study import ORDER_1_5_HZ_FACTOR, StudyResults, stable_peak_1_5

__all__ = ['FREQ_TOL_HZ', 'BAND_TOL_RPM', 'RESONANCE_RATIO', 'PEAK_WINDOW_RPM', 'PEAK_RATIO',
           'PEAK_NEAR_720_RPM', 'CONVERGED_GAP', 'FLAT_MATCH', 'SCALING_SPREAD', 'WORSE_BY',
           'WORSE_MIN_RAD', 'NEWMARK_MATCH', 'MARGINAL', 'Claim', 'claims']

YES, PARTLY, NO = 'yes', 'partly', 'no'

FREQ_TOL_HZ = 0.5            # the paper's frequencies are whole hertz
BAND_TOL_RPM = 20.0          # a resonance stretch may overhang the band by one coarse grid step
RESONANCE_RATIO = 5.0        # "high": the alpha = 3 peak at least this x its directly forced level
PEAK_WINDOW_RPM = 60.0       # a peak rises above the level this far on both sides ...
PEAK_RATIO = 1.5             # ... by at least this factor
PEAK_NEAR_720_RPM = (700.0, 740.0)   # "at 720 rpm": 18 Hz x 40 = 716 rpm
CONVERGED_GAP = 0.25         # NNM branches "approach the same frequency": gap below this x start
FLAT_MATCH = 0.02            # n x flat-branch frequency within 2 % of a subsystem resonance
SCALING_SPREAD = 1e-6        # NNM frequency spread over (theta, distance)
WORSE_BY = 1.05              # a part load "exceeds" full load by 5 % ...
WORSE_MIN_RAD = 2e-3         # ... at a 1.5th order of at least 2 mrad
NEWMARK_MATCH = 0.15         # a time-integrated coexisting state within 15 % of its HBM twin
MARGINAL = 0.1               # "only marginally affected": the 3rd mode moves less than 10 %


@dataclass
class Claim:
    key: str
    topic: str
    paper: str                   # the paper's words
    package: str                 # what the package computes (numbers from the study)
    status: str                  # yes / partly / no
    why: str = ''                # why the package disagrees (or what to know)
    figure: str = ''             # the figure file it refers to
    values: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return asdict(self)


def _mrad(x: float) -> str:
    return f'{1e3 * x:.1f} mrad'


def claims(r: StudyResults) -> list[Claim]:
    """Every claim row, in the paper's order."""
    return [_frequency_shift(r), _frequencies(r), _band(r), _growth(r), _pure_third(r),
            _low_damping(r), *_nnm(r), _scaling(r), _fig15(r), _worst_load(r), _coexisting(r)]


# ------------------------------------------------------------------------------------------------
def _frequency_shift(r: StudyResults) -> Claim:
    fc, fd = r.modes_conventional.frequencies_hz, r.modes_dmf.frequencies_hz
    shift3 = abs(fd[3] - fc[3]) / fc[3]
    ok = fd[2] < fc[2] and shift3 < MARGINAL
    return Claim(
        'frequency_shift', 'Fig. 12: modes, conventional vs DMF',
        '"When a dual mass flywheel is introduced, the frequency of the second mode is reduced. '
        '[...] The frequency of the third resonance mode in the driveline is only marginally '
        'affected by the dual mass flywheel."',
        f'2nd mode {fc[2]:.1f} Hz (conventional) -> {fd[2]:.1f} Hz (DMF, primary stiffness); '
        f'3rd mode {fc[3]:.1f} -> {fd[3]:.1f} Hz ({100 * shift3:.0f} % change).',
        YES if ok else NO, figure='fig12.png',
        values={'conventional_hz': [float(f) for f in fc[1:5]],
                'dmf_hz': [float(f) for f in fd[1:5]]})


def _frequencies(r: StudyResults) -> Claim:
    f1 = float(r.modes_dmf.frequencies_hz[2])
    f2 = float(r.modes_dmf_band.frequencies_hz[2])
    a = r.settings.band_alpha
    ok = abs(f1 - 18.0) < FREQ_TOL_HZ and abs(f2 - 27.0) < FREQ_TOL_HZ
    return Claim(
        'frequencies', 'DMF second mode: 18 Hz -> 27 Hz',
        '"The resonance frequency of the second driveline mode at the primary stiffness in the '
        'dual flywheel is 18 Hz and the corresponding frequency for the higher stiffness for α = '
        '3 is 27 Hz."',
        f'{f1:.2f} Hz at the primary stiffness k, {f2:.2f} Hz at k(1 + α), α = {a:g}.',
        YES if ok else NO, figure='fig12.png', values={'primary_hz': f1, 'secondary_hz': f2})


def _band_rpm(r: StudyResults) -> tuple[float, float]:
    return (float(r.modes_dmf.frequencies_hz[2]) / ORDER_1_5_HZ_FACTOR,
            float(r.modes_dmf_band.frequencies_hz[2]) / ORDER_1_5_HZ_FACTOR)


def _band(r: StudyResults) -> Claim:
    lo, hi = _band_rpm(r)
    spans, inside = [], True
    for (a, ls), res in r.sweeps.items():
        for d in res.subharmonic_summary():
            if not d['peak_stable']:
                continue
            spans.append({'alpha': a, 'load_set': ls, 'from_rpm': d['speed_min_rpm'],
                          'to_rpm': d['speed_max_rpm'], 'peak_rad': d['peak_order_1_5_rad'],
                          'peak_rpm': d['peak_speed_rpm']})
            inside &= (d['speed_min_rpm'] >= lo - BAND_TOL_RPM
                       and d['speed_max_rpm'] <= hi + BAND_TOL_RPM)
    text = '; '.join(f'α {s["alpha"]:g} Load {s["load_set"]}: {s["from_rpm"]:.0f}-'
                     f'{s["to_rpm"]:.0f} rpm (peak {_mrad(s["peak_rad"])} at {s["peak_rpm"]:.0f})'
                     for s in spans) or 'none found'
    return Claim(
        'band_720_1080', '1.5th-order resonance between 720 and 1080 rpm',
        '"[...] we should expect a resonance with frequency somewhere in between these values, '
        'and it would show up as a 1.5th engine order vibration at engine speeds between 720 and '
        '1080 rpm."',
        f'The package\'s band (1.5 x speed between the two mode frequencies): {lo:.0f}-{hi:.0f} '
        f'rpm. Stable 1.5th-order resonances (> 3 x the directly forced level) at full load: '
        f'{text}.',
        YES if spans and inside else (PARTLY if spans else NO), figure='fig13.png',
        values={'band_rpm': [lo, hi], 'resonances': spans})


def _growth(r: StudyResults) -> Claim:
    lo, hi = _band_rpm(r)
    peaks = {a: stable_peak_1_5(r.sweeps[(a, 'A')], lo, hi) for a in r.settings.alphas}
    amps = [peaks[a]['order_1_5'] for a in r.settings.alphas]
    top = peaks[max(r.settings.alphas)]
    ratio = top['order_1_5'] / top['forced_order_1_5']
    grows = bool(np.all(np.diff(amps) > 0))
    ok = grows and ratio >= RESONANCE_RATIO
    text = ', '.join(f'α {a:g}: {_mrad(peaks[a]["order_1_5"])} at {peaks[a]["speed_rpm"]:.0f} rpm'
                     for a in r.settings.alphas)
    return Claim(
        'growth_with_alpha', 'growth with α (Load A, full load)',
        '"When α is increasing we can observe high vibration amplitudes at low engine speeds with '
        'a frequency corresponding to 1.5th engine order."',
        f'Largest stable 1.5th-order wind-up, Load A, full load: {text}; the α = '
        f'{max(r.settings.alphas):g} peak is {ratio:.1f} x its directly forced level '
        f'({_mrad(top["forced_order_1_5"])}) and {top["order_1_5"] / top["order_3"]:.2f} x the '
        '3rd order there.',
        YES if ok else (PARTLY if grows else NO), figure='fig13.png',
        why='' if ok else 'the peaks do not grow with α, or the largest is not a resonance',
        values={'peaks': {f'{a:g}': peaks[a] for a in r.settings.alphas},
                'ratio_to_forced': ratio})


def _pure_third(r: StudyResults) -> Claim:
    res = r.pure_third
    subs = [d for d in res.subharmonic_summary() if d['peak_stable']]
    a = r.settings.band_alpha
    forced = max(p.forced_order_1_5 for b in res.branches for p in b.points)
    lost = [e for e in res.events if e.kind == 'stability_loss' and 'subharmonic' in e.detail]
    if subs:
        best = max(subs, key=lambda d: d['peak_order_1_5_rad'])
        text = (f'with only n = 0 and the 3rd order (n = 6) of the engine, α = {a:g}, full Load A '
                f'(directly forced 1.5th order: {forced:.1e} rad): '
                + (f'the 3rd-order solution loses stability to a sub-harmonic at '
                   f'{lost[0].speed_rpm:.0f} rpm and ' if lost else '')
                + f'a stable 1.5th-order branch reaches {_mrad(best["peak_order_1_5_rad"])} at '
                f'{best["peak_speed_rpm"]:.0f} rpm ({best["speed_min_rpm"]:.0f}-'
                f'{best["speed_max_rpm"]:.0f} rpm).')
    else:
        text = f'no stable 1.5th-order response found with pure 3rd-order excitation (α = {a:g})'
    return Claim(
        'pure_third_order', '1.5th order under pure 3rd-order excitation',
        '"[...] the high 1.5th engine order response is observed also for pure third engine order '
        'excitation so this is a consequence of the non-linearity in the dual mass flywheel."',
        text, YES if subs else NO,
        values={'subharmonic': subs, 'events': [e.as_dict() for e in res.events]})


def _peak_near(res, theta: float) -> dict:
    """The 1.5th-order curve of a sweep's main branch: largest value, where, whether it is a
    peak (PEAK_RATIO above the level PEAK_WINDOW_RPM away on both sides) and whether the wind-up
    stays below the knee there."""
    m = res.main()
    s, y = m.column('speed_rpm'), m.column('order_1_5')
    k = int(np.argmax(y))
    side = max(np.interp(s[k] - PEAK_WINDOW_RPM, s, y), np.interp(s[k] + PEAK_WINDOW_RPM, s, y))
    top = m.points[k].summary
    return {'max_rad': float(y[k]), 'speed_rpm': float(s[k]),
            'primary_only': bool(top.mean + top.max_deviation < theta),
            'at_720_rad': float(np.interp(720.0, s, y)), 'prominence': float(y[k] / side),
            'peak': bool(y[k] >= PEAK_RATIO * side and s[0] + PEAK_WINDOW_RPM <= s[k]
                         <= s[-1] - PEAK_WINDOW_RPM)}


def _low_damping(r: StudyResults) -> Claim:
    table = _peak_near(r.low_damping['table'], r.theta)
    lower = _peak_near(r.low_damping['lower'], r.theta)
    c = r.dmf_damping
    near = PEAK_NEAR_720_RPM[0] <= lower['speed_rpm'] <= PEAK_NEAR_720_RPM[1]
    ok = lower['peak'] and near and not table['peak'] and lower['primary_only']
    text = (f'Full Load A, α = {r.settings.band_alpha:g}, DMF damping {c["table"]:g} Nms/rad '
            f'(Table 1): 1.5th order {_mrad(table["at_720_rad"])} at 720 rpm, largest '
            f'{_mrad(table["max_rad"])} at {table["speed_rpm"]:.0f} rpm, '
            f'{"a" if table["peak"] else "no"} peak (ratio {table["prominence"]:.2f} to the level '
            f'{PEAK_WINDOW_RPM:.0f} rpm away). DMF damping {c["lower"]:g} Nms/rad: peak '
            f'{_mrad(lower["max_rad"])} at {lower["speed_rpm"]:.0f} rpm (ratio '
            f'{lower["prominence"]:.1f}); the wind-up '
            + ('stays in the primary region there.' if lower['primary_only'] else
               'reaches the secondary region there.'))
    return Claim(
        'peak_720_lower_damping', 'the 720 rpm peak with lower damping',
        '"At 720 rpm, the vibration is only in the linear primary stiffness region so here we '
        'would expect to see a resonance peak for engine order 1.5. This is the case for lower '
        'damping, but not with the used damping from Table 1."',
        text, YES if ok else NO, figure='fig13_damping.png',
        why=('"Lower damping" is not quantified in the paper; the package uses '
             f'{r.settings.low_damping_factor:g} x the Table 1 DMF damping.'),
        values={'table': table, 'lower': lower, 'damping_nms_per_rad': c})


def _nnm(r: StudyResults) -> list[Claim]:
    br = r.nnm.branches
    xi_max = r.settings.nnm_xi_max
    f = {k: br[k].frequency_at([1.0, xi_max]) for k in br}
    prim_up = f['primary'][1] > f['primary'][0]
    sec_down = f['secondary'][1] < f['secondary'][0]
    gap0, gap1 = abs(f['secondary'][0] - f['primary'][0]), abs(f['secondary'][1] - f['primary'][1])
    alpha = r.settings.nnm_alpha
    primary = Claim(
        'nnm_primary_branch', 'NNM, mean wind-up in the primary region (blue)',
        '"As the system energy and ξ increase a longer time is spent in the secondary stiffness '
        'region and hence the resonance frequency decreases."',
        f'α = {alpha:g}: {f["primary"][0]:.2f} Hz at ξ = 1 -> {f["primary"][1]:.2f} Hz at ξ = '
        f'{xi_max:g} (the frequency rises).',
        NO if prim_up else YES, figure='fig14.png',
        why=('More time in the secondary region means more time at the higher stiffness k(1 + α), '
             'so the frequency of this branch must rise. The paper\'s own conclusion says so: "If '
             'the wind-up angle caused by the mean torque is in the secondary stiffness region of '
             'the dual mass flywheel, a higher torque amplitude will lead to a lower resonance '
             'frequency, otherwise it will lead to a higher resonance frequency." doc/theory.md '
             '§11 treats the sentence in the results section as a slip of the text.')
        if prim_up else '',
        values={'frequency_hz': [float(v) for v in f['primary']], 'xi': [1.0, xi_max]})
    secondary = Claim(
        'nnm_secondary_branch', 'NNM, mean wind-up in the secondary region (red)',
        '"When ξ increases [...] the time spent in the primary stiffness region also increases '
        'and we get a decrease in frequency."',
        f'α = {alpha:g}: {f["secondary"][0]:.2f} Hz at ξ = 1 -> {f["secondary"][1]:.2f} Hz at ξ = '
        f'{xi_max:g}.', YES if sec_down else NO, figure='fig14.png',
        values={'frequency_hz': [float(v) for v in f['secondary']], 'xi': [1.0, xi_max]})
    converge = Claim(
        'nnm_convergence', 'NNM branches approach one frequency',
        '"As ξ increases the branches following the linear resonance modes at primary and '
        'secondary stiffness approach the same frequency."',
        f'gap between the branches {gap0:.2f} Hz at ξ = 1, {gap1:.2f} Hz at ξ = {xi_max:g} '
        f'({100 * gap1 / gap0:.0f} %).',
        YES if gap1 < CONVERGED_GAP * gap0 else (PARTLY if gap1 < gap0 else NO),
        figure='fig14.png',
        why='' if gap1 < CONVERGED_GAP * gap0 else
        f'they approach each other but are still {gap1:.2f} Hz apart at ξ = {xi_max:g}',
        values={'gap_hz': [float(gap0), float(gap1)]})
    flats = [fb for fb in r.nnm.flat_branches if fb.xi_min <= xi_max]
    mism = [abs(fb.harmonic * fb.frequency_hz - fb.subsystem_frequency_hz)
            / fb.subsystem_frequency_hz for fb in flats]
    text = '; '.join(f'{fb.region} n = {fb.harmonic}: {fb.frequency_hz:.2f} Hz x {fb.harmonic} = '
                     f'{fb.harmonic * fb.frequency_hz:.1f} Hz vs {fb.subsystem} part '
                     f'{fb.subsystem_frequency_hz:.1f} Hz' for fb in flats) or 'none found'
    flat = Claim(
        'flat_branches', 'flat NNM branches at multiples of subsystem resonances',
        '"[...] at some frequencies we have horizontal branches where the frequency is constant '
        'as ξ increases. Here the frequency is close to a multiple of one of the linear '
        'resonances of the systems to the rear and front of the non-linearity"',
        text, YES if flats and max(mism) < FLAT_MATCH else NO, figure='fig14.png',
        values={'flat_branches': [fb.as_dict() for fb in flats],
                'max_relative_mismatch': float(max(mism)) if mism else None})
    return [primary, secondary, converge, flat]


def _scaling(r: StudyResults) -> Claim:
    sc = r.scaling
    spread = max(v['max_relative_spread'] for v in sc.values())
    td = [v for v in sc.values() if 'max_time_domain_error' in v]
    text = (f'frequency at ξ = {", ".join(f"{x:g}" for x in next(iter(sc.values()))["xi"])} for '
            f'{len(next(iter(sc.values()))["rows"])} (θ, distance) cases: largest relative spread '
            f'{spread:.1e}')
    ok = spread < SCALING_SPREAD
    if td:
        err = max(v['max_time_domain_error'] for v in td)
        ctrl = min(v['min_control_error'] for v in td)
        text += (f'; the scaled orbits integrated in time on the full non-linear driveline close '
                 f'after one period to {err:.1e} (a 0.1 % longer period: {ctrl:.1e})')
        ok = ok and err < 0.1 * ctrl
    return Claim(
        'theta_independence', 'NNM frequency independent of θ (and E_nl)',
        '"It has been seen that for fixed values of α and ξ the same frequencies are obtained '
        'independent of E and E_nl. This means that it is only necessary to analyse the '
        'non-linear normal modes for one value of the stiffness change angle θ."',
        text + '.', YES if ok else NO, figure='fig14.png',
        values={'max_relative_spread': spread})


def _fig15(r: StudyResults) -> Claim:
    a = r.settings.fig15_alpha
    lo, hi = _band_rpm(r)
    peaks = {ls: stable_peak_1_5(r.sweeps[(a, ls)], lo - BAND_TOL_RPM, hi + BAND_TOL_RPM)
             for ls in r.settings.load_sets}
    s = {ls: p['speed_rpm'] for ls, p in peaks.items()}
    order = sorted(s, key=lambda ls: -s[ls])
    ok = all(s[ls] < s['A'] for ls in s if ls != 'A')
    return Claim(
        'fig15_ordering', 'Fig. 15: peaks of Loads B and C at lower speeds',
        '"In Figure 15, the relative angle [...] is shown for α = 2.5 and Load A, B and C. The '
        'peak amplitudes occur at lower engine speeds for the higher load."',
        f'α = {a:g}, full load, largest stable 1.5th order: ' + ', '.join(
            f'Load {ls} {_mrad(peaks[ls]["order_1_5"])} at {s[ls]:.0f} rpm' for ls in order) + '.',
        YES if ok else NO, figure='fig15.png', values={'peaks': peaks})


def _scan_cases(scan) -> list[dict]:
    """Speeds where a part load's stable 1.5th order exceeds the full load's."""
    out = []
    for (ls, a), per_load in scan.order_1_5.items():
        full = per_load.get(1.0)
        if full is None:
            continue
        for ld, y in per_load.items():
            if ld >= 1.0:
                continue
            for v, part, top in zip(scan.speeds_rpm, y, full, strict=True):
                if part > WORSE_BY * top and part > WORSE_MIN_RAD:
                    out.append({'load_set': ls, 'alpha': a, 'load': ld, 'speed_rpm': float(v),
                                'part_rad': float(part), 'full_rad': float(top)})
    return sorted(out, key=lambda c: -c['part_rad'] / c['full_rad'])


def _worst_load(r: StudyResults) -> Claim:
    cases = _scan_cases(r.scan)
    what_if = _scan_cases(r.what_if) if r.what_if is not None else []
    per = r.scan.order_1_5
    (ls0, a0), loads0 = max(per.items(), key=lambda kv: np.nanmax(kv[1].get(1.0, [0.0])))
    k = int(np.nanargmax(loads0[1.0]))
    v0 = r.scan.speeds_rpm[k]
    at_peak = ', '.join(f'{ld:g}: {_mrad(y[k])}' for ld, y in sorted(loads0.items()))
    plateau = r.settings.what_if_plateau_nm
    if cases:
        c = cases[0]
        text = (f'{len(cases)} (speed, load) points where a part load exceeds full load, e.g. '
                f'Load {c["load_set"]}, α {c["alpha"]:g}, {c["speed_rpm"]:.0f} rpm: load '
                f'{c["load"]:g} gives {_mrad(c["part_rad"])}, full load {_mrad(c["full_rad"])}.')
        status, why = YES, ''
    else:
        text = (f'No speed in {r.scan.speeds_rpm[0]:.0f}-{r.scan.speeds_rpm[-1]:.0f} rpm where a '
                f'part load ({", ".join(f"{ld:g}" for ld in r.scan.loads if ld < 1)}) exceeds '
                f'full load (Loads {", ".join(sorted({ls for ls, _ in per}))}, α '
                f'{", ".join(f"{a:g}" for a in sorted({a for _, a in per}))}); at the strongest '
                f'resonance (Load {ls0}, α {a0:g}, {v0:.0f} rpm) the 1.5th order by load is '
                f'{at_peak}.')
        status = PARTLY if what_if else NO
        why = (f'The mechanism needs the mean wind-up near the knee. The engine\'s full-load '
               f'plateau ({r.full_load_max_nm:.0f} Nm) lies only '
               f'{100 * (r.full_load_max_nm / r.knee_torque_nm - 1):.0f} % above the knee torque '
               f'k θ = {r.knee_torque_nm:.0f} Nm, so at the resonance speeds the full-load mean '
               'wind-up is the one nearest the knee and lower loads excite less.')
    if what_if:
        c = what_if[0]
        why += (f' With the full-load curve scaled to a {plateau:g} Nm plateau the model shows '
                f'it: Load {c["load_set"]}, α {c["alpha"]:g}, {c["speed_rpm"]:.0f} rpm, load '
                f'{c["load"]:g} gives {_mrad(c["part_rad"])} against {_mrad(c["full_rad"])} at '
                f'full load ({len(what_if)} such points).')
    fails = r.scan.failures + (r.what_if.failures if r.what_if is not None else [])
    if fails:
        why += ' Sweeps that failed (not counted): ' + '; '.join(fails) + '.'
    return Claim(
        'worst_not_at_highest_load', 'worst amplitude not at the highest load',
        '"This means that the worst vibration amplitudes do not necessarily occur at the highest '
        'load."', text, status, why=why.strip(),
        values={'cases': cases[:10], 'what_if_cases': what_if[:10],
                'what_if_plateau_nm': plateau})


def _coexisting(r: StudyResults) -> Claim:
    co = r.coexisting
    pairs = co['pairs']
    nm = co['newmark']
    if not pairs:
        return Claim('coexisting_solutions', 'several stable steady states',
                     _COEXIST_WORDS, 'no speed with two physically different stable steady '
                     'states found in the computed sweeps.', NO)
    p = pairs[0]
    text = (f'{len(pairs)} (sweep, speed) points with two physically different stable steady '
            f'states (120° twins excluded), e.g. Load {p["load_set"]}, α {p["alpha"]:g}, load '
            f'{p["load"]:g}, {p["speed_rpm"]:.0f} rpm: 1.5th order {_mrad(p["order_1_5"][0])} and '
            f'{_mrad(p["order_1_5"][1])}.')
    ok = False
    if nm is not None:
        runs = nm['runs']
        stay = [abs(x['newmark_order_1_5'] - x['hbm_order_1_5']) / x['hbm_order_1_5']
                for x in runs]
        apart = abs(runs[0]['newmark_order_1_5'] - runs[1]['newmark_order_1_5']) \
            / max(x['newmark_order_1_5'] for x in runs)
        ok = max(stay) < NEWMARK_MATCH and apart > 0.2
        text += (' Newmark started on each stays there: ' + ', '.join(
            f'{_mrad(x["hbm_order_1_5"])} (HBM) -> {_mrad(x["newmark_order_1_5"])} after '
            f'{x["cycles"]} cycles' for x in runs) + '.')
    shown = p['load'] == 1.0 and (p['alpha'], p['load_set']) in r.sweeps
    return Claim('coexisting_solutions', 'several stable steady states', _COEXIST_WORDS, text,
                 YES if ok else PARTLY, figure='fig15.png' if shown else '',
                 why='' if ok else 'time integration did not confirm both states',
                 values={'pairs': pairs[:10], 'newmark': nm})


_COEXIST_WORDS = ('"At some frequencies there are several stable solutions with different energy. '
                  'Time-domain simulations also show that several different steady-state '
                  'solutions can be obtained for the same engine load."')
