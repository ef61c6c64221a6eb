"""Oriented bounding box B = [θ, x, y, w, h] (4.2) of the UAV in a frame or a silhouette.

Convention (image pixels, x right, y down, OpenCV pixel centres): ``w`` is the longer side,
``h`` the shorter, so the aspect ratio R = w/h (4.3) is ≥ 1; ``θ`` is the direction of the
longer side, in degrees from the image x axis towards the image y axis (clockwise on screen),
wrapped to [0, 180) — a box is the same box turned by 180°, so θ is periodic with period 180.
A square's two sides qualify alike: its θ is the one in [0, 90), whichever side OpenCV lists first
(``cv2.minAreaRect``'s angle is in (0°, 90°] in OpenCV 4.6, in [−90°, 0°) in 5.0, so
``cv2.boxPoints`` starts from another corner).
"""

from dataclasses import dataclass
from typing import NamedTuple

import cv2
import numpy as np

THETA_PERIOD_DEG = 180.0
SQUARE_TOL_PX = 1e-3  # sides this close are equal: float32 corner noise is ~1e-4 px in a 1280 px image


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


@dataclass(frozen=True)
class FastConfig:
    """FAST corners (radius-3 Bresenham circle, OpenCV) that outline the UAV in the ROI.

    Non-maximum suppression is off: the box needs the outermost corner pixels, not well-spread
    ones, and suppression drops every corner whose neighbours tie its score.

    ``thresholds`` are tried in turn, highest first (ours; the thesis has one threshold, the
    default): the first whose corners span at least ``min_cover`` of the ROI's longer side gives
    the box, else the one that spans the most. One threshold cannot suit every range: a near
    UAV's wings are wide, smooth and low in contrast against the sea, so at 20 only the fuselage
    and fin give corners (a box a third of the UAV's, a depth (4.5) three times too far), while
    at 8 a far UAV's box takes in waves and clouds. ``(20, 16, 12, 10, 8)`` with ``min_cover``
    0.9 fixes those boxes; in the tracker it trades better translation for more rotation flips
    near the ship (README, "Pose boosting"), so it is not the default.

    ``ladder_max_px`` (ours; 0 = no limit): the thresholds after the first are tried only for a
    ROI whose longer side is at most this many pixels, i.e. for a far UAV; a larger ROI gets
    the first threshold alone.

    ``pixel_extent`` (ours; off, as shipped): the box of the corners' pixel extents, as the
    database's boxes are of their masks' pixels (:func:`obb_from_mask`). Off, the box runs
    through the corner pixels' centres and is a pixel shorter each way than the database's
    measure of the same outline, which biases (4.4) and (4.5) most for a far UAV. In the
    tracker it trades rotation for translation (docs/tracking.md, "The box's pixel extents").
    """

    thresholds: tuple[int, ...] = (20,)
    min_cover: float = 0.9
    min_corners: int = 3
    ladder_max_px: float = 0.0
    pixel_extent: bool = False

    def __post_init__(self):
        if not self.thresholds or not all(0 < t < 256 for t in self.thresholds):
            raise ValueError(f"FAST thresholds must be in 1..255, got {self.thresholds}")
        if list(self.thresholds) != sorted(self.thresholds, reverse=True):
            raise ValueError(f"FAST thresholds must be in decreasing order, got {self.thresholds}")
        if not 0.0 <= self.min_cover <= 1.0:
            raise ValueError(f"min_cover must be in [0, 1], got {self.min_cover}")
        if self.min_corners < 3:
            raise ValueError(f"min_corners must be at least 3, got {self.min_corners}")
        if not (np.isfinite(self.ladder_max_px) and self.ladder_max_px >= 0.0):
            raise ValueError(f"ladder_max_px must be >= 0 (0: no limit), got {self.ladder_max_px}")

    def thresholds_for(self, length_px: float) -> tuple[int, ...]:
        """The thresholds to try for a ROI whose longer side is ``length_px``."""
        if self.ladder_max_px and length_px > self.ladder_max_px:
            return self.thresholds[:1]
        return self.thresholds


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
    if w - h <= SQUARE_TOL_PX:  # a square: either side is "the longer", take the one in [0, 90)
        theta %= THETA_PERIOD_DEG / 2
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
    # The hull of the outer boundary pixels carries the box; grown to pixel extents.
    return obb_from_pixels(cv2.convexHull(np.concatenate(contours)).reshape(-1, 2).astype(np.float32))


