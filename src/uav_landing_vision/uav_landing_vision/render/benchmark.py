"""Silhouette throughput: median time of one batched ``Renderer.silhouettes`` call."""

import time

import numpy as np

from ..camera import load_camera_info_yaml
from ..geometry import quat_normalise
from ..model import fixed_wing_mesh
from ..resources import config_path
from .renderer import Renderer


def random_poses(camera, count: int, rng: np.random.Generator, near: float = 5.0, far: float = 80.0):
    """Uniformly random attitudes at 5–80 m, centred anywhere in the middle 80 % of the image."""
    z = rng.uniform(near, far, count)
    u = rng.uniform(0.1, 0.9, count) * camera.width
    v = rng.uniform(0.1, 0.9, count) * camera.height
    K = camera.K
    trans = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=1)
    return quat_normalise(rng.normal(size=(count, 4))), trans


def run(particles=(100, 300), tiles=(64, 128), repeats: int = 20, seed: int = 0) -> list[dict]:
    """One row per (mesh, particles, tile): median ms per call and particles per second.

    Every combination with the "low" mesh, plus the largest batch and tile with "high".
    """
    camera = load_camera_info_yaml(config_path("camera.yaml")).rectified()
    rng = np.random.default_rng(seed)
    cases = [("low", m, t) for m in particles for t in tiles] + [("high", max(particles), max(tiles))]
    meshes = {level: fixed_wing_mesh(level) for level in ("low", "high")}
    rows = []
    for level, m, tile in cases:
        renderer = Renderer(camera, meshes[level], tile=tile, max_batch=max(particles))
        quats, trans = random_poses(camera, m, rng)
        renderer.silhouettes(quats, trans)  # warm-up: shader compilation, first frame
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            renderer.silhouettes(quats, trans)
            times.append(time.perf_counter() - start)
        ms = 1e3 * float(np.median(times))
        rows.append(
            {
                "mesh": level,
                "triangles": meshes[level].triangle_count,
                "particles": m,
                "tile": tile,
                "ms": round(ms, 2),
                "particles_per_s": round(m / ms * 1e3),
                "gl_renderer": renderer.gl_renderer,
            }
        )
        renderer.release()
    return rows


def format_rows(rows: list[dict]) -> str:
    """A plain-text table of :func:`run`'s rows."""
    lines = [f"renderer: {rows[0]['gl_renderer']}" if rows else "renderer: -"]
    lines.append(f"{'mesh':<5} {'tris':>5} {'particles':>9} {'tile':>5} {'ms/call':>8} {'particles/s':>12}")
    for r in rows:
        lines.append(
            f"{r['mesh']:<5} {r['triangles']:>5} {r['particles']:>9} {r['tile']:>5} "
            f"{r['ms']:>8.2f} {r['particles_per_s']:>12}"
        )
    return "\n".join(lines)
