"""What a recording node stores about its model in a bag, and how analysis reads it back (one
schema).

rosbag2's ``metadata.yaml`` has a free ``custom_data`` string map. The live node writes a
:class:`RunMetadata` there when it starts a recording; ``dmf-sim analyze`` reads it back to
rebuild the same model (driveline, engine, load set, DMF spring, load). Keys carry the prefix
``dmf_sim.``; values are strings (rosbag2 allows nothing else). Reading is tolerant: a bag
written by another tool, or an older dmf_sim, gives None for what it lacks.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

__all__ = ['CUSTOM_PREFIX', 'RunMetadata']

CUSTOM_PREFIX = 'dmf_sim.'


def _float(raw: str | None) -> float | None:
    if raw in (None, ''):
        return None
    try:
        v = float(raw)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _mapping(raw: str | None) -> dict | None:
    if raw in (None, ''):
        return None
    try:
        d = json.loads(raw)
    except (TypeError, ValueError):
        return None
    return d if isinstance(d, dict) else None


@dataclass(frozen=True)
class RunMetadata:
    """The model behind a recording (SI; speed in rpm).

    Attributes:
        driveline, engine: YAML names or paths as the node was given them.
        load_set: 'A', 'B' or 'C'.
        alpha, theta_rad: the first drive stage of the DMF spring (None without a DMF).
        spring: the whole spring (``PiecewiseLinearSpring.as_dict()``: k, stages, coast_stages).
        load, speed_rpm: load fraction and engine speed when the recording started.
        dt_s: Newmark step; publish_rate_hz: samples per simulated second.
        node: fully qualified node name (namespace included) of the recording node, or the
            command that wrote the bag (``dmf-sim run``).
        profile: the speed/load profile ``dmf-sim run`` followed (its name).
        profile_table: that whole profile (``Profile.as_table()`` of
            :mod:`dmf_sim.transient.profiles`, which ``profile_from_table`` reads back), so the
            run can be followed again where its file is not (``dmf-sim identify``).
        settle_s: the first seconds of the recording (from its first message) in which the
            driveline settles from static equilibrium (``dmf-sim run`` starts there): their
            engine cycles are not steady running, and the analysis leaves them out.
        sensors: the sensors recorded (``SensorSet.as_dict()`` of
            :mod:`dmf_sim.physics.sensors`; ``parse_sensors`` gives the set back), None when
            the recording has none.
    """

    driveline: str | None = None
    engine: str | None = None
    load_set: str | None = None
    alpha: float | None = None
    theta_rad: float | None = None
    spring: dict | None = None
    load: float | None = None
    speed_rpm: float | None = None
    dt_s: float | None = None
    publish_rate_hz: float | None = None
    node: str | None = None
    profile: str | None = None
    profile_table: dict | None = None
    settle_s: float | None = None
    sensors: dict | None = None

    _FLOATS = ('alpha', 'theta_rad', 'load', 'speed_rpm', 'dt_s', 'publish_rate_hz', 'settle_s')
    _MAPPINGS = ('spring', 'sensors', 'profile_table')

    def to_custom_data(self) -> dict[str, str]:
        """The ``custom_data`` entries (only the known values)."""
        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None:
                continue
            if f.name in self._MAPPINGS:
                text = json.dumps(v, separators=(',', ':'), allow_nan=False)
            elif f.name in self._FLOATS:
                text = repr(float(v))
            else:
                text = str(v)
            out[CUSTOM_PREFIX + f.name] = text
        return out

    @classmethod
    def from_custom_data(cls, custom: Mapping[str, Any] | None) -> 'RunMetadata':
        """Read the entries back (missing or malformed values become None)."""
        custom = dict(custom or {})
        kw: dict[str, Any] = {}
        for f in fields(cls):
            raw = custom.get(CUSTOM_PREFIX + f.name)
            if f.name in cls._MAPPINGS:
                kw[f.name] = _mapping(raw)
            elif f.name in cls._FLOATS:
                kw[f.name] = _float(raw)
            else:
                kw[f.name] = str(raw) if raw not in (None, '') else None
        return cls(**kw)

    @classmethod
    def from_bag_metadata(cls, metadata: Mapping[str, Any] | None) -> 'RunMetadata':
        """From a parsed ``rosbag2_bagfile_information`` mapping (or None)."""
        return cls.from_custom_data((metadata or {}).get('custom_data'))
