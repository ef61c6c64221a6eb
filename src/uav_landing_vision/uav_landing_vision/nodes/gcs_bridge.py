"""``gcs_bridge``: tracker pose → MAVLink to the GCS/autopilot and ``uav/landing_guidance``.

Subscribes ``uav/pose`` (PoseWithCovarianceStamped) and ``uav/tracker_status`` (TrackerStatus),
both reliable; every ``1 / mavlink.rate_hz`` seconds it ticks the core (``gcs.GcsBridge``:
landing cone, stage machine, MAVLink) and publishes its ``LandingGuidance`` (frame ``landing``:
x bow, y starboard, z down, origin at the net), stamped with its pose's header stamp as received
(the core's float seconds cannot hold an epoch stamp to the nanosecond) or, without a fresh pose,
the tick's time. The ticks are timed by the steady clock, and under ``use_sim_time`` by sim time
(``/clock``): a timer on the system clock would wait out a step back of that clock (NTP or GPS
time setting it right), for as long as the step, with no heartbeat and no GO_AROUND. The core
reads the time of each tick, and of each pose, from the node's clock, as the stamps are; it
handles that clock jumping back.
Parameters: ``config/gcs_bridge.yaml``, validated into ``gcs.GcsBridgeConfig``.
A malformed pose (NaN, non-unit quaternion, bad covariance), a pose in a frame other than the
camera's (``camera.frame_id``: the mount describes that camera only) or an unknown tracker state
is logged and dropped; no position is sent for it. So are every pose and status while
``uav/pose`` or ``uav/tracker_status`` has more than one publisher (a second tracker or graph on
the domain, a bag replayed with its recorded poses): a status could then vouch for another
tracker's pose. The MAVLink link never stops the node (``gcs.link``): a GCS not up at start-up,
gone, or no longer reading, or a radio unplugged, leaves the ticks and the stage machine running;
the frames not sent are dropped (``mavlink_dropped``, with the link's error in the log and on
/diagnostics) and a TCP or serial link is reopened every second until it is back. ``mavlink_sent``
counts what the bridge handed to the link, ``mavlink_written`` what went out. The service
``~/reset`` (std_srvs/Trigger) is the
operator's reset of the stage machine to LOITER (NO_RETURN holds until it, e.g. after recovery
from the net). With MAVLink signing on, a signing timestamp file that cannot be read or written
stops the node at start-up; one that cannot be written later is logged as an error (``gcs.signing``).
"""

import sys

from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.clock import Clock, ClockType
from std_srvs.srv import Trigger
from uav_landing_msgs.msg import LandingGuidance, TrackerStatus

from ..config import ConfigError
from ..gcs import GcsBridge, GcsBridgeConfig
from ..stamps import stamp_fields, stamp_ns
from .base import LandingNode, run_node
from .qos import RELIABLE_QOS

LANDING_FRAME_ID = "landing"
POSE_STAMPS_KEPT = 16  # poses wait for their status and are sent at the next tick: a few frames at most


