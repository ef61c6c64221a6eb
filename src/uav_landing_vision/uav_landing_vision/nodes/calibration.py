"""Calibration from ``sensor_msgs/CameraInfo``, parsed and validated once per distinct calibration."""

from ..camera import CameraInfoError, CameraModel, camera_from_info_msg


class Calibration:
    """The camera of the latest valid camera_info message. With ``rectified`` (``camera_info_rect``)
    one with distortion is refused: the nodes on rectified images use K alone."""

    def __init__(self, rectified: bool = False):
        self.camera: CameraModel | None = None
        self.rectified = rectified
        self.refused = ""  # why the latest camera_info was refused; "" once one is taken or repeated
        self._key = None

    def update(self, msg, use=None) -> bool:
        """True when ``msg`` carries a new calibration, now in :attr:`camera`.

        A repeat of the current calibration costs a tuple comparison; an invalid one raises
        :class:`~uav_landing_vision.camera.CameraInfoError` and leaves the current camera as is.
        ``use(camera)``, when given, switches the node to the new camera before it is taken; if
        it raises CameraInfoError the current camera stays, and a repeat of ``msg`` is tried again.
        """
        roi = msg.roi
        key = (msg.width, msg.height, msg.distortion_model, tuple(msg.d), tuple(msg.k), tuple(msg.r),
               msg.binning_x, msg.binning_y, roi.x_offset, roi.y_offset, roi.width, roi.height)
        if key == self._key:
            self.refused = ""
            return False
        try:
            camera = self._camera(msg, use)
        except CameraInfoError as exc:
            self.refused = str(exc)
            raise
        self._key, self.camera, self.refused = key, camera, ""
        return True

    def waiting_for(self, what: str) -> str:
        """``what`` a frame without a camera waits for, and why the latest camera_info was refused:
        a node logs one drop a second, and its frames' drops could hide the refusal's."""
        return f"{what} (the latest camera_info was refused: {self.refused})" if self.refused else what

    def _camera(self, msg, use) -> CameraModel:
        camera = camera_from_info_msg(msg)
        if self.rectified and camera.is_distorted:
            raise CameraInfoError(f"{camera.distortion_model} distortion {camera.dist.tolist()} in the camera_info "
                                  "of a rectified image (expected none, as undistort's camera/camera_info_rect has)")
        if use is not None:
            use(camera)
        return camera
