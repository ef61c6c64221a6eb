"""Thin rclpy nodes of the graph (DESIGN §4): parameters → core config, messages → core types → messages.

The only package of ``uav_landing_vision`` that imports ROS. Each node module has a ``main()``
(console script ``lib/uav_landing_vision/<node>``; also ``python -m uav_landing_vision.nodes.<node>``).
"""
