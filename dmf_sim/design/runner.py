"""Running a study on Dask: a local cluster by default, or an existing one.

* :func:`local_cluster`: a ``dask.distributed.LocalCluster`` of worker *processes* (one thread
  each: the solvers hold the GIL), listening on 127.0.0.1 only, without a dashboard.
* :func:`connect`: a client of an existing scheduler (``tcp://HOST:8786``); an address that does
  not answer is a one-line ConfigError naming ``--scheduler``.
* :func:`run_study`: sends the study context (base driveline, engines, settings) to every worker
  once (``scatter(broadcast=True)``: each worker process unpickles it once and keeps it), submits
  the designs in batches (one Dask task each), takes the results as they finish
  (``as_completed``), writes each batch to the store at once, and shows a progress bar with ETA.
  A batch whose task is lost (a worker died) is recorded as 'lost' and recomputed on resume.
"""
from __future__ import annotations

import math
import os
import re
import time
import uuid

from dmf_sim.design.evaluate import BatchResult, StudyContext, evaluate_batch
from dmf_sim.design.result import StudyResult
from dmf_sim.design.study import load_study
from dmf_sim.design.table import ResultStore
from dmf_sim.errors import ConfigError, one_line

LOOPBACK = '127.0.0.1'
CONNECT_TIMEOUT_S = 5.0
DEFAULT_BATCH_SIZE = 4
"""Designs per Dask task (benchmarks/bench_design.py measures the task overhead it amortizes)."""
BATCHES_PER_WORKER = 4
"""Smaller batches when a study is short, so that every worker gets work until the end."""
_ADDRESS = re.compile(r'^(tcp|tls)://[^\s/:]+:\d{1,5}$')


def available_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:                     # not on Linux
        return os.cpu_count() or 1


def local_cluster(workers: int | None = None):
    """A LocalCluster of ``workers`` processes (default: one per core) on 127.0.0.1."""
    from distributed import LocalCluster
    n = workers or available_cores()
    if not (isinstance(n, int) and n >= 1):
        raise ConfigError(f'--workers {n!r}: must be an integer >= 1')
    return LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host=LOOPBACK,
                        dashboard_address=None)


def connect(address: str, timeout_s: float = CONNECT_TIMEOUT_S):
    """A ``distributed.Client`` of the scheduler at ``address`` (``tcp://HOST:PORT``)."""
    from distributed import Client
    if not isinstance(address, str) or not _ADDRESS.match(address.strip()):
        raise ConfigError(f'--scheduler {address!r}: expected tcp://HOST:PORT (e.g. '
                          'tcp://10.0.0.5:8786)')
    try:
        return Client(address.strip(), timeout=timeout_s)
    except (OSError, TimeoutError) as exc:
        raise ConfigError(f'--scheduler {address}: no Dask scheduler answers there within '
                          f'{timeout_s:g} s ({one_line(exc)}); start one with `dask scheduler` '
                          'or leave out --scheduler to use a local cluster') from None


def batch_size_for(n_designs: int, n_workers: int, batch_size: int | None = None) -> int:
    """The given batch size, or the default, made smaller for short studies so that there are
    at least BATCHES_PER_WORKER batches per worker."""
    if batch_size is not None:
        if not (isinstance(batch_size, int) and batch_size >= 1):
            raise ConfigError(f'--batch-size {batch_size!r}: must be an integer >= 1')
        return batch_size
    per = math.ceil(n_designs / max(1, BATCHES_PER_WORKER * n_workers))
    return max(1, min(DEFAULT_BATCH_SIZE, per))


def run_study(study, client=None, *, out=None, resume: bool = False, workers: int | None = None,
              batch_size: int | None = None, progress: bool = False,
              on_batch=None) -> StudyResult:
    """Evaluate every design of ``study`` (a study file, mapping or Study) on Dask.

    Args:
        client: a ``distributed.Client``; None starts a LocalCluster of ``workers`` processes
            (default one per core) on 127.0.0.1 for this call.
        out: directory for the incremental store and the final table (None: in memory only).
        resume: continue the study stored in ``out`` (finished designs are not recomputed).
        batch_size: designs per Dask task (default :func:`batch_size_for`).
        progress: tqdm progress bar with ETA on stderr.
        on_batch: called as ``on_batch(n_done, n_total)`` after each stored batch.
    """
    study = load_study(study)
    store = ResultStore(out, study, resume) if out is not None else None
    designs = study.designs()
    done = store.finished() if store else set()
    todo = [i for i in range(len(designs)) if i not in done]
    own = client is None
    cluster = local_cluster(workers) if own else None
    t0 = time.perf_counter()
    new_rows: list[dict] = []
    loads: dict[int, int] = {}
    bar = None
    try:
        if own:
            from distributed import Client
            client = Client(cluster)
        n_workers = max(1, len(client.scheduler_info().get('workers', {})))
        size = batch_size_for(len(todo), n_workers, batch_size)
        if store:
            store.start()
        if todo:
            ctx = client.scatter(StudyContext.from_study(study), broadcast=True, hash=False)
            futures = {}
            for k in range(0, len(todo), size):
                ids = todo[k:k + size]
                items = [(i, designs[i].tolist()) for i in ids]
                key = f'dmf-design-{ids[0]}-{uuid.uuid4().hex[:8]}'
                futures[client.submit(evaluate_batch, ctx, items, key=key, pure=False)] = ids
            bar = _bar(progress, len(designs), len(done))
            from distributed import as_completed
            for fut in as_completed(futures):
                ids = futures.pop(fut)
                rows = _rows_of(fut, ids, designs, study, loads)
                fut.release()
                if store:
                    store.append(rows)
                new_rows += rows
                if bar is not None:
                    bar.update(len(ids))
                if on_batch is not None:
                    on_batch(len(designs) - len(todo) + _n_designs(new_rows), len(designs))
    finally:
        if bar is not None:
            bar.close()
        if own:
            if client is not None:
                client.close()
            cluster.close()
    rows = (store.rows if store else []) + new_rows
    result = StudyResult.from_rows(study, rows, n_computed=_n_designs(new_rows),
                                   seconds=time.perf_counter() - t0, workers=n_workers,
                                   batch_size=size, context_loads=loads)
    if store:
        result.files.update(store.finalize(result.table))
    return result


def _rows_of(fut, ids, designs, study, loads: dict) -> list[dict]:
    """The batch's rows, or 'lost' summary rows (with the reason) if its task failed."""
    try:
        br: BatchResult = fut.result()
    except Exception as exc:      # noqa: BLE001 - a lost task never stops the study
        reason = f'task lost: {type(exc).__name__}: {one_line(exc)}'
        return [{'design_id': i, 'kind': 'design', 'status': 'lost', 'error': reason,
                 'condition': 'all', **dict(zip(study.variable_names, designs[i].tolist()))}
                for i in ids]
    loads[br.pid] = br.context_loads
    return br.rows


def _n_designs(rows: list[dict]) -> int:
    return sum(1 for r in rows if r['kind'] == 'design')


def _bar(enabled: bool, total: int, initial: int):
    if not enabled:
        return None
    from tqdm import tqdm
    return tqdm(total=total, initial=initial, unit='design', desc='designs', smoothing=0.1,
                mininterval=0.5)
