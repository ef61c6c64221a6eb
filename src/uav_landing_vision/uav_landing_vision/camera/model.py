"""The deck camera: pinhole intrinsics (3.16) and radial/tangential distortion (3.17).

Distortion models, named and ordered as in ``sensor_msgs/CameraInfo`` (ROS's
``distortion_models.h``) and read as OpenCV reads them:

- ``plumb_bob`` (the thesis's (3.17)): ``[k1, k2, p1, p2, k3]``;
- ``rational_polynomial``: ``[k1, k2, p1, p2, k3, k4, k5, k6]``, the radial factor
  ``(1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)`` (OpenCV's 8-coefficient model);
- ``equidistant`` (fisheye): ``[k1, k2, k3, k4]``, ``θ_d = θ (1 + k1 θ² + k2 θ⁴ + k3 θ⁶ + k4 θ⁸)``
  with θ the ray's angle to the optical axis (``cv2.fisheye``).

Image coordinates are OpenCV's: ``(u, v)`` with integer values at pixel centres, u to the
right, v down.
"""

from dataclasses import dataclass, field

import cv2
import numpy as np

DEFAULT_FRAME_ID = "camera_optical_frame"
MIN_FOV_DEG, MAX_FOV_DEG = 0.01, 179.0  # per axis, 2 atan(side / 2f): beyond them K is not a lens's
MAX_IMAGE_SIDE = 16384  # px; larger than any deck camera, and GL's usual renderbuffer limit
# Coefficient counts of each distortion model; plumb_bob also takes none or 4 (k3 = 0).
DISTORTION_MODELS = {"plumb_bob": 5, "rational_polynomial": 8, "equidistant": 4}
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)


