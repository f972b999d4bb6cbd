"""Cylinder pressure and crank-throw torque of one cylinder: the default engine model.

One 720 deg cycle is sampled finely (``samples_per_cycle``) in the cylinder's own angle ``theta``
(0 = firing TDC):

* closed cycle IVC..EVO with a constant polytropic exponent gamma and a double Wiebe burn fraction
  ``x_b`` (premixed + diffusion, Ghojel 2010). With constant gamma,
  ``d(p V^gamma)/dtheta = (gamma - 1) V^(gamma - 1) dQ/dtheta`` integrates to::

      p = V^-gamma [ p_ivc V_ivc^gamma + (gamma - 1) Q_tot * int_{ivc}^{theta} V^(gamma-1) dx_b ]

  so the pressure, the torque and every ``A_n`` are affine in the total heat release ``Q_tot``;
* blowdown from the EVO pressure to the exhaust back pressure (cosine ramp), exhaust stroke at
  the exhaust pressure, intake stroke at the boost pressure (cosine blend over the valve overlap);
* intake pressure ``p_amb + load * boost_gauge(speed)``; exhaust pressure above it by a
  load-dependent back pressure; Wiebe start/durations depend on speed and load (YAML tables);
* ``Q_tot`` is solved exactly so that the mean torque equals ``load * full_load_curve(speed) /
  n_cylinders`` per cylinder. **Friction is not modelled**: the mean indicated torque equals the
  configured (brake) full-load curve times the load fraction.

Engine braking (load b in [-1, 0), an engine YAML with ``brake_curve`` and
``compression_release_brake``; :meth:`PressureModel.brake_cycle`): no fuel; the exhaust valve's
charging lift fills the cylinder from the exhaust manifold before the intake closes, the charge is
compressed polytropically to the release angle before TDC, the release lift lets it fall to the
manifold pressure (cosine ramp) and holds it there to the lift's end, what is left re-expands to
the normal exhaust opening; exhaust stroke at the manifold pressure, intake stroke at ambient
pressure. Every part of that cycle but the intake stroke is proportional to the manifold pressure
``P`` (the brake's exhaust back pressure), so the mean torque is affine in ``P`` and ``P`` is
solved exactly per speed so that it equals the brake curve; the compression work is not returned
on the expansion stroke. Part braking is the pressure between the zero-load cycle and the full
brake cycle, ``p_b = (1 - |b|) p_0 + |b| p_brake``: its mean torque is ``|b|`` times the curve's
(the zero-load mean is 0) and every ``A_n`` moves linearly from the zero-load cycle (b = 0, no
jump) to the full brake (b = -1).

Crank torque: gas ``(p - p_crankcase) A_p dx/dtheta`` plus the oscillating-mass inertia torque
``-m omega^2 (d2x/dtheta2)(dx/dtheta)`` (exact slider-crank kinematics, load independent). The
``A_n`` are the half orders of the sampled cycle (dmf_sim.physics.orders.half_orders).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from dmf_sim.core.bounds import BOUNDS
from dmf_sim.core.errors import ConfigError
from dmf_sim.core.units import RPM_TO_RAD_S
from dmf_sim.physics.engine.config import EngineConfig, require_model
from dmf_sim.physics.orders import half_orders, synthesize

__all__ = ['CycleResult', 'PressureModel']


@dataclass(frozen=True)
class CycleResult:
    """One 720 deg cycle of one cylinder, sampled at ``psi_deg`` (0 = its firing TDC)."""

    psi_deg: np.ndarray
    pressure_pa: np.ndarray
    gas_torque_nm: np.ndarray
    inertia_torque_nm: np.ndarray
    heat_release_j: float            # total Q of the Wiebe law (the part after EVO is not used)
    intake_pa: float
    exhaust_pa: float
    brake_fraction: float = 0.0      # |b| of a braking cycle (0: fired or motored)
    brake_manifold_pa: float = 0.0   # the full brake's calibrated exhaust manifold pressure

    @property
    def torque_nm(self) -> np.ndarray:
        return self.gas_torque_nm + self.inertia_torque_nm

    @property
    def peak_pressure_pa(self) -> float:
        return float(self.pressure_pa.max())


class PressureModel:
    """Cylinder pressure and crank-throw torque of one cylinder (default engine model)."""

    def __init__(self, cfg: EngineConfig) -> None:
        require_model(cfg)
        self.cfg = cfg
        n = cfg.samples_per_cycle
        # Cylinder angle theta in [-360, 360) deg: one contiguous closed cycle around firing TDC.
        self.theta_deg = -360.0 + 720.0 * np.arange(n) / n
        theta = np.radians(self.theta_deg)
        x, self._dx, _ = cfg.geometry.kinematics(theta)
        self._volume = cfg.geometry.clearance_volume_m3 + cfg.geometry.piston_area_m2 * x
        self._roll = -n // 2   # theta = 0 (psi = 0) is sample n/2
        self._inertia_shape = cfg.geometry.inertia_shape(theta)      # [Nm s^2]
        self.inertia_unit = cfg.geometry.inertia_coefficients(cfg.n_max, n)
        gas = cfg.gas_exchange
        th = self.theta_deg
        self._i_ivc = int(np.searchsorted(th, gas.ivc_deg))
        self._i_evo = int(np.searchsorted(th, gas.evo_deg, side='right')) - 1
        self._closed = (np.arange(n) >= self._i_ivc) & (np.arange(n) <= self._i_evo)
        t_evo = th[self._i_evo]
        frac = np.clip((th - t_evo) / gas.blowdown_deg, 0.0, 1.0)
        self._blowdown_w = np.where(th > t_evo, 0.5 * (1.0 + np.cos(np.pi * frac)), 0.0)
        # Exhaust -> intake blend around the gas-exchange TDC (theta = +-360 deg).
        d_ge = np.where(th > 0.0, th - 360.0, th + 360.0)
        w = np.clip(0.5 + d_ge / gas.overlap_deg, 0.0, 1.0)
        self._intake_w = 0.5 - 0.5 * np.cos(np.pi * w)
        self._blowdown_w[self._closed] = 0.0
        if cfg.has_brake:
            self.check_brake_curve()

    def burn_fraction(self, speed_rpm: float, load: float) -> np.ndarray:
        """Double Wiebe burn fraction x_b(theta) (Ghojel 2010), premixed + diffusion."""
        cb = self.cfg.combustion
        z = np.clip(self.theta_deg - cb.start_deg(speed_rpm), 0.0, None)
        beta = cb.premixed_fraction_zero_load + load * (cb.premixed_fraction_full_load
                                                        - cb.premixed_fraction_zero_load)
        dur_d = cb.diffusion_duration_full_load_deg(speed_rpm) * (
            cb.diffusion_duration_zero_load_factor
            + (1.0 - cb.diffusion_duration_zero_load_factor) * load)
        pre = 1.0 - np.exp(-cb.wiebe_a
                           * (z / cb.premixed_duration_deg) ** (cb.premixed_shape + 1.0))
        dif = 1.0 - np.exp(-cb.wiebe_a * (z / dur_d) ** (cb.diffusion_shape + 1.0))
        return beta * pre + (1.0 - beta) * dif

    def _pressure_parts(self, speed_rpm: float, load: float
                        ) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Pressure as ``p_base + Q_tot * p_unit`` over the cycle, plus intake/exhaust pressure."""
        gas, cb = self.cfg.gas_exchange, self.cfg.combustion
        g = cb.polytropic_exponent
        V = self._volume
        p_int = gas.ambient_pa + load * gas.boost_gauge_full_load(speed_rpm)
        p_exh = p_int + gas.exhaust_backpressure_zero_load_pa + load * (
            gas.exhaust_backpressure_full_load_pa - gas.exhaust_backpressure_zero_load_pa)
        # closed cycle: p V^g = p_ivc V_ivc^g + (g-1) Q int V^(g-1) dx_b
        xb = self.burn_fraction(speed_rpm, load)
        Vg = V ** (g - 1.0)
        dI = 0.5 * (Vg[1:] + Vg[:-1]) * np.diff(xb)
        integral = np.concatenate(([0.0], np.cumsum(dI)))
        integral -= integral[self._i_ivc]
        Vmg = V ** -g
        closed_base = p_int * V[self._i_ivc] ** g * Vmg
        closed_unit = (g - 1.0) * integral * Vmg
        # open cycle: exhaust/intake strokes plus the blowdown ramp from the EVO pressure
        exchange = p_exh + (p_int - p_exh) * self._intake_w
        i_evo = self._i_evo
        wb = self._blowdown_w
        p_base = np.where(self._closed, closed_base,
                          exchange + (closed_base[i_evo] - exchange[i_evo]) * wb)
        p_unit = np.where(self._closed, closed_unit, closed_unit[i_evo] * wb)
        return p_base, p_unit, p_int, p_exh

    def target_cylinder_mean(self, speed_rpm: float, load: float) -> float:
        """Mean torque of one cylinder [Nm]: load x full-load curve / n_cylinders (no friction);
        a braking load b < 0: |b| x brake curve / n_cylinders (the curve is negative)."""
        curve = self.cfg.full_load_curve if load >= 0.0 else self.cfg.brake_curve
        return abs(load) * curve(speed_rpm) / self.cfg.n_cylinders

    # -- engine braking ------------------------------------------------------------------------
    @cached_property
    def _brake_shapes(self) -> tuple[np.ndarray, np.ndarray]:
        """The full brake cycle's pressure as ``P * per_manifold + p_ambient * per_intake``
        over the cycle (module docstring); every angle is fixed, so neither depends on speed."""
        cfg = self.cfg
        gas, brake, g = cfg.gas_exchange, cfg.brake, cfg.combustion.polytropic_exponent
        th, V = self.theta_deg, self._volume

        def ramp(start: float, width: float) -> np.ndarray:     # cosine 0 -> 1 over the width
            f = np.clip((th - start) / width, 0.0, 1.0)
            return 0.5 - 0.5 * np.cos(np.pi * f)

        i_ivc = self._i_ivc
        start = max(gas.ivc_deg - brake.charge_duration_deg, -360.0 + 0.5 * gas.overlap_deg)
        charged = ramp(start, gas.ivc_deg - start)
        intake = self._intake_w * np.where(th < gas.ivc_deg, 1.0 - charged, 0.0)
        per_p = 1.0 - intake                              # open cycle: manifold, intake at p_a
        per_i = intake.copy()
        compressed = (V[i_ivc] / V) ** g                  # from P at intake closing
        released = ramp(brake.release_deg, brake.release_duration_deg)
        i_close = min(int(np.searchsorted(th, brake.close_deg, side='right')) - 1, self._i_evo)
        closed = self._closed
        per_p = np.where(closed & (th <= brake.release_deg), compressed, per_p)
        lift = closed & (th > brake.release_deg) & (th <= th[i_close])
        per_p = np.where(lift, compressed * (1.0 - released) + released, per_p)
        # the gas left at the lift's end re-expands (from the manifold's pressure once released)
        expanded = per_p[i_close] * (V[i_close] / V) ** g
        per_p = np.where(closed & (th > th[i_close]), expanded, per_p)
        per_i = np.where(closed, 0.0, per_i)
        # normal exhaust opening: from the re-expanded pressure to the manifold's (blowdown)
        i_evo = self._i_evo
        per_p = np.where(~closed & (th > th[i_evo]),
                         per_p + (per_p[i_evo] - per_p) * self._blowdown_w, per_p)
        return per_p, per_i

    @cached_property
    def _brake_torques(self) -> tuple[np.ndarray, np.ndarray, float]:
        """Gas torque per unit manifold pressure [Nm/Pa], the part of the ambient intake [Nm]
        (crankcase pressure included), and the mean of the first (< 0: braking)."""
        gas = self.cfg.gas_exchange
        per_p, per_i = self._brake_shapes
        lever = self.cfg.geometry.piston_area_m2 * self._dx
        t_p = per_p * lever
        t_rest = (gas.ambient_pa * per_i - gas.crankcase_pa) * lever
        return t_p, t_rest, float(t_p.mean())

    def brake_manifold_pressure(self, speed_rpm: float) -> float:
        """The exhaust manifold pressure [Pa] (absolute) whose full brake cycle has the brake
        curve's mean torque at ``speed_rpm`` (solved exactly: the mean is affine in it)."""
        t_p, t_rest, per_pa = self._brake_torques
        return (self.target_cylinder_mean(speed_rpm, -1.0) - float(t_rest.mean())) / per_pa

    def brake_torque_range(self) -> tuple[float, float]:
        """The whole engine's full-brake mean torque [Nm] with the manifold at ambient pressure
        (the weakest this brake gives) and at the largest manifold pressure of the bounds."""
        t_p, t_rest, per_pa = self._brake_torques
        n, rest = self.cfg.n_cylinders, float(t_rest.mean())
        return (n * (rest + per_pa * self.cfg.gas_exchange.ambient_pa),
                n * (rest + per_pa * BOUNDS['brake_manifold_pressure'].hi))

    def check_brake_curve(self) -> None:
        """Refuse a brake curve this brake cannot give at a speed of the grid or a point of the
        curve: a manifold pressure below ambient or above the bound (one line naming the
        field)."""
        cfg = self.cfg
        speeds = np.union1d(cfg.grid.speeds_rpm, cfg.brake_curve.x)
        weakest, strongest = self.brake_torque_range()
        hi = BOUNDS['brake_manifold_pressure'].hi
        for s in speeds.tolist():
            p = self.brake_manifold_pressure(s)
            if not cfg.gas_exchange.ambient_pa <= p <= hi:
                raise ConfigError(
                    f"{cfg.path.name}: field 'brake_curve.torque_nm' at {s:g} rpm: "
                    f'{cfg.brake_curve(s):g} Nm needs the exhaust manifold at {p / 1e5:.3g} bar '
                    f'while braking; this compression-release brake gives {weakest:.0f} Nm '
                    f'(manifold at ambient pressure) to {strongest:.0f} Nm ({hi / 1e5:g} bar)')

    def brake_cycle(self, speed_rpm: float) -> CycleResult:
        """The full brake's cycle (load -1) at ``speed_rpm``: manifold pressure calibrated to the
        brake curve (:meth:`brake_manifold_pressure`), no heat release."""
        per_p, per_i = self._brake_shapes
        t_p, t_rest, _ = self._brake_torques
        p = self.brake_manifold_pressure(speed_rpm)
        amb = self.cfg.gas_exchange.ambient_pa
        return self._result(speed_rpm, p * per_p + amb * per_i, p * t_p + t_rest, 0.0, amb, p,
                            brake_fraction=1.0, brake_manifold_pa=p)

    def _result(self, speed_rpm: float, pressure: np.ndarray, gas_torque: np.ndarray,
                q: float, p_int: float, p_exh: float, **brake) -> CycleResult:
        """A cycle in the cylinder's angle theta, rolled to psi in [0, 720) deg."""
        omega = speed_rpm * RPM_TO_RAD_S
        roll = self._roll
        return CycleResult(
            psi_deg=np.roll(self.theta_deg, roll) % 720.0, pressure_pa=np.roll(pressure, roll),
            gas_torque_nm=np.roll(gas_torque, roll),
            inertia_torque_nm=np.roll(omega ** 2 * self._inertia_shape, roll),
            heat_release_j=float(q), intake_pa=p_int, exhaust_pa=p_exh, **brake)

    def cycle(self, speed_rpm: float, load: float, *, fired: bool = True) -> CycleResult:
        """Pressure and torques of one cycle with Q_tot solved for the target mean torque.

        ``fired=False``: the cylinder that does not fire (a misfire), at the same operating point:
        the intake and exhaust pressures of ``load`` (the other cylinders keep the turbocharger
        running) and no heat release, Q_tot = 0: compression and expansion of the charge and the
        gas exchange only. (Load 0 is not that: its Q_tot is what overcomes the pumping loss so
        that the mean torque is 0, a few tens of joules per cycle.)

        A braking load b < 0 (an engine with a brake): ``(1 - |b|)`` times the zero-load cycle
        (``fired=False``: the cycle without heat release) plus ``|b|`` times
        :meth:`brake_cycle` (module docstring)."""
        if load < 0.0:
            b = -load
            zero, brake = self.cycle(speed_rpm, 0.0, fired=fired), self.brake_cycle(speed_rpm)
            return CycleResult(
                psi_deg=zero.psi_deg, inertia_torque_nm=zero.inertia_torque_nm,
                pressure_pa=(1.0 - b) * zero.pressure_pa + b * brake.pressure_pa,
                gas_torque_nm=(1.0 - b) * zero.gas_torque_nm + b * brake.gas_torque_nm,
                heat_release_j=(1.0 - b) * zero.heat_release_j,
                intake_pa=(1.0 - b) * zero.intake_pa + b * brake.intake_pa,
                exhaust_pa=(1.0 - b) * zero.exhaust_pa + b * brake.exhaust_pa,
                brake_fraction=b, brake_manifold_pa=brake.brake_manifold_pa)
        area = self.cfg.geometry.piston_area_m2
        p_base, p_unit, p_int, p_exh = self._pressure_parts(speed_rpm, load)
        t_base = (p_base - self.cfg.gas_exchange.crankcase_pa) * area * self._dx  # Q_tot = 0
        t_unit = p_unit * area * self._dx                                          # per joule
        q = ((self.target_cylinder_mean(speed_rpm, load) - t_base.mean()) / t_unit.mean()
             if fired else 0.0)
        return self._result(speed_rpm, p_base + q * p_unit, t_base + q * t_unit, q, p_int, p_exh)

    def gas_coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        """Gas-torque A_n of one cylinder [Nm] from one cycle (exact, no cache)."""
        return half_orders(self.cycle(speed_rpm, load).gas_torque_nm, self.cfg.n_max)

    def motored_gas_coefficients(self, speed_rpm: float, load: float) -> np.ndarray:
        """Gas-torque A_n of one cylinder that does not fire at (speed, load) [Nm]: the cycle of
        :meth:`cycle` with ``fired=False`` (exact, no cache)."""
        return half_orders(self.cycle(speed_rpm, load, fired=False).gas_torque_nm,
                           self.cfg.n_max)

    def inertia_coefficients(self, speed_rpm: float) -> np.ndarray:
        """Inertia-torque A_n of one cylinder [Nm]: omega^2 times the unit-speed shape."""
        return (speed_rpm * RPM_TO_RAD_S) ** 2 * self.inertia_unit

    def truncation_error(self, speed_rpm: float, load: float) -> float:
        """Relative rms error of one cylinder's torque when the series stops at n_max.

        ``rms(P - P_trunc) / rms(P)`` over the finely sampled cycle (P = gas + inertia torque).
        """
        torque = self.cycle(speed_rpm, load).torque_nm
        residual = torque - synthesize(half_orders(torque, self.cfg.n_max), torque.size)
        return float(np.sqrt(np.mean(residual ** 2) / np.mean(torque ** 2)))
