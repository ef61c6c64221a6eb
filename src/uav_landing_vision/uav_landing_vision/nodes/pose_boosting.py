"""``pose_boosting``: rectified frame + detections → ``uav/pose_hypotheses`` (§4.3).

Subscribes ``camera/image_rect`` (rgb8 or bgr8), ``uav/detections`` (DetectionArray) and
``camera/camera_info_rect`` (the latest calibration is used); publishes
``uav/pose_hypotheses`` (PoseHypotheses, the image's header): the poses of the best detection's
ROI in the camera optical frame, best first, with their (4.4) distances and the observed OBB;
no poses (and a zero OBB) when there is no detection or no box in it, so that the tracker
tracks that frame by prediction. No GL context: the pose database is loaded once at start-up.

Matching: image and detections are paired by exact ``header.stamp`` in a cache of
``node.cache_size`` stamps, in either order of arrival (pairs complete before a calibration the
database matches are held, as many, until one comes); when it overflows, the oldest
unpaired entry is dropped and counted, and so are the waiting entries more than 2 s after a new
message's stamp (a replay started again). A pair completes every entry older than it: a frame
the detector skipped (slower than the camera), or detections whose image left this node's queue
unread, is counted (``skipped``), not dropped.

Hypothesis count: every message carries M = ``particles`` poses
(``HypothesisConfig.count(first_frame=True)``); the tracker takes the first M (at
(re)initialisation, C1) or M − M0 it needs, so this node keeps no track state and a lost
message cannot desynchronise the two. ``kept`` (M0) is only checked (0 ≤ M0 < M).

Parameters (``config/pose_boosting.yaml``): the ``boosting.HypothesisConfig`` keys at the top
level, the node's own under ``node``. A missing or corrupt database fails start-up (exit code 2);
a calibration the database was not made for is logged and its frames dropped.
"""

import math
import sys
from collections import deque
from dataclasses import dataclass

import numpy as np
from geometry_msgs.msg import Pose
from sensor_msgs.msg import CameraInfo, Image
from uav_landing_msgs.msg import DetectionArray, OrientedBox, PoseHypotheses

from ..boosting import DatabaseError, HypothesisConfig, PoseDatabase, PoseHypothesisGenerator
from ..boosting.obb import check_roi
from ..config import ConfigError
from ..resources import model_file
from ..stamps import stamp_ns
from .base import LandingNode, run_node
from .calibration import Calibration
from .poses import numpy_to_pose
from .qos import IMAGE_QOS, RELIABLE_QOS
from .sync import RESTART_BEHIND_NS, RepeatedStampError, StampCache

LOGGED_REASONS = 3  # the reasons of the first unusable detections of a message that are logged


@dataclass(frozen=True)
class PoseBoostingNodeConfig:
    cache_size: int = 10  # unpaired stamps kept while waiting for the other message

    def __post_init__(self):
        if self.cache_size < 1:
            raise ValueError(f"cache_size must be at least 1, got {self.cache_size}")


