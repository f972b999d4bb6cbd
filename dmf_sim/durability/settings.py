"""Durability settings (``config/durability.yaml``): the S-N curve and the bins.

The S-N curve is Basquin's ``N(S) = N_ref (S / S_ref)^-b`` over the torque range S [Nm] of a
rainflow cycle; the packaged values are placeholders (``placeholder: true``) and every report
made with them says so.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from dmf_sim.core.paths import read_yaml_mapping
from dmf_sim.core.validation import bounded, check_keys, field_error, integer, number

__all__ = ['DEFAULT_SETTINGS', 'SNCurve', 'DurabilitySettings', 'read_settings']

DEFAULT_SETTINGS = 'durability'      # config/durability.yaml


@dataclass(frozen=True)
class SNCurve:
    """Basquin S-N curve over torque ranges: ``N(S) = reference_cycles (S /
    reference_range_nm)^-exponent``; ranges below ``endurance_range_nm`` do no damage."""

    exponent: float
    reference_range_nm: float
    reference_cycles: float
    endurance_range_nm: float = 0.0
    placeholder: bool = True

    def cycles_to_failure(self, ranges_nm) -> np.ndarray:
        """N(S) for torque ranges S [Nm] (inf below the endurance range and at S = 0)."""
        s = np.abs(np.asarray(ranges_nm, dtype=float))
        with np.errstate(divide='ignore'):
            n = self.reference_cycles * (s / self.reference_range_nm) ** (-self.exponent)
        return np.where((s <= 0) | (s < self.endurance_range_nm), np.inf, n)

    def damage(self, ranges_nm, counts) -> float:
        """Palmgren-Miner sum of ``counts`` cycles at ``ranges_nm`` (half cycles: 0.5)."""
        return float(np.sum(np.asarray(counts, float) / self.cycles_to_failure(ranges_nm)))

    def as_dict(self) -> dict:
        return {'exponent': self.exponent, 'reference_range_nm': self.reference_range_nm,
                'reference_cycles': self.reference_cycles,
                'endurance_range_nm': self.endurance_range_nm, 'placeholder': self.placeholder,
                'law': 'N = reference_cycles * (S / reference_range_nm)^-exponent, S = torque '
                       'range of a rainflow cycle [Nm]'}


@dataclass(frozen=True)
class DurabilitySettings:
    """What ``config/durability.yaml`` says (see its comments for each field)."""

    sn: SNCurve
    torque_bin_nm: float
    range_bin_nm: float
    mean_bin_nm: float
    speed_bin_rpm: float
    power_time_s: float
    largest: int
    largest_separation_s: float
    window_s: float
    source: str = ''


_SN_FIELDS = {'exponent': ('sn_exponent', False), 'reference_range_nm': ('torque_range', True),
              'reference_cycles': ('sn_cycles', False),
              'endurance_range_nm': ('torque_range', False)}
"""S-N field -> (its physical quantity in dmf_sim.core.bounds.BOUNDS, 0 excluded)."""
_BIN_FIELDS = {'torque_nm': (1e-3, 1e6), 'range_nm': (1e-3, 1e6), 'mean_nm': (1e-3, 1e6),
               'speed_rpm': (1.0, 5000.0), 'power_time_s': (1e-3, 3600.0)}


def _sn_value(value, where: str, field: str, key: str) -> float:
    quantity, positive = _SN_FIELDS[key]
    return bounded(value, where, field, quantity, positive=positive)


def _section(data: dict, key: str, path, fields) -> dict:
    sec = data.get(key, {})
    allowed = list(fields) + (['placeholder'] if key == 'sn_curve' else [])
    return dict(check_keys(sec, str(path), key, (), allowed))


def read_settings(source: str | os.PathLike = DEFAULT_SETTINGS, **overrides) -> DurabilitySettings:
    """Settings from a YAML file (name in ``config/`` or a path; what it leaves out comes from
    the packaged ``config/durability.yaml``); ``overrides`` replace S-N fields (exponent,
    reference_range_nm, reference_cycles, endurance_range_nm) given as options. One-line
    ConfigError for a bad field. The curve counts as a placeholder unless the file says
    ``placeholder: false`` or gives its own S-N numbers, or options do."""
    _, base = read_yaml_mapping(DEFAULT_SETTINGS, 'durability settings')
    path, data = read_yaml_mapping(source, 'durability settings')
    check_keys(data, str(path), '', (), ('sn_curve', 'bins', 'largest', 'largest_separation_s',
                                         'window_s'))
    user_sn = _section(data, 'sn_curve', path, _SN_FIELDS)
    sn = {**base['sn_curve'], **user_sn}
    values = {k: _sn_value(sn[k], str(path), f'sn_curve.{k}', k) for k in _SN_FIELDS}
    own = path.resolve() != read_yaml_mapping(DEFAULT_SETTINGS)[0].resolve() and any(
        k in user_sn for k in _SN_FIELDS)
    placeholder = user_sn.get('placeholder', sn['placeholder'] and not own)
    if not isinstance(placeholder, bool):
        raise field_error(str(path), 'sn_curve.placeholder', 'must be true or false', placeholder)
    given = {k: v for k, v in overrides.items() if v is not None}
    for k, v in given.items():
        values[k] = _sn_value(v, 'command line', f'--{k.replace("_", "-")}', k)
    bins = {**base['bins'], **_section(data, 'bins', path, _BIN_FIELDS)}
    b = {k: number(bins[k], str(path), f'bins.{k}', *_BIN_FIELDS[k]) for k in _BIN_FIELDS}
    largest = integer(data.get('largest', base['largest']), str(path), 'largest', 1, 1000)
    window = number(data.get('window_s', base['window_s']), str(path), 'window_s', 1e-3, 10.0,
                    unit='s')
    sep = number(data.get('largest_separation_s', base['largest_separation_s']), str(path),
                 'largest_separation_s', 0.0, 1e6, unit='s')
    return DurabilitySettings(
        SNCurve(**values, placeholder=placeholder and not given),
        torque_bin_nm=b['torque_nm'], range_bin_nm=b['range_nm'], mean_bin_nm=b['mean_nm'],
        speed_bin_rpm=b['speed_rpm'], power_time_s=b['power_time_s'], largest=largest,
        largest_separation_s=sep, window_s=window, source=str(path))
