"""Echo process for the DDS round-trip test: republishes every message type it receives.

Run as ``python echo_messages.py``; listens on ``/echo/in/<Type>`` and answers on
``/echo/out/<Type>``. Exits after ``--timeout`` seconds.
"""

import argparse
import time

import rclpy
from rclpy.node import Node

from uav_landing_msgs import msg

TYPES = ["Detection", "DetectionArray", "OrientedBox", "PoseHypotheses", "TrackerStatus", "LandingGuidance"]


class Echo(Node):
    def __init__(self):
        super().__init__("echo_messages")
        self._pubs = {}
        for name in TYPES:
            cls = getattr(msg, name)
            self._pubs[name] = self.create_publisher(cls, f"/echo/out/{name}", 10)
            self.create_subscription(cls, f"/echo/in/{name}", lambda m, n=name: self._pubs[n].publish(m), 10)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--timeout", type=float, default=60.0)
    args = parser.parse_args()
    rclpy.init()
    node = Echo()
    end = time.monotonic() + args.timeout
    try:
        while rclpy.ok() and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    main()
