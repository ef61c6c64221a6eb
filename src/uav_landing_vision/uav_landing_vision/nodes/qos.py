"""QoS of the graph's topics (DESIGN §4), reliable everywhere inside the graph.

Images and camera_info: reliable, keep last 5. Measured here (rclpy + Fast DDS 2.14, two
processes, 1280x720 rgb8 at 5 Hz): best effort delivered 5 of 20 images (8 of 20 with
``FASTDDS_BUILTIN_TRANSPORTS=LARGE_DATA``), reliable 20 of 20. Large best-effort samples
are lost whole when one fragment is, so the graph cannot promise every frame with the
sensor-data profile. :data:`SENSOR_QOS` remains for subscribing to a camera driver that
publishes best effort (``undistort``'s ``camera_qos: sensor_data``).
Hypotheses, pose, status, ground truth, diagnostics: reliable, keep last 10. The evaluator
takes pose and ground truth reliable, keep all (:data:`KEEP_ALL_QOS`): it scores every frame,
and a stall of its process must not cost it the oldest ones.
"""

from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

IMAGE_QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)
SENSOR_QOS = qos_profile_sensor_data  # best effort, keep last 5: matches any camera driver
RELIABLE_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
KEEP_ALL_QOS = QoSProfile(history=HistoryPolicy.KEEP_ALL, reliability=ReliabilityPolicy.RELIABLE)

_IMAGE_TYPES = frozenset({"sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo"})


def qos_for_type(type_name: str) -> QoSProfile:
    """The graph's QoS for a message type given as ``pkg/msg/Name``."""
    return IMAGE_QOS if type_name in _IMAGE_TYPES else RELIABLE_QOS
