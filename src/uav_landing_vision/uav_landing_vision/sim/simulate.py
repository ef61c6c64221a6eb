"""A whole simulated sequence: scenario → trajectory → frames → rosbag2 (and PNG + CSV)."""

import shutil
import time
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..camera import CameraModel, load_camera_info_yaml
from ..resources import config_file
from .backgrounds import make_background
from .config import Scenario, ScenarioError
from .trajectory import Trajectory, landing_approach, single_frame_poses

# Child seeds, in this fixed order, one per subsystem: adding frames never changes earlier draws.
_STREAMS = ("uav", "ship", "background", "noise")


@dataclass(frozen=True)
class SimulationResult:
    frames: int
    seconds: float
    bag_dir: Path


def generators(seed: int) -> dict[str, np.random.Generator]:
    """One independent generator per subsystem, derived from the scenario seed."""
    children = np.random.SeedSequence(seed).spawn(len(_STREAMS))
    return {name: np.random.default_rng(s) for name, s in zip(_STREAMS, children)}


def scenario_camera(scenario: Scenario) -> CameraModel:
    """The camera of the scenario's ``camera_info`` (a ``config/`` file name or a path)."""
    return load_camera_info_yaml(config_file(scenario.camera_info))


def make_trajectory(scenario: Scenario, rngs: dict[str, np.random.Generator]) -> Trajectory:
    """The scenario's ground-truth sequence (landing approach or single-frame poses)."""
    if scenario.approach is not None:
        return landing_approach((rngs["uav"], rngs["ship"]), scenario.approach, scenario.ship, scenario.dt_s)
    return single_frame_poses(rngs["uav"], scenario.single_frame, scenario.ship, scenario.dt_s)


def stamps_ns(scenario: Scenario, times_s: np.ndarray) -> np.ndarray:
    """Header stamps (ns) of frames at ``times_s`` after the scenario's start time."""
    return np.int64(round(scenario.start_time_s * 1e9)) + np.round(np.asarray(times_s) * 1e9).astype(np.int64)


def sun_direction(scenario: Scenario) -> np.ndarray:
    """Unit vector towards the sun in M."""
    az, el = np.radians([scenario.background.sun_azimuth_deg, scenario.background.sun_elevation_deg])
    return np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


@contextmanager
def staged(path: Path):
    """Yield where to write the new folder ``path``: inside a sibling ``<path>.partial`` folder
    (replacing one left by a killed run); it becomes ``path`` only if the block succeeds and is
    deleted otherwise, so that an interrupted or failed run never leaves a complete-looking one."""
    if path.exists():
        raise FileExistsError(f"{path} exists already; give a new directory")
    staging = path.with_name(path.name + ".partial")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    try:
        yield staging / path.name
        (staging / path.name).rename(path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def simulate(scenario: Scenario, bag_dir, *, seed: int | None = None, frames: int | None = None,
             video: str | None = None, png_dir=None, compress: bool = False, progress: bool = True,
             mesh=None) -> SimulationResult:
    """Generate the sequence of ``scenario`` (seed overridden by ``seed``) into the new folder
    ``bag_dir`` (and ``png_dir``); both appear only once complete (:func:`staged`).

    ``frames`` keeps the first N frames of the sequence (the approach length is set by the
    seed's start range and speed). Returns the frame count and the wall time.
    """
    from tqdm import tqdm

    from .bag import SequenceWriter
    from .synthesis import FrameSynthesizer

    start = time.perf_counter()
    rngs = generators(scenario.seed if seed is None else seed)
    traj = make_trajectory(scenario, rngs)
    if frames is not None:
        if frames > len(traj):
            raise ScenarioError(f"scenario '{scenario.name}' with this seed has {len(traj)} frames; "
                                f"--frames {frames} is too many (raise start_range_m or lower the speed)")
        traj = traj.head(frames)
    stamps = stamps_ns(scenario, traj.times_s)
    late = np.flatnonzero(stamps >= 2**31 * 10**9)  # builtin_interfaces/Time.sec is an int32
    if late.size:
        raise ScenarioError(f"frame {late[0]} would be stamped {stamps[late[0]] / 1e9:.3f} s, past the ROS time "
                            "range (2^31 s): lower start_time_s")
    camera = scenario_camera(scenario)
    with FrameSynthesizer(camera, scenario.imaging, mesh) as synth:
        background = make_background(scenario.background, synth.render_camera, scenario.ship, rngs["background"], video)
        sun = sun_direction(scenario)
        centres = synth.render_camera.project_pinhole(traj.trans)
        shifts = np.zeros_like(centres)
        if traj.continuous:
            shifts[1:] = np.diff(centres, axis=0) * scenario.imaging.exposure_fraction
            lengths = np.linalg.norm(shifts, axis=1, keepdims=True)
            shifts *= np.minimum(1.0, scenario.imaging.max_blur_px / np.maximum(lengths, 1e-9))

        with ExitStack() as stack:
            bag = stack.enter_context(staged(Path(bag_dir)))
            png = stack.enter_context(staged(Path(png_dir))) if png_dir else None
            writer = stack.enter_context(SequenceWriter(bag, camera, png_dir=png, compress=compress))
            for i in tqdm(range(len(traj)), desc=f"simulate {scenario.name}", unit="frame", disable=not progress):
                bg = background.frame(i, traj.times_s[i], traj.cam_rot[i], traj.cam_pos[i])
                light = traj.cam_rot[i].T @ sun
                raw, _ = synth.frame(bg, traj.quat[i], traj.trans[i], light, shifts[i], rngs["noise"])
                writer.write(int(stamps[i]), raw, traj.trans[i], traj.quat[i])
    return SimulationResult(len(traj), time.perf_counter() - start, Path(bag_dir))
