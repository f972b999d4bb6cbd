"""DMF durability from a record: rainflow counts of the spring torque, Palmgren-Miner damage
with a Basquin S-N curve, time and torque per spring stage, the largest torques, the power the
DMF damping dissipates (``dmf-sim durability``)."""
