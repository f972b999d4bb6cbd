"""Parameters of the DMF fitted to a measurement (``dmf-sim identify``):
:mod:`dmf_sim.identify.fit`."""
