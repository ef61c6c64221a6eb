"""Pose hypotheses from one frame (§4.3.2–4.3.3): OBB → nearest database entries → 6-DoF poses.

Orientation: the quaternions of the k entries nearest to the observed (θ, R) by (4.4).
Translation: depth by the weak-perspective area ratio (4.5), then X, Y by back-projecting the
box centre (4.6)–(4.7). With ``centre_offset`` (default) the centre is first moved by the
entry's own offset between its box centre and the projection of the body origin, scaled to
the observed size and turned by the angle difference; the thesis uses the box centre as is.
With ``turn_orientation`` (default) the entry's orientation is turned by that angle difference
too, about the optical axis: the entry was rendered on that axis, so its silhouette turns
rigidly with it, and the hypothesis's box then lies at the observed angle; the thesis uses the
entry's quaternion as is.
"""

from dataclasses import dataclass, field

import numpy as np

from ..camera import CameraModel
from ..geometry.quaternion import quat_multiply
from .database import ASPECT_WEIGHT, DEFAULT_FILE, PoseDatabase, check_aspect_weight
from .obb import THETA_PERIOD_DEG, FastConfig, Obb, check_roi, obb_from_frame

FAST_RADIUS_PX = 3  # FAST's ring: no corner is found closer than this to the image's edge


MAX_ROI_MARGIN, MAX_ROI_PAD_PX = 10.0, 1e4  # an ROI grown more covers any frame


@dataclass(frozen=True)
class HypothesisConfig:
    """M hypotheses at the first frame, M − M0 afterwards; the database file (a name in
    ``models/`` or a path) and its (4.4) weight; FAST settings; centre offset and orientation turn
    on/off; how much the ROI is grown before its FAST corners are taken; how much of the ROI the
    box must span.

    The growth is ours: FAST needs its radius-3 ring inside the image, so in a ROI that is
    tight on the UAV the corners of its outermost pixels (wing tips, tail) are never found and
    the box comes out too small, i.e. the depth (4.5) too far. Every ROI source (detector,
    ground-truth oracle, the boosting evaluation) goes through the same growth.

    ``min_roi_cover`` (ours; 0 = thesis): no hypotheses when the box's long side spans less than
    this fraction of the ROI's longer side. Such a box holds only part of the UAV (the fuselage
    of a near UAV whose wings give no corners, or a far UAV's brightest spot), and its depth
    (4.5) is off by 34–746 % on the simulated landings, against 3–34 % for the other boxes.

    Nor are there hypotheses when the ROI reaches within :data:`FAST_RADIUS_PX` of the frame's
    edge (ours): the UAV may run off the frame there, or its outermost corners cannot be found,
    and the ROI is cut like the box, so ``min_roi_cover`` passes a partial UAV whose depth (4.5)
    comes out far too far (22 m for 15 m with half the UAV out of the frame).
    """

    particles: int = 100
    kept: int = 75
    database: str = DEFAULT_FILE
    aspect_weight: float = ASPECT_WEIGHT
    fast: FastConfig = field(default_factory=FastConfig)
    centre_offset: bool = True
    roi_margin: float = 0.10  # of the ROI's width / height, each side
    roi_pad_px: float = 2.0  # plus this, each side
    min_roi_cover: float = 0.6  # ours, 0 = thesis: least long side of the box / longer side of the ROI
    turn_orientation: bool = True  # ours, False = thesis: turn each entry's orientation to the observed angle

    def __post_init__(self):
        if not 0.0 <= self.min_roi_cover <= 1.0:
            raise ValueError(f"min_roi_cover must be in [0, 1], got {self.min_roi_cover}")
        if not (0 <= self.roi_margin <= MAX_ROI_MARGIN and 0 <= self.roi_pad_px <= MAX_ROI_PAD_PX):
            raise ValueError(f"roi_margin and roi_pad_px must be within 0 to {MAX_ROI_MARGIN:g} and 0 to "
                             f"{MAX_ROI_PAD_PX:g} px, got {self.roi_margin}, {self.roi_pad_px}")
        if not all(isinstance(n, (int, np.integer)) and not isinstance(n, bool) for n in (self.particles, self.kept)):
            raise ValueError(f"particles M and kept M0 must be integers, got {self.particles!r}, {self.kept!r}")
        if self.particles < 1 or not 0 <= self.kept < self.particles:
            raise ValueError(f"need particles M >= 1 and 0 <= kept M0 < M, got M={self.particles}, M0={self.kept}")
        check_aspect_weight(self.aspect_weight)

    def count(self, first_frame: bool) -> int:
        """M at the first frame, M − M0 afterwards."""
        return self.particles if first_frame else self.particles - self.kept


