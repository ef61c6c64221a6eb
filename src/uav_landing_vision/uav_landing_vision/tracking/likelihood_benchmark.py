"""Likelihood throughput: median ms of one batched render and of each metric's scoring pass."""

import time

import numpy as np

from ..camera import load_camera_info_yaml
from ..model import fixed_wing_mesh
from ..render import Renderer
from ..render.benchmark import random_poses
from ..render.backdrop import sky_and_sea
from ..resources import config_path
from .likelihood import LIKELIHOODS, make_likelihood


def _median_ms(fn, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return round(1e3 * float(np.median(times)), 2)


def run(particles: int = 100, tile: int = 64, repeats: int = 20, seed: int = 0) -> dict:
    """ms for ``silhouettes`` (render + readback), per-frame ``prepare`` and ``score_batch``
    of every metric, for ``particles`` random poses ("low" mesh) on a 1280×720 frame."""
    camera = load_camera_info_yaml(config_path("camera.yaml")).rectified()
    renderer = Renderer(camera, fixed_wing_mesh("low"), tile=tile, max_batch=particles)
    rng = np.random.default_rng(seed)
    frame, _ = renderer.shaded(*random_poses(camera, 1, rng, 5.0, 20.0), sky_and_sea(camera.width, camera.height))
    quats, trans = random_poses(camera, particles, rng)
    renderer.silhouettes(quats, trans)  # warm-up
    result = {"particles": particles, "tile": tile, "gl_renderer": renderer.gl_renderer,
              "render_ms": _median_ms(lambda: renderer.silhouettes(quats, trans), repeats),
              "prepare_ms": {}, "score_ms": {}}
    batch = renderer.silhouettes(quats, trans)
    for name in LIKELIHOODS:
        likelihood = make_likelihood(name, renderer)
        result["prepare_ms"][name] = _median_ms(lambda: likelihood.prepare(frame), repeats)
        result["score_ms"][name] = _median_ms(lambda: likelihood.score_batch(batch), repeats)
    return result


def format_result(result: dict) -> str:
    """Plain-text lines of :func:`run`'s result."""
    lines = [f"renderer: {result['gl_renderer']}; {result['particles']} particles, tile {result['tile']} px",
             f"render + readback: {result['render_ms']:.2f} ms",
             f"{'metric':<20} {'prepare ms/frame':>17} {'score ms/call':>14}"]
    for name, ms in result["score_ms"].items():
        lines.append(f"{name:<20} {result['prepare_ms'][name]:>17.2f} {ms:>14.2f}")
    return "\n".join(lines)
