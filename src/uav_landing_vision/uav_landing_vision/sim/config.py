"""Scenario files (``config/scenarios/*.yaml``): one dataclass per simulator part, strict loading.

Every key has a default; an unknown key, a wrong type or an out-of-range value is a
:class:`ScenarioError` naming the key. Angles are in degrees in the files (DESIGN §3).
"""

import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import yaml

from ..config import ConfigError, UniqueKeyLoader, from_mapping
from ..resources import config_path


class ScenarioError(ConfigError):
    """A scenario file or value that the simulator cannot use."""


MAX_FRAMES = 1_000_000  # longest sequence (an approach of a few days of simulation)


@dataclass(frozen=True)
class ApproachConfig:
    """Landing approach inside the landing cone (Fig. 1.5), relative to the ship."""

    start_range_m: tuple[float, float] = (80.0, 100.0)  # camera–UAV distance at the first frame
    cone_start_m: float = 50.0  # d: the cone begins this far from the landing area
    alpha1_deg: float = 10.0  # maximum apparent descent angle
    alpha2_deg: float = 3.0  # minimum apparent descent angle
    beta2_deg: float = 20.0  # full horizontal opening: |β1| ≤ β2/2
    airspeed_mps: float = 15.0  # cruise speed (Table 1.1); the ship's speed is subtracted
    speed_jitter_mps: float = 0.3  # smooth variation of the closing speed
    angle_of_attack_deg: float = 3.0
    path_wander_deg: float = 1.5  # smooth wander of the apparent angles about the nominal line
    roll_far_deg: float = 15.0  # RMS roll disturbance at and beyond `disturbance_range_m`
    roll_near_deg: float = 3.0  # RMS roll disturbance at the net
    pitch_far_deg: float = 4.0
    pitch_near_deg: float = 1.0
    yaw_far_deg: float = 5.0
    yaw_near_deg: float = 1.0
    disturbance_range_m: float = 60.0
    disturbance_band_hz: tuple[float, float] = (0.1, 0.8)


@dataclass(frozen=True)
class SingleFrameConfig:
    """The single-frame protocol of §6.4/§6.6: independent poses at fixed distances, static camera."""

    distances_m: tuple[float, ...] = (5.0, 15.0, 25.0, 35.0, 45.0)
    poses_per_distance: int = 20
    angle_limit_deg: float = 180.0  # α, β, γ uniform in [−limit, limit] (90 for §6.4's hemisphere)


@dataclass(frozen=True)
class ShipConfig:
    """The patrol boat: forward speed, wave-induced motion and where the camera sits.

    Ship frame: origin at the centre of the net (landing point), x forward, y port, z up.
    The camera mount is given by a position and Z-Y-X roll/pitch/yaw of a camera body frame
    whose x axis is the optical axis (yaw 180° looks aft, negative pitch tilts it up).
    """

    speed_mps: float = 8.0
    net_height_m: float = 2.0  # net centre above the waterline
    camera_position_m: tuple[float, float, float] = (5.0, 0.0, 0.5)
    camera_rpy_deg: tuple[float, float, float] = (0.0, -2.0, 180.0)
    roll_deg: float = 2.5  # RMS of each motion
    pitch_deg: float = 1.5
    yaw_deg: float = 0.5
    heave_m: float = 0.3
    wave_period_s: tuple[float, float] = (5.0, 10.0)


@dataclass(frozen=True)
class BackgroundConfig:
    """Background kind and its parameters (``normal``, ``complex`` or ``video``)."""

    kind: str = "normal"
    sun_azimuth_deg: float = 150.0  # from the ship's bow, positive to port
    sun_elevation_deg: float = 35.0
    cloud_drift_deg_s: float = 0.6  # complex: horizontal translation of the sky (wraps around)
    sea_jitter_m: float = 0.05  # normal and complex: random per-frame displacement of the sea surface (§6.2.1)
    video: str = ""  # video: a video file or a rosbag2 directory/file
    video_topic: str = ""  # video: image topic in a bag (default: the first sensor_msgs/Image)


