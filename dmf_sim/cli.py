"""``dmf-sim``: command-line entry point. Subcommands live in ``dmf_sim.commands``.

Each module in ``dmf_sim/commands`` defines ``NAME``, ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``; they are discovered automatically. Every mistake of a user is one line on
stderr, ``dmf-sim <command>: error: <message>`` (:func:`error_line`), and exit code 2: a command
line argparse refuses (an unknown option, a value of the wrong type, a missing argument) and a
:class:`dmf_sim.core.errors.DmfSimError` a command raises. Anything else is a bug and keeps its
traceback.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from dmf_sim import __version__, commands
from dmf_sim.core.errors import DmfSimError, one_line

__all__ = ['UNITS', 'USAGE_EXIT', 'error_line', 'build_parser', 'main']

UNITS = """units (SI throughout unless a name says otherwise):
  angles rad, angular speed rad/s (engine speed on the command line in rpm),
  torque Nm, stiffness Nm/rad, damping Nms/rad, inertia kg m^2, time s, frequency Hz.
  Wind-up of the DMF = primary angle - secondary angle (through the gear ratio), positive
  when the engine drives. Orders are engine orders (per crank revolution); half-order n/2."""
USAGE_EXIT = 2
"""Exit code of a user's mistake (argparse's own code for a bad command line)."""


def error_line(prog: str, message: str) -> str:
    """The one line a user's mistake prints on stderr: ``dmf-sim <command>: error: <message>``
    (``prog``: 'dmf-sim <command>', or 'dmf-sim' before a command is known)."""
    return f'{prog}: error: {one_line(message)}'


class _Parser(argparse.ArgumentParser):
    """argparse with the package's one-line error (no usage block); the command parsers are of
    this class too (``add_subparsers`` makes them of the parent's class)."""

    def error(self, message: str):
        self.exit(USAGE_EXIT, error_line(self.prog, f'{message}; see {self.prog} --help') + '\n')


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
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
        p.set_defaults(_run=mod.run, _parser=p)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:                     # named by the command they were given to
        getattr(args, '_parser', parser).error('unrecognized arguments: ' + ' '.join(unknown))
    if not getattr(args, '_run', None):
        parser.print_help()
        return 0
    try:
        return int(args._run(args) or 0)
    except DmfSimError as exc:      # a user's mistake (bad option, file, data): one line, exit 2
        print(error_line(args._parser.prog, str(exc)), file=sys.stderr)
        return USAGE_EXIT
    except KeyboardInterrupt:
        print(f'dmf-sim {args.command}: interrupted', file=sys.stderr)
        return 130
    # anything else is a bug of ours: Python prints its traceback (exit 1)


if __name__ == '__main__':
    sys.exit(main())
