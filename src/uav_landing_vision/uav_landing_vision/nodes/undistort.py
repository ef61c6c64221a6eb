"""``undistort``: ``camera/image_raw`` → ``camera/image_rect`` by the calibrated lens model (3.16)–(3.17).

Subscribes ``camera/image_raw`` and ``camera/camera_info``; publishes
``camera/image_rect`` (same header, same encoding) and, with the same header,
``camera/camera_info_rect`` (same K, zero distortion). The remap tables are built once per
distinct calibration. Parameters (``config/undistort.yaml``):

- ``interpolation``: ``nearest`` | ``linear`` | ``cubic``.
- ``camera_info_file``: a camera_info YAML (``config/camera.yaml`` form) for cameras that
  publish no ``camera_info``; when set, the node uses it and does not subscribe to
  ``camera/camera_info``. Relative paths are relative to the working directory.
- ``camera_qos``: ``reliable`` (the graph's image QoS, ``qos.IMAGE_QOS``) or ``sensor_data``
  (best effort, to accept a camera driver that publishes best effort; frames may be lost).
- ``image_transport``: ``raw`` (``camera/image_raw``, ``sensor_msgs/Image``) or ``compressed``
  (``camera/image_raw/compressed``, ``sensor_msgs/CompressedImage``, JPEG or PNG as
  ``image_transport``'s compressed plugin sends them; published rectified as ``bgr8``, or
  ``mono8`` for a grey camera).

Images that come before the first usable calibration are held (the newest :data:`HELD_IMAGES`)
and rectified once it comes: a camera_info may arrive a moment after the image it was sent with.
Dropped (logged, counted on ``/diagnostics``): held images beyond those, images whose size
differs from the calibration's, unsupported encodings, malformed or undecodable data, and unusable
``camera_info`` messages (the previous calibration stays in use).
"""

import sys
from collections import deque
from dataclasses import dataclass
from typing import Literal

import cv2
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from ..camera import CameraInfoError, camera_info_fields, load_camera_info_yaml
from ..config import ConfigError
from .base import LandingNode, run_node
from .calibration import Calibration
from .image import ImageError, compressed_to_numpy, image_to_numpy, numpy_to_image
from .qos import IMAGE_QOS, SENSOR_QOS

HELD_IMAGES = 5  # images kept while no calibration is usable, as many as the image QoS keeps
_INTERPOLATION = {"nearest": cv2.INTER_NEAREST, "linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}


@dataclass(frozen=True)
class UndistortConfig:
    interpolation: Literal["nearest", "linear", "cubic"] = "linear"
    camera_info_file: str = ""  # calibration YAML used instead of the camera_info topic; "" = topic
    camera_qos: Literal["reliable", "sensor_data"] = "reliable"  # QoS of the two input subscriptions
    image_transport: Literal["raw", "compressed"] = "raw"  # camera/image_raw, or camera/image_raw/compressed


class Undistort(LandingNode):
    def __init__(self, **kwargs):
        super().__init__("undistort", **kwargs)
        self.config = self.load_config(UndistortConfig)
        self._camera = None
        self._maps = None
        self._calibration = Calibration()
        self._uncalibrated = deque()  # (image,) received before a usable calibration, oldest first
        self._image_pub = self.create_publisher(Image, "camera/image_rect", IMAGE_QOS)
        self._info_pub = self.create_publisher(CameraInfo, "camera/camera_info_rect", IMAGE_QOS)
        camera_qos = IMAGE_QOS if self.config.camera_qos == "reliable" else SENSOR_QOS
        if self.config.camera_info_file:
            try:
                self._use_camera(load_camera_info_yaml(self.config.camera_info_file))
            except CameraInfoError as exc:
                raise ConfigError(f"camera_info_file: {exc}") from exc
        else:
            self.create_subscription(CameraInfo, "camera/camera_info", self._on_camera_info, camera_qos)
        if self.config.image_transport == "compressed":
            self.create_subscription(CompressedImage, "camera/image_raw/compressed", self._on_image, camera_qos)
        else:
            self.create_subscription(Image, "camera/image_raw", self._on_image, camera_qos)

    def _use_camera(self, camera) -> None:
        try:
            maps = camera.undistortion_maps()
            if self.config.interpolation == "nearest":  # on fixed-point maps OpenCV's nearest takes the
                maps = cv2.convertMaps(*maps, cv2.CV_32FC1)  # next pixel half the time (opencv#24106)
        except (cv2.error, MemoryError) as exc:
            raise CameraInfoError(f"cannot build the {camera.width}x{camera.height} remap tables: {exc}") from exc
        self._camera, self._maps = camera, maps
        self._rect_info = camera_info_fields(camera.rectified())
        self.get_logger().info(
            f"calibration {camera.width}x{camera.height}, fx={camera.fx:.1f} fy={camera.fy:.1f}, "
            f"{camera.distortion_model} distortion {camera.dist.tolist()}: remap tables built"
        )

    def _on_camera_info(self, msg: CameraInfo) -> None:
        self.counters["camera_info_received"] += 1
        if self.take_camera_info(self._calibration, msg, use=self._use_camera):
            held, self._uncalibrated = self._uncalibrated, deque()
            for (image,) in held:
                self._rectify(image)

    def _on_image(self, msg: Image | CompressedImage) -> None:
        self.counters["received"] += 1
        if self._camera is None:
            self.hold(self._uncalibrated, (msg,), HELD_IMAGES, self._calibration.waiting_for("no usable camera_info"))
            return
        self._rectify(msg)

    def _rectify(self, msg: Image | CompressedImage) -> None:
        camera = self._camera
        try:
            if isinstance(msg, CompressedImage):
                raw, encoding = compressed_to_numpy(msg, (camera.width, camera.height))
            else:
                raw, encoding = image_to_numpy(msg), msg.encoding
        except ImageError as exc:
            self.drop(str(exc))
            return
        height, width = raw.shape[:2]
        if (width, height) != (camera.width, camera.height):
            self.drop(f"image is {width}x{height} but the calibration is {camera.width}x{camera.height}")
            return
        rect = cv2.remap(raw, *self._maps, _INTERPOLATION[self.config.interpolation])
        self._image_pub.publish(numpy_to_image(rect, encoding, msg.header))
        self._info_pub.publish(CameraInfo(header=msg.header, **self._rect_info))
        self.counters["published"] += 1


def main(args=None) -> int:
    return run_node(Undistort, args)


if __name__ == "__main__":
    sys.exit(main())
