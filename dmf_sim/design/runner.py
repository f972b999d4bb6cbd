"""Running a study on Dask: a local cluster by default, or an existing one.

* :func:`local_cluster`: a ``dask.distributed.LocalCluster`` of worker *processes* (one thread
  each: the solvers hold the GIL), listening on 127.0.0.1 only, without a dashboard.
* :func:`connect`: a client of an existing scheduler (``tcp://HOST:8786``); an address that does
  not answer is a one-line ConfigError naming ``--scheduler``.
* :func:`run_study`: installs the study context (base driveline, engines, settings) once in
  every worker process with a WorkerPlugin (also on workers that join later), submits
  the designs in batches (one Dask task each), takes the results as they finish
  (``as_completed``), writes each batch to the store at once, and shows a progress bar with ETA.
  A batch whose task is lost (a worker died) is recorded as 'lost' and recomputed on resume.
* :class:`WorkerWatch`: while the designs run, one line per change of the cluster's workers
  (lost, joined, restarted: lost and back under its name), from the scheduler's worker list.
"""
from __future__ import annotations

import logging
import math
import re
import threading
import time
import uuid
from collections.abc import Callable

from dmf_sim.core.errors import ConfigError, one_line
from dmf_sim.core.limits import usable_cpus
from dmf_sim.core.optional import require
from dmf_sim.design.evaluate import (
    BatchResult,
    StudyContext,
    drop_context,
    evaluate_batch,
    install_context,
)
from dmf_sim.design.result import StudyResult
from dmf_sim.design.study import read_study
from dmf_sim.design.table import ResultStore

distributed = require('distributed', 'design')
WorkerPlugin = require('distributed.diagnostics.plugin', 'design').WorkerPlugin

__all__ = ['LOOPBACK', 'CONNECT_TIMEOUT_S', 'WORKER_WATCH_INTERVAL_S', 'DEFAULT_BATCH_SIZE',
           'BATCHES_PER_WORKER', 'WORKER_PROFILER', 'WORKER_THREADS', 'QUIET_CLUSTER',
           'StudyPlugin', 'limit_threads', 'WorkerWatch',
           'local_cluster', 'start_local', 'close_local', 'close_run',
           'connect', 'wait_for_workers', 'batch_size_for', 'batch_sizes', 'run_study']

LOOPBACK = '127.0.0.1'
CONNECT_TIMEOUT_S = 5.0
WORKER_WATCH_INTERVAL_S = 1.0
"""How often the client compares the cluster's workers while a study runs [s]."""
DEFAULT_BATCH_SIZE = 8
"""Designs per Dask task. benchmarks/bench_design.py measured 4.7 ms of Dask overhead per task
against 58 ms per paper-case design: 1 design per task loses 8 %, 4 lose 2.0 %, 8 lose 1.0 %."""
BATCHES_PER_WORKER = 4
"""Smaller batches when a study is short, so that every worker gets work until the end."""
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


class StudyPlugin(WorkerPlugin):
    """Installs a study context in a worker process when the worker starts (or at once)."""

    def __init__(self, key: str, context: StudyContext):
        self.key = key
        self.context = context

    def setup(self, worker) -> None:
        limit_threads()
        install_context(self.key, self.context)
        # the sweep's compiled kernels loaded (compiled the first time on this machine) now,
        # not in the worker's first design
        from dmf_sim.solvers.hbm.warm import warm_up
        warm_up()

    def teardown(self, worker) -> None:
        drop_context(self.key)


def limit_threads(threads: int = WORKER_THREADS) -> dict[str, int]:
    """Limit this process's BLAS / OpenMP thread pools to ``threads`` (a design-study worker:
    Dask's nanny sets OMP_NUM_THREADS etc. for the workers it spawns, but a worker started
    otherwise, or a library loaded after the environment was read, may still use one thread
    per core). Returns {library: threads} after the change. The sweep's numba kernels are not
    parallel and start no threads."""
    from threadpoolctl import threadpool_info, threadpool_limits
    threadpool_limits(limits=threads)
    return {p['internal_api']: int(p['num_threads']) for p in threadpool_info()}


