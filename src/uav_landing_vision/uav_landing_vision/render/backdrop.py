"""A plain procedural backdrop (sky gradient over sea) for benchmarks and tests."""

import numpy as np


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
