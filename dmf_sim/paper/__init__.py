"""Reproduction of the reference paper: the study and the claims report."""