class WorkerWatch:
    """Reports changes of a cluster's workers, one line each, to ``say``: a worker lost (its
    running designs are rescheduled by Dask, or recorded 'lost' if that fails), a worker that
    joined, a worker restarted (lost, then back under the same name, e.g. by its nanny).

    Polls ``client.scheduler_info()`` every ``interval_s`` in a daemon thread while used as a
    context manager; :meth:`check` does one comparison (also usable without the thread)."""

    def __init__(self, client, say: Callable[[str], None],
                 interval_s: float = WORKER_WATCH_INTERVAL_S):
        self._client, self._say, self._interval = client, say, interval_s
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
                         'designs are rescheduled')
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
    # error): every failure of a design or a task is in the result table with its reason.
    # The workers' statistical profiler is off: it keeps an hour of stack samples, and its
    # tree of the solvers' call paths made worker memory grow by ~10 kB per design
    # (benchmarks/bench_design.py measures the RSS over a long study).
    dask = require('dask', 'design')
    with dask.config.set({WORKER_PROFILER: False, **QUIET_CLUSTER}):
        return distributed.LocalCluster(
            n_workers=n, threads_per_worker=1, processes=True, host=LOOPBACK,
            dashboard_address=f'{LOOPBACK}:0', worker_dashboard_address=None,
            silence_logs=logging.CRITICAL)


def start_local(workers: int | None = None):
    """(cluster, client): a :func:`local_cluster` and a client of it, its workers all up."""
    cluster = local_cluster(workers)
    client = distributed.Client(cluster)
    client.wait_for_workers(len(cluster.workers))
    return cluster, client


def close_local(cluster, client) -> None:
    """Close what :func:`start_local` started (either may be None)."""
    if client is not None:
        client.close()
    if cluster is not None:
        cluster.close()


def close_run(cluster, client, store) -> None:
    """End of a run: close the local cluster and client it started (None: none) and release
    its store's lock (None: no store)."""
    close_local(cluster, client)
    if store:
        store.close()


def connect(address: str, timeout_s: float = CONNECT_TIMEOUT_S):
    """A ``distributed.Client`` of the scheduler at ``address`` (``tcp://HOST:PORT``)."""
    if not isinstance(address, str) or not _ADDRESS.match(address.strip()):
        raise ConfigError(f'--scheduler {address!r}: expected tcp://HOST:PORT (e.g. '
                          'tcp://10.0.0.5:8786)')
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


def batch_size_for(n_designs: int, n_workers: int, batch_size: int | None = None) -> int:
    """The given batch size, or the default, made smaller for short studies so that there are
    at least BATCHES_PER_WORKER batches per worker."""
    if batch_size is not None:
        if not (isinstance(batch_size, int) and batch_size >= 1):
            raise ConfigError(f'--batch-size {batch_size!r}: must be an integer >= 1')
        return batch_size
    per = math.ceil(n_designs / max(1, BATCHES_PER_WORKER * n_workers))
    return max(1, min(DEFAULT_BATCH_SIZE, per))


def batch_sizes(n_designs: int, n_workers: int, batch_size: int | None = None) -> list[int]:
    """The sizes of a run's batches, in the order they are submitted (their sum is
    ``n_designs``). A given ``batch_size``: batches of that size, the last one the rest. By
    default the sizes are guided: each batch carries the designs left divided by
    BATCHES_PER_WORKER x workers (at least 1, at most DEFAULT_BATCH_SIZE), so the batches are
    full while much is left and shrink towards the end, and the workers finish together
    instead of one waiting while another computes a last full batch."""
    if batch_size is not None:
        size = batch_size_for(n_designs, n_workers, batch_size)
        return [min(size, n_designs - k) for k in range(0, n_designs, size)]
    sizes, left = [], n_designs
    while left > 0:
        size = batch_size_for(left, n_workers)
        sizes.append(size)
        left -= size
    return sizes


