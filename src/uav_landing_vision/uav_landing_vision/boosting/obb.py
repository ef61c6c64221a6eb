"""Oriented bounding box B = [θ, x, y, w, h] (4.2) of the UAV in a frame or a silhouette.

Convention (image pixels, x right, y down, OpenCV pixel centres): ``w`` is the longer side,
``h`` the shorter, so the aspect ratio R = w/h (4.3) is ≥ 1; ``θ`` is the direction of the
longer side, in degrees from the image x axis towards the image y axis (clockwise on screen),
wrapped to [0, 180) — a box is the same box turned by 180°, so θ is periodic with period 180.
"""

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

THETA_PERIOD_DEG = 180.0


class Obb(NamedTuple):
    """An oriented box (4.2): angle (deg), centre (px), long side w and short side h (px)."""

    theta: float
    x: float
    y: float
    w: float
    h: float

    @property
    def aspect(self) -> float:
        return aspect_ratio(self.w, self.h)

    @property
    def area(self) -> float:
        return self.w * self.h


CUES = ("border", "fast")


@dataclass(frozen=True)
class ObbConfig:
    """Which image cue gives the box inside the ROI, and its thresholds.

    ``fast`` (the thesis): FAST corners (radius-3 Bresenham circle, OpenCV) with intensity
    ``fast_threshold``; non-maximum suppression off, as the box needs the outermost corner
    pixels and suppression drops corners whose neighbours tie their score. ``border`` (default,
    better on the simulator — see ``models/README.md``): the pixels that differ by more than
    ``border_threshold`` from the background interpolated from the ROI border (:func:`border_foreground`).
    """

    cue: str = "border"
    fast_threshold: int = 20
    border_threshold: float = 20.0
    min_points: int = 3

    def __post_init__(self):
        if self.cue not in CUES:
            raise ValueError(f"OBB cue must be one of {CUES}, got {self.cue!r}")
        if not 0 < self.fast_threshold < 256:
            raise ValueError(f"fast_threshold must be in 1..255, got {self.fast_threshold}")
        if not 0 < self.border_threshold < 255:
            raise ValueError(f"border_threshold must be in (0, 255), got {self.border_threshold}")
        if self.min_points < 3:
            raise ValueError(f"min_points must be at least 3, got {self.min_points}")


def aspect_ratio(w, h):
    """Aspect ratio R = w/h (4.3) of boxes (scalars or arrays)."""
    return np.divide(w, h)


def obb_from_points(points: np.ndarray) -> Obb | None:
    """Minimum-area oriented box (4.2) of 2-D points ``(N, 2)``; None if degenerate (< 1 px thick)."""
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 2)
    if len(pts) < 3:
        return None
    (cx, cy), _, _ = rect = cv2.minAreaRect(pts)
    corners = cv2.boxPoints(rect).astype(float)
    e1, e2 = corners[1] - corners[0], corners[2] - corners[1]
    l1, l2 = float(np.hypot(*e1)), float(np.hypot(*e2))
    (long_edge, w), h = ((e1, l1), l2) if l1 >= l2 else ((e2, l2), l1)
    if h < 1.0:
        return None
    theta = float(np.degrees(np.arctan2(long_edge[1], long_edge[0]))) % THETA_PERIOD_DEG
    return Obb(theta, float(cx), float(cy), w, h)


def obb_from_mask(mask: np.ndarray) -> Obb | None:
    """Oriented box (4.2) of the foreground pixels of a 2-D mask (pixel centres, box grown by
    half a pixel each side so a filled w×h rectangle gives w×h); None if empty or degenerate."""
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {mask.shape}")
    contours, _ = cv2.findContours((mask != 0).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return None
    # The hull of the outer boundary pixels carries the box; grow it to pixel extents.
    hull = cv2.convexHull(np.concatenate(contours)).reshape(-1, 2).astype(np.float32)
    return obb_from_points(np.concatenate([hull + d for d in _PIXEL_CORNERS]))


_PIXEL_CORNERS = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]], dtype=np.float32)


def check_roi(roi, width: int, height: int) -> tuple[int, int, int, int]:
    """Validate a ROI ``(x, y, w, h)`` (sensor_msgs/RegionOfInterest) and clip it to the image."""
    try:
        x, y, w, h = (int(round(float(v))) for v in roi)
    except (TypeError, ValueError):
        raise ValueError(f"ROI must be four numbers (x, y, width, height), got {roi!r}") from None
    if w <= 0 or h <= 0:
        raise ValueError(f"ROI is empty: {w}x{h}")
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + w, width), min(y + h, height)
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"ROI {(x, y, w, h)} lies outside the {width}x{height} image")
    return x0, y0, x1 - x0, y1 - y0


def to_gray(image: np.ndarray) -> np.ndarray:
    """8-bit grayscale of a uint8 grayscale ``(H, W)`` or RGB/RGBA ``(H, W, 3|4)`` frame."""
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise ValueError(f"frame must be uint8, got {image.dtype}")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] in (3, 4):
        return cv2.cvtColor(image[..., :3], cv2.COLOR_RGB2GRAY)
    raise ValueError(f"frame must be (H, W), (H, W, 3) or (H, W, 4), got shape {image.shape}")


def fast_corners(gray_roi: np.ndarray, threshold: int) -> np.ndarray:
    """FAST corners ``(N, 2)`` (x, y pixels) of an 8-bit grayscale image, no non-maximum suppression."""
    detector = cv2.FastFeatureDetector_create(threshold=threshold, nonmaxSuppression=False)
    keypoints = detector.detect(np.ascontiguousarray(gray_roi))
    return np.array([kp.pt for kp in keypoints], dtype=np.float32).reshape(-1, 2)


def border_foreground(image_roi: np.ndarray, threshold: float) -> np.ndarray:
    """Foreground mask of a ROI crop whose border is background: each pixel is compared with the
    background interpolated linearly between the left/right border pixels of its row and between
    the top/bottom border pixels of its column; it is foreground if both differ by more than
    ``threshold`` (max over channels). Smooth sky/sea gradients and a horizon stay background."""
    crop = image_roi.astype(np.float32).reshape(image_roi.shape[0], image_roi.shape[1], -1)
    h, w = crop.shape[:2]
    s = np.linspace(0.0, 1.0, w, dtype=np.float32)[None, :, None]
    t = np.linspace(0.0, 1.0, h, dtype=np.float32)[:, None, None]
    across = crop[:, :1] + (crop[:, -1:] - crop[:, :1]) * s
    down = crop[:1] + (crop[-1:] - crop[:1]) * t
    diff = np.minimum(np.abs(crop - across).max(axis=2), np.abs(crop - down).max(axis=2))
    return (diff > threshold).astype(np.uint8)


def obb_from_frame(image: np.ndarray, roi, config: ObbConfig = ObbConfig()) -> Obb | None:
    """Oriented box (4.2) of the UAV inside the detector ROI ``(x, y, w, h)`` of a rectified
    uint8 frame, in full-image pixels, from the configured cue; None when the cue finds too little."""
    image = np.asarray(image)
    gray = to_gray(image)
    x, y, w, h = check_roi(roi, gray.shape[1], gray.shape[0])
    if config.cue == "fast":
        points = fast_corners(gray[y : y + h, x : x + w], config.fast_threshold)
        box = obb_from_points(points) if len(points) >= config.min_points else None
    else:
        mask = border_foreground(image[y : y + h, x : x + w], config.border_threshold)
        box = obb_from_mask(mask) if np.count_nonzero(mask) >= config.min_points else None
    return None if box is None else box._replace(x=box.x + x, y=box.y + y)
