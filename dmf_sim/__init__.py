"""dmf_sim: torsional vibrations of a heavy-truck driveline with a two-step dual mass flywheel.

The pure-Python core (model, loads, solvers, bag tools) runs without ROS; ``dmf_sim.node``
is a thin rclpy shell over it.
"""

__version__ = '0.1.0'
