"""Pose boosting evaluation (§6.4): closest-hypothesis error at several distances and top-k.

Each sample is a random orientation from the database's interval, placed at ``distance`` metres
on the optical axis (``axis``, X = Y = 0 as the database) or on a random ray that keeps the
model inside the image (``view``), rendered shaded (sun light) over the simulator's ``normal``
background seen from the still deck camera (one of a few pre-drawn frames, the sea moving
between them; no noise or blur). The ROI is the rendered silhouette's bounding box, grown as the
boosting stage grows ROIs. Among the top-k hypotheses the one with the smallest geodesic error
(6.3) is taken; its errors are hypothesis minus ground truth per coordinate and the Z-Y-X Euler
angles of q_g ⊗ q̄_r (6.4).
"""

import sys
from dataclasses import dataclass, field

import numpy as np

from ..camera import CameraModel
from ..config import check_seed
from ..evaluation.statistics import ROW_NAMES, STAT_KEYS, error_statistics
from ..geometry import euler_error, geodesic_angle
from .database import ASPECT_WEIGHT, PoseDatabase, check_aspect_weight, sample_orientations
from .hypotheses import HypothesisConfig, hypotheses_from_obb
from .obb import FastConfig, obb_from_frame

PLACEMENTS = ("axis", "view")
BACKGROUND_FRAMES = 8
MAX_PLACEMENT_DRAWS = 1000  # batches of pixels drawn for view placements before giving up


def check_distances(distances) -> None:
    """ValueError unless ``distances`` (m) are finite, positive and differ as printed (``:g``),
    each the key of its own table."""
    if not distances or not all(0 < d < np.inf for d in distances):
        raise ValueError(f"distances must be finite and positive, got {distances}")
    if len({f"{d:g}" for d in distances}) != len(distances):
        raise ValueError(f"distances must differ, got {distances}")


@dataclass(frozen=True)
class BoostingEvalConfig:
    """Samples per distance, distances (m), top-k, seed, placement, centre offset, orientation turn, FAST, (4.4) weight."""

    samples: int = 15000
    distances: tuple[float, ...] = (5.0, 15.0, 30.0)
    top: tuple[int, ...] = (10, 25, 50, 100)
    seed: int = 0
    placement: str = "axis"
    centre_offset: bool = True
    turn_orientation: bool = True
    fast: FastConfig = field(default_factory=FastConfig)
    aspect_weight: float = ASPECT_WEIGHT

    def __post_init__(self):
        if self.placement not in PLACEMENTS:
            raise ValueError(f"placement must be one of {PLACEMENTS}, got {self.placement!r}")
        if self.samples < 1 or not self.top or min(self.top) < 1:
            raise ValueError(f"samples and top must be positive, got {self.samples} and {self.top}")
        check_distances(self.distances)
        check_seed(self.seed)
        check_aspect_weight(self.aspect_weight)


def normal_backgrounds(camera: CameraModel, count: int, seed: int):
    """``count`` frames of the simulator's ``normal`` background from the still deck camera, 1 s
    apart, the sun direction in the optical frame and the simulator's UAV albedo."""
    from ..sim import NormalBackground, camera_mount
    from ..sim.config import BackgroundConfig, ImagingConfig, ShipConfig

    ship = ShipConfig()
    background = NormalBackground(camera, BackgroundConfig(), ship, np.random.default_rng(seed))
    rot, pos = camera_mount(ship)
    frames = [background.frame(i, float(i), rot, pos) for i in range(count)]
    return frames, rot.T @ background.sun, ImagingConfig().albedo


def view_planes(camera: CameraModel) -> np.ndarray:
    """Unit inward normals ``(4, 3)`` of the planes through the camera centre and the image's
    border pixel centres (u = 0, u = width − 1, v = 0, v = height − 1): a point X projects inside
    the image when every ``normal · X`` is positive, a sphere of radius R when each is ≥ R."""
    k = camera.K
    right, bottom = camera.width - 1.0, camera.height - 1.0
    normals = np.stack([k[0], right * k[2] - k[0], k[1], bottom * k[2] - k[1]])
    return normals / np.linalg.norm(normals, axis=1, keepdims=True)


