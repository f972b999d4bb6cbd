"""What a study returns (:class:`StudyResult`): the table, the Pareto front, run figures."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dmf_sim.core.optional import require
from dmf_sim.design.pareto import compromise, pareto_mask
from dmf_sim.design.table import sort_rows, to_table

pa = require('pyarrow', 'design')

__all__ = ['StudyResult']


@dataclass
class StudyResult:
    """Rows of every design (condition rows and summary rows), the non-dominated designs of the
    study's first two objectives, the compromise ('best') design among them, and run figures.

    ``table`` is a pyarrow Table (``.to_pylist()``, ``.to_pandas()`` if pandas is there)."""

    study: object
    table: pa.Table
    pareto_ids: list[int]
    best_id: int | None
    n_computed: int = 0
    seconds: float = 0.0
    workers: int = 0
    batch_size: int = 0
    context_loads: dict = field(default_factory=dict)
    files: dict = field(default_factory=dict)

    @classmethod
    def from_rows(cls, study, rows: list[dict], **run) -> 'StudyResult':
        rows = sort_rows(rows, [c.label for c in study.conditions])
        o1, o2 = study.objectives[:2]
        summ = [r for r in rows if r['kind'] == 'design' and r['status'] == 'ok']
        f1 = np.array([r[o1] for r in summ], dtype=float)
        f2 = np.array([r[o2] for r in summ], dtype=float)
        mask = pareto_mask(f1, f2) if summ else np.zeros(0, dtype=bool)
        front = {r['design_id'] for r, m in zip(summ, mask) if m}
        best = summ[compromise((f1, f2), mask)]['design_id'] if summ else None
        for r in rows:
            r['pareto'] = (r['design_id'] in front) if r['kind'] == 'design' else None
        table = to_table(rows, study.variable_names, final=True)
        return cls(study, table, sorted(front), best, **run)

    # ---- views ----------------------------------------------------------------------------------
    def rows(self, kind: str | None = None) -> list[dict]:
        """Table rows as dicts; ``kind`` 'condition' or 'design' selects one kind."""
        rows = self.table.to_pylist()
        return rows if kind is None else [r for r in rows if r['kind'] == kind]

    def design(self, design_id: int) -> dict:
        """The summary row of one design."""
        return next(r for r in self.rows('design') if r['design_id'] == design_id)

    @property
    def n_designs(self) -> int:
        return len(self.rows('design'))

    def failed(self) -> list[dict]:
        return [r for r in self.rows('design') if r['status'] != 'ok']

    def summary(self) -> dict:
        """JSON-able summary: counts, throughput, Pareto front, best design, failures, files."""
        s = self.study
        o1, o2 = s.objectives[:2]
        keep = ['design_id', *s.variable_names, *s.objectives]
        front = [{k: r[k] for k in keep} for r in self.rows('design') if r['pareto']]
        return {
            'study': s.name, 'n_designs': self.n_designs,
            'n_ok': self.n_designs - len(self.failed()), 'n_failed': len(self.failed()),
            'n_computed': self.n_computed, 'n_resumed': self.n_designs - self.n_computed,
            'conditions': [c.label for c in s.conditions], 'objectives': s.objectives,
            'pareto_objectives': [o1, o2], 'pareto': front,
            'best': ({k: self.design(self.best_id)[k] for k in keep}
                     if self.best_id is not None else None),
            'failed': [{'design_id': r['design_id'], 'error': r['error']} for r in self.failed()],
            'seconds': self.seconds, 'workers': self.workers, 'batch_size': self.batch_size,
            'designs_per_s': self.n_computed / self.seconds if self.seconds > 0 else None,
            'context_loads_per_worker': sorted(self.context_loads.values()),
            'files': self.files,
        }
