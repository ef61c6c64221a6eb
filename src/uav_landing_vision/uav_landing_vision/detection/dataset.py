"""Synthetic detection dataset (§4.2.2): the UAV model rendered over backgrounds, YOLO labels.

Each image: a background (the simulator's ``normal``/``complex`` skies and seas seen in a
random direction at a random time, a random crop/flip of a user image, or a frame of a
video), the UAV shaded at a random pose 5–150 m away (sometimes partly out of the frame, or
absent: a negative), then photometric jitter, blur, noise and JPEG coding. A configurable
fraction are instead frames of simulated landings (:class:`LandingFrames`), made and
undistorted exactly as the evaluation's sequences, with jitter and coding on top; a configurable
fraction of those leave the UAV out (negatives of the landing's own sky and sea). The label comes
from the model at the drawn pose as Fig. 4.4 (silhouette → oriented box → axis-aligned ROI),
the silhouette's outline taken exactly from the projected model (:func:`model_roi`); a pose
is labelled when at least ``min_visible_px`` pixels of its rendered coverage pass
``coverage_threshold``, else it is drawn again.

Layout: ``images/NNNNNN.jpg``, ``labels/NNNNNN.txt`` (YOLO: ``0 cx cy w h`` normalised to the
image, empty for a negative), ``settings.json`` (written first) and ``dataset.json`` (settings,
counts; written last, when complete). Image ``i`` depends only on ``(seed, i)`` and the settings.
"""

import json
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from ..camera import write_image
from ..config import check_seed
from ..geometry import euler_zyx_to_matrix, matrix_to_quat, quat_multiply, quat_normalise
from .detector import box_iou

FAMILIES = ("normal", "complex", "images", "video")
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp")
LABEL_BOXES = ("oriented", "extent")  # model_roi with oriented=True / False


