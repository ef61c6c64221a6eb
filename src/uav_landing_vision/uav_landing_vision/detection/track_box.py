"""The tracked pose's box for the frames in which the network finds no UAV (ours).

Without a box, pose boosting (§4.3) has nothing to work on and the tracker predicts the frame
from its particles alone. The network misses the UAV in 15–36 frames of each simulated landing,
in runs, so the track then coasts furthest exactly where it needs new hypotheses. This
supplies, instead, the box of the model projected at the last published pose, grown by
``grow`` of its size on each side, as a region for boosting: boosting still finds the UAV's
oriented box in the frame's pixels, so the hypotheses come from the image, not from the track.

It feeds the track back into its own input, so it is bounded: only a pose at most ``max_age_s``
old (by stamps) is used, and after ``max_frames`` consecutive frames on track boxes none is
given until the network finds the UAV again. A track that has wandered off the UAV can thus not
keep itself alive on its own boxes for more than ``max_frames`` frames.
"""

from dataclasses import dataclass

import numpy as np

from ..render.boxes import projected_roi
from ..stamps import within_age


@dataclass(frozen=True)
class TrackBoxConfig:
    enabled: bool = True  # as config/detector.yaml: the detector node run without it behaves alike
    grow: float = 0.25  # each side moves out by this fraction of the box's width / height
    max_frames: int = 15  # consecutive frames on track boxes, then none until a detection
    max_age_s: float = 0.5  # a pose older than this (frame stamp − pose stamp) is not used

    def __post_init__(self):
        if not (np.isfinite(self.grow) and 0.0 <= self.grow <= 2.0):
            raise ValueError(f"grow must be in [0, 2], got {self.grow}")
        if self.max_frames < 1:
            raise ValueError(f"max_frames must be at least 1, got {self.max_frames}")
        if not (np.isfinite(self.max_age_s) and self.max_age_s > 0.0):
            raise ValueError(f"max_age_s must be finite and > 0, got {self.max_age_s}")


def grow_roi(roi, grow: float, width: int, height: int) -> tuple[int, int, int, int]:
    """``(x, y, w, h)`` with each side moved out by ``grow`` × w (left, right) or × h (top,
    bottom), rounded to whole pixels and clipped to the ``width`` × ``height`` image."""
    x, y, w, h = roi
    dx, dy = int(round(grow * w)), int(round(grow * h))
    x0, y0 = max(x - dx, 0), max(y - dy, 0)
    x1, y1 = min(x + w + dx, width), min(y + h + dy, height)
    return x0, y0, x1 - x0, y1 - y0


class TrackBox:
    """Feed it the last published pose (:meth:`set_pose`) and every frame's network result: a
    frame with a box ends the run of track boxes (:meth:`detected`); for a frame without one,
    :meth:`roi` gives the track box to use, or None."""

    def __init__(self, config: TrackBoxConfig, vertices: np.ndarray):
        self.config = config
        self._vertices = np.asarray(vertices, float)
        self._pose = None  # (stamp_ns, position (3,), quat (4,))
        self._run = 0  # consecutive frames given a track box

    def set_pose(self, stamp_ns: int, position, quat) -> None:
        self._pose = (int(stamp_ns), np.asarray(position, float), np.asarray(quat, float))

    def detected(self) -> None:
        self._run = 0

    def roi(self, camera, stamp_ns: int):
        """The track box for a frame stamped ``stamp_ns`` in which the network found nothing."""
        if not self.config.enabled or self._pose is None or self._run >= self.config.max_frames:
            return None
        pose_stamp, position, quat = self._pose
        if not within_age(int(stamp_ns) - pose_stamp, self.config.max_age_s):
            return None
        roi = projected_roi(camera, self._vertices, quat, position)
        if roi is None:
            return None
        self._run += 1
        return grow_roi(roi, self.config.grow, camera.width, camera.height)
