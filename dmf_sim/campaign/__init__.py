"""Fault campaigns: grids of offline runs with faults, scored by the reference detector on Dask.

:mod:`dmf_sim.campaign.runner` (``dmf-sim campaign``).
"""
