"""The Dask cluster the applications run their work on: a local one by default, or an existing one.

Design studies (:mod:`dmf_sim.design.runner`) and the optimizer (:mod:`dmf_sim.optimize.runner`)
share it; what they submit is theirs.

* :func:`local_cluster` / :func:`start_local`: a ``dask.distributed.LocalCluster`` of worker
  *processes* (one thread each: the solvers hold the GIL), listening on 127.0.0.1 only, without
  a dashboard, its housekeeping timers slowed (:data:`QUIET_CLUSTER`); :func:`close_local`.
* :func:`connect`: a client of an existing scheduler (``tcp://HOST:8786``); an address that does
  not answer is a one-line ConfigError naming ``--scheduler``; :func:`wait_for_workers`.
* :func:`limit_threads`: a worker's BLAS / OpenMP pools to one thread (what a worker plugin calls
  when the worker starts).
* :class:`WorkerWatch`: while the work runs, one line per change of the cluster's workers (lost,
  joined, restarted: lost and back under its name), from the scheduler's worker list.

Dask comes with the feature extras (``dmf_sim.core.optional``); importing this module needs none.
"""
from __future__ import annotations

import logging
import re
import threading
from collections.abc import Callable

from dmf_sim.core.errors import ConfigError, one_line
from dmf_sim.core.limits import usable_cpus
from dmf_sim.core.optional import require

__all__ = ['LOOPBACK', 'CONNECT_TIMEOUT_S', 'WORKER_WATCH_INTERVAL_S', 'WORKER_PROFILER',
           'WORKER_THREADS', 'QUIET_CLUSTER', 'limit_threads', 'WorkerWatch', 'local_cluster',
           'start_local', 'close_local', 'connect', 'wait_for_workers']

LOOPBACK = '127.0.0.1'
CONNECT_TIMEOUT_S = 5.0
WORKER_WATCH_INTERVAL_S = 1.0
"""How often the client compares the cluster's workers while work runs [s]."""
WORKER_PROFILER = 'distributed.worker.profile.enabled'
WORKER_THREADS = 1
"""Threads of a worker's BLAS / OpenMP pools: the worker computes one design at a time, on
matrices of 34 x 34 at most, and more threads only take the other workers' cores."""
QUIET_CLUSTER = {
    'distributed.admin.tick.interval': '1s',
    'distributed.admin.system-monitor.interval': '5s',
    'distributed.worker.memory.monitor-interval': '1s',
}
"""The local cluster's housekeeping timers, slower than Dask's defaults (event-loop check every
20 ms, system monitor every 0.5 s, memory check every 0.1 s). Every wake-up of a process's event
loop takes the GIL from the thread computing a design; with the defaults a 2-worker cluster cost
0.14 cores while idle (scheduler and nannies 0.077, the two workers 0.064; 0.023 with these),
~7 % of a 2-core machine's second core that two workers need. benchmarks/bench_design.py."""
_ADDRESS = re.compile(r'^(tcp|tls)://[^\s/:]+:\d{1,5}$')


def limit_threads(threads: int = WORKER_THREADS) -> dict[str, int]:
    """Limit this process's BLAS / OpenMP thread pools to ``threads`` (a worker: Dask's nanny
    sets OMP_NUM_THREADS etc. for the workers it spawns, but a worker started otherwise, or a
    library loaded after the environment was read, may still use one thread per core). Returns
    {library: threads} after the change. The numba kernels are not parallel and start no
    threads."""
    from threadpoolctl import threadpool_info, threadpool_limits
    threadpool_limits(limits=threads)
    return {p['internal_api']: int(p['num_threads']) for p in threadpool_info()}


