"""Transient runs: speed/load profiles, following them with the live core, offline runs to a
bag (``dmf-sim run``), run-up analysis against the HBM sweep."""
