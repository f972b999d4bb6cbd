"""The result table (one tidy table, Parquet via pyarrow and CSV) and its incremental store.

Rows: one per design x condition (``kind`` 'condition') and one summary per design (``kind``
'design', every metric at its worst condition). Columns: ``design_id``, ``kind``, ``status``
('ok', 'failed': the design itself failed, with ``error``; 'lost': its task was lost, e.g. a
worker died, and it is recomputed on ``--resume``), the design variables, ``load_set``,
``load``, ``condition``, the metrics (dmf_sim.design.metrics; the load steps' ``transient_*``
and the road cycle's ``cycle_*`` columns on the summary rows, dmf_sim.design.transient),
``seconds`` (compute time) and, in the final table, ``pareto`` (summary rows on the front of the
first two objectives of a design study, of all of an optimization's).

:class:`ResultStore` writes every finished batch at once as its own small Parquet file
(``DIR/parts/part-NNNNNN.parquet``, written to a temporary name and renamed, so a part is either
complete or absent) next to ``DIR/study.json``. An interrupted study leaves its finished designs
there; ``resume`` reads them back and only the rest is computed. At the end the parts are merged
into ``DIR/results.parquet`` and ``DIR/results.csv``.
"""
from __future__ import annotations

import fcntl
import json
import os
from pathlib import Path

from dmf_sim.core.csv_out import write_csv
from dmf_sim.core.destinations import check_output_dir
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.json_out import write_json
from dmf_sim.core.optional import require
from dmf_sim.design.metrics import WORST

pa = require('pyarrow', 'design')
pq = require('pyarrow.parquet', 'design')

__all__ = ['STUDY_FILE', 'LOCK_FILE', 'PARTS', 'RESULTS', 'schema', 'to_table', 'sort_rows',
           'ResultStore']

STUDY_FILE = 'study.json'
LOCK_FILE = '.lock'
PARTS = 'parts'
RESULTS = 'results'


def schema(variable_names: list[str], final: bool = False, extra=()) -> pa.Schema:
    """Column names and types of the table for a study with these design variables; ``extra``:
    (name, pyarrow type) columns a layer above adds (the optimizer's feasibility and rank)."""
    f64, text = pa.float64(), pa.string()
    cols = [('design_id', pa.int64()), ('kind', text), ('status', text), ('error', text)]
    cols += [(v, f64) for v in variable_names]
    cols += [('load_set', text), ('load', f64), ('condition', text)]
    for name in WORST:
        cols += [(name, f64), (f'{name}_rpm', f64), (f'{name}_condition', text)]
    cols += [('max_windup', f64), ('rpm_1_5', f64), ('speeds_1_5', text),
             ('rpm_nonperiodic', f64), ('speeds_nonperiodic', text),
             ('max_stable_states', pa.int64()), ('max_stable_states_rpm', f64),
             ('max_stable_states_condition', text), ('n_branches', pa.int64()),
             ('transient_windup', f64), ('transient_windup_condition', text),
             ('transient_dmf_torque', f64), ('transient_dmf_torque_condition', text),
             ('transient_stop_contacts', pa.int64()), ('transient_travel_margin', f64),
             ('transient_seconds', f64), ('cycle_friction_heat', f64),
             ('cycle_dmf_torque', f64), ('cycle_dmf_torque_condition', text),
             ('cycle_seconds', f64), ('seconds', f64)]
    cols += list(extra)
    if final:
        cols.append(('pareto', pa.bool_()))
    return pa.schema(cols)


def to_table(rows: list[dict], variable_names: list[str], final: bool = False,
             extra=()) -> pa.Table:
    return pa.Table.from_pylist(rows, schema=schema(variable_names, final, extra))


def sort_rows(rows: list[dict], conditions: list[str]) -> list[dict]:
    """Design by design; its condition rows in study order, then its summary row."""
    order = {c: i for i, c in enumerate(conditions)}
    return sorted(rows, key=lambda r: (r['design_id'], r['kind'] == 'design',
                                       order.get(r.get('condition'), 0)))


