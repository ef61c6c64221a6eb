"""Landing cone (thesis Fig. 1.5) and the trajectory stage machine (thesis Fig. 1.4, right).

Positions are in the landing frame L of ``frames.py`` (x bow, y starboard, z down, origin at
the net). The landing axis leaves the net opposite to ``approach_course``, rising at the
cone's glide slope; "starboard" is the right-hand side of a UAV flying that course.
"""

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from .config import ConeConfig


class Stage(IntEnum):
    """Values of ``uav_landing_msgs/LandingGuidance.stage``."""

    LOITER = 0
    APPROACH = 1
    LAND = 2
    NO_RETURN = 3
    GO_AROUND = 4


@dataclass(frozen=True)
class ConeGeometry:
    range: float  # m, UAV to landing point
    glide_slope_angle: float  # rad, apparent descent angle seen from the landing point
    glide_slope_error: float  # rad, glide_slope_angle − nominal glide slope
    lateral_angle: float  # rad, from the landing axis, positive to starboard
    inside_cone: bool


@dataclass(frozen=True)
class LandingGuidance:
    """Mirror of ``uav_landing_msgs/LandingGuidance``; NaN angles and range when there is no track."""

    stamp_s: float
    stage: Stage
    range: float
    glide_slope_angle: float
    glide_slope_error: float
    lateral_angle: float
    inside_cone: bool


def glide_slope_angle(position) -> float:
    """Apparent descent angle α of Fig. 1.5 (lateral view): elevation of the UAV above the landing point."""
    x, y, z = np.asarray(position, dtype=float)
    return math.atan2(-z, math.hypot(x, y))


def lateral_angle(position, approach_course: float) -> float:
    """Horizontal angle β1 of Fig. 1.5 (top view) between the landing axis and the UAV, + to starboard."""
    x, y, _ = np.asarray(position, dtype=float)
    out = (-math.cos(approach_course), -math.sin(approach_course))  # landing axis, away from the net
    right = (-math.sin(approach_course), math.cos(approach_course))  # right of the approach path
    return math.atan2(x * right[0] + y * right[1], x * out[0] + y * out[1])


def inside_cone(rng: float, alpha: float, beta1: float, cone: ConeConfig) -> bool:
    """Fig. 1.5: α2 ≤ α ≤ α1, |β1| ≤ β2/2 (β2 the full opening), within d of the landing point."""
    return rng <= cone.distance_m and cone.alpha2 <= alpha <= cone.alpha1 and abs(beta1) <= 0.5 * cone.beta2


def cone_geometry(position, cone: ConeConfig) -> ConeGeometry:
    """Range, glide-slope and lateral errors of a UAV position in the landing frame."""
    rng = float(np.linalg.norm(position))
    alpha = glide_slope_angle(position)
    beta1 = lateral_angle(position, cone.approach_course)
    return ConeGeometry(rng, alpha, alpha - cone.glide_slope, beta1, inside_cone(rng, alpha, beta1, cone))


class StageMachine:
    """The trajectory state machine of Fig. 1.4 (right).

    LOITER → APPROACH when a pose is tracked; APPROACH → LAND inside the cone; LAND →
    NO_RETURN within ``no_return_distance_m``, once the last ``no_return_confirm_poses`` poses
    (distinct stamps, as ticked) were all inside the cone and none changed the range faster than
    ``max_range_rate_mps`` since the one before; LAND → GO_AROUND on track loss or outside the
    cone (a pose outside it never commits the landing); GO_AROUND → LOITER after
    ``go_around_hold_s`` (restarted if the clock jumps back). A loss during APPROACH returns to
    LOITER (the UAV has not started its descent). NO_RETURN holds until ``reset()``.

    So a lone outlier can commit the landing at most ``max_range_rate_mps`` × (its stamp − the
    previous pose's) metres early; one that jumps further restarts the count.
    """

    def __init__(self, cone: ConeConfig, go_around_hold_s: float):
        self._cone = cone
        self._hold = go_around_hold_s
        self._go_around_since = 0.0
        self._run: list[tuple[float, float]] = []  # (stamp, range) of the successive plausible in-cone poses
        self.stage = Stage.LOITER

    def reset(self) -> None:
        """Back to LOITER, e.g. after the UAV is recovered from the net."""
        self.stage = Stage.LOITER
        self._run = []

    def _follow(self, stamp_s: float, geometry: ConeGeometry | None) -> None:
        """Extend, restart or end the run of plausible in-cone poses with this tick's pose."""
        if geometry is None or not geometry.inside_cone:
            self._run = []
            return
        if self._run:
            last_stamp, last_range = self._run[-1]
            if stamp_s == last_stamp:  # the same pose ticked again: no new evidence
                return
            if stamp_s < last_stamp:  # the clock jumped back: the run so far is another time-line's
                self._run = []
            if abs(geometry.range - last_range) > self._cone.max_range_rate_mps * (stamp_s - last_stamp):
                self._run = []
        self._run = [*self._run[-(self._cone.no_return_confirm_poses - 1):], (stamp_s, geometry.range)]

    def update(self, now_s: float, geometry: ConeGeometry | None, stamp_s: float) -> Stage:
        """Advance by at most one transition; ``geometry`` (of the pose stamped ``stamp_s``) is
        None when there is no fresh track."""
        self._follow(stamp_s, geometry)
        self._go_around_since = min(self._go_around_since, now_s)  # a clock that jumped back restarts the hold
        s = self.stage
        if s is Stage.LOITER and geometry is not None:
            s = Stage.APPROACH
        elif s is Stage.APPROACH:
            if geometry is None:
                s = Stage.LOITER
            elif geometry.inside_cone:
                s = Stage.LAND
        elif s is Stage.LAND:
            if geometry is None or not geometry.inside_cone:
                s = Stage.GO_AROUND
                self._go_around_since = now_s
            elif (geometry.range <= self._cone.no_return_distance_m
                  and len(self._run) >= self._cone.no_return_confirm_poses):
                s = Stage.NO_RETURN
        elif s is Stage.GO_AROUND and now_s - self._go_around_since >= self._hold:
            s = Stage.LOITER
        self.stage = s
        return s
