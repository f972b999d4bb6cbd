"""A minimal EngineExcitation with fixed coefficients, for solver tests independent of
engine.py."""
import numpy as np


class FakeEngine:
    """Per-cylinder coefficients A_n = load * base_n (speed independent). SI units [Nm]."""

    n_cylinders = 6
    firing_phases_deg = np.array([0, 480, 240, 600, 120, 360.0])

    def __init__(self, coeffs: dict[int, complex], n_max: int = 24):
        self.n_max = n_max
        self.base = np.zeros(n_max + 1, dtype=complex)
        for n, c in coeffs.items():
            self.base[n] = c

    def coefficients(self, speed_rpm, load):
        return self.base * load

    def mean_torque(self, speed_rpm, load):
        return 6 * self.base[0].real * load

    def full_load_torque(self, speed_rpm):
        return 6 * self.base[0].real
