"""Monocular 6-DoF pose tracking of a fixed-wing UAV landing on a ship.

Everything in this package except ``uav_landing_vision.nodes`` is the ROS-free core.
"""

__version__ = "0.1.0"