class WorkerWatch:
    """Reports changes of a cluster's workers, one line each, to ``say``: a worker lost (its
    running ``work`` -- 'designs' -- is rescheduled by Dask, or recorded 'lost' by the
    application if that fails), a worker that joined, a worker restarted (lost, then back under
    the same name, e.g. by its nanny).

    Polls ``client.scheduler_info()`` every ``interval_s`` in a daemon thread while used as a
    context manager; :meth:`check` does one comparison (also usable without the thread)."""

    def __init__(self, client, say: Callable[[str], None],
                 interval_s: float = WORKER_WATCH_INTERVAL_S, work: str = 'designs'):
        self._client, self._say, self._interval, self._work = client, say, interval_s, work
        self._known = self._workers()
        self._lost_names: set[str] = set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, name='dmf-worker-watch', daemon=True)

    def _workers(self) -> dict[str, str]:
        info = self._client.scheduler_info(n_workers=-1).get('workers', {})
        return {addr: str(w.get('name', addr)) for addr, w in info.items()}

    def check(self) -> list[str]:
        """Compare the workers with the last look; say and return one line per change."""
        now = self._workers()
        lines = []
        for addr in sorted(self._known.keys() - now.keys()):
            name = self._known[addr]
            self._lost_names.add(name)
            lines.append(f'worker {name} ({addr}) lost; {len(now)} worker(s) left, its running '
                         f'{self._work} are rescheduled')
        for addr in sorted(now.keys() - self._known.keys()):
            name = now[addr]
            if name in self._lost_names:
                self._lost_names.discard(name)
                lines.append(f'worker {name} restarted ({addr}); {len(now)} worker(s)')
            else:
                lines.append(f'worker {name} ({addr}) joined; {len(now)} worker(s)')
        self._known = now
        for line in lines:
            self._say(line)
        return lines

    def _loop(self) -> None:
        while not self._stop.wait(self._interval):
            try:
                self.check()
            except Exception:  # noqa: BLE001 - the client closing under us ends the watch
                if self._stop.is_set():
                    return

    def __enter__(self) -> 'WorkerWatch':
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def local_cluster(workers: int | None = None):
    """A LocalCluster of ``workers`` processes (default: one per core) on 127.0.0.1."""
    n = workers or usable_cpus()
    if not (isinstance(n, int) and n >= 1):
        raise ConfigError(f'--workers {n!r}: must be an integer >= 1')
    # every listener on 127.0.0.1 (the scheduler's HTTP routes on a free port, not 8787);
    # the workers' own log lines stay quiet (a heartbeat racing the shutdown is logged as an
    # error): every failure of a task is in the application's results with its reason.
    # The workers' statistical profiler is off: it keeps an hour of stack samples, and its
    # tree of the solvers' call paths made worker memory grow by ~10 kB per design
    # (benchmarks/bench_design.py measures the RSS over a long study).
    dask = require('dask')
    distributed = require('distributed')
    with dask.config.set({WORKER_PROFILER: False, **QUIET_CLUSTER}):
        return distributed.LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, host=LOOPBACK,
            dashboard_address=f'{LOOPBACK}:0', worker_dashboard_address=None,
            silence_logs=logging.CRITICAL)


def start_local(workers: int | None = None):
    """(cluster, client): a :func:`local_cluster` and a client of it, its workers all up."""
    cluster = local_cluster(workers)
    client = require('distributed').Client(cluster)
    client.wait_for_workers(len(cluster.workers))
    return cluster, client


def close_local(cluster, client) -> None:
    """Close what :func:`start_local` started (either may be None)."""
    if client is not None:
        client.close()
    if cluster is not None:
        cluster.close()


def connect(address: str, timeout_s: float = CONNECT_TIMEOUT_S):
    """A ``distributed.Client`` of the scheduler at ``address`` (``tcp://HOST:PORT``)."""
    if not isinstance(address, str) or not _ADDRESS.match(address.strip()):
        raise ConfigError(f'--scheduler {address!r}: expected tcp://HOST:PORT (e.g. '
                          'tcp://10.0.0.5:8786)')
    distributed = require('distributed')
    try:
        return distributed.Client(address.strip(), timeout=timeout_s)
    except (OSError, TimeoutError) as exc:
        raise ConfigError(f'--scheduler {address}: no Dask scheduler answers there within '
                          f'{timeout_s:g} s ({one_line(exc)}); start one with `dask scheduler` '
                          'or leave out --scheduler to use a local cluster') from None


def wait_for_workers(client, timeout_s: float = CONNECT_TIMEOUT_S) -> int:
    """Number of workers of the client's cluster, after waiting for at least one."""
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except TimeoutError:
        raise ConfigError(f'--scheduler {client.scheduler.address}: the scheduler has no workers '
                          f'(waited {timeout_s:g} s); start some with `dask worker '
                          f'{client.scheduler.address}`') from None
    return len(client.scheduler_info().get('workers', {}))