def obb_from_pixels(centres: np.ndarray) -> Obb | None:
    """:func:`obb_from_points` of the pixels at ``centres (N, 2)``: each counted to its extent,
    half a pixel each side of its centre."""
    return obb_from_points(np.concatenate([centres + d for d in _PIXEL_CORNERS]))


_PIXEL_CORNERS = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]], dtype=np.float32)


def check_roi(roi, width: int, height: int) -> tuple[int, int, int, int]:
    """Validate a ROI ``(x, y, w, h)`` (sensor_msgs/RegionOfInterest) and clip it to the image."""
    try:
        x, y, w, h = (int(round(float(v))) for v in roi)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an infinite value
        raise ValueError(f"ROI must be four numbers (x, y, width, height), got {roi!r}") from None
    if w <= 0 or h <= 0:
        raise ValueError(f"ROI is empty: {w}x{h}")
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + w, width), min(y + h, height)
    if x1 <= x0 or y1 <= y0:
        raise ValueError(f"ROI {(x, y, w, h)} lies outside the {width}x{height} image")
    return x0, y0, x1 - x0, y1 - y0


def grow_roi(roi, margin: float, pad_px: float, width: int, height: int) -> tuple[int, int, int, int]:
    """ROI ``(x, y, w, h)`` grown by ``margin`` of its size + ``pad_px`` on every side (outward
    to whole pixels) and clipped to the image; validated as :func:`check_roi`."""
    if margin < 0 or pad_px < 0:
        raise ValueError(f"ROI growth must be non-negative, got margin {margin}, pad {pad_px} px")
    x, y, w, h = check_roi(roi, width, height)
    gx, gy = margin * w + pad_px, margin * h + pad_px
    x0, y0 = max(int(np.floor(x - gx)), 0), max(int(np.floor(y - gy)), 0)
    x1, y1 = min(int(np.ceil(x + w + gx)), width), min(int(np.ceil(y + h + gy)), height)
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


def obb_from_frame(image: np.ndarray, roi, config: FastConfig = FastConfig(), margin: float = 0.0,
                   pad_px: float = 0.0) -> Obb | None:
    """Oriented box (4.2) of the FAST corners of a rectified uint8 frame, in full-image pixels,
    taken inside the ROI ``(x, y, w, h)`` grown by ``margin``/``pad_px`` (:func:`grow_roi`); the
    threshold is chosen by ``config`` against the ROI as given. None when too few corners."""
    gray = to_gray(image)
    roi = check_roi(roi, gray.shape[1], gray.shape[0])
    x, y, w, h = grow_roi(roi, margin, pad_px, gray.shape[1], gray.shape[0])
    corners = outline_corners(gray[y : y + h, x : x + w], max(roi[2], roi[3]), config)
    if corners is None:
        return None
    corners = corners + np.array([x, y], dtype=np.float32)
    box = obb_from_points(corners)  # degenerate (under a pixel thick) either way
    if box is None or not config.pixel_extent:
        return box
    return obb_from_pixels(corners)


def outline_corners(gray_roi: np.ndarray, length_px: float, config: FastConfig) -> np.ndarray | None:
    """FAST corners of the first of ``config.thresholds_for(length_px)`` whose corners span (along
    x or y, the longer) at least ``min_cover`` of ``length_px``, else of the widest-spanning one;
    None if no threshold gives ``min_corners``."""
    best, best_span = None, -1.0
    for threshold in config.thresholds_for(length_px):
        corners = fast_corners(gray_roi, threshold)
        if len(corners) < config.min_corners:
            continue
        span = float(np.ptp(corners, axis=0).max())
        if span > best_span:
            best, best_span = corners, span
        if span >= config.min_cover * length_px:
            return corners
    return best
