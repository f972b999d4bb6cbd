"""The bounds of every physical quantity an input file may hold, in one table with their reasons.

A number outside its bound is refused when the file is read (one line naming the field,
:func:`dmf_sim.core.validation.bounded`), so a value no real driveline or engine can have
(``inertia: 1e308``, ``stiffness: 1e300``, ``damping: 1e300``) never reaches a solver, where it
would overflow, empty a bag or fail every design. Every file format that carries the same
quantity uses the same row: the driveline YAML and the engine YAML share ``firing_phase``; a
driveline element's stiffness, the DMF's primary stiffness and a design study's ``k`` share
``stiffness``; damping likewise; stage angles, angle increments and the spring's travel share
``windup_angle``; engine speeds of engine files and study conditions share ``engine_speed``;
torques of engine curves and of optimizer constraints share ``torque``.

The bounds are generous: a margin beyond the largest real value, never a design rule. The
reference is the shipped driveline (``config/truck_dmf.yaml``, the paper's Table 1) and engine
(``config/engine_d13.yaml``).

Numbers that are settings of the software (time steps, grids, tolerances, bins, node rates) are
not physical quantities; they keep their ranges beside the setting they limit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ['Bound', 'BOUNDS']


@dataclass(frozen=True)
class Bound:
    """The allowed range of one quantity: ``lo`` .. ``hi`` [``unit``] (``lo_open`` /
    ``hi_open``: the end itself excluded); ``signed``: the magnitude is bounded and either sign
    allowed (a gear ratio); ``reason``: why no real driveline goes beyond."""

    lo: float
    hi: float
    unit: str
    reason: str
    lo_open: bool = False
    hi_open: bool = False
    signed: bool = False

    def contains(self, x: float) -> bool:
        """Whether the finite number ``x`` is inside."""
        if not math.isfinite(x):
            return False
        v = abs(x) if self.signed else x
        return ((v > self.lo if self.lo_open else v >= self.lo)
                and (v < self.hi if self.hi_open else v <= self.hi))

    def text(self) -> str:
        """The range as messages write it: ``in (0, 1e+06] kg m^2``."""
        lo, hi = f'{self.lo:g}', f'{self.hi:g}'
        left, right = '(' if self.lo_open else '[', ')' if self.hi_open else ']'
        if self.signed:
            rng = f'in [-{hi}, -{lo}] or [{lo}, {hi}]'
        else:
            rng = f'in {left}{lo}, {hi}{right}'
        return f'{rng} {self.unit}'.rstrip()


_VEHICLE_REASON = (
    "the largest inertia of a road driveline is the vehicle's mass at the wheels, m r^2: the "
    "shipped truck's VEHICLE element is 11436 kg m^2 (a 46 t truck on 0.5 m tyres, in the "
    'wheel frame after the gearbox and the 2.66 final drive); a 500 t heavy-haulage '
    'combination on 0.55 m tyres has 1.5e5 kg m^2. Reflected to a faster shaft (through the '
    'lowest gear, 16:1 x 5:1, a 40 t truck is 1.6 kg m^2 at the crankshaft) it is smaller still')

BOUNDS: dict[str, Bound] = {
    # ---- the driveline: elements (Table 1) and the DMF -----------------------------------------
    'inertia': Bound(0.0, 1.0e6, 'kg m^2', lo_open=True, reason=(
        _VEHICLE_REASON + '. 1e6 kg m^2 is 87x the shipped vehicle element and 6.6x the '
        'heaviest road vehicle; > 0: every element has mass')),
    'stiffness': Bound(0.0, 1.0e10, 'Nm/rad', reason=(
        'the stiffest connection of the shipped truck is the counter shaft, 7.0e6 Nm/rad; a '
        'short solid steel shaft of a heavy driveline (d 0.2 m, 50 mm long) has G J / L = '
        '2.5e8 Nm/rad. 1e10 Nm/rad is 40x that: a connection stiffer than this is rigid '
        "(write 'rigid'); 0: no connection (the first element's to the ground)")),
    'damping': Bound(0.0, 1.0e6, 'Nms/rad', reason=(
        "the shipped truck's largest damping is the tyres' 300 Nms/rad; its DMF damps 49.5 "
        'Nms/rad. The critical damping 2 sqrt(k J) of its heaviest connection (tyres to '
        'vehicle: 1.39e6 Nm/rad, 11436 kg m^2) is 2.5e5 Nms/rad; 1e6 Nms/rad is 4x that, '
        'where a damper acts as a rigid link')),
    'ratio': Bound(0.01, 100.0, '', signed=True, reason=(
        "a gear ratio of one element: a truck's lowest gear is ~16:1, a final drive with hub "
        'reduction ~7:1, the shipped truck has 0.88, 0.91 and 2.66; |ratio| in [0.01, 100] '
        'covers every gear stage 6x over; negative: a stage that reverses the rotation')),
    'firing_phase': Bound(0.0, 720.0, 'deg', hi_open=True, reason=(
        "a cylinder's firing angle within the four-stroke cycle of 720 deg (driveline and "
        'engine files alike)')),
    'windup_angle': Bound(0.0, 2.0, 'rad', lo_open=True, reason=(
        'a DMF wind-up angle (a stage knee, an increment between knees, the travel to the end '
        'stop): 2 rad = 115 deg, beyond the arc-spring travel of any DMF (truck DMFs travel '
        '~40-70 deg; the shipped knee is at 0.24 rad); > 0: a knee on the drive or coast side')),
    'stiffness_factor': Bound(0.0, 50.0, '', reason=(
        'a stage stiffness k (1 + factor): a stage stiffer than 51 k is an end stop, which '
        "has its own contact law (the spring's dmf.end_stops) rather than a stage; the paper "
        'varies alpha 1..5')),
    'friction_torque': Bound(0.0, 1.0e4, 'Nm', reason=(
        "the arc springs' constant friction torque T0 (eq. 8a of doc/theory.md): measured DMF "
        'hysteresis loops of car and truck DMFs show tens to a few hundred Nm; 1e4 Nm is 3.6x '
        "the shipped engine's peak torque (a DMF that never slips); 0: no constant friction")),
    'friction_speed_coefficient': Bound(0.0, 0.1, 'Nm s^2/rad^2', reason=(
        'the centrifugal friction coefficient c_Omega of T0 + c_Omega Omega^2 (eq. 8a): a '
        'few hundred Nm at 2000 rpm (209 rad/s) is ~5e-3 Nm s^2/rad^2; 0.1 gives 4.4 kNm at '
        '2000 rpm, beyond what a truck DMF carries; 0: no speed-dependent friction')),
    'friction_regularization': Bound(1.0e-4, 10.0, 'rad/s', reason=(
        'the slip speed omega_reg of the regularized Coulomb law (eq. 8a): 76 % (tanh 1) of the '
        'full friction torque at this relative speed. The 3rd-order wind-up rate of the shipped '
        'DMF is ~1-10 rad/s; above 10 rad/s the law is viscous rather than Coulomb; below 1e-4 '
        'rad/s (1e-5 of that rate) it is a Coulomb step to within what a measurement tells. The '
        'harmonic balance, whose 256 samples a cycle cannot resolve such a step, traced the '
        'friction DMF at 1100-1300 rpm with spurious closed loops from 1e-3 rad/s down and at '
        '1e-300 reached no periodic state')),
    # ---- the operating point ---------------------------------------------------------------
    'engine_speed': Bound(0.0, 1.0e4, 'rpm', reason=(
        'truck diesels run below 2500 rpm (the shipped engine to 2200 rpm), the fastest '
        'road-vehicle diesels below 5000 rpm; 10000 rpm is twice that')),
    'load': Bound(-1.0, 1.0, '', reason=(
        'the torque demand: 1 the full-load curve, 0 no load, -1 the full engine brake (the '
        "engine file's brake curve); below 0 only for an engine with a brake curve")),
    'torque': Bound(0.0, 1.0e6, 'Nm', reason=(
        'an engine or DMF torque: the largest truck engines give ~3.7 kNm (the shipped one '
        '2.8 kNm); 1e6 Nm is 270x that (ship engines beyond are not drivelines this model '
        'describes)')),
    'brake_torque': Bound(-1.0e6, 0.0, 'Nm', reason=(
        'the engine brake curve (a torque that brakes is negative): compression-release brakes '
        'of 13-litre truck engines absorb ~300-350 kW, about -1.5 kNm at 2200 rpm; -1e6 Nm is '
        'the torque bound on the braking side. > 0 would drive: that is the full-load curve')),
    'torque_range': Bound(0.0, 2.0e6, 'Nm', reason=(
        'a rainflow range (peak to valley) of a torque: at most twice the torque bound')),
    'sn_exponent': Bound(0.5, 50.0, '', reason=(
        "Basquin exponent of an S-N curve: steels' torsion curves 3-15; 50 is flat enough to "
        'be an endurance limit')),
    'sn_cycles': Bound(1.0, 1.0e18, '', reason=(
        'cycles to failure at the reference range of an S-N curve: 1e18 cycles at 3000 rpm '
        'take 6e8 years')),
    # ---- the engine's slider-crank ---------------------------------------------------------
    'bore': Bound(0.0, 2.0, 'm', lo_open=True, reason=(
        'cylinder bore: the shipped engine 0.131 m; the largest two-stroke ship engines 0.96 m')),
    'stroke': Bound(0.0, 3.0, 'm', lo_open=True, reason=(
        'piston stroke: the shipped engine 0.158 m; the largest ship engines 2.5 m')),
    'conrod': Bound(0.0, 10.0, 'm', lo_open=True, reason=(
        'connecting-rod length: 1.5-4x the crank radius (the shipped engine 0.255 m)')),
    'compression_ratio': Bound(1.0, 40.0, '', lo_open=True, reason=(
        'compression ratio: diesels 14-23 (the shipped engine 18.1); > 1: the piston '
        'compresses')),
    'oscillating_mass': Bound(0.0, 5000.0, 'kg', reason=(
        'piston, pin, rings and a third of the rod per cylinder: ~5 kg in a truck engine, '
        'a few tonnes in the largest ship engines')),
    # ---- the engine's pressure model -----------------------------------------------------------
    'ambient_pressure': Bound(1.0e4, 2.0e5, 'Pa', reason=(
        'ambient and crankcase pressure: 0.1-2 bar covers any altitude and crankcase '
        'ventilation (standard atmosphere 1.013 bar)')),
    'boost_pressure': Bound(0.0, 1.0e6, 'Pa', reason=(
        'charge-air gauge pressure: truck turbochargers give up to ~3.5 bar, two-stage ~5 bar; '
        '10 bar is twice that')),
    'exhaust_backpressure': Bound(0.0, 5.0e5, 'Pa', reason=(
        'exhaust above intake pressure: up to ~1 bar before a turbine; 5 bar is 5x that')),
    'cylinder_pressure': Bound(0.0, 3.5e7, 'Pa', lo_open=True, reason=(
        'peak cylinder pressure: current heavy-duty diesels fire at 250-300 bar; 350 bar bounds '
        'what a table of A_n may imply')),
    'ivc_angle': Bound(-240.0, -90.0, 'deg', reason=(
        'intake valve closing, crank angle from firing TDC: BDC (-180) +- 60 deg, and before '
        'the compression stroke is half done')),
    'evo_angle': Bound(90.0, 200.0, 'deg', reason=(
        'exhaust valve opening: 90 deg after TDC to 20 deg after BDC')),
    'blowdown_duration': Bound(1.0, 120.0, 'deg', reason=(
        'crank angle over which the cylinder falls to exhaust pressure after the valve opens')),
    'valve_overlap': Bound(1.0, 120.0, 'deg', reason=(
        'intake and exhaust valves open together around gas-exchange TDC: ~20-80 deg in '
        'diesels')),
    'brake_release_angle': Bound(-90.0, 0.0, 'deg', reason=(
        'a compression-release brake opens the exhaust valve on the compression stroke near '
        'TDC (Jacobs, Volvo VEB): 90 deg before TDC at the earliest, at TDC at the latest')),
    'brake_close_angle': Bound(0.0, 180.0, 'deg', reason=(
        "the brake's exhaust valve lift ends after compression TDC and before BDC")),
    'brake_charge_duration': Bound(0.0, 120.0, 'deg', lo_open=True, reason=(
        "the brake's charging lift (the exhaust valve opened near intake BDC so the exhaust "
        'manifold fills the cylinder, Volvo VEB) before the intake valve closes: at most a '
        'third of the intake and compression strokes')),
    'brake_manifold_pressure': Bound(0.0, 1.0e6, 'Pa', lo_open=True, reason=(
        'the exhaust manifold pressure a compression-release brake runs at (absolute), '
        "calibrated per speed so the mean torque is the brake curve's: exhaust pressure "
        'governors and closed variable turbines hold a few bar; 10 bar is twice the most')),
    'polytropic_exponent': Bound(1.0, 1.67, '', lo_open=True, reason=(
        "compression and expansion exponent: above 1 (isothermal), at most a monatomic gas's "
        'heat-capacity ratio 5/3 (air 1.4; apparent values with wall heat loss 1.30-1.37)')),
    'wiebe_efficiency': Bound(0.0, 20.0, '', lo_open=True, reason=(
        "Wiebe efficiency parameter a: 6.908 burns 99.9 % by the end of the duration; 20 "
        'burns all but 2e-9')),
    'combustion_start': Bound(-60.0, 30.0, 'deg', reason=(
        'start of combustion from firing TDC: diesels inject 0-25 deg before TDC and may start '
        'burning after it')),
    'fraction': Bound(0.0, 1.0, '', reason='a share of the fuel burnt in one phase'),
    'premixed_duration': Bound(0.0, 90.0, 'deg', lo_open=True, reason=(
        'premixed combustion lasts ~5-15 deg of crank angle')),
    'diffusion_duration': Bound(1.0, 180.0, 'deg', reason=(
        'diffusion combustion lasts ~40-100 deg of crank angle; at most the expansion stroke')),
    'duration_factor': Bound(0.0, 1.0, '', lo_open=True, reason=(
        'the diffusion duration at zero load as a share of the full-load duration')),
    'wiebe_shape': Bound(0.0, 10.0, '', reason='Wiebe shape exponent m: 0.5-3 in practice'),
}
"""Quantity name -> :class:`Bound`. The files name their fields; which quantity a field is
says its reader (``bounded(value, where, field, quantity)``)."""
