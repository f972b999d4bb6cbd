"""A cycle of the live order analysis as the monitor receives it, with chosen values (helper)."""
from __future__ import annotations

from types import SimpleNamespace

from dmf_sim.physics.orders import OrderSummary


def cycle(order_1_5=0.0163, speed=950.0, load=1.0, mean=0.1989, max_dev=0.03, min_dev=-0.03):
    """One analysed engine cycle: its summary, values and region shares."""
    summ = OrderSummary(order_3=0.01499, order_1_5=order_1_5, max_deviation=max_dev,
                        min_deviation=min_dev, mean=mean, mean_minus_theta=mean - 0.2,
                        static_windup=0.19, theta=0.2)
    c = SimpleNamespace(index=7, t_start_s=1.0, t_end_s=1.126, speed_rpm=speed, load=load,
                        summary=summ, region_share={'primary': 0.6, 'secondary': 0.4})
    c.max_windup, c.min_windup = mean + max_dev, mean + min_dev
    c.values = lambda: {'cycle': 7.0, 'speed_rpm': speed, 'load': load, 'order_3_rad': 0.01499,
                        'order_1_5_rad': order_1_5, 'mean_rad': mean,
                        'max_windup_rad': mean + max_dev, 'min_windup_rad': mean + min_dev,
                        'theta_minus_static_rad': 0.01, 'share_primary': 0.6,
                        'share_secondary': 0.4}
    return c
