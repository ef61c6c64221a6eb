"""A DDS participant of its own for a node's images, apart from its other messages.

rclpy gives every node of a context one DDS participant. Measured with Fast DDS (Jazzy's
default middleware; shared-memory transport between processes on one machine): with the bag
player's 2.7 MB frames and small ground-truth poses sent from one participant, paced replays of
373 frames lost 1–2 truths in 7 of 9 runs; with the frames from a participant of their own, or
with the UDP transport alone, none in any run (README, "Frames leave from a DDS participant of
their own"). So a node that publishes images as well as small messages that must all arrive
sends the images through :class:`ImageParticipant` (``LandingNode.create_image_publisher``).
"""

import rclpy
from rclpy.node import Node

IMAGE_TYPES = frozenset({"sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage"})


class ImageParticipant:
    """Publishers in a second participant (same domain and namespace) beside ``owner``'s;
    topic names are resolved by ``owner``, so its remapping rules apply to them."""

    def __init__(self, owner: Node):
        self._owner = owner
        self.context = rclpy.Context()
        rclpy.init(args=[], context=self.context, domain_id=owner.context.get_domain_id())
        self.node = Node(f"{owner.get_name()}_images", namespace=owner.get_namespace(), context=self.context,
                         use_global_arguments=False, start_parameter_services=False)

    def create_publisher(self, msg_type, topic: str, qos):
        return self.node.create_publisher(msg_type, self._owner.resolve_topic_name(topic), qos)

    def destroy(self) -> None:
        self.node.destroy_node()
        self.context.try_shutdown()
