"""The driveline model, the DMF spring law, engine excitation, loads, modes, orders."""
