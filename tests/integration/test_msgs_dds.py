"""Every uav_landing_msgs message survives a round trip through a second process over real DDS."""

import os
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from geometry_msgs.msg import Point, Pose, Quaternion
from rclpy.node import Node
from sensor_msgs.msg import RegionOfInterest

from uav_landing_msgs import msg

ECHO = Path(__file__).with_name("echo_messages.py")


def _header(m, frame="camera_optical_frame"):
    m.header.stamp.sec, m.header.stamp.nanosec = 1_700_000_000, 123_456_789
    m.header.frame_id = frame
    return m


def _samples():
    det = msg.Detection(roi=RegionOfInterest(x_offset=10, y_offset=20, width=64, height=32, do_rectify=True), score=0.875)
    arr = _header(msg.DetectionArray(detections=[det, msg.Detection(score=0.5)]))
    obb = msg.OrientedBox(center_x=640.5, center_y=360.25, width=120.0, height=30.0, angle=-0.3)
    hyp = _header(
        msg.PoseHypotheses(
            obb=obb,
            poses=[
                Pose(position=Point(x=1.0, y=-2.0, z=30.0), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)),
                Pose(position=Point(x=0.5, y=0.5, z=12.0), orientation=Quaternion(x=0.5, y=0.5, z=0.5, w=0.5)),
            ],
            distances=[0.01, 0.25],
        )
    )
    status = _header(
        msg.TrackerStatus(
            state=msg.TrackerStatus.TRACKING, best_likelihood=0.9375, effective_particles=41.5,
            stage_names=["boosting", "render", "score"], stage_ms=[3.5, 20.25, 5.0],
        )
    )
    guidance = _header(
        msg.LandingGuidance(
            stage=msg.LandingGuidance.LAND, range=42.0, glide_slope_angle=0.07, glide_slope_error=-0.01,
            lateral_angle=0.02, inside_cone=True,
        ),
        frame="landing_point_ned",
    )
    return {
        "Detection": det, "DetectionArray": arr, "OrientedBox": obb,
        "PoseHypotheses": hyp, "TrackerStatus": status, "LandingGuidance": guidance,
    }


def test_constants():
    assert (msg.TrackerStatus.LOST, msg.TrackerStatus.ACQUIRING, msg.TrackerStatus.TRACKING) == (0, 1, 2)
    assert [msg.LandingGuidance.LOITER, msg.LandingGuidance.APPROACH, msg.LandingGuidance.LAND,
            msg.LandingGuidance.NO_RETURN, msg.LandingGuidance.GO_AROUND] == [0, 1, 2, 3, 4]


def test_round_trip_between_processes(ros_domain_id):
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain_id))
    echo = subprocess.Popen([sys.executable, str(ECHO), "--timeout", "60"], env=env)
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=ros_domain_id)
    node = Node("round_trip_test", context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    try:
        samples = _samples()
        received = {}
        pubs = {}
        for name, sample in samples.items():
            cls = type(sample)
            pubs[name] = node.create_publisher(cls, f"/echo/in/{name}", 10)
            node.create_subscription(cls, f"/echo/out/{name}", lambda m, n=name: received.setdefault(n, m), 10)
        executor.add_node(node)
        deadline = time.monotonic() + 45.0
        while len(received) < len(samples) and time.monotonic() < deadline:
            assert echo.poll() is None, "echo process died"
            for name, pub in pubs.items():
                # Publish only once the echo's subscription is matched; repeat until the answer arrives.
                if name not in received and pub.get_subscription_count() > 0:
                    pub.publish(samples[name])
            executor.spin_once(timeout_sec=0.1)
        assert set(received) == set(samples), f"no echo for {sorted(set(samples) - set(received))}"
        for name, sample in samples.items():
            assert received[name] == sample, name
    finally:
        node.destroy_node()
        executor.shutdown()
        context.try_shutdown()
        echo.terminate()
        echo.wait(timeout=10)
