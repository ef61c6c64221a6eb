"""The landing simulator (§6.2): trajectories, backgrounds, frame synthesis, rosbag2 output."""

from .backgrounds import BackgroundError, ComplexBackground, NormalBackground, VideoBackground, make_background
from .bag import (
    Poses,
    SequenceWriter,
    iter_frames,
    iter_images,
    read_camera,
    read_pose_csv,
    read_poses,
    write_pose_csv,
)
from .config import Scenario, ScenarioError, load_scenario
from .simulate import generators, make_trajectory, scenario_camera, simulate
from .trajectory import Trajectory, camera_mount, cone_direction, landing_approach, single_frame_poses

__all__ = [
    "BackgroundError",
    "ComplexBackground",
    "NormalBackground",
    "Poses",
    "Scenario",
    "ScenarioError",
    "SequenceWriter",
    "Trajectory",
    "VideoBackground",
    "camera_mount",
    "cone_direction",
    "generators",
    "iter_frames",
    "iter_images",
    "landing_approach",
    "load_scenario",
    "make_background",
    "make_trajectory",
    "read_camera",
    "read_pose_csv",
    "read_poses",
    "scenario_camera",
    "simulate",
    "single_frame_poses",
    "write_pose_csv",
]
