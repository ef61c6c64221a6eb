"""``tracker``: rectified frames + pose hypotheses → the UAV's pose (Algorithm 3, ``tracking.upf``).

Subscribes ``camera/image_rect`` (rgb8 or bgr8), ``camera/camera_info_rect`` (the latest
calibration is used) and ``uav/pose_hypotheses``. Publishes, with the image's header:

- ``uav/pose`` (PoseWithCovarianceStamped, the UAV body in the camera optical frame) and
  ``uav/particles`` (PoseArray, best first) — only for frames with an estimate: nothing is
  published when the tracker has none (LOST, nothing scored), never a held pose;
- ``uav/tracker_status`` (TrackerStatus: state, best likelihood, effective particle number,
  milliseconds per stage) for every tracked frame — the acknowledgement ``bag_player`` paces on;
- ``uav/overlay`` (rgb8) with ``node.overlay``: the frame with the estimate's silhouette outline,
  from a DDS participant of its own (``LandingNode.create_image_publisher``).

Matching: an image and its hypotheses are paired by exact ``header.stamp`` (either order,
cache of ``node.cache_size`` stamps). An image waits at most ``node.hypotheses_timeout_s``
for its hypotheses, then is tracked by prediction, unless a newer image has come: frames are
tracked in stamp order, and one superseded by a newer frame (a complete successor, or a newer
image waiting) is skipped and counted (``skipped``), so a camera faster than the tracker builds
no backlog of ever older frames (the motion model then predicts over the gap). Hypotheses whose
image never came while a newer one did (lost from the image queue while the tracker was busy)
count as skipped too. Frames due before the first
calibration are held (``node.cache_size`` of them) and tracked once it comes. A usable image (checked
first: encoding, layout, size) stamped more than 2 s before the last tracked frame starts a new
time-line (a replay or clock started again): the track restarts, where every later frame would
otherwise be dropped as out of order, and the stamps still waiting are dropped and counted. A frame
tracked longer after the last one than the core's prediction reaches (``MAX_PREDICTION_STEPS`` Δt,
~2 s: a camera that stalled) restarts the track too: its carried particles are not of that
frame's time, and its status would say TRACKING on them. Hypotheses without
an image (none newer either), late ones and malformed ones (non-finite, non-unit quaternion: the frame is then
tracked by prediction at once) are logged, counted and dropped. A frame the core cannot step
with the current track (e.g. one started from finite but absurd hypotheses) restarts the track there.

Each message carries M hypotheses; the tracker takes the first ``Tracker.hypotheses_needed()``
(M at (re)initialisation and in C1, M − M0 otherwise). This node owns the process's only
moderngl context (its ``GL_RENDERER`` is logged at start-up). It refuses to start when that
context fails the renderer's self-test (``render.selftest``: silhouettes unlike the shipped
reference's). Parameters: the ``tracker`` section of ``config/tracker.yaml`` (``TrackerConfig``)
and the node's own under ``node`` (given with ``-p node.overlay:=true`` or a second parameter file).
"""

import sys
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

import cv2
import moderngl
import numpy as np
from geometry_msgs.msg import Pose, PoseArray, PoseWithCovarianceStamped
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import CameraInfo, Image
from uav_landing_msgs.msg import PoseHypotheses, TrackerStatus

from ..camera import CameraInfoError
from ..config import ConfigError
from ..model import fixed_wing_mesh
from ..render import Renderer
from ..render.context import GLContextError, gl_context
from ..render.renderer import check_atlas
from ..render.selftest import RendererSelfTestError, check_renderer
from ..stamps import stamp_ns
from ..tracking.upf import MAX_PREDICTION_STEPS, Tracker, TrackerConfig, gap_steps, render_batch
from .base import LandingNode, run_node
from .calibration import Calibration
from .image import numpy_to_image
from .poses import numpy_to_pose, pose_to_numpy
from .qos import IMAGE_QOS, RELIABLE_QOS
from .sync import RESTART_BEHIND_NS, RepeatedStampError, StampCache