@dataclass(frozen=True)
class CameraModel:
    """A calibrated camera; immutable. ``K`` is the 3×3 intrinsic matrix (zero skew), ``dist`` the
    coefficients of ``distortion_model`` (module docstring)."""

    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    frame_id: str = DEFAULT_FRAME_ID
    distortion_model: str = "plumb_bob"

    def __post_init__(self):
        K = np.array(self.K, dtype=float)
        dist = np.array(self.dist, dtype=float).ravel()
        if not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) for n in (self.width, self.height)):
            raise ValueError(f"camera width/height must be integers, got {self.width!r}, {self.height!r}")
        if not (0 < self.width <= MAX_IMAGE_SIDE and 0 < self.height <= MAX_IMAGE_SIDE):
            raise ValueError(f"camera size must be 1..{MAX_IMAGE_SIDE} px a side, got {self.width}x{self.height}")
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise ValueError("camera matrix K must be a finite 3x3 matrix")
        if K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
            raise ValueError(f"camera matrix K is not an intrinsic matrix [[fx,s,cx],[0,fy,cy],[0,0,1]]: {K.tolist()}")
        if K[0, 1] != 0:  # OpenCV's undistortion (points and remap tables) ignores it
            raise ValueError(f"camera matrix K has skew {K[0, 1]}; only zero skew is supported (as in plumb_bob)")
        if not (0 <= K[0, 2] <= self.width and 0 <= K[1, 2] <= self.height):
            raise ValueError(f"principal point ({K[0, 2]:g}, {K[1, 2]:g}) lies outside the {self.width}x{self.height} image")
        fov = np.degrees(2 * np.arctan2([self.width / 2, self.height / 2], [K[0, 0], K[1, 1]]))
        if not np.all((MIN_FOV_DEG <= fov) & (fov <= MAX_FOV_DEG)):
            raise ValueError(f"focal lengths fx = {K[0, 0]:g}, fy = {K[1, 1]:g} px give a {fov[0]:.3g}° x {fov[1]:.3g}° "
                             f"field of view (read as a pinhole's), outside {MIN_FOV_DEG}..{MAX_FOV_DEG}°")
        model = self.distortion_model
        if model not in DISTORTION_MODELS:
            raise ValueError(f"distortion model {model!r} is not one of {sorted(DISTORTION_MODELS)}")
        if model == "plumb_bob" and dist.size in (0, 4):  # none (as ROS's image_geometry reads an empty D), or k3 = 0
            dist = np.append(dist, np.zeros(5 - dist.size))
        if dist.size == 0:
            dist = np.zeros(DISTORTION_MODELS[model])
        if dist.size != DISTORTION_MODELS[model] or not np.all(np.isfinite(dist)):
            counts = "0, 4 or 5" if model == "plumb_bob" else f"0 or {DISTORTION_MODELS[model]}"
            raise ValueError(f"distortion must be {counts} finite {model} coefficients, got {dist.tolist()}")
        K.setflags(write=False)
        dist.setflags(write=False)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def is_distorted(self) -> bool:
        """Whether the raw image differs from the pinhole one: any coefficient, or the equidistant
        projection, which is not the pinhole's even with none."""
        return self._fisheye or bool(np.any(self.dist != 0.0))

    def rectified(self) -> "CameraModel":
        """The camera of the undistorted image: same intrinsics, no distortion."""
        return CameraModel(self.width, self.height, self.K, np.zeros(5), self.frame_id)

    @property
    def _fisheye(self) -> bool:
        return self.distortion_model == "equidistant"

    def project_pinhole(self, points_cam: np.ndarray) -> np.ndarray:
        """Pinhole projection (3.16) of camera-frame points ``(..., 3)`` to pixels ``(..., 2)``, no distortion."""
        return self._to_pixels(_normalised(points_cam))

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Projection with lens distortion (3.16)–(3.17): camera-frame points ``(..., 3)`` → raw-image pixels."""
        return self._to_pixels(self.distort_normalised(_normalised(points_cam)))

    def distort_normalised(self, xy: np.ndarray) -> np.ndarray:
        """Lens distortion of normalised image coordinates ``(..., 2)`` by the camera's model."""
        if self._fisheye:
            return _equidistant(xy, self.dist)
        return _radial_tangential(xy, *self.dist)

    def backproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Camera-frame points at ``depth`` (Z, metres) of rectified-image pixels ``uv (..., 2)``."""
        uv = np.asarray(uv, dtype=float)
        depth = np.asarray(depth, dtype=float)
        y = (uv[..., 1] - self.cy) / self.fy
        x = (uv[..., 0] - self.cx - self.K[0, 1] * y) / self.fx
        return np.stack([x * depth, y * depth, np.broadcast_to(depth, x.shape)], axis=-1)

    def undistort_points(self, uv: np.ndarray) -> np.ndarray:
        """Raw-image pixels ``(..., 2)`` → rectified-image pixels (same K), by OpenCV's iterative inverse."""
        uv = np.asarray(uv, dtype=float)
        flat = uv.reshape(-1, 1, 2)
        if self._fisheye:
            out = cv2.fisheye.undistortPoints(flat, self.K, self.dist, R=np.eye(3), P=self.K)
        elif hasattr(cv2, "undistortPointsIter"):  # OpenCV 4 (Ubuntu 24.04's python3-opencv is 4.6)
            out = cv2.undistortPointsIter(flat, self.K, self.dist, None, self.K, _CRITERIA)
        else:  # OpenCV 5 takes the criteria in undistortPoints itself
            out = cv2.undistortPoints(flat, self.K, self.dist, R=None, P=self.K, criteria=_CRITERIA)
        return out.reshape(uv.shape)

    def undistortion_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` maps from the raw image to the rectified image (same K, no rectification rotation)."""
        size = (self.width, self.height)
        if self._fisheye:
            return cv2.fisheye.initUndistortRectifyMap(self.K, self.dist, np.eye(3), self.K, size, cv2.CV_16SC2)
        return cv2.initUndistortRectifyMap(self.K, self.dist, None, self.K, size, cv2.CV_16SC2)

    def distortion_maps(self) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap`` float maps that turn a rectified image into the raw (distorted) image.

        For each raw pixel they give the rectified pixel it sees: :meth:`undistort_points`, OpenCV's
        iterative inversion of the lens model.
        """
        u, v = np.meshgrid(np.arange(self.width, dtype=float), np.arange(self.height, dtype=float))
        rect = self.undistort_points(np.stack([u, v], axis=-1))
        return rect[..., 0].astype(np.float32), rect[..., 1].astype(np.float32)

    def _to_pixels(self, xy: np.ndarray) -> np.ndarray:
        x, y = xy[..., 0], xy[..., 1]
        return np.stack(
            [self.fx * x + self.K[0, 1] * y + self.cx, self.fy * y + self.cy], axis=-1
        )


def _radial_tangential(xy, k1, k2, p1, p2, k3, k4=0.0, k5=0.0, k6=0.0) -> np.ndarray:
    """Radial and tangential distortion (3.17) of normalised coordinates ``(..., 2)``; with k4–k6
    the radial factor is OpenCV's rational one (ours: the thesis's lens needs none)."""
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def _equidistant(xy, dist) -> np.ndarray:
    """Equidistant (fisheye) distortion of normalised coordinates ``(..., 2)``, as ``cv2.fisheye``."""
    k1, k2, k3, k4 = dist
    r = np.hypot(xy[..., 0], xy[..., 1])
    theta = np.arctan(r)
    t2 = theta * theta
    theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
    scale = np.divide(theta_d, r, out=np.ones_like(r), where=r > 1e-12)  # the centre maps to itself
    return xy * scale[..., None]


def _normalised(points_cam: np.ndarray) -> np.ndarray:
    points_cam = np.asarray(points_cam, dtype=float)
    if points_cam.shape[-1] != 3:
        raise ValueError(f"points must have shape (..., 3), got {points_cam.shape}")
    z = points_cam[..., 2:3]
    if np.any(z <= 0.0):
        raise ValueError("cannot project points at or behind the camera (Z <= 0)")
    return points_cam[..., :2] / z
