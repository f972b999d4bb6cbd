"""Helpers shared by the tests (bags, CDR, DDS peers, figures, ...); not tests."""
