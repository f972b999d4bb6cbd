"""Edges every layer may use: errors, units, packaged paths, field validation, how kernels are
compiled, how numbers are written in messages."""