@dataclass(frozen=True)
class DatasetConfig:
    """Generator settings; ranges are [low, high]."""

    count: int = 1000
    seed: int = 0
    camera_info: str = ""  # a camera_info YAML (a path, else a config/ file name); "": config/camera.yaml
    families: tuple[str, ...] = ("normal", "complex")  # "images"/"video" need image_dir/video
    image_dir: str = ""
    video: str = ""
    banks_per_family: int = 3  # sky/sea panoramas (each with its own sun) per simulator family
    range_m: tuple[float, float] = (5.0, 150.0)  # log-uniform
    negative_fraction: float = 0.1
    partial_fraction: float = 0.1  # UAV centre drawn up to 0.3 frame outside the image
    # Attitudes: this fraction flies an approach (nose to the camera, banked ±40° about the line
    # of sight, nose ±15° up/down and ±20° left/right: the head-on views of a landing, boxes up
    # to ~6:1); of the rest, 60 % are "landing-like" (±60°, ±30°, ±60° about the camera's x, y,
    # z axes from facing the camera) and 40 % uniformly random.
    approach_fraction: float = 0.0
    # This fraction of images are frames of simulated landings of the family's scenario
    # (:class:`LandingFrames`).
    landing_fraction: float = 0.0
    # Of those landing frames, this fraction leaves the UAV out: the landing's sky and sea as
    # the deck camera sees them (negatives where the graph looks; the other negatives are
    # random views of the backgrounds).
    landing_negative_fraction: float = 0.0
    # Landing frames' sun azimuth: the scenario's own ± this (180: any azimuth). The elevation is
    # drawn as for the random views.
    landing_sun_spread_deg: float = 180.0
    # Label: "oriented" is Fig. 4.4 (outline → minimum-area oriented box → its axis-aligned ROI);
    # "extent" is the projected model's own extent (model_roi, docs/detector.md).
    label_box: str = "oriented"
    coverage_threshold: float = 0.5  # binarisation of the rendered coverage (the visibility test)
    min_visible_px: int = 4
    noise_sigma: tuple[float, float] = (0.0, 6.0)
    blur_probability: float = 0.4
    jpeg_quality: int = 92

    def __post_init__(self):
        check_seed(self.seed)
        unknown = set(self.families) - set(FAMILIES)
        if not self.families or unknown:
            raise ValueError(f"families must be a non-empty subset of {FAMILIES}, got {self.families}")
        if "images" in self.families and not self.image_dir:
            raise ValueError("the 'images' family needs image_dir")
        if "video" in self.families and not self.video:
            raise ValueError("the 'video' family needs video")
        if self.count < 1 or self.banks_per_family < 1 or not 0 < self.range_m[0] < self.range_m[1]:
            raise ValueError("need count ≥ 1, banks_per_family ≥ 1 and 0 < range_m[0] < range_m[1]")
        if not (0 <= self.negative_fraction < 1 and 0 <= self.partial_fraction <= 1 and 0 < self.coverage_threshold < 1):
            raise ValueError("negative_fraction in [0,1), partial_fraction in [0,1], coverage_threshold in (0,1)")
        if not 0 <= self.approach_fraction <= 1:
            raise ValueError(f"approach_fraction must be in [0, 1], got {self.approach_fraction}")
        if not 0 <= self.landing_fraction <= 1:
            raise ValueError(f"landing_fraction must be in [0, 1], got {self.landing_fraction}")
        if not 0 < self.landing_sun_spread_deg <= 180:
            raise ValueError(f"landing_sun_spread_deg must be in (0, 180], got {self.landing_sun_spread_deg}")
        if not 0 <= self.landing_negative_fraction <= 1:
            raise ValueError(f"landing_negative_fraction must be in [0, 1], got {self.landing_negative_fraction}")
        if self.label_box not in LABEL_BOXES:
            raise ValueError(f"label_box must be one of {LABEL_BOXES}, got {self.label_box!r}")
        if self.landing_fraction and not {"normal", "complex"} & set(self.families):
            raise ValueError("landing frames need the 'normal' or 'complex' family")

    @property
    def oriented_labels(self) -> bool:
        """Whether labels are Fig. 4.4's oriented-box ROIs (else the model's extent)."""
        return self.label_box == "oriented"


def projected_outline(vertices: np.ndarray, K: np.ndarray, quat, trans, width: int, height: int,
                      faces: np.ndarray | None = None) -> np.ndarray | None:
    """The outline of the model projected at the pose (rectified pinhole ``K``): the convex hull
    of its projected vertices clipped to the image, ``(N, 2)`` pixel-centre coordinates. This is
    the outline of the silhouette drawn at unlimited resolution, so wings thinner than a pixel
    still count. None if the model is out of view or reaches behind the camera.

    A model that crosses the image's edge shows only its part inside, whose hull can be much
    smaller than the clipped hull of the whole (sky between a wing in view and a tail out of it):
    with the mesh's triangle ``faces`` the outline is then the hull of the faces clipped to the
    image, as a binarised frame would give it."""
    from ..render.boxes import pose_matrices, project_points

    rot, t = pose_matrices(np.asarray(quat, float)[None], np.asarray(trans, float)[None])
    z, uv = project_points(np.asarray(K, float), rot, t, np.asarray(vertices, float))
    if not np.all(z > 0):
        return None
    hull = cv2.convexHull(uv[0].astype(np.float32))
    frame = np.array([[-0.5, -0.5], [width - 0.5, -0.5], [width - 0.5, height - 0.5], [-0.5, height - 0.5]],
                     np.float32)
    area, clipped = cv2.intersectConvexConvex(hull, frame)
    if area <= 0 or clipped is None:
        return None
    if faces is not None and area < cv2.contourArea(hull) - 1e-6:
        pieces = [piece.reshape(-1, 2) for tri in uv[0][np.asarray(faces)].astype(np.float32)
                  for inside, piece in [cv2.intersectConvexConvex(tri, frame)] if inside > 0 and piece is not None]
        if not pieces:
            return None
        clipped = cv2.convexHull(np.concatenate(pieces))
    return clipped.reshape(-1, 2).astype(np.float64)


