"""The agreement the documentation states between a recorded run's orders and the HBM, in one
place for the tests that check it (helpers)."""

# the README's tolerances of a measured steady state against the HBM
TOL_ORDER_3 = 0.01            # relative
TOL_ORDER_1_5 = 0.15          # of the HBM value
TOL_MEAN = 1.5e-3             # rad

# Tolerances doc/commands/analyze.md states for a run-up at <= 20 rpm/s against the steady HBM:
RUNUP_TOL = {'order_3': ('rel', 0.01), 'order_1_5': ('peak', 0.15),
             'max_deviation': ('peak', 0.05), 'min_deviation': ('peak', 0.05),
             'mean_minus_theta': ('abs', 1.5e-3)}