def sample_positions(camera: CameraModel, distance: float, radius: float, count: int,
                     rng: np.random.Generator) -> np.ndarray:
    """Positions ``(count, 3)`` at range ``distance`` on the rays of pixels drawn uniformly among
    those whose ray keeps a ``radius`` sphere there wholly in view (:func:`view_planes`; off the
    axis the sphere's image is an ellipse, larger than on it). ValueError when the sphere does
    not fit on the principal ray."""
    planes = view_planes(camera)
    if not np.all(planes[:, 2] * distance >= radius):
        raise ValueError(f"a {radius:g} m sphere at {distance:g} m does not fit in the "
                         f"{camera.width}x{camera.height} image: no view placement there")
    hi = np.array([camera.width - 1.0, camera.height - 1.0])
    kept, found = [], 0
    for _ in range(MAX_PLACEMENT_DRAWS):
        rays = camera.backproject(rng.uniform(0.0, hi, size=(max(count, 256), 2)), 1.0)
        positions = distance * rays / np.linalg.norm(rays, axis=1, keepdims=True)
        positions = positions[np.all(positions @ planes.T >= radius, axis=1)]
        kept.append(positions)
        found += len(positions)
        if found >= count:
            return np.concatenate(kept)[:count]
    raise ValueError(f"a {radius:g} m sphere at {distance:g} m fits in the image on too few rays: "
                     f"{found} of {count} view placements in {MAX_PLACEMENT_DRAWS} draws")


def silhouette_roi(alpha: np.ndarray):
    """ROI ``(x, y, w, h)``: the bounding box of the rendered coverage, or None if empty."""
    ys, xs = np.nonzero(alpha > 0)
    if len(xs) == 0:
        return None
    return int(xs.min()), int(ys.min()), int(xs.max() + 1 - xs.min()), int(ys.max() + 1 - ys.min())


def rendered_hypotheses(renderer, db: PoseDatabase, camera: CameraModel, quat, trans, background, sun, albedo,
                        fast: FastConfig, k: int, centre_offset: bool = True, turn_orientation: bool = True):
    """The UAV at ``(quat, trans)`` shaded over ``background`` and boosting's ``k`` hypotheses
    from its silhouette's box (grown as the boosting stage grows ROIs): ``(frame, hypotheses)``,
    the hypotheses None when FAST finds no box."""
    frame, alpha = renderer.shaded(quat, trans, background, albedo=albedo, light_dir=sun)
    roi = silhouette_roi(alpha)
    obb = None if roi is None else obb_from_frame(frame, roi, fast, HypothesisConfig.roi_margin,
                                                  HypothesisConfig.roi_pad_px)
    return frame, None if obb is None else hypotheses_from_obb(db, obb, k, camera, centre_offset, turn_orientation)


def closest_errors(q_true, t_true, quats, positions, top) -> tuple[np.ndarray, np.ndarray]:
    """Per top-k, translation ``(len(top), 3)`` and Euler ``(len(top), 3)`` (rad) errors of the
    hypothesis with the smallest geodesic error among the first k.

    Signs as everywhere in the project's evaluation: translation estimate − truth, rotation the
    Euler angles of q_e = q_g ⊗ q̄_r (6.4).
    """
    geo = geodesic_angle(np.broadcast_to(q_true, quats.shape), quats)
    best = np.array([np.argmin(geo[:k]) for k in top])
    return positions[best] - t_true, euler_error(np.broadcast_to(q_true, (len(best), 4)), quats[best])


