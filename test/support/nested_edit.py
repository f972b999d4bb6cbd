"""Test helper: a nested mapping with one field replaced or deleted (bad-input tests)."""
from __future__ import annotations

import copy

DELETE = object()      # as the value: delete the field


def edited(doc: dict, keys: list[str], value) -> dict:
    """A deep copy of ``doc`` with ``doc[k0][k1]...[kn]`` set to ``value`` (or deleted)."""
    out = copy.deepcopy(doc)
    node = out
    for k in keys[:-1]:
        node = node[k]
    if value is DELETE:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return out