@dataclass(frozen=True)
class ImagingConfig:
    """Frame synthesis: shading, blur, noise."""

    albedo: tuple[float, float, float] = (0.82, 0.82, 0.80)
    samples: int = 4  # anti-aliasing samples of the renderer
    exposure_fraction: float = 0.3  # motion blur length = this × apparent motion per frame
    max_blur_px: float = 9.0
    noise_sigma: float = 2.0  # sensor noise, grey levels (0–255)


@dataclass(frozen=True)
class Scenario:
    name: str = "normal"
    seed: int = 0
    dt_s: float = 0.034
    start_time_s: float = 1_700_000_000.0  # header stamp of the first frame
    camera_info: str = "camera.yaml"  # a path (a relative one from the scenario file's folder) or a config/ file name
    approach: ApproachConfig | None = None
    single_frame: SingleFrameConfig | None = None
    ship: ShipConfig = field(default_factory=ShipConfig)
    background: BackgroundConfig = field(default_factory=BackgroundConfig)
    imaging: ImagingConfig = field(default_factory=ImagingConfig)


BACKGROUND_KINDS = ("normal", "complex", "video")
SECTIONS = ("approach", "single_frame", "ship", "background", "imaging")


def load_scenario(name_or_path) -> Scenario:
    """A shipped scenario by name (``normal``, ``complex``, ``video``, …) or any scenario YAML file."""
    path = Path(name_or_path)
    if not path.suffix:
        try:
            path = config_path(f"scenarios/{name_or_path}.yaml")
        except FileNotFoundError as exc:
            raise ScenarioError(f"no shipped scenario named {name_or_path!r}: {exc}") from exc
    try:
        doc = yaml.load(path.read_bytes(), UniqueKeyLoader)  # bytes: an undecodable file is a YAMLError
    except (OSError, yaml.YAMLError) as exc:
        raise ScenarioError(f"cannot read scenario {path}: {exc}") from exc
    if not isinstance(doc, dict):
        raise ScenarioError(f"{path}: a scenario must be a YAML mapping")
    doc.setdefault("name", path.stem)
    for key in SECTIONS:  # "approach:" with nothing (or only comments) under it: an empty section
        if key in doc and doc[key] is None:
            doc[key] = {}
    try:
        scenario = from_mapping(Scenario, doc, str(path))
    except ConfigError as exc:
        raise ScenarioError(str(exc)) from exc
    return validate(_with_files_found(scenario, path.parent), str(path))


def _with_files_found(s: Scenario, folder: Path) -> Scenario:
    """``s`` with a relative ``camera_info`` or video path taken from the scenario's ``folder``, a
    ``camera_info`` not there from ``config/`` (never from the working directory: a ./camera.yaml
    replaced the shipped scenarios' calibration unnoticed); a file found nowhere keeps the
    folder's path, which its reader names."""
    def found(name: str, shipped: bool) -> str:
        if not name or Path(name).is_absolute():
            return name
        if (folder / name).exists():
            return str((folder / name).resolve())
        if shipped:
            try:
                return str(config_path(name))
            except FileNotFoundError:
                pass
        return str((folder / name).resolve())  # not there: its reader names where it was looked for

    background = replace(s.background, video=found(s.background.video, shipped=False))
    return replace(s, camera_info=found(s.camera_info, shipped=True), background=background)


