"""Unit conversions used at the package's edges (SI inside; engine speed in rpm for people).

One place for the rpm <-> rad/s factor and the engine cycle: every module imports these.
"""
from __future__ import annotations

import math

__all__ = ['RPM_TO_RAD_S', 'RAD_S_TO_RPM', 'CYCLE_RAD', 'rpm_to_rad_s', 'rad_s_to_rpm',
           'cycle_period_s']

RPM_TO_RAD_S = math.pi / 30.0
"""Engine speed [rpm] times this is the crank angular speed [rad/s]."""

RAD_S_TO_RPM = 30.0 / math.pi
"""Crank angular speed [rad/s] times this is the engine speed [rpm]."""

CYCLE_RAD = 4.0 * math.pi
"""One four-stroke engine cycle: 720 deg of crank angle [rad]."""


def rpm_to_rad_s(speed_rpm):
    """Engine speed [rpm] (scalar or array) -> crank angular speed [rad/s]."""
    return speed_rpm * RPM_TO_RAD_S


def rad_s_to_rpm(omega):
    """Crank angular speed [rad/s] (scalar or array) -> engine speed [rpm]."""
    return omega * RAD_S_TO_RPM


def cycle_period_s(speed_rpm):
    """Duration [s] of one 720 deg engine cycle at ``speed_rpm``."""
    return CYCLE_RAD / (speed_rpm * RPM_TO_RAD_S)
