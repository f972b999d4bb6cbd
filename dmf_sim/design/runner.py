"""Running a study on Dask: a local cluster by default, or an existing one (the cluster itself:
:mod:`dmf_sim.cluster`).

* :func:`run_study`: installs the study context (base driveline, engines, settings) once in
  every worker process with a WorkerPlugin (also on workers that join later), submits
  the designs in batches (one Dask task each), takes the results as they finish
  (``as_completed``), writes each batch to the store at once, and shows a progress bar with ETA.
  A batch whose task is lost (a worker died) is recorded as 'lost' and recomputed on resume.
  While the designs run, :class:`dmf_sim.cluster.WorkerWatch` can report every worker lost,
  joined or restarted.
"""
from __future__ import annotations

import math
import time
import uuid
from collections.abc import Callable

from dmf_sim.cluster import WorkerWatch, close_local, limit_threads, start_local, wait_for_workers
from dmf_sim.core.errors import ConfigError, one_line
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

__all__ = ['DEFAULT_BATCH_SIZE', 'BATCHES_PER_WORKER', 'StudyPlugin', 'close_run',
           'batch_size_for', 'batch_sizes', 'run_study']

DEFAULT_BATCH_SIZE = 8
"""Designs per Dask task. benchmarks/bench_design.py measured 4.7 ms of Dask overhead per task
against 58 ms per paper-case design: 1 design per task loses 8 %, 4 lose 2.0 %, 8 lose 1.0 %."""
BATCHES_PER_WORKER = 4
"""Smaller batches when a study is short, so that every worker gets work until the end."""


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


def close_run(cluster, client, store) -> None:
    """End of a run: close the local cluster and client it started (None: none) and release
    its store's lock (None: no store)."""
    close_local(cluster, client)
    if store:
        store.close()


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