@dataclass(frozen=True)
class Hypotheses:
    """Poses ``quats (k, 4)``, ``positions (k, 3)`` (optical frame), best first, with their
    distances (4.4), database indices and the observed box."""

    obb: Obb
    quats: np.ndarray
    positions: np.ndarray
    distances: np.ndarray
    indices: np.ndarray

    def __len__(self) -> int:
        return len(self.quats)


def weak_perspective_depth(z_ref, area_ref, area):
    """Weak-perspective depth (4.5): Z = Z^i·sqrt(A^i / A)."""
    return np.multiply(z_ref, np.sqrt(np.divide(area_ref, area)))


def weak_perspective_position(uv, depth, camera: CameraModel) -> np.ndarray:
    """X = Z(x − c_x)/f_x, Y = Z(y − c_y)/f_y (4.6)–(4.7): points ``(..., 3)`` of pixels at depth Z."""
    return camera.backproject(uv, depth)


def hypotheses_from_obb(database: PoseDatabase, obb: Obb, k: int, camera: CameraModel,
                        centre_offset: bool = True, turn_orientation: bool = True) -> Hypotheses:
    """The ``k`` poses of the entries nearest to an observed box, best first (vectorised)."""
    if not (obb.w > 0 and obb.h > 0):
        raise ValueError(f"observed box must have positive sides, got {obb}")
    idx, dist = database.query(obb.theta, obb.aspect, k)
    ref = database.obbs[idx].astype(float)
    depth = weak_perspective_depth(database.distance, database.areas[idx].astype(float), obb.area)
    centre = np.broadcast_to(np.array([obb.x, obb.y]), (len(idx), 2))
    turn = np.radians(_wrap_half_period(obb.theta - ref[:, 0]))  # observed angle − entry's, image x → y
    if centre_offset:
        scale = database.distance / depth
        offset = ref[:, 1:3] - np.array([database.camera.cx, database.camera.cy])
        c, s = np.cos(turn), np.sin(turn)
        rotated = np.stack([c * offset[:, 0] - s * offset[:, 1], s * offset[:, 0] + c * offset[:, 1]], axis=1)
        centre = centre - scale[:, None] * rotated
    positions = weak_perspective_position(centre, depth, camera)
    quats = database.quats[idx].astype(float)
    if turn_orientation:
        about_axis = np.stack([np.zeros_like(turn), np.zeros_like(turn), np.sin(turn / 2), np.cos(turn / 2)], axis=1)
        quats = quat_multiply(about_axis, quats)  # the camera's z: an image angle x → y
    return Hypotheses(obb, quats, positions, dist, idx)


def _wrap_half_period(d_theta):
    return (np.asarray(d_theta) + THETA_PERIOD_DEG / 2) % THETA_PERIOD_DEG - THETA_PERIOD_DEG / 2


class PoseHypothesisGenerator:
    """Frame + detector ROI → pose hypotheses; the core of the ``pose_boosting`` node."""

    def __init__(self, database: PoseDatabase, camera: CameraModel,
                 config: HypothesisConfig = HypothesisConfig()):
        if camera.is_distorted:
            camera = camera.rectified()
        database.check_compatible(camera)
        self.database, self.camera, self.config = database, camera, config

    @classmethod
    def from_config(cls, config: HypothesisConfig, camera: CameraModel, mesh=None) -> "PoseHypothesisGenerator":
        """Load ``config.database`` (checked against the camera and, if given, the mesh)."""
        from ..resources import model_file

        database = PoseDatabase.load(model_file(config.database), camera=camera.rectified(), mesh=mesh, aspect_weight=config.aspect_weight)
        return cls(database, camera, config)

    def generate(self, frame: np.ndarray, roi, first_frame: bool = False, count: int | None = None) -> Hypotheses | None:
        """Hypotheses for the rectified ``frame`` and ROI ``(x, y, w, h)`` (grown as configured):
        ``count`` of them (default M at the first frame, M − M0 otherwise); None if the ROI
        reaches the frame's edge, if no box is found in it, or if the box spans less than
        ``min_roi_cover`` of the ROI's longer side."""
        frame = np.asarray(frame)
        if frame.shape[:2] != (self.camera.height, self.camera.width):
            raise ValueError(f"frame is {frame.shape[1]}x{frame.shape[0]}, camera is {self.camera.width}x{self.camera.height}")
        x, y, w, h = check_roi(roi, self.camera.width, self.camera.height)
        if min(x, y, self.camera.width - (x + w), self.camera.height - (y + h)) <= FAST_RADIUS_PX:
            return None
        obb = obb_from_frame(frame, roi, self.config.fast, self.config.roi_margin, self.config.roi_pad_px)
        if obb is None or obb.w < self.config.min_roi_cover * max(w, h):
            return None
        k = self.config.count(first_frame) if count is None else count
        return hypotheses_from_obb(self.database, obb, k, self.camera, self.config.centre_offset,
                                   self.config.turn_orientation)
