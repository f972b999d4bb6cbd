"""How the live node is asked to stop, without ROS: SIGINT, SIGTERM, the end of its parent.

The first SIGINT or SIGTERM (or the death of the process that started the node: Linux's
parent-death signal, SIGTERM, or a pid watch elsewhere, :func:`dmf_sim.core.process.
end_with_parent`) sets :attr:`StopSignals.requested`; the node then leaves its tick loop and
closes its bag, its monitor and its Foxglove server. **Every later SIGINT or SIGTERM is logged and
ignored** until the process ends, so nothing interrupts closing the bag. They do come: ``ros2
launch`` sends SIGINT, then SIGTERM ``sigterm_timeout`` later; ``kill -TERM`` to a launch's job
reaches launch and node together, and launch, which ends at once on SIGTERM, makes Linux send the
node the parent-death SIGTERM a few milliseconds later. Only SIGKILL (launch's last resort,
``sigkill_timeout`` after its SIGTERM) stops the node at once; it leaves the bag's last file
without its footer (``dmf-sim bag-recover`` completes it). See doc/node.md, "Stopping the node".

The handlers only record the signal, set an event (no lock is taken in them) and log (rclpy's
logger; a logging failure is swallowed, since an exception raised in a handler would surface in
whatever the main thread runs, the bag's close included), so a signal that arrives while the node
writes or closes the bag changes nothing in what is being written.
"""
from __future__ import annotations

import os
import signal
import threading
from collections.abc import Callable

from dmf_sim.core.process import end_with_parent

__all__ = ['STOP_SIGNALS', 'StopSignals']

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
_ORDINALS = ('first', 'second', 'third', 'fourth', 'fifth')


def _ordinal(n: int) -> str:
    return _ORDINALS[n - 1] if n <= len(_ORDINALS) else f'{n}th'


class StopSignals:
    """The stop request of a process: the first SIGINT/SIGTERM or parent death; later ones are
    logged and ignored.

    Args:
        log: called with one line for every signal ignored (from the signal handler, in the
            main thread, or from the parent-watch thread).

    Attributes:
        requested: set by the first signal (the node's loop polls it).
        doing: what the process is busy with, for the log line of a later signal (the node sets
            it to ``closing the bag <path>`` while it closes the bag).
        received: every signal or parent death, in order (``'SIGTERM'``, ``'SIGINT'``,
            ``'parent process <pid> ended'``).
        parent: the parent's pid when :meth:`install` ran.
    """

    def __init__(self, log: Callable[[str], None]) -> None:
        self.log = log
        self.requested = threading.Event()
        self.doing = 'stopping'
        self.received: list[str] = []
        self.parent: int | None = None
        self._previous: dict[int, object] = {}

    def install(self) -> StopSignals:
        """Handle SIGINT and SIGTERM from now on, and end with the parent (SIGTERM from
        Linux's parent-death signal, else a parent-pid watch). Main thread only."""
        for signum in STOP_SIGNALS:
            self._previous[signum] = signal.signal(signum, self._on_signal)
        self.parent = end_with_parent(self._on_parent_death, signal.SIGTERM)
        return self

    def uninstall(self) -> None:
        """Give SIGINT and SIGTERM back to the handlers they had before :meth:`install` (the
        parent-death signal stays asked for)."""
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)
        self._previous.clear()

    def ignore_until_exit(self) -> None:
        """Ignore SIGINT and SIGTERM at the C level from now on (main thread only): called when
        the node has closed everything. The interpreter's finalization gives every signal that
        has a Python handler back to its default action, so without this a SIGTERM that came
        while the process was exiting would end it with -15 after a clean stop; an ignored
        signal stays ignored through the finalization."""
        for signum in STOP_SIGNALS:
            signal.signal(signum, signal.SIG_IGN)
        self._previous.clear()

    @property
    def ignored(self) -> list[str]:
        """The signals that came after the first (logged, ignored)."""
        return self.received[1:]

    @property
    def reason(self) -> str:
        """Why the process stops: the first signal, ``SIGTERM: parent process <pid> ended``
        when that SIGTERM came with the parent's death, or ``shutdown`` (no signal)."""
        if not self.received:
            return 'shutdown'
        first = self.received[0]
        if first == 'SIGTERM' and self.parent is not None and os.getppid() != self.parent:
            return f'SIGTERM: parent process {self.parent} ended'
        return first

    def _on_signal(self, signum: int, _frame) -> None:
        name = signal.Signals(signum).name
        self._request(name, name)

    def _on_parent_death(self, pid: int) -> None:
        self._request(f'parent process {pid} ended', f'the end of parent process {pid}')

    def _request(self, what: str, said: str) -> None:
        self.received.append(what)
        if len(self.received) == 1:
            self.requested.set()
            return
        try:
            self.log(f'{said} ignored while {self.doing} (the {_ordinal(len(self.received))} '
                     'stop signal); SIGKILL stops at once, leaving the last bag file to '
                     'dmf-sim bag-recover')
        except Exception:  # noqa: BLE001 - raised here, it would interrupt what it reports on
            pass
