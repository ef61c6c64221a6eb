"""QoS of the graph's topics (DESIGN §4): images best-effort sensor data, everything else reliable.

A best-effort subscription matches both kinds of publisher; a reliable one only reliable
publishers. Subscribers of camera streams therefore use :data:`SENSOR_QOS` too.
"""

from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

SENSOR_QOS = qos_profile_sensor_data  # best effort, keep last 5, volatile
RELIABLE_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)  # hypotheses, pose, status, ...

_SENSOR_TYPES = frozenset({"sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo"})


def qos_for_type(type_name: str) -> QoSProfile:
    """The graph's QoS for a message type given as ``pkg/msg/Name``."""
    return SENSOR_QOS if type_name in _SENSOR_TYPES else RELIABLE_QOS
