"""Subcommands of ``dmf-sim``; each module is discovered by ``dmf_sim.cli``."""