DEADLINE_CHECK_S = 0.02
OVERLAY_COLOUR = (0, 255, 0)


@dataclass(frozen=True)
class TrackerNodeConfig:
    hypotheses_timeout_s: float = 1.0  # how long an image waits for its hypotheses
    cache_size: int = 10  # unpaired stamps kept
    overlay: bool = False  # publish uav/overlay

    def __post_init__(self):
        if not self.hypotheses_timeout_s > 0.0 or self.cache_size < 1:
            raise ValueError("need hypotheses_timeout_s > 0 and cache_size >= 1")


class BoostedPoses(NamedTuple):
    """One PoseHypotheses message as the tracker core takes it: ``quats (k,4)``, ``positions (k,3)``."""

    quats: np.ndarray
    positions: np.ndarray


class TrackerNode(LandingNode):
    def __init__(self, **kwargs):
        super().__init__("tracker", **kwargs)
        self.config = self.load_config(TrackerConfig, exclude=("node",))
        self.node_config = self.load_config(TrackerNodeConfig, group="node")
        try:
            ctx = gl_context()
            self_test = check_renderer()
        except (GLContextError, RendererSelfTestError) as exc:
            raise ConfigError(f"OpenGL: {exc}") from exc
        try:  # checked now, not at the first camera_info: a node that can never draw must not start
            check_atlas(ctx, self.config.tile, render_batch(self.config),
                        f"lower particles ({self.config.particles}), refine.candidates "
                        f"({self.config.refine.candidates}) or tile ({self.config.tile})")
        except ValueError as exc:
            raise ConfigError(f"tracker parameters: {exc}") from exc
        self.get_logger().info(f"GL_RENDERER: {ctx.info['GL_RENDERER']}; tracker {self.config.name}, M={self.config.particles}")
        self.get_logger().info(f"renderer self-test {self_test.summary}")
        self._mesh = fixed_wing_mesh("low")
        self._tracker = self._renderer = None
        self._calibration = Calibration(rectified=True)
        self._uncalibrated = deque()  # (image, frame, hypotheses) due before the first calibration
        self._last_stamp = -1
        self._cache = StampCache(("image", "hypotheses"), self.node_config.cache_size)
        self._pose_pub = self.create_publisher(PoseWithCovarianceStamped, "uav/pose", RELIABLE_QOS)
        self._particles_pub = self.create_publisher(PoseArray, "uav/particles", RELIABLE_QOS)
        self._status_pub = self.create_publisher(TrackerStatus, "uav/tracker_status", RELIABLE_QOS)
        self._overlay_pub = self.create_image_publisher(Image, "uav/overlay", IMAGE_QOS) if self.node_config.overlay else None
        self.create_subscription(CameraInfo, "camera/camera_info_rect", self._on_camera_info, IMAGE_QOS)
        self.create_subscription(Image, "camera/image_rect", self._on_image, IMAGE_QOS)
        self.create_subscription(PoseHypotheses, "uav/pose_hypotheses", self._on_hypotheses, RELIABLE_QOS)
        self.create_timer(DEADLINE_CHECK_S, self._on_deadline, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _on_camera_info(self, msg: CameraInfo) -> None:
        self.take_camera_info(self._calibration, msg, use=self._use_camera)

    def _use_camera(self, camera) -> None:
        try:
            renderer = Renderer(camera, self._mesh, tile=self.config.tile, max_batch=render_batch(self.config))
        except (ValueError, moderngl.Error) as exc:
            raise CameraInfoError(f"cannot render at {camera.width}x{camera.height}: {exc}") from exc
        if self._tracker is not None:
            self.get_logger().warn("the calibration changed: the track restarts")
        if self._renderer is not None:
            self._renderer.release()
        self._renderer = renderer
        self._tracker = Tracker(self.config, camera, renderer)
        self.get_logger().info(f"calibration {camera.width}x{camera.height} fx={camera.fx:.1f}: tracker ready")
        held, self._uncalibrated = self._uncalibrated, deque()
        for frame in held:
            self._track(*frame)

    def _on_image(self, msg: Image) -> None:
        if (frame := self.receive_frame(msg)) is None:  # checked first: only a usable frame may start a new time-line
            return
        stamp = stamp_ns(msg.header.stamp)
        if mismatch := self._size_mismatch(msg):
            self.drop(mismatch)
            return
        if self._last_stamp - stamp > RESTART_BEHIND_NS:
            self._restart_time_line(stamp)
        if stamp <= self._last_stamp:
            self.drop(f"image stamped {stamp} ns is not after the last tracked frame ({self._last_stamp} ns)")
            return
        self._add("image", stamp, (msg, frame))

    def _size_mismatch(self, image: Image) -> str:
        """Why ``image`` does not fit the calibration in use, or "" (also without one yet)."""
        if self._renderer is None or (image.width, image.height) == (self._renderer.width, self._renderer.height):
            return ""
        return f"image is {image.width}x{image.height} but the calibration is {self._renderer.width}x{self._renderer.height}"

    def _restart_time_line(self, stamp: int) -> None:
        self.get_logger().warning(
            f"image stamped {stamp} ns is {(self._last_stamp - stamp) * 1e-9:.1f} s before the last tracked frame: "
            "a new time-line (replay or clock restarted?); the track restarts")
        self._last_stamp = -1
        # The new time-line's own hypotheses may have come first: only the old one's entries go.
        if waiting := self._cache.pop_newer(stamp + RESTART_BEHIND_NS):
            self.drop(f"{len(waiting)} stamp(s) of the old time-line still waiting for their pair, not tracked "
                      "(the new time-line started)", count=len(waiting))
        if self._tracker is not None:
            self._tracker.reset()

    def _on_hypotheses(self, msg: PoseHypotheses) -> None:
        self.counters["hypotheses_received"] += 1
        stamp = stamp_ns(msg.header.stamp)
        if 0 <= self._last_stamp - stamp <= RESTART_BEHIND_NS:  # further behind: a new time-line's, before its image
            self.drop(f"hypotheses stamped {stamp} ns arrived after their frame was tracked")
            return
        try:
            poses = [pose_to_numpy(p) for p in msg.poses]
        except ValueError as exc:
            self.drop(f"uav/pose_hypotheses rejected: {exc}")
            poses = []
        boosted = BoostedPoses(np.array([q for _, q in poses]), np.array([p for p, _ in poses])) if poses else None
        self._add("hypotheses", stamp, boosted)

    def _add(self, name: str, stamp: int, item) -> None:
        try:
            entry, evicted = self._cache.add(name, stamp, item)
        except RepeatedStampError as exc:
            self.drop(str(exc))
            return
        for old in evicted:
            self._expire(old)
        if entry is not None:
            for old in self._cache.pop_older(stamp):
                self._expire(old, superseded=True)
            self._track(*entry.items["image"], entry.items["hypotheses"])

    def _on_deadline(self) -> None:
        expired = self._cache.pop_expired(self.node_config.hypotheses_timeout_s)
        newest = max((e.stamp_ns for e in expired if "image" in e.items), default=None)
        for old in expired:
            self._expire(old, superseded=newest is not None and old.stamp_ns < newest)

    def _expire(self, entry, superseded: bool = False) -> None:
        """An entry that will not be completed: its image is tracked by prediction, unless a newer
        frame has come (a camera faster than the tracker): tracking a stale frame would only delay
        that one, and every later one, further. A skipped frame is counted, not tracked. So are
        hypotheses whose image was lost while the tracker was busy (the image queue keeps the
        newest frames); without a newer image either, the image stream has stopped: an error."""
        if superseded or self._cache.has_newer("image", entry.stamp_ns):
            self.counters["skipped"] += 1
            return
        if "image" in entry.items:
            self.counters["without_hypotheses"] += 1
            self.get_logger().warning(
                f"frame stamped {entry.stamp_ns} ns tracked by prediction: no hypotheses within "
                f"{self.node_config.hypotheses_timeout_s:g} s or before the next frame's", throttle_duration_sec=1.0)
            self._track(*entry.items["image"], None)
        else:
            self.drop(f"hypotheses stamped {entry.stamp_ns} ns have no image")

    def _track(self, image: Image, frame: np.ndarray, boosted: BoostedPoses | None) -> None:
        tracker = self._tracker
        if tracker is None:
            self.hold(self._uncalibrated, (image, frame, boosted), self.node_config.cache_size,
                      self._calibration.waiting_for("no camera/camera_info_rect"))
            return
        if mismatch := self._size_mismatch(image):  # a frame held from before this calibration
            self.drop(mismatch)
            return
        stamp = stamp_ns(image.header.stamp)
        if stamp <= self._last_stamp:  # a restart below must never track a frame out of order
            self.drop(f"frame stamped {stamp} ns is not after the last tracked frame ({self._last_stamp} ns)")
            return
        self._restart_after_gap(tracker, stamp)
        try:
            result = tracker.step(frame, stamp, boosted)
        except ValueError as exc:  # a track the core cannot go on with (e.g. absurd hypotheses): start afresh
            self.get_logger().warning(f"frame stamped {stamp} ns: {exc}; the track restarts", throttle_duration_sec=1.0)
            tracker.reset()
            try:
                result = tracker.step(frame, stamp, boosted)
            except ValueError as exc:
                self.drop(f"frame stamped {stamp} ns not tracked: {exc}")
                return
        self._last_stamp = stamp
        header = image.header
        if result.has_pose:
            pose = PoseWithCovarianceStamped(header=header)
            numpy_to_pose(pose.pose.pose, result.position, result.quat)
            pose.pose.covariance = result.covariance.ravel().tolist()
            self._pose_pub.publish(pose)
            self._particles_pub.publish(PoseArray(header=header, poses=[
                numpy_to_pose(Pose(), p, q) for p, q in zip(result.particles.pos, result.particles.quat)
            ]))
            self.counters["published"] += 1
        self._status_pub.publish(TrackerStatus(
            header=header, state=int(result.state), best_likelihood=float(result.best_likelihood),
            effective_particles=float(result.effective_particles),
            stage_names=list(result.stage_ms), stage_ms=[float(v) for v in result.stage_ms.values()],
        ))
        self.counters["tracked"] += 1
        if self._overlay_pub is not None:
            self._overlay_pub.publish(numpy_to_image(self._overlay(frame, result), "rgb8", header))

    def _restart_after_gap(self, tracker: Tracker, stamp: int) -> None:
        """Restart the track if ``stamp`` is further after the last tracked frame than the motion model predicts."""
        dt, gap_ns = self.config.motion.dt, stamp - self._last_stamp
        if self._last_stamp >= 0 and tracker.particles is not None and gap_steps(gap_ns, dt) > MAX_PREDICTION_STEPS:
            self.get_logger().warning(f"frame stamped {stamp} ns comes {gap_ns * 1e-9:.1f} s after the last tracked frame, "
                                      f"beyond the {MAX_PREDICTION_STEPS * dt:.1f} s the motion model predicts: the track restarts")
            tracker.reset()

    def _overlay(self, frame: np.ndarray, result) -> np.ndarray:
        """The frame with the outline of the model at the estimate (the plain frame without one)."""
        out = frame.copy()
        if result.has_pose:
            mask = self._renderer.silhouette_full(result.quat, result.position).astype(np.uint8)
            contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cv2.drawContours(out, contours, -1, OVERLAY_COLOUR, 1)
        return out


def main(args=None) -> int:
    return run_node(TrackerNode, args)


if __name__ == "__main__":
    sys.exit(main())
