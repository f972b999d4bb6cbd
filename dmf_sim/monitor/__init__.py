"""Live monitoring off the real-time path: per-cycle orders, HBM prediction, alarms."""