def run_study(study, client=None, *, out=None, resume: bool = False, workers: int | None = None,
              batch_size: int | None = None, progress: bool = False,
              on_batch=None, on_worker_event: Callable[[str], None] | None = None
              ) -> StudyResult:
    """Evaluate every design of ``study`` (a study file, mapping or Study) on Dask.

    Args:
        client: a ``distributed.Client``; None starts a LocalCluster of ``workers`` processes
            (default one per core) on 127.0.0.1 for this call.
        out: directory for the incremental store and the final table (None: in memory only).
        resume: continue the study stored in ``out`` (finished designs are not recomputed).
        batch_size: designs per Dask task (default: :func:`batch_sizes`, guided).
        progress: tqdm progress bar with ETA on stderr.
        on_batch: called as ``on_batch(n_done, n_total)`` after each stored batch.
        on_worker_event: called with one line per worker lost, joined or restarted while the
            designs run (:class:`WorkerWatch`); None: not watched.
    """
    study = read_study(study)
    store = ResultStore(out, study, resume) if out is not None else None
    own = client is None
    t0 = time.perf_counter()
    cluster, n_workers, size = None, 0, 0
    try:
        if store:
            store.lock()              # before reading what earlier runs stored
        designs = study.designs()
        run = _Run(study, designs, store, on_batch)
        done = store.finished() if store else set()
        todo = [i for i in range(len(designs)) if i not in done]
        if store:
            store.start()
        if todo:
            if own:
                cluster, client = start_local(workers)
            n_workers = wait_for_workers(client)
            sizes = batch_sizes(len(todo), n_workers, batch_size)
            size = sizes[0]                                             # the largest batch
            if on_worker_event is None:
                run.compute(client, todo, sizes, _bar(progress, len(designs), len(done)))
            else:
                with WorkerWatch(client, on_worker_event):
                    run.compute(client, todo, sizes, _bar(progress, len(designs), len(done)))
        rows = (store.rows if store else []) + run.rows
        result = StudyResult.from_rows(study, rows, n_computed=_n_designs(run.rows),
                                       seconds=time.perf_counter() - t0, workers=n_workers,
                                       batch_size=size, context_loads=run.loads)
        if store:
            result.files.update(store.finalize(result.table))
        return result
    finally:
        close_run(cluster if own else None, client if own else None, store)


class _Run:
    """Submitting the batches of one run and collecting their rows as they finish."""

    def __init__(self, study, designs, store, on_batch):
        self.study, self.designs, self.store, self.on_batch = study, designs, store, on_batch
        self.rows: list[dict] = []
        self.loads: dict[int, int] = {}        # worker pid -> contexts installed there

    def compute(self, client, todo: list[int], sizes: list[int], bar) -> None:
        """Submit ``todo`` (design indices) in batches of the given ``sizes``
        (:func:`batch_sizes`, in order) and collect their rows."""
        if not todo:
            return
        key = f'dmf-study-{self.study.fingerprint()}-{uuid.uuid4().hex[:8]}'
        client.register_plugin(StudyPlugin(key, StudyContext.from_study(self.study)), name=key)
        futures = {}
        n_total, n_before = len(self.designs), len(self.designs) - len(todo)
        try:
            k = 0
            for n in sizes:
                ids = todo[k:k + n]
                k += n
                items = [(i, self.designs[i].tolist()) for i in ids]
                task = f'dmf-design-{ids[0]}-{uuid.uuid4().hex[:8]}'
                futures[client.submit(evaluate_batch, key, items, key=task, pure=False)] = ids
            for fut in distributed.as_completed(list(futures)):
                ids = futures.pop(fut)
                rows = self._rows_of(fut, ids)
                fut.release()
                if self.store:
                    self.store.append(rows)
                self.rows += rows
                if bar is not None:
                    bar.update(len(ids))
                if self.on_batch is not None:
                    self.on_batch(n_before + _n_designs(self.rows), n_total)
        finally:
            if bar is not None:
                bar.close()
            if futures and client.status == 'running':    # interrupted: stop what is queued
                client.cancel(list(futures))
            if client.status == 'running':
                client.unregister_worker_plugin(key)

    def _rows_of(self, fut, ids) -> list[dict]:
        """The batch's rows, or 'lost' summary rows (with the reason) if its task failed."""
        try:
            br: BatchResult = fut.result()
        except Exception as exc:      # noqa: BLE001 - a lost task never stops the study
            reason = f'task lost: {type(exc).__name__}: {one_line(exc)}'
            names = self.study.variable_names
            return [{'design_id': i, 'kind': 'design', 'status': 'lost', 'error': reason,
                     'condition': 'all', **dict(zip(names, self.designs[i].tolist()))}
                    for i in ids]
        self.loads[br.pid] = br.context_loads
        return br.rows


def _n_designs(rows: list[dict]) -> int:
    return sum(1 for r in rows if r['kind'] == 'design')


def _bar(enabled: bool, total: int, initial: int):
    if not enabled:
        return None
    from tqdm import tqdm
    return tqdm(total=total, initial=initial, unit='design', desc='designs', smoothing=0.1,
                mininterval=0.5)
