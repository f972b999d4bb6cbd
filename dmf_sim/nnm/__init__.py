"""Non-linear normal modes (NNMs) of the conservative DMF driveline (design.md §3, paper Fig. 14).

The conservative system is the driveline without damping and without excitation, held at the static
equilibrium of a mean torque (static wind-up ``w_s``). With ``x`` the DOF deviation from that
equilibrium and ``u = e.x`` the wind-up deviation:

    J x'' + K_lin x + e f(u) = 0,     K_lin = K + g'(w_s) e e^T,
    f(u) = g(w_s + u) - g(w_s) - g'(w_s) u                         (piecewise linear, f(0) = f'(0) = 0)

``g`` is the DMF's extra torque (dmf_sim.spring). For the drive-side knee alone: with the static point
in the primary region (``w_s < theta``), ``K_lin`` has the primary stiffness and ``f(u) = b max(u - d, 0)``
(stiffening, knee at ``d = theta - w_s`` above); in the secondary region ``K_lin`` has ``k(1+alpha)`` and
``f(u) = -b min(u + d, 0)`` (softening, knee at ``d = w_s - theta`` below). A coast knee, if
configured, is one more ramp term of the same kind.

Harmonic balance condensed on the wind-up. The NNMs followed here are the synchronous (symmetric)
periodic orbits: all velocities vanish at t = 0, so every DOF is a cosine series in ``tau = Omega t``,

    u(tau) = sum_{n=0}^{H} a_n cos(n tau),     x(tau) = sum_n x_n cos(n tau).

This fixes the phase (time-shift invariance; stronger than "sine part of the 1st harmonic = 0").
Balancing harmonic n of the linear chain with the DMF force as a load gives ``x_n = -H_n e f_n`` with
``H_n = (K_lin - (n Omega)^2 J)^-1`` and, on the wind-up row, ``a_n = -h_n f_n`` with the wind-up
receptance ``h_n = e.H_n e = sum_k (e.phi_k)^2 / (omega_k^2 - (n Omega)^2)`` (modal sum over the elastic
modes of (K_lin, J); at n = 0 this is the static flexibility with the rigid mode removed, as
harmonic.solve_static). The residual is written in a form that stays finite at the poles of h_n
(the linear resonances, where the branch starts: a_1 is free and f_1 = 0):

    r_n = c_n a_n + s_n f_n / b,     (c_n, s_n) = sign * (1, b h_n) / sqrt(1 + (b h_n)^2),

with ``b`` the knee's stiffness jump and the sign of det(K_lin - (n Omega)^2 J) making (c_n, s_n)
continuous through the poles. The force harmonics f_n are exact Galerkin integrals, not sampled:
the knee crossings of u(tau) on the half period are located (grid + Newton on the trigonometric
polynomial) and ``f_n = (2/pi) int_{active} c (u - beta) cos(n tau) dtau`` is integrated in closed form,
with the exact Jacobian ``df_n/da_m = (2/pi) c int_{active} cos(m tau) cos(n tau) dtau``. (hbm.py's AFT
is a sampled FFT on a complex, forced, 720-degree layout; this autonomous cosine problem has its own
small version.) Unknowns: a_0..a_H plus Omega; the one-parameter family is followed with
continuation.py's pseudo-arc-length continuation, started on the linear mode exactly at the knee
(xi = 1, tangent along a_1) and stopped once xi exceeds ``xi_stop``. Where the branch climbs a flat
branch (below) beyond ``xi_stop``, the backbone is restarted on the far side of that internal
resonance (Newton at fixed Omega), and the tongue's far side is traced back up to ``xi_stop``;
``NNMBranch.segment`` numbers the pieces. Tongues narrower than a continuation step are stepped over
(``NNMOptions.step_max`` decides how thin a tongue is still resolved).

Energy (relative to the static equilibrium, evaluated at t = 0 where all velocities vanish):

    E = 1/2 x(0)^T K_lin x(0) + F(u(0)),   F' = f,
    x_n = (H_n e / h_n) a_n = -H_n e f_n   (the first form at resonance, the second near h_n = 0;
                                           evaluated as a least-squares blend, finite everywhere),

and ``xi = E / E_nl`` with ``E_nl = 1/2 omega_m^2 (d / e.phi_m)^2`` the energy of the linear mode m
(mass-normalized phi_m, mode of (K_lin, J)) whose wind-up amplitude just reaches the knee.

Scaling (paper, after eq. 19): ``f`` is positively homogeneous in (u, d), so every orbit scales with d,
E and E_nl with d^2; frequency against xi does not depend on theta nor on the static point's distance
to the knee (exactly, without a coast knee). :func:`scaling_check` confirms it numerically.

Flat branches (paper: "close to a multiple of one of the linear resonances of the systems to the rear
and front of the non-linearity"): where n Omega meets a linear resonance with little DMF motion, the
branch runs into an internal-resonance tongue: the energy of harmonic n grows at almost constant
Omega. Such points are those where a harmonic n >= 2 carries more than ``tongue_share`` (25 %) of the
kinetic energy; they are labelled with n and with the subsystem resonance (front or rear of the DMF,
each free at the DMF, DMF spring removed) nearest to n Omega. On the truck these agree with n Omega
to ~1 % (with the driveline's own resonance at K_lin to ~0.1 %); the natural frequencies with the
wind-up clamped (flywheels rigidly joined, the zeros of h) lie 1-7 % away and are reported only for
reference.

Modules: :mod:`~dmf_sim.nnm.conservative` (the condensed problem and one branch),
:mod:`~dmf_sim.nnm.branches` (both branches of Fig. 14, flat branches, the scaling check),
:mod:`~dmf_sim.nnm.ramp_force` (exact Galerkin harmonics), :mod:`~dmf_sim.nnm.subsystems`,
:mod:`~dmf_sim.nnm.time_domain`, :mod:`~dmf_sim.nnm.results`.
"""
from dmf_sim.nnm.branches import nnm_branches, scaling_check
from dmf_sim.nnm.conservative import ConservativeNNM
from dmf_sim.nnm.results import REGIONS, FlatBranch, NNMBranch, NNMOptions, NNMResult
from dmf_sim.nnm.subsystems import clamped_frequencies, static_windup, subsystem_frequencies
from dmf_sim.nnm.time_domain import integrate_chain, integrate_physical, static_state

__all__ = ['nnm_branches', 'scaling_check', 'ConservativeNNM', 'REGIONS', 'FlatBranch', 'NNMBranch',
           'NNMOptions', 'NNMResult', 'clamped_frequencies', 'static_windup', 'subsystem_frequencies',
           'integrate_chain', 'integrate_physical', 'static_state']