def _corner_rois(corners: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned ROIs ``(..., 4)`` ``[x0,y0,x1,y1]`` (pixel edges) of pixel-centre corner
    points ``(..., K, 2)``, clipped to the image, and whether each is non-empty."""
    corners = np.asarray(corners, float) + 0.5
    lo = np.maximum(corners.min(axis=-2), 0.0)
    hi = np.minimum(corners.max(axis=-2), (width, height))
    return np.concatenate([lo, hi], axis=-1), np.all(hi > lo, axis=-1)


def outline_roi(outline: np.ndarray | None, width: int, height: int, oriented: bool = True) -> np.ndarray | None:
    """Fig. 4.4 on an outline (:func:`projected_outline`): minimum-area oriented box → its
    axis-aligned ROI ``[x0,y0,x1,y1]`` (pixel edges: pixel u covers [u, u+1)), clipped; None for
    no outline. The oriented box of a binarised silhouette is that of its convex hull, so on the
    exact outline this is the §4.2.2 label of a silhouette drawn at unlimited resolution.

    ``oriented=False`` skips the oriented box: the ROI is then the extent of the outline, the
    smallest axis-aligned box that holds the projected model. For a thin, tilted UAV the two
    differ widely (docs/detector.md, "Oriented and extent boxes").
    """
    if outline is None:
        return None
    corners = cv2.boxPoints(cv2.minAreaRect(outline.astype(np.float32))) if oriented else outline
    roi, non_empty = _corner_rois(corners, width, height)
    return roi if non_empty else None


def model_roi(vertices: np.ndarray, K: np.ndarray, quat, trans, width: int, height: int,
              oriented: bool = True, faces: np.ndarray | None = None) -> np.ndarray | None:
    """The label of the model at a pose: :func:`outline_roi` of its :func:`projected_outline`."""
    return outline_roi(projected_outline(vertices, K, quat, trans, width, height, faces), width, height, oriented)


def oriented_box_tie(outline: np.ndarray, width: int, height: int,
                     distinct_iou: float = 0.8) -> tuple[float, np.ndarray | None]:
    """How narrowly Fig. 4.4's minimum-area rule picks its oriented box for a convex ``outline``
    (pixel-centre coordinates, as :func:`projected_outline` gives).

    A minimum-area enclosing rectangle has a side along an edge of the outline, so each edge
    gives a candidate rectangle. Among the candidates whose ROI overlaps the label's ROI by IoU
    < ``distinct_iou``, the smallest is the runner-up. Returns ``(margin, roi)``: its area over
    the minimum, minus 1, and its ROI; ``(inf, None)`` when every candidate gives nearly the
    label's ROI. A margin of a few per cent means the label turns on sub-pixel detail.
    """
    outline = np.asarray(outline, float)
    label = outline_roi(outline, width, height)
    edges = np.roll(outline, -1, axis=0) - outline
    edges = edges[np.hypot(edges[:, 0], edges[:, 1]) > 1e-9]
    if label is None or not len(edges):
        return np.inf, None
    axis_u = edges / np.hypot(edges[:, 0], edges[:, 1])[:, None]      # along each edge
    axis_v = np.stack([-axis_u[:, 1], axis_u[:, 0]], axis=1)           # across it
    u, v = axis_u @ outline.T, axis_v @ outline.T                      # (E, N)
    lo_u, hi_u, lo_v, hi_v = u.min(1), u.max(1), v.min(1), v.max(1)
    area = (hi_u - lo_u) * (hi_v - lo_v)
    corner_u = np.stack([lo_u, hi_u, hi_u, lo_u], axis=1)[..., None]
    corner_v = np.stack([lo_v, lo_v, hi_v, hi_v], axis=1)[..., None]
    rois, valid = _corner_rois(corner_u * axis_u[:, None] + corner_v * axis_v[:, None], width, height)  # (E, 4)
    distinct = valid & (box_iou(rois, label[None])[:, 0] < distinct_iou)
    if not distinct.any():
        return np.inf, None
    k = int(np.argmin(np.where(distinct, area, np.inf)))
    return float(area[k] / area.min() - 1.0), rois[k]


def yolo_line(box: np.ndarray, width: int, height: int) -> str:
    x0, y0, x1, y1 = box
    return f"0 {(x0 + x1) / 2 / width:.6f} {(y0 + y1) / 2 / height:.6f} {(x1 - x0) / width:.6f} {(y1 - y0) / height:.6f}"


def read_labels(path, width: int, height: int) -> np.ndarray:
    """Boxes ``(N,4)`` ``[x0,y0,x1,y1]`` (pixels) of a YOLO label file."""
    text = Path(path).read_text().strip()
    rows = np.array([line.split() for line in text.splitlines()], dtype=np.float64).reshape(-1, 5)
    cx, cy, w, h = rows[:, 1] * width, rows[:, 2] * height, rows[:, 3] * width, rows[:, 4] * height
    return np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)


def image_rng(seed: int, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence([seed, index]))


# The UAV facing the camera, upright (body x → −z_C, body y → +x_C, body z → −y_C).
_FACING = matrix_to_quat(np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]]))
# Camera body (x forward, y left, z up) from the optical frame (x right, y down, z forward).
_BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def random_pose(rng: np.random.Generator, camera, cfg: DatasetConfig) -> tuple[np.ndarray, np.ndarray]:
    """A UAV pose ``(quat, trans)`` in the camera frame: log-uniform range, centre in (or, for a
    partial case, around) the image; attitudes as :class:`DatasetConfig` says."""
    r = np.exp(rng.uniform(*np.log(cfg.range_m)))
    margin = 0.3 if rng.random() < cfg.partial_fraction else 0.0
    u = rng.uniform(-margin, 1 + margin) * camera.width
    v = rng.uniform(-margin, 1 + margin) * camera.height
    ray = np.array([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0])
    trans = r * ray / np.linalg.norm(ray)
    kind = rng.random()
    if kind >= cfg.approach_fraction + 0.6 * (1 - cfg.approach_fraction):
        quat = quat_normalise(rng.standard_normal(4))
    else:  # turned from facing the camera, up to these angles about the camera's x, y, z axes
        limits = np.array([15.0, 20.0, 40.0] if kind < cfg.approach_fraction else [60.0, 30.0, 60.0])
        angles = np.radians(rng.uniform(-limits, limits))
        quat = quat_multiply(matrix_to_quat(euler_zyx_to_matrix(angles)), _FACING)
    return quat, trans


def random_sun(rng: np.random.Generator, family: str, azimuth_deg: float = 0.0, spread_deg: float = 180.0):
    """A sun ``(azimuth, elevation)`` in degrees: ``azimuth_deg ± spread_deg``, high for the
    ``normal`` sky and low for the ``complex`` sunset."""
    az = azimuth_deg + rng.uniform(-spread_deg, spread_deg)
    return az, rng.uniform(5, 45) if family == "normal" else rng.uniform(1, 12)


class BackgroundSource:
    """Backgrounds of the configured families for one camera (panoramas built once)."""

    def __init__(self, camera, cfg: DatasetConfig):
        from ..sim.backgrounds import VideoBackground, make_background
        from ..sim.config import BackgroundConfig, ShipConfig

        self.camera, self.cfg, self.banks = camera, cfg, {}
        for fam in ("normal", "complex"):
            if fam in cfg.families:
                seeds = np.random.SeedSequence([cfg.seed, 1 << 30, FAMILIES.index(fam)]).spawn(cfg.banks_per_family)
                self.banks[fam] = [self._bank(fam, BackgroundConfig, ShipConfig, make_background, s) for s in seeds]
        self.images = sorted(p for p in Path(cfg.image_dir).rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES) \
            if "images" in cfg.families else []
        if "images" in cfg.families and not self.images:
            raise ValueError(f"no images ({', '.join(IMAGE_SUFFIXES)}) under {cfg.image_dir!r}")
        self.video = VideoBackground(camera, cfg.video) if "video" in cfg.families else None

    def _bank(self, fam, background_cfg, ship_cfg, make_background, seed):
        rng = np.random.default_rng(seed)
        az, el = random_sun(rng, fam)
        cfg = background_cfg(kind=fam, sun_azimuth_deg=float(az), sun_elevation_deg=float(el))
        return make_background(cfg, self.camera, ship_cfg(), rng)

    def draw(self, rng: np.random.Generator, index: int) -> np.ndarray:
        """The background ``(H, W, 3)`` uint8 of image ``index``, of a randomly chosen family."""
        fam = self.cfg.families[rng.integers(len(self.cfg.families))]
        if fam == "images":
            return self._user_image(rng)
        if fam == "video":  # frame ``index`` of the footage (looping): the same in any worker and on resume
            return self.video.frame(index, 0.0)
        bank = self.banks[fam][rng.integers(len(self.banks[fam]))]
        bank.jitter_rng = rng  # sea jitter from this image's generator: image i depends on (seed, i) only
        yaw, elev, roll = np.radians(rng.uniform([-180, -8, -10], [180, 30, 10]))
        cam_rot = euler_zyx_to_matrix(np.array([roll, -elev, yaw])) @ _BODY_FROM_OPTICAL  # [roll, pitch, yaw]
        return bank.frame(0, float(rng.uniform(0, 600)), cam_rot, np.array([0.0, 0.0, 0.5]))

    def _user_image(self, rng: np.random.Generator) -> np.ndarray:
        path = self.images[rng.integers(len(self.images))]
        bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ValueError(f"cannot read image {path}")
        h, w = bgr.shape[:2]
        aspect = self.camera.width / self.camera.height
        cw = min(w, h * aspect) * rng.uniform(0.4, 1.0)
        ch = cw / aspect
        x0, y0 = rng.uniform(0, w - cw), rng.uniform(0, h - ch)
        # at least one pixel a side (an image of a pixel or two would give an empty crop)
        crop = bgr[int(y0) : max(int(y0 + ch), int(y0) + 1), int(x0) : max(int(x0 + cw), int(x0) + 1)]
        if rng.random() < 0.5:
            crop = crop[:, ::-1]
        crop = cv2.resize(crop, (self.camera.width, self.camera.height), interpolation=cv2.INTER_AREA)
        return cv2.cvtColor(crop, cv2.COLOR_BGR2RGB)


def photometric(image: np.ndarray, rng: np.random.Generator, cfg: DatasetConfig) -> np.ndarray:
    """Brightness/contrast/saturation/gamma jitter, optional Gaussian or motion blur, sensor noise."""
    from ..sim.synthesis import motion_blur_kernel

    img = image.astype(np.float32) / 255.0
    grey = img.mean(axis=2, keepdims=True)
    img = grey + rng.uniform(0.6, 1.4) * (img - grey)  # saturation
    img = (img - 0.5) * rng.uniform(0.7, 1.3) + 0.5 + rng.uniform(-0.15, 0.15)  # contrast, brightness
    img = np.clip(img, 0.0, 1.0) ** rng.uniform(0.7, 1.4)
    if rng.random() < cfg.blur_probability:
        if rng.random() < 0.5:
            img = cv2.GaussianBlur(img, (0, 0), rng.uniform(0.4, 1.5))
        else:
            angle = rng.uniform(0, 2 * np.pi)
            kernel = motion_blur_kernel(rng.uniform(1.5, 8.0) * np.array([np.cos(angle), np.sin(angle)]))
            img = cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REFLECT)
    sigma = rng.uniform(*cfg.noise_sigma) / 255.0
    img = img + rng.standard_normal(img.shape, dtype=np.float32) * np.float32(sigma)
    return np.clip(img * 255.0 + 0.5, 0, 255).astype(np.uint8)


def dataset_camera(cfg: DatasetConfig):
    """The rectified camera the images are drawn with: the shipped ``config/camera.yaml`` unless
    ``cfg.camera_info`` names another (never a ``camera.yaml`` that happens to be in the working
    directory)."""
    from ..camera import load_camera_info_yaml
    from ..resources import config_file, config_path

    path = config_file(cfg.camera_info) if cfg.camera_info else config_path("camera.yaml")
    return load_camera_info_yaml(path).rectified()


# Landing seeds are drawn at or above this, so a training landing never repeats an evaluation
# sequence made with a smaller seed (the shipped evaluations use 9001).
LANDING_SEED_MIN = 10_000


class LandingFrames:
    """Frames of simulated landings for the ``normal``/``complex`` families.

    Each frame: a new landing of the family's shipped scenario (seed drawn from the image's
    generator, ≥ :data:`LANDING_SEED_MIN`), one of its frames at random, drawn as the
    simulator draws it (render camera, motion blur, lens distortion, sensor noise) over one of
    ``banks_per_family`` backgrounds with a random sun (its azimuth within
    ``landing_sun_spread_deg`` of the scenario's), then undistorted as the graph does. Its
    label is :func:`model_roi` at the true pose in the rectified camera, as ``eval-detector``
    labels a bag.
    """

    def __init__(self, cfg: DatasetConfig, rectified, mesh):
        from ..sim.backgrounds import make_background
        from ..sim.config import load_scenario
        from ..sim.simulate import scenario_camera
        from ..sim.synthesis import FrameSynthesizer

        self.vertices, self.faces, self.K = mesh.vertices, mesh.faces, rectified.K
        self.size = (rectified.width, rectified.height)
        self.oriented = cfg.oriented_labels
        self.families, self.parts = [], {}
        for fam in ("normal", "complex"):
            if fam not in cfg.families:
                continue
            scenario = load_scenario(fam)
            camera = scenario_camera(scenario)
            rect = camera.rectified()
            if (rect.width, rect.height) != self.size or not np.allclose(rect.K, self.K):
                raise ValueError(f"landing frames are drawn with the '{fam}' scenario's camera "
                                 f"({scenario.camera_info}); the dataset's camera_info must be the same")
            synth = FrameSynthesizer(camera, scenario.imaging, mesh)
            banks = []
            for seed in np.random.SeedSequence([cfg.seed, 1 << 31, FAMILIES.index(fam)]).spawn(cfg.banks_per_family):
                rng = np.random.default_rng(seed)
                # Any azimuth (180) is drawn about 0, as datasets made before the spread existed.
                spread = cfg.landing_sun_spread_deg
                az, el = random_sun(rng, fam, scenario.background.sun_azimuth_deg if spread < 180 else 0.0, spread)
                bcfg = replace(scenario.background, sun_azimuth_deg=float(az), sun_elevation_deg=float(el))
                az, el = np.radians([az, el])
                sun = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
                banks.append((make_background(bcfg, synth.render_camera, scenario.ship, rng), sun))
            self.families.append(fam)
            self.parts[fam] = (scenario, synth, banks, camera.undistortion_maps())

    def sample(self, rng: np.random.Generator, with_uav: bool = True):
        """An undistorted landing frame (RGB uint8), its ROI (None if the UAV is not in view or
        left out) and the true pose ``(quat, trans)`` in the camera frame (where the UAV is, drawn
        or not)."""
        from ..sim.simulate import generators, make_trajectory

        scenario, synth, banks, (map1, map2) = self.parts[self.families[rng.integers(len(self.families))]]
        background, sun = banks[rng.integers(len(banks))]
        rngs = generators(int(rng.integers(LANDING_SEED_MIN, 2**62)))
        traj = make_trajectory(scenario, rngs)
        k = int(rng.integers(1, len(traj)))
        centres = synth.render_camera.project_pinhole(traj.trans[k - 1 : k + 1])
        shift = (centres[1] - centres[0]) * scenario.imaging.exposure_fraction
        shift *= min(1.0, scenario.imaging.max_blur_px / max(float(np.linalg.norm(shift)), 1e-9))
        background.jitter_rng = rng
        bg = background.frame(k, float(traj.times_s[k]), traj.cam_rot[k], traj.cam_pos[k])
        if with_uav:
            raw, _ = synth.frame(bg, traj.quat[k], traj.trans[k], traj.cam_rot[k].T @ sun, shift, rng)
        else:
            raw = synth.sensor(bg, rng)
        image = cv2.remap(raw, map1, map2, cv2.INTER_LINEAR)
        box = model_roi(self.vertices, self.K, traj.quat[k], traj.trans[k], *self.size,
                        oriented=self.oriented, faces=self.faces) if with_uav else None
        return image, box, (traj.quat[k], traj.trans[k])


class SampleGenerator:
    """Makes image ``i`` of a dataset: ``(rgb uint8, ROI [x0,y0,x1,y1] or None)``."""

    def __init__(self, cfg: DatasetConfig, mesh=None):
        from ..model import fixed_wing_mesh
        from ..render import Renderer

        self.camera = dataset_camera(cfg)
        self.cfg = cfg
        self.mesh = mesh if mesh is not None else fixed_wing_mesh("high")
        self.renderer = Renderer(self.camera, self.mesh)
        self.backgrounds = BackgroundSource(self.camera, cfg)
        self.landing = LandingFrames(cfg, self.camera, self.mesh) if cfg.landing_fraction else None

    def release(self) -> None:
        """Free its renderers' GL objects (moderngl frees none when garbage collected)."""
        self.renderer.release()
        for _, synth, _, _ in (self.landing.parts.values() if self.landing is not None else ()):
            synth.renderer.release()

    def sample(self, index: int) -> tuple[np.ndarray, np.ndarray | None]:
        cfg, rng = self.cfg, image_rng(self.cfg.seed, index)
        # Drawn only when landing frames are asked for: datasets made without them keep their images.
        if self.landing is not None and rng.random() < cfg.landing_fraction:
            # Drawn only when asked for, as above.
            with_uav = not (cfg.landing_negative_fraction and rng.random() < cfg.landing_negative_fraction)
            image, box, _ = self.landing.sample(rng, with_uav)
            return photometric(image, rng, cfg), box
        image, box = self.backgrounds.draw(rng, index), None
        if rng.random() >= cfg.negative_fraction:
            albedo = np.clip(rng.uniform(0.15, 0.95) + rng.uniform(-0.05, 0.05, 3), 0, 1)
            light = rng.standard_normal(3) + np.array([0.0, -1.0, 0.0])
            for _ in range(20):  # redraw poses whose visible part is too small to label
                quat, trans = random_pose(rng, self.camera, cfg)
                rgb, alpha = self.renderer.shaded(quat, trans, image, albedo=tuple(albedo), light_dir=light)
                if np.count_nonzero(alpha >= cfg.coverage_threshold) >= cfg.min_visible_px:
                    box = model_roi(self.mesh.vertices, self.camera.K, quat, trans, self.camera.width,
                                    self.camera.height, oriented=cfg.oriented_labels, faces=self.mesh.faces)
                if box is not None:
                    image = rgb
                    break
        return photometric(image, rng, cfg), box


_WORKER: SampleGenerator | None = None


def _start_worker(cfg: DatasetConfig) -> None:
    global _WORKER
    _WORKER = SampleGenerator(cfg)


def _write_images(out: Path, indices) -> list[float | None]:
    """Write images ``indices`` with the process's generator; the width of each ROI (None: no UAV)."""
    gen, widths = _WORKER, []
    w, h = gen.camera.width, gen.camera.height
    for i in indices:
        label = out / "labels" / f"{i:06d}.txt"
        if label.exists():  # written by an interrupted run (after its image): the same sample
            boxes = read_labels(label, w, h)
            widths.append(float(boxes[0, 2] - boxes[0, 0]) if len(boxes) else None)
            continue
        image, box = gen.sample(i)
        write_image(out / "images" / f"{i:06d}.jpg", image, [cv2.IMWRITE_JPEG_QUALITY, gen.cfg.jpeg_quality])
        label.with_suffix(".tmp").write_text("" if box is None else yolo_line(box, w, h) + "\n")
        label.with_suffix(".tmp").replace(label)
        widths.append(None if box is None else float(box[2] - box[0]))
    return widths


def _record_settings(cfg: DatasetConfig, out: Path) -> None:
    """Write ``out/settings.json`` (atomically), or check that the unfinished run in ``out`` had the
    same settings; images without that record are refused too."""
    settings = json.loads(json.dumps(asdict(cfg)))
    path = out / "settings.json"
    if path.exists():
        recorded = json.loads(path.read_text())
        differ = sorted(k for k in settings.keys() | recorded.keys() if settings.get(k) != recorded.get(k))
        if differ:
            raise ValueError(f"{out} holds part of a dataset made with other settings ({', '.join(differ)}); "
                             "give the same settings to continue it, or choose a new folder")
        return
    if any(p for sub in ("images", "labels") for p in (out / sub).glob("*")):
        raise ValueError(f"{out} holds images but no settings.json to tell what made them; choose a new folder")
    out.mkdir(parents=True, exist_ok=True)
    path.with_suffix(".tmp").write_text(json.dumps(settings, indent=2))
    path.with_suffix(".tmp").replace(path)


def generate(cfg: DatasetConfig, out_dir, progress: bool = True, workers: int = 1) -> dict:
    """Write the dataset to ``out_dir`` (which must not hold one yet); return its summary.

    An interrupted run is continued by running it again with the same settings (any other is
    refused): images whose label exists are kept (image ``i`` depends only on ``(seed, i)``).

    ``workers`` > 1 spreads the images over that many processes (each with its own GL
    context); image ``i`` is the same whichever process makes it."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    if workers < 1:
        raise ValueError("workers must be ≥ 1")
    out = Path(out_dir)
    if (out / "dataset.json").exists():
        raise FileExistsError(f"{out} already holds a dataset; choose a new folder")
    camera = dataset_camera(cfg)
    # Bad images, video or seed are refused before anything is written, and by name (raised in a
    # worker, they broke the pool); with workers, the generator made to check them is freed.
    if workers == 1:
        _start_worker(cfg)
    else:
        SampleGenerator(cfg).release()
    _record_settings(cfg, out)
    (out / "images").mkdir(exist_ok=True)
    (out / "labels").mkdir(exist_ok=True)
    chunks = [range(a, min(a + 25, cfg.count)) for a in range(0, cfg.count, 25)]
    bar = tqdm(total=cfg.count, desc="detection data", unit="img", disable=not progress)
    widths: list[float | None] = []
    pool = None
    if workers > 1:
        pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_start_worker, initargs=(cfg,))
    try:
        for chunk_widths in (pool.map if pool else map)(_write_images, [out] * len(chunks), chunks):
            widths += chunk_widths
            bar.update(len(chunk_widths))
    finally:
        if pool:
            pool.shutdown(cancel_futures=True)
    bar.close()
    found = [x for x in widths if x is not None]
    summary = {"config": asdict(cfg), "width": camera.width, "height": camera.height, "images": cfg.count,
               "positives": len(found),
               "box_width_px_percentiles": np.percentile(found, [0, 5, 50, 95, 100]).round(1).tolist() if found else []}
    (out / "dataset.json").write_text(json.dumps(summary, indent=2))
    return summary
