"""``detector``: ``camera/image_rect`` → ``uav/detections`` with the ONNX detector (§4.2).

Subscribes ``camera/image_rect`` (rgb8 or bgr8); publishes ``uav/detections``
(``DetectionArray``, the image's header, detections best first, none when the UAV is not
found). Parameters (``config/detector.yaml``): the ``detection.detector.DetectorConfig`` keys
at the top level, the node's own under ``node``:

- ``node.search_window``: search only around the last tracked pose (``uav/pose``, projected
  with ``camera/camera_info_rect``; window by ``detection.detector.search_window``), and the
  full frame when that window holds nothing or the pose is older than ``node.window_max_age_s``
  (by stamps) or newer than the image.
- ``track_box`` (``detection.track_box.TrackBoxConfig``): in a frame where the network finds
  nothing, publish instead the box of the last tracked pose, grown, with score 0 — a region for
  pose boosting, not a detection; bounded in pose age and in consecutive frames.

A missing or unusable model fails start-up (exit code 2) with the commands that make it;
detections are never made up. Unusable images and poses are logged, counted and dropped.
"""

import math
import sys
from dataclasses import dataclass

from geometry_msgs.msg import PoseWithCovarianceStamped
from sensor_msgs.msg import CameraInfo, Image, RegionOfInterest
from uav_landing_msgs.msg import Detection, DetectionArray

from ..config import ConfigError
from ..detection.detector import Detector, DetectorConfig, search_window
from ..detection.track_box import TrackBox, TrackBoxConfig
from ..model import fixed_wing_mesh
from ..render.boxes import projected_roi
from ..stamps import stamp_ns, within_age
from .base import LandingNode, run_node
from .calibration import Calibration
from .poses import pose_to_numpy
from .qos import IMAGE_QOS, RELIABLE_QOS

MAKE_MODEL = (
    "uav-landing make-detection-data --out out/detection_data && "
    "uav-landing train-detector --data out/detection_data --out out/detector_train && "
    "cp out/detector_train/detector.onnx src/uav_landing_vision/models/detector.onnx, and the verifier with "
    "uav-landing train-verifier (see docs/detector.md)"
)


@dataclass(frozen=True)
class DetectorNodeConfig:
    search_window: bool = False  # search around the last uav/pose first
    window_max_age_s: float = 0.5  # an older pose (image stamp − pose stamp) is not used

    def __post_init__(self):
        if not (math.isfinite(self.window_max_age_s) and self.window_max_age_s > 0.0):
            raise ValueError(f"window_max_age_s must be finite and > 0, got {self.window_max_age_s}")


class DetectorNode(LandingNode):
    def __init__(self, **kwargs):
        super().__init__("detector", **kwargs)
        self.config = self.load_config(DetectorConfig, exclude=("node", "track_box"))
        self.node_config = self.load_config(DetectorNodeConfig, group="node")
        self._vertices = fixed_wing_mesh("high").vertices
        self._track_box = TrackBox(self.load_config(TrackBoxConfig, group="track_box"), self._vertices)
        self._detector = _load_detector(self.config)
        self._pub = self.create_publisher(DetectionArray, "uav/detections", RELIABLE_QOS)
        self.create_subscription(Image, "camera/image_rect", self._on_image, IMAGE_QOS)
        self._calibration, self._pose = Calibration(rectified=True), None
        if self.node_config.search_window or self._track_box.config.enabled:
            self.create_subscription(CameraInfo, "camera/camera_info_rect", self._on_camera_info, IMAGE_QOS)
            self.create_subscription(PoseWithCovarianceStamped, "uav/pose", self._on_pose, RELIABLE_QOS)
        self.get_logger().info(
            f"model {self.config.model}: input {self._detector.input_size}, strides {self._detector.strides}, "
            f"search window {'on' if self.node_config.search_window else 'off'}, "
            f"track box {'on' if self._track_box.config.enabled else 'off'}"
        )

    def _on_camera_info(self, msg: CameraInfo) -> None:
        self.take_camera_info(self._calibration, msg)

    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        try:
            position, quat = pose_to_numpy(msg.pose.pose)
        except ValueError as exc:
            self.drop(f"uav/pose rejected: {exc}")
            return
        self._pose = (stamp_ns(msg.header.stamp), position, quat)
        self._track_box.set_pose(*self._pose)

    def _camera(self, width: int, height: int):
        """The rectified camera, or None before camera_info_rect or when the image is not its size."""
        camera = self._calibration.camera
        return camera if camera is not None and (camera.width, camera.height) == (width, height) else None

    def _window(self, image_stamp_ns: int, width: int, height: int):
        """The search window around the last pose, or None (full frame)."""
        camera, pose = self._camera(width, height), self._pose
        if camera is None or pose is None:
            return None
        if not within_age(image_stamp_ns - pose[0], self.node_config.window_max_age_s):
            return None
        roi = projected_roi(camera, self._vertices, pose[2], pose[1])
        if roi is None:
            return None
        return search_window(roi, width, height, self.config.window_grow, self.config.window_min_px)

    def _on_image(self, msg: Image) -> None:
        if (frame := self.receive_frame(msg)) is None:
            return
        stamp = stamp_ns(msg.header.stamp)
        window = self._window(stamp, msg.width, msg.height) if self.node_config.search_window else None
        dets = self._detector.detect(frame, window)
        if window is not None:
            self.counters["windowed"] += 1
            if not len(dets.scores):
                dets = self._detector.detect(frame)
        rois, scores = dets.rois(msg.width, msg.height), dets.scores
        if len(scores):
            self._track_box.detected()
        else:
            rois, scores = self._track_box_roi(stamp, msg.width, msg.height), [0.0]
        out = DetectionArray(header=msg.header, detections=[
            Detection(roi=RegionOfInterest(x_offset=int(x), y_offset=int(y), width=int(w), height=int(h)), score=float(s))
            for (x, y, w, h), s in zip(rois, scores)
        ])
        self._pub.publish(out)
        self.counters["published"] += 1
        self.counters["detections" if len(dets.scores) else "track_boxes"] += len(out.detections)

    def _track_box_roi(self, image_stamp_ns: int, width: int, height: int) -> list:
        """[the track box] for a frame without detections, or []."""
        camera = self._camera(width, height)
        if camera is None:
            return []
        roi = self._track_box.roi(camera, image_stamp_ns)
        return [] if roi is None else [roi]


def _load_detector(config: DetectorConfig) -> Detector:
    models = f"the detector model '{config.model}'" + (f" or the verifier '{config.verifier}'" if config.verifier else "")
    try:
        return Detector(config)
    except FileNotFoundError as exc:
        raise ConfigError(f"model: {models} is missing ({exc}); make it with: {MAKE_MODEL}") from exc
    except Exception as exc:  # onnxruntime raises its own exception types for unreadable models
        raise ConfigError(f"model: {models} cannot be loaded: {exc}") from exc


def main(args=None) -> int:
    return run_node(DetectorNode, args)


if __name__ == "__main__":
    sys.exit(main())