def evaluate_boosting(camera: CameraModel, mesh, config: BoostingEvalConfig = BoostingEvalConfig(), *,
                      database_path=None, progress: bool = True) -> dict:
    """Run the evaluation; returns ``{"stats": {dist: {k: {...}}}, "failures": {dist: n}, ...}``."""
    from tqdm import tqdm

    from ..render import Renderer
    from ..resources import model_path
    from .database import DEFAULT_FILE

    camera = camera.rectified()
    db = PoseDatabase.load(database_path or model_path(DEFAULT_FILE), camera=camera, mesh=mesh,
                           aspect_weight=config.aspect_weight)
    with Renderer(camera, mesh) as renderer:
        backgrounds, sun, albedo = normal_backgrounds(camera, BACKGROUND_FRAMES, config.seed)
        radius = float(np.max(np.linalg.norm(mesh.vertices, axis=1)))
        kmax, top = max(config.top), tuple(config.top)
        stats, failures = {}, {}
        for d_i, distance in enumerate(config.distances):
            # A spawn key keeps these draws independent of a database built with the same seed.
            rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(1, d_i)))
            quats = sample_orientations(config.samples, db.half_range_deg, rng)
            if config.placement == "axis":
                trans = np.tile([0.0, 0.0, distance], (config.samples, 1))
            else:
                trans = sample_positions(camera, distance, radius, config.samples, rng)
            t_err = np.full((config.samples, len(top), 3), np.nan)
            r_err = np.full((config.samples, len(top), 3), np.nan)
            for i in tqdm(range(config.samples), desc=f"{distance:g} m", disable=not progress, file=sys.stderr,
                          mininterval=2.0):
                _, hyp = rendered_hypotheses(renderer, db, camera, quats[i], trans[i], backgrounds[i % len(backgrounds)],
                                             sun, albedo, config.fast, kmax, config.centre_offset, config.turn_orientation)
                if hyp is None:
                    continue
                t_err[i], r_err[i] = closest_errors(quats[i], trans[i], hyp.quats, hyp.positions, top)
            ok = np.isfinite(t_err[:, 0, 0])
            failures[f"{distance:g}"] = int(np.sum(~ok))
            stats[f"{distance:g}"] = {
                str(k): {
                    "translation_m": {a: error_statistics(t_err[ok, j, c]) for c, a in enumerate("xyz")},
                    "rotation_deg": {a: error_statistics(np.degrees(r_err[ok, j, c]))
                                     for c, a in enumerate(("alpha", "beta", "gamma"))},
                }
                for j, k in enumerate(top)
            }
    return {"stats": stats, "failures": failures, "samples": config.samples, "database_entries": len(db)}


def format_tables(result: dict) -> str:
    """Thesis-format tables (as Tables 6.2–6.3) per distance: translation (m) and rotation (deg)."""
    out = []
    for dist, per_k in result["stats"].items():
        ks = list(per_k)
        for group, axes, unit, label in (
            ("translation_m", ("x", "y", "z"), "meters", ("X", "Y", "Z")),
            ("rotation_deg", ("alpha", "beta", "gamma"), "degrees", ("Alpha (α)", "Beta (β)", "Gamma (γ)")),
        ):
            kind = "Translation" if group == "translation_m" else "Rotation"
            out.append(f"{kind} error ({unit}) at {dist} m using {', '.join(ks)} database poses "
                       f"({result['samples'] - result['failures'][dist]}/{result['samples']} samples with a box)")
            width = 8 * len(ks)
            out.append(f"{'':16}" + "".join(f"| {name:<{width - 2}}" for name in label))
            out.append(f"{'':16}" + "".join("| " + "".join(f"{k:>8}" for k in ks)[2:] for _ in axes))
            for key in STAT_KEYS:
                row = ROW_NAMES[key]
                cells = "".join(f"{per_k[k][group][a][key]:8.2f}" for a in axes for k in ks)
                out.append(f"{row:16}{cells}")
            out.append("")
    return "\n".join(out)