class ResultStore:
    """Incremental, resumable storage of a study's rows in directory ``out``.

    Raises ConfigError (naming ``out``) when ``out`` holds another study's results, or any
    results while ``resume`` is false, before anything is computed."""

    def __init__(self, out, study, resume: bool = False, extra=()):
        self.dir = Path(out)
        self.study = study
        self.names = study.variable_names
        self.extra = tuple(extra)
        self._rows: list[dict] | None = []
        meta = self.dir / STUDY_FILE
        check_output_dir(self.dir)
        if meta.exists():
            if not resume:
                raise ConfigError(f'--out {self.dir}: already holds a study; pass --resume to '
                                  'continue it, or choose another directory')
            try:
                stored = json.loads(meta.read_text())
            except (OSError, ValueError) as exc:
                raise ConfigError(f'--out {self.dir}: {STUDY_FILE} unreadable ({exc})') from None
            if stored.get('fingerprint') != study.fingerprint():
                raise ConfigError(f'--resume: {self.dir} holds the results of a different study '
                                  f'({stored.get("name")!r}: other variables, conditions or '
                                  'files); choose another --out')
            self._rows = None                # read from the parts when first needed
        self._seq = len(self._part_files())
        self._lock = None

    # ---- one run at a time -----------------------------------------------------------------
    def lock(self) -> None:
        """Create ``out`` and hold its lock file for this run (another run there is refused);
        :meth:`close` removes it. A lock file another run removed between our opening it and
        locking it is opened again (the path must still name the file we lock)."""
        self.dir.mkdir(parents=True, exist_ok=True)
        path = self.dir / LOCK_FILE
        while True:
            fh = open(path, 'a+')
            try:
                fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                fh.close()
                raise ConfigError(f'--out {self.dir}: another study run is using this '
                                  'directory') from None
            try:
                if os.stat(path).st_ino == os.fstat(fh.fileno()).st_ino:
                    break
            except FileNotFoundError:
                pass
            fh.close()
        self._lock = fh

    def close(self) -> None:
        """Release and remove the lock file (the end of the run, also after an error)."""
        if self._lock is not None:
            (self.dir / LOCK_FILE).unlink(missing_ok=True)   # while held: no other run has it
            self._lock.close()
            self._lock = None

    # ---- reading --------------------------------------------------------------------------------
    def _part_files(self) -> list[Path]:
        return sorted((self.dir / PARTS).glob('part-*.parquet'))

    def _read_parts(self) -> list[dict]:
        rows = []
        for f in self._part_files():
            rows += pq.read_table(f).to_pylist()
        rows = [r for r in rows if r['status'] != 'lost']
        done = {r['design_id'] for r in rows if r['kind'] == 'design'}
        return [r for r in rows if r['design_id'] in done]

    @property
    def rows(self) -> list[dict]:
        """Rows stored by earlier runs (resume), lost designs left out."""
        if self._rows is None:
            self._rows = self._read_parts()
        return self._rows

    def finished(self) -> set[int]:
        """Design ids whose rows are stored (ok or failed; lost ones are computed again)."""
        return {r['design_id'] for r in self.rows if r['kind'] == 'design'}

    # ---- writing --------------------------------------------------------------------------------
    def start(self) -> None:
        """Create the directory and write study.json (the study and its fingerprint)."""
        (self.dir / PARTS).mkdir(parents=True, exist_ok=True)
        meta = {**self.study.as_dict(), 'fingerprint': self.study.fingerprint()}
        _atomic_write(self.dir / STUDY_FILE, lambda p: write_json(p, meta))

    def append(self, rows: list[dict]) -> None:
        """Store one finished batch (one Parquet part, complete or absent)."""
        if not rows:
            return
        table = to_table(rows, self.names, extra=self.extra)
        path = self.dir / PARTS / f'part-{self._seq:06d}.parquet'
        self._seq += 1
        _atomic_write(path, lambda p: pq.write_table(table, p))

    def finalize(self, table: pa.Table) -> dict[str, str]:
        """Write the merged table as results.parquet and results.csv; returns their paths."""
        files = {'parquet': str(self.dir / f'{RESULTS}.parquet'),
                 'csv': str(self.dir / f'{RESULTS}.csv')}
        _atomic_write(Path(files['parquet']), lambda p: pq.write_table(table, p))
        _atomic_write(Path(files['csv']),
                      lambda p: write_csv(p, table.column_names, table.to_pylist()))
        return files


def _atomic_write(path: Path, write) -> None:
    tmp = path.with_name(f'.{path.name}.tmp-{os.getpid()}')
    write(tmp)
    os.replace(tmp, path)