def validate(s: Scenario, where: str = "scenario") -> Scenario:
    """Check value ranges and the choice of exactly one trajectory kind; return ``s``."""
    def need(cond, msg):
        if not cond:
            raise ScenarioError(f"{where}: {msg}")

    need((s.approach is None) != (s.single_frame is None), "give exactly one of 'approach' or 'single_frame'")
    need(s.dt_s >= 1e-6, f"dt_s must be at least 1e-06 s (stamps are in ns), got {s.dt_s}")
    need(s.seed >= 0, f"seed must be non-negative, got {s.seed}")
    need(0 <= s.start_time_s < 2**31, f"start_time_s must be in [0, 2^31) s (a ROS time stamp), got {s.start_time_s}")
    need(math.isfinite(s.background.sun_azimuth_deg), "background.sun_azimuth_deg must be finite")
    need(0 <= s.background.sun_elevation_deg <= 90,
         f"background.sun_elevation_deg must be in [0, 90] (above the horizon), got {s.background.sun_elevation_deg}")
    need(s.background.kind in BACKGROUND_KINDS, f"background.kind must be one of {BACKGROUND_KINDS}")
    need(s.background.sea_jitter_m >= 0, "background.sea_jitter_m must be non-negative")
    _need_non_negative(need, "ship", s.ship, ("roll_deg", "pitch_deg", "yaw_deg", "heave_m"))
    need(s.ship.net_height_m + s.ship.camera_position_m[2] > 0,
         "the camera must be above the waterline (ship.net_height_m + camera_position_m[2] > 0)")
    a = s.approach
    if a is not None:
        need(0 < a.alpha2_deg < a.alpha1_deg < 45, "approach needs 0 < alpha2_deg < alpha1_deg < 45")
        need(0 < a.beta2_deg < 90, "approach.beta2_deg must be in (0, 90)")
        need(10 < a.start_range_m[0] <= a.start_range_m[1], "approach.start_range_m must be [low, high] above 10 m")
        net = math.hypot(*s.ship.camera_position_m)
        need(a.start_range_m[0] > net,
             f"approach.start_range_m must start beyond the net ({net:.1f} m from the camera)")
        need(a.cone_start_m > 0, "approach.cone_start_m must be positive")
        need(a.disturbance_range_m > 0, "approach.disturbance_range_m must be positive")
        _need_non_negative(need, "approach", a, ("roll_far_deg", "roll_near_deg", "pitch_far_deg", "pitch_near_deg",
                                                 "yaw_far_deg", "yaw_near_deg"))
        need(a.airspeed_mps > s.ship.speed_mps, "approach.airspeed_mps must exceed ship.speed_mps (the UAV must close in)")
        need(0 < a.disturbance_band_hz[0] < a.disturbance_band_hz[1], "approach.disturbance_band_hz must be [low, high] > 0")
        need(a.path_wander_deg >= 0 and a.speed_jitter_mps >= 0, "approach wander/jitter must be non-negative")
        need(a.speed_jitter_mps < (a.airspeed_mps - s.ship.speed_mps) / 4,
             "approach.speed_jitter_mps must be under a quarter of the closing speed (airspeed_mps - ship.speed_mps): "
             "its peaks reach 3.5 times it, and the UAV must keep closing in")
    f = s.single_frame
    if f is not None:
        need(all(d > 0 for d in f.distances_m) and f.distances_m, "single_frame.distances_m must be positive")
        need(f.poses_per_distance >= 1, "single_frame.poses_per_distance must be at least 1")
        need(len(f.distances_m) * f.poses_per_distance <= MAX_FRAMES,
             f"single_frame: {len(f.distances_m)} distances × {f.poses_per_distance} poses is over {MAX_FRAMES} frames")
        need(0 < f.angle_limit_deg <= 180, "single_frame.angle_limit_deg must be in (0, 180]")
    need(s.ship.wave_period_s[0] > 0 and s.ship.wave_period_s[0] <= s.ship.wave_period_s[1], "ship.wave_period_s must be [low, high] > 0")
    need(s.ship.net_height_m > 0, "ship.net_height_m must be positive")
    im = s.imaging
    need(all(0 <= c <= 1 for c in im.albedo), "imaging.albedo values must be in [0, 1]")
    need(im.samples >= 1 and im.noise_sigma >= 0 and im.exposure_fraction >= 0 and im.max_blur_px >= 0,
         "imaging: samples ≥ 1 and non-negative noise/blur")
    return s


def _need_non_negative(need, section: str, cfg, names) -> None:
    """Check that the RMS values ``names`` of ``cfg`` are not negative."""
    for name in names:
        need(getattr(cfg, name) >= 0, f"{section}.{name} must be non-negative, got {getattr(cfg, name)}")
