"""Edges every layer may use: errors, units, packaged paths, field validation."""
