"""Frame synthesis: shaded UAV over the background, motion blur, lens distortion, sensor noise.

The scene is drawn as the rectified pinhole image of a slightly larger "render camera" (same
focal lengths, padded so that every raw pixel's ray falls inside it), then warped to the raw
image of the configured camera with the distortion model (3.17), so undistortion has real
work to do and no border pixel is invented.
"""

import cv2
import numpy as np

from ..camera import CameraModel
from .config import ImagingConfig


def render_camera_for(camera: CameraModel) -> tuple[CameraModel, np.ndarray, np.ndarray]:
    """The padded rectified camera and the ``cv2.remap`` maps (raw pixel → render-camera pixel)."""
    mx, my = camera.distortion_maps()
    left = max(0, int(np.ceil(-mx.min())) + 2)
    top = max(0, int(np.ceil(-my.min())) + 2)
    right = max(0, int(np.ceil(mx.max() - (camera.width - 1))) + 2)
    bottom = max(0, int(np.ceil(my.max() - (camera.height - 1))) + 2)
    K = camera.K.copy()
    K[0, 2] += left
    K[1, 2] += top
    padded = CameraModel(camera.width + left + right, camera.height + top + bottom, K, np.zeros(5), camera.frame_id)
    return padded, mx + np.float32(left), my + np.float32(top)


def motion_blur_kernel(shift_px: np.ndarray) -> np.ndarray | None:
    """Normalised line kernel along ``shift_px`` (2,), or None below one pixel of smear."""
    length = float(np.hypot(*shift_px))
    if length < 1.0:
        return None
    size = 2 * int(np.ceil(length / 2)) + 1
    kernel = np.zeros((size, size), np.float32)
    c = size // 2
    d = np.asarray(shift_px, float) / 2
    ends = [(round((c - d[0]) * 16), round((c - d[1]) * 16)), (round((c + d[0]) * 16), round((c + d[1]) * 16))]
    cv2.line(kernel, ends[0], ends[1], 1.0, thickness=1, lineType=cv2.LINE_AA, shift=4)
    return kernel / kernel.sum()


class FrameSynthesizer:
    """Turns (background, pose) into the raw camera frame; one renderer for the whole sequence,
    released on leaving a ``with`` block."""

    def __init__(self, camera: CameraModel, imaging: ImagingConfig, mesh=None):
        from ..model import fixed_wing_mesh
        from ..render import Renderer

        self.camera, self.imaging = camera, imaging
        self.render_camera, mx, my = render_camera_for(camera)
        self.map1, self.map2 = cv2.convertMaps(mx, my, cv2.CV_16SC2)
        self.renderer = Renderer(self.render_camera, mesh if mesh is not None else fixed_wing_mesh("high"))

    def __enter__(self) -> "FrameSynthesizer":
        return self

    def __exit__(self, *exc) -> None:
        self.renderer.release()

    def frame(self, background: np.ndarray, quat, trans, light_dir, blur_shift_px, rng: np.random.Generator):
        """Raw RGB uint8 frame and the UAV's coverage (alpha) in the raw image.

        ``background`` is drawn for :attr:`render_camera`; ``light_dir`` points to the sun in the
        camera optical frame; ``blur_shift_px`` is the UAV's smear during the exposure (2,).
        """
        im = self.imaging
        rgb, alpha = self.renderer.shaded(quat, trans, background, albedo=im.albedo, light_dir=light_dir,
                                          samples=im.samples)
        kernel = motion_blur_kernel(blur_shift_px)
        if kernel is not None:  # blur the UAV layer only (premultiplied), then composite again
            bg = background.astype(np.float32)
            layer = rgb.astype(np.float32) - (1.0 - alpha[..., None]) * bg
            layer = cv2.filter2D(layer, -1, kernel, borderType=cv2.BORDER_CONSTANT)
            alpha = cv2.filter2D(alpha, -1, kernel, borderType=cv2.BORDER_CONSTANT)
            rgb = np.clip(layer + (1.0 - alpha[..., None]) * bg + 0.5, 0, 255).astype(np.uint8)
        return self.sensor(rgb, rng), cv2.remap(alpha, self.map1, self.map2, cv2.INTER_LINEAR)

    def sensor(self, scene: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The raw frame (lens distortion, sensor noise) of a scene drawn for :attr:`render_camera`."""
        raw = cv2.remap(scene, self.map1, self.map2, cv2.INTER_LINEAR)
        if self.imaging.noise_sigma > 0:
            noise = rng.standard_normal(raw.shape, dtype=np.float32) * np.float32(self.imaging.noise_sigma)
            raw = np.clip(raw + noise + 0.5, 0, 255).astype(np.uint8)
        return raw
