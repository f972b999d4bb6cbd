"""The ROS-free live core of the node: simulation, pacing, run loop, recording, health,
parameters, runtime, Foxglove bridge."""
