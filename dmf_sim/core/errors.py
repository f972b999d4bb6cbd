"""The package's exceptions: what a user can get wrong, and what a solver can fail at.

Every error a user causes (a bad YAML file, an option out of range, a file that is not a bag) is
one of these, with a one-line message naming the field and the allowed range. The command line
(``dmf_sim.cli``) and the node report exactly these as one line with exit code 2; anything else
is a bug of ours and keeps its traceback.

The classes also derive from the builtin they refine (``ValueError``, ``RuntimeError``), so
code written against the builtins keeps working.
"""
from __future__ import annotations

__all__ = ['DmfSimError', 'ConfigError', 'ConfigFileError', 'BagError', 'BagFileError',
           'ConvergenceError', 'TimeLimitError', 'OperatingRangeError', 'one_line',
           'BagExistsError', 'NoResponseError', 'MissingExtraError']


class DmfSimError(Exception):
    """Base class of every error the package reports to a user as one line."""


class ConfigError(DmfSimError, ValueError):
    """Invalid configuration or input: a YAML/CSV field, a command-line option, a parameter."""


class ConfigFileError(ConfigError, FileNotFoundError):
    """A configuration file that cannot be used: missing, a directory, unreadable, not a
    mapping."""


class BagError(DmfSimError, ValueError):
    """A bag (MCAP / rosbag2 directory) that cannot be read, written or recovered as asked."""


class BagFileError(BagError, FileNotFoundError):
    """A bag path that does not exist or holds no MCAP file."""


class ConvergenceError(DmfSimError, RuntimeError):
    """A solver did not converge (Newton, continuation corrector)."""


class TimeLimitError(DmfSimError, TimeoutError):
    """A solver stopped at the wall-clock time limit it was given (e.g. a design study's
    ``solver.time_limit_s``); the message names the limit, the phase and the speed reached."""


class OperatingRangeError(ConfigError):
    """An operating point outside the data: engine speed or load beyond the engine's tables."""


def one_line(exc: BaseException) -> str:
    """The exception's message on one line (whitespace runs collapsed)."""
    return ' '.join(str(exc).split()) or type(exc).__name__


class BagExistsError(BagError, FileExistsError):
    """A bag (or recovery output) path that exists already: bags are never overwritten."""


class NoResponseError(DmfSimError, TimeoutError):
    """No ROS node answered within the timeout (``dmf-sim setpoint`` / ``monitor``)."""


class MissingExtraError(DmfSimError, ImportError):
    """An optional library a feature needs is not installed, or cannot be imported here (e.g.
    a release that refuses the installed numpy); the message names the extra and the pip line
    (:func:`dmf_sim.core.optional.require`)."""
