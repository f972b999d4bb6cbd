"""Edges every layer may use: errors, units, packaged paths, output paths, limits, field
validation, how kernels are compiled, how numbers are written in messages."""
