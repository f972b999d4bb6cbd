"""Every JSON the package writes is valid JSON: a number that is not finite is ``null`` (Python's
``json`` writes ``NaN``, which readers refuse), and every JSON output goes through the one writer
(``dmf_sim.core.json_out``)."""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from dmf_sim.core.json_out import json_text, jsonable, write_json

ROOT = Path(__file__).resolve().parents[2]

# json.dumps outside the writer, each with why: texts hashed into a fingerprint (their bytes
# must not change: stored studies would no longer resume) and the bag metadata's compact
# round-trip text (allow_nan=False there)
ALLOWED = {'dmf_sim/core/json_out.py', 'dmf_sim/design/study.py', 'dmf_sim/optimize/problem.py',
           'dmf_sim/bags/metadata.py'}


def _strict(text: str):
    """json.loads that refuses NaN / Infinity, as RFC 8259 readers do."""
    def refuse(name):
        raise ValueError(f'not JSON: {name}')
    return json.loads(text, parse_constant=refuse)


def test_non_finite_numbers_are_null_and_numpy_is_plain(tmp_path):
    obj = {'rel_std': {'k': math.nan, 'c': np.float64(0.1)}, 'peak': [np.inf, -math.inf],
           'arr': np.array([1.0, np.nan]), 'n': np.int64(3), 'ok': np.bool_(True),
           'path': tmp_path, 7: (1, 2)}
    d = _strict(json_text(obj))
    assert d == {'rel_std': {'k': None, 'c': 0.1}, 'peak': [None, None], 'arr': [1.0, None],
                 'n': 3, 'ok': True, 'path': str(tmp_path), '7': [1, 2]}
    assert _strict(write_json(tmp_path / 'x.json', obj).read_text()) == d
    assert jsonable(object(), default=str).startswith('<object')
    with pytest.raises(TypeError):                  # an unknown object is our bug: loud
        json_text({'x': object()})


def test_every_json_output_goes_through_the_writer():
    found = []
    for path in sorted((ROOT / 'dmf_sim').rglob('*.py')):
        rel = path.relative_to(ROOT).as_posix()
        if rel not in ALLOWED and re.search(r'\bjson\.dumps?\(', path.read_text()):
            found.append(rel)
    assert found == [], f'use dmf_sim.core.json_out (json_text / write_json) in {found}'
