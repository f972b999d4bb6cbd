"""``dmf-sim detect``: the reference misfire detector on a bag, scored per cylinder."""
from __future__ import annotations

import argparse

from dmf_sim.commands import _options as opt
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import json_text

__all__ = ['NAME', 'HELP', 'add_arguments', 'run']

NAME = 'detect'
HELP = ('reference misfire detector on the tooth edges of a bag (DMF-aware), scored against the '
        "bag's fault ground truth per cylinder; the DMF wind-up from the sensors against the true")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument('bag', help='a bag with tooth-wheel edges (dmf-sim run, or a recording node)')
    p.add_argument('--crank', default='crank', help='the crank (primary flywheel) tooth wheel')
    p.add_argument('--secondary', default='flywheel_secondary',
                   help='the secondary flywheel tooth wheel')
    p.add_argument('--threshold', type=float,
                   help='alarm when the engine work of a firing interval falls this fraction of '
                        'the mean work below its neighbours (default: the detector\'s '
                        'DEFAULT_THRESHOLD, 0.3)')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    opt.add_config(p, default=None, help_default="the bag's driveline, else truck_dmf")


def run(args: argparse.Namespace) -> int:
    from dmf_sim.analysis.misfire_detector import DEFAULT_THRESHOLD, detect_bag
    from dmf_sim.analysis.windup_estimate import windup_from_bag

    opt.check_common(args)
    if args.threshold is None:
        args.threshold = DEFAULT_THRESHOLD
    if not 0.0 < args.threshold < 10.0:
        raise ConfigError(f'--threshold {args.threshold!r}: must be in (0, 10)')
    scores, result = detect_bag(args.bag, crank=args.crank, secondary=args.secondary,
                                threshold=args.threshold, config=args.config)
    w = windup_from_bag(args.bag, args.crank, args.secondary)
    out = result.as_dict()
    out['windup'] = {'p2p_sensors_rad': w.p2p_est_rad, 'p2p_true_rad': w.p2p_true_rad,
                     'rel_err': w.rel_err}
    out['alarms'] = [{'t_s': float(t), 'cylinder': int(c), 'score': float(s)}
                     for t, c, s, a in zip(scores['t_s'], scores['cylinder'], scores['score'],
                                           scores['alarm']) if a]
    if args.json:
        print(json_text(out))
        return 0
    print(f'{args.bag}: {result.cycles:.1f} engine cycles, mean {result.mean_speed_rpm:.0f} rpm; '
          f'{result.misfires} misfires in the ground truth, {result.detected} detected, '
          f'{result.false_alarms} false alarms')
    print(f'{"cylinder":>8} {"misfires":>8} {"detected":>8} {"missed":>6} {"false_alarms":>12}')
    for c, v in result.per_cylinder.items():
        print(f'{c:8d} {v["misfires"]:8d} {v["detected"]:8d} {v["missed"]:6d} '
              f'{v["false_alarms"]:12d}')
    for a in out['alarms']:
        print(f'alarm at {a["t_s"]:.4f} s (from the first crank edge): cylinder {a["cylinder"]}, '
              f'score {a["score"]:.2f}')
    print(f'wind-up from the sensors: p2p {w.p2p_est_rad:.5f} rad, true {w.p2p_true_rad:.5f} '
          f'rad ({100 * w.rel_err:.2f} %)')
    return 0
