"""``dmf-sim``: command-line entry point. Subcommands live in ``dmf_sim.commands``.

Each module in ``dmf_sim/commands`` defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``; they are discovered automatically. Errors a user causes are
:class:`dmf_sim.core.errors.DmfSimError` and are reported as one line with exit code 2; anything
else is a bug and keeps its traceback.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from dmf_sim import __version__, commands
from dmf_sim.core.errors import DmfSimError, one_line

__all__ = ['UNITS', 'build_parser', 'main']

UNITS = """units (SI throughout unless a name says otherwise):
  angles rad, angular speed rad/s (engine speed on the command line in rpm),
  torque Nm, stiffness Nm/rad, damping Nms/rad, inertia kg m^2, time s, frequency Hz.
  Wind-up of the DMF = primary angle - secondary angle (through the gear ratio), positive
  when the engine drives. Orders are engine orders (per crank revolution); half-order n/2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='dmf-sim',
        description='Truck driveline torsional vibrations with a two-step dual mass flywheel.',
        epilog=UNITS, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--version', action='version', version=f'dmf-sim {__version__}')
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    for info in sorted(pkgutil.iter_modules(commands.__path__), key=lambda m: m.name):
        if info.name.startswith('_'):
            continue
        mod = importlib.import_module(f'{commands.__name__}.{info.name}')
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP, epilog=UNITS,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, '_run', None):
        parser.print_help()
        return 0
    try:
        return int(args._run(args) or 0)
    except DmfSimError as exc:      # a user's mistake (bad option, file, data): one line, exit 2
        print(f'dmf-sim {args.command}: error: {one_line(exc)}', file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f'dmf-sim {args.command}: interrupted', file=sys.stderr)
        return 130
    # anything else is a bug of ours: Python prints its traceback (exit 1)


if __name__ == '__main__':
    sys.exit(main())
