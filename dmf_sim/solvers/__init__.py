"""Newmark time integration, harmonic balance, continuation, stability, non-periodic
classification, steady states, non-linear normal modes."""