class PoseBoostingNode(LandingNode):
    def __init__(self, **kwargs):
        super().__init__("pose_boosting", **kwargs)
        self.config = self.load_config(HypothesisConfig, exclude=("node",))
        self.node_config = self.load_config(PoseBoostingNodeConfig, group="node")
        self._database = _load_database(self.config)
        self._generator = None
        self._calibration = Calibration(rectified=True)
        self._uncalibrated = deque()  # (image, frame, detections) paired before a usable calibration
        self._cache = StampCache(("image", "detections"), self.node_config.cache_size, RESTART_BEHIND_NS)
        self._pub = self.create_publisher(PoseHypotheses, "uav/pose_hypotheses", RELIABLE_QOS)
        self.create_subscription(CameraInfo, "camera/camera_info_rect", self._on_camera_info, IMAGE_QOS)
        self.create_subscription(Image, "camera/image_rect", self._on_image, IMAGE_QOS)
        self.create_subscription(DetectionArray, "uav/detections", self._on_detections, RELIABLE_QOS)
        self.get_logger().info(
            f"pose database {len(self._database.quats)} entries at {self._database.distance:g} m; "
            f"{self.config.count(first_frame=True)} hypotheses per frame"
        )

    def _on_camera_info(self, msg: CameraInfo) -> None:
        if not self.take_camera_info(self._calibration, msg):
            return
        camera = self._calibration.camera
        try:
            self._generator = PoseHypothesisGenerator(self._database, camera, self.config)
        except DatabaseError as exc:
            self._generator = None
            self.drop(f"camera_info rejected: {exc}")
            return
        self.get_logger().info(f"calibration {msg.width}x{msg.height} fx={camera.fx:.1f}: pose database matches")
        held, self._uncalibrated = self._uncalibrated, deque()
        for pair in held:
            self._boost(*pair)

    def _on_image(self, msg: Image) -> None:
        if (frame := self.receive_frame(msg)) is None:
            return
        self._add("image", msg.header, (msg, frame))

    def _on_detections(self, msg: DetectionArray) -> None:
        self.counters["detections_received"] += 1
        self._add("detections", msg.header, msg)

    def _add(self, name: str, header, item) -> None:
        try:
            entry, evicted = self._cache.add(name, stamp_ns(header.stamp), item)
        except RepeatedStampError as exc:
            self.drop(str(exc))
            return
        for old in evicted:
            missing = "detections" if "image" in old.items else "image"
            self.drop(f"no {missing} with stamp {old.stamp_ns} ns within {self._cache.size} stamps")
        if entry is not None:
            # Both inputs arrive in stamp order: an older entry's other message is not coming. The
            # detector skipped that frame, or its image left this node's queue unread (slower than the camera).
            self.counters["skipped"] += len(self._cache.pop_older(entry.stamp_ns))
            self._boost(*entry.items["image"], entry.items["detections"])

    def _best_roi(self, detections: DetectionArray, width: int, height: int):
        """The ROI of the highest-scoring usable detection, or None. The unusable ones are each
        counted as dropped but logged in one line: rclpy's logger takes ~0.3 ms a call."""
        best, unusable, reasons = None, 0, []
        for i, det in enumerate(detections.detections):
            try:
                roi = _usable_roi(det, width, height)
            except ValueError as exc:
                unusable += 1
                if len(reasons) < LOGGED_REASONS:
                    reasons.append(f"detection {i}: {exc}")
                continue
            if best is None or det.score > best[0]:
                best = (det.score, roi)
        if unusable:
            more = f"; and {unusable - len(reasons)} more" if unusable > len(reasons) else ""
            self.drop(f"{unusable} unusable detection{'s' if unusable > 1 else ''} of stamp "
                      f"{stamp_ns(detections.header.stamp)} ns: {'; '.join(reasons)}{more}", count=unusable)
        return None if best is None else best[1]

    def _boost(self, image: Image, frame: np.ndarray, detections: DetectionArray) -> None:
        if self._generator is None:
            self.hold(self._uncalibrated, (image, frame, detections), self.node_config.cache_size,
                      self._calibration.waiting_for("no calibration the pose database matches (camera/camera_info_rect)"))
            return
        roi = self._best_roi(detections, image.width, image.height)
        try:
            hyps = None if roi is None else self._generator.generate(frame, roi, count=self.config.count(first_frame=True))
        except ValueError as exc:
            self.drop(str(exc))
            return
        out = PoseHypotheses(header=image.header)
        if hyps is not None:
            theta = math.radians(hyps.obb.theta)
            out.obb = OrientedBox(center_x=hyps.obb.x, center_y=hyps.obb.y, width=hyps.obb.w, height=hyps.obb.h,
                                  angle=theta - math.pi if theta >= math.pi / 2 else theta)
            quats = hyps.quats / np.linalg.norm(hyps.quats, axis=1, keepdims=True)
            out.poses = [numpy_to_pose(Pose(), p, q) for p, q in zip(hyps.positions, quats)]
            out.distances = hyps.distances.astype(float).tolist()
        self._pub.publish(out)
        self.counters["published"] += 1
        self.counters["without_hypotheses"] += hyps is None


def _usable_roi(det, width: int, height: int) -> tuple[int, int, int, int]:
    """The ROI of detection ``det`` clipped to the image; ValueError if its score or box is unusable."""
    if not (math.isfinite(det.score) and 0.0 <= det.score <= 1.0):
        raise ValueError(f"score {det.score} is not in [0, 1]")
    r = det.roi
    return check_roi((r.x_offset, r.y_offset, r.width, r.height), width, height)


def _load_database(config: HypothesisConfig) -> PoseDatabase:
    try:
        return PoseDatabase.load(model_file(config.database), aspect_weight=config.aspect_weight)
    except FileNotFoundError as exc:
        raise ConfigError(f"database: {exc}; make it with `uav-landing build-database --camera <camera_info YAML>`") from exc
    except DatabaseError as exc:  # its message says what to do
        raise ConfigError(f"database: {exc}") from exc


def main(args=None) -> int:
    return run_node(PoseBoostingNode, args)


if __name__ == "__main__":
    sys.exit(main())