class GcsBridgeNode(LandingNode):
    def __init__(self, **kwargs):
        super().__init__("gcs_bridge", **kwargs)
        self.config = self.load_config(GcsBridgeConfig)
        self._pose_stamps = {}  # float seconds the core knows a pose by -> its header stamp, the last few
        self._signing_store_error = ""
        try:
            self._bridge = GcsBridge(self.config)
        except (OSError, ValueError) as exc:
            raise ConfigError(f"gcs_bridge parameters: {exc}") from exc
        self._guidance = self.create_publisher(LandingGuidance, "uav/landing_guidance", RELIABLE_QOS)
        self._inputs = (
            self.create_subscription(PoseWithCovarianceStamped, "uav/pose", self._on_pose, RELIABLE_QOS),
            self.create_subscription(TrackerStatus, "uav/tracker_status", self._on_status, RELIABLE_QOS),
        )
        self.create_service(Trigger, "~/reset", self._on_reset)
        sim_time = self.get_parameter("use_sim_time").value
        self.create_timer(1.0 / self.config.mavlink.rate_hz, self._tick,
                          clock=None if sim_time else Clock(clock_type=ClockType.STEADY_TIME))
        self.get_logger().info(f"MAVLink {self.config.mavlink.messages} to {self.config.mavlink.connection}")

    def _now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _second_tracker(self) -> str:
        """Why the tracker's topics cannot be trusted (more than one publisher), or ""."""
        for sub in self._inputs:
            count = self.count_publishers(sub.topic_name)
            if count > 1:
                return f"{count} publishers of {sub.topic_name.lstrip('/')}: a second tracker, or a bag that replays it?"
        return ""

    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        self.counters["received"] += 1
        if conflict := self._second_tracker():
            self.drop(f"uav/pose: {conflict}")
            return
        if msg.header.frame_id != self.config.camera.frame_id:
            self.drop(f"uav/pose rejected: in frame '{msg.header.frame_id}', but the camera mount (camera.frame_id) "
                      f"is that of '{self.config.camera.frame_id}'")
            return
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        try:
            taken = self._bridge.on_pose(
                stamp_ns(msg.header.stamp) * 1e-9, (p.x, p.y, p.z), (q.x, q.y, q.z, q.w),
                msg.pose.covariance, self._now_s(),
            )
        except ValueError as exc:
            self.drop(f"uav/pose rejected: {exc}")
            return
        if not taken:
            self.counters["stale_poses"] += 1
            return
        self._pose_stamps[stamp_ns(msg.header.stamp) * 1e-9] = msg.header.stamp
        while len(self._pose_stamps) > POSE_STAMPS_KEPT:
            del self._pose_stamps[next(iter(self._pose_stamps))]

    def _on_status(self, msg: TrackerStatus) -> None:
        self.counters["status_received"] += 1
        if conflict := self._second_tracker():
            self.drop(f"uav/tracker_status: {conflict}")
            return
        try:
            self._bridge.on_tracker_state(msg.state, stamp_ns(msg.header.stamp) * 1e-9)
        except ValueError as exc:
            self.drop(f"uav/tracker_status rejected: {exc}")

    def _on_reset(self, _request, response):
        before = self._bridge.reset()
        response.success = True
        response.message = f"stage {before.name} -> LOITER"
        self.get_logger().warning(f"operator reset: {response.message}")
        return response

    def _tick(self) -> None:
        result = self._bridge.tick(self._now_s())
        g = result.guidance
        msg = LandingGuidance(
            stage=int(g.stage), range=g.range, glide_slope_angle=g.glide_slope_angle,
            glide_slope_error=g.glide_slope_error, lateral_angle=g.lateral_angle, inside_cone=g.inside_cone,
        )
        msg.header.frame_id = LANDING_FRAME_ID
        pose_stamp = self._pose_stamps.get(g.stamp_s)
        if pose_stamp is not None:
            msg.header.stamp = pose_stamp
        else:
            msg.header.stamp.sec, msg.header.stamp.nanosec = stamp_fields(round(g.stamp_s * 1e9))
        self._guidance.publish(msg)
        self.counters["published"] += 1
        self.counters["mavlink_sent"] += len(result.sent)
        self._report_link()

    def _report_link(self) -> None:
        """The link's counters (``mavlink_*``) on /diagnostics; frames it could not send count as
        dropped, with the link's error (WARN on /diagnostics, logged at most once a second). The
        link going down (e.g. nobody listens at a udpout address: frames still go out) and coming
        back are logged once each."""
        link = self._bridge.link_stats
        connection = self.config.mavlink.connection
        lost = link.dropped - self.counters["mavlink_dropped"]
        if link.up != bool(self.counters.get("mavlink_up", True)):  # as last reported; up until told otherwise
            if link.up:
                self.get_logger().info(f"MAVLink to '{connection}' is up")
            else:
                self.get_logger().warning(f"MAVLink to '{connection}' is down: {link.last_error}")
        if link.restored > self.counters["mavlink_restored"]:
            self.get_logger().warning(f"MAVLink to '{connection}' sends again")
        for key in ("written", "dropped", "failures", "restored"):
            self.counters[f"mavlink_{key}"] = getattr(link, key)
        self.counters["mavlink_up"] = int(link.up)
        store_error = self._bridge.signing_store_error
        if store_error != self._signing_store_error:
            if store_error:
                self.get_logger().error(f"MAVLink signing timestamp not stored: {store_error}; a restart may "
                                        "sign below what the GCS has seen, and the GCS would refuse it")
            else:
                self.get_logger().info("MAVLink signing timestamp stored again")
            self._signing_store_error = store_error
        if lost:
            self.drop(f"{lost} MAVLink frame(s) not sent to '{connection}': {link.last_error}", count=lost, kind="mavlink")

    def destroy_node(self):
        self._bridge.close()
        super().destroy_node()


def main(args=None) -> int:
    return run_node(GcsBridgeNode, args)


if __name__ == "__main__":
    sys.exit(main())
