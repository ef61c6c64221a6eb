"""A short fly-by of the UAV model towards the deck camera, rendered shaded to PNG files."""

from pathlib import Path

import cv2
import numpy as np

from ..camera import load_camera_info_yaml
from ..geometry import euler_zyx_to_quat, matrix_to_quat, quat_multiply
from ..model import fixed_wing_mesh
from ..resources import config_path
from .renderer import Renderer

# Body axes of a UAV flying straight at the camera, level: nose towards the camera (−z),
# left wing to the image right (+x), up to the image top (−y).
_FACING_CAMERA = matrix_to_quat(np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]]))


def sky_and_sea(width: int, height: int, horizon: float = 0.6) -> np.ndarray:
    """A procedural RGB background: sky gradient above the horizon row, darker sea below."""
    rows = np.arange(height, dtype=float)[:, None]
    h = horizon * height
    sky_t = np.clip(rows / h, 0.0, 1.0)
    sea_t = np.clip((rows - h) / max(height - h, 1.0), 0.0, 1.0)
    sky = (1 - sky_t) * np.array([70.0, 120.0, 200.0]) + sky_t * np.array([190.0, 215.0, 235.0])
    sea = (1 - sea_t) * np.array([60.0, 95.0, 125.0]) + sea_t * np.array([20.0, 45.0, 70.0])
    column = np.where(rows < h, sky, sea)
    return np.broadcast_to(column[:, None, :], (height, width, 3)).round().astype(np.uint8)


def flyby_poses(frames: int, start: float = 60.0, end: float = 8.0):
    """Quaternions and translations (camera optical frame) of a descending, rolling approach."""
    s = np.linspace(0.0, 1.0, frames)
    z = start + (end - start) * s
    x = 0.08 * z * np.sin(2.0 * np.pi * s)  # a gentle S-turn across the image
    y = -np.tan(np.radians(3.0)) * z - 0.5  # on a 3° glide slope above the camera axis
    roll = np.radians(25.0) * np.cos(2.0 * np.pi * s)
    pitch = np.radians(3.0) * np.ones(frames)  # about the body y axis (left): nose 3° down
    yaw = np.radians(10.0) * np.sin(2.0 * np.pi * s)
    attitude = euler_zyx_to_quat(np.stack([roll, pitch, yaw], axis=1))
    return quat_multiply(_FACING_CAMERA, attitude), np.stack([x, y, z], axis=1)


def render_flyby(out_dir, frames: int = 24) -> list[Path]:
    """Render ``frames`` PNGs (``flyby_000.png`` …) into ``out_dir``; return their paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    camera = load_camera_info_yaml(config_path("camera.yaml")).rectified()
    renderer = Renderer(camera, fixed_wing_mesh("high"))
    background = sky_and_sea(camera.width, camera.height)
    paths = []
    for i, (q, t) in enumerate(zip(*flyby_poses(frames))):
        rgb, _ = renderer.shaded(q, t, background)
        path = out_dir / f"flyby_{i:03d}.png"
        if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1])):
            raise OSError(f"cannot write {path}")
        paths.append(path)
    return paths
