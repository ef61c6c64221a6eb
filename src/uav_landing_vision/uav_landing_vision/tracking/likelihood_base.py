"""Shared machinery of the §5.4.1 likelihoods: frame checks, the batched render, tile geometry.

A likelihood is built once per process around a :class:`~uav_landing_vision.render.Renderer`.
``prepare(frame)`` does the per-frame work once; ``score(quats, trans)`` renders all poses in
one instanced draw and scores them together; ``score_batch`` scores a batch already rendered.
Tile pixel (row r, column c) of a box ``[x0, y0, x1, y1]`` samples the image at
``(x0 + (c+½)s, y0 + (r+½)s)`` with ``s = (x1 − x0)/T`` (boxes are square, :mod:`render.boxes`).
"""

from abc import ABC, abstractmethod

import numpy as np

from ..render import Renderer, SilhouetteBatch


def check_frame(frame, width: int, height: int) -> np.ndarray:
    """``frame`` as a contiguous ``(height, width, 3)`` uint8 RGB array, else ValueError."""
    if not isinstance(frame, np.ndarray):
        raise ValueError(f"frame must be a numpy array, got {type(frame).__name__}")
    if frame.size == 0:
        raise ValueError(f"frame is empty (shape {frame.shape})")
    if frame.dtype != np.uint8:
        raise ValueError(f"frame must be uint8 RGB, got dtype {frame.dtype}")
    if frame.shape != (height, width, 3):
        raise ValueError(f"frame must have shape ({height}, {width}, 3), got {frame.shape}")
    return np.ascontiguousarray(frame)


def tile_centres(boxes: np.ndarray, tile: int) -> tuple[np.ndarray, np.ndarray]:
    """Image x of every tile column and y of every tile row: two ``(M, T)`` arrays."""
    frac = (np.arange(tile) + 0.5) / tile
    xs = boxes[:, 0:1] + frac * (boxes[:, 2:3] - boxes[:, 0:1])
    ys = boxes[:, 1:2] + frac * (boxes[:, 3:4] - boxes[:, 1:2])
    return xs, ys


def outline_points(masks: np.ndarray, boxes: np.ndarray):
    """Sample points on the silhouette outline of every tile, with outward unit normals.

    A point sits on each crack between an inside tile pixel and an outside 4-neighbour
    (mid-way between their centres), so the outline is found to half a tile pixel. The normal
    is the outward gradient of the mask smoothed by a 5×5 binomial kernel at the inside pixel
    (the crack's direction where that gradient vanishes). Returns image points ``(N, 2)``,
    normals ``(N, 2)`` and the owning tile of each point ``(N,)``, ordered by tile.
    """
    m, t, _ = masks.shape
    inside = masks.astype(bool)
    padded = np.pad(inside, ((0, 0), (1, 1), (1, 1)))
    smooth = np.pad(masks.astype(np.float32), ((0, 0), (3, 3), (3, 3)))
    for axis in (1, 2):  # binomial [1 4 6 4 1]/16 along rows, then columns
        n = smooth.shape[axis] - 4
        take = [np.take(smooth, np.arange(k, k + n), axis=axis) for k in range(5)]
        smooth = (take[0] + 4 * take[1] + 6 * take[2] + 4 * take[3] + take[4]) / 16
    gx = 0.5 * (smooth[:, 1:-1, 2:] - smooth[:, 1:-1, :-2])
    gy = 0.5 * (smooth[:, 2:, 1:-1] - smooth[:, :-2, 1:-1])
    owner, rows, cols, dirs = [], [], [], []
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        crack = inside & ~padded[:, 1 + dr : 1 + dr + t, 1 + dc : 1 + dc + t]
        k, r, c = np.nonzero(crack)
        owner.append(k)
        rows.append(r)
        cols.append(c)
        dirs.append(np.broadcast_to(np.array([dc, dr], float), (len(k), 2)))
    owner, rows, cols, dirs = (np.concatenate(a) for a in (owner, rows, cols, dirs))
    order = np.argsort(owner, kind="stable")
    owner, rows, cols, dirs = owner[order], rows[order], cols[order], dirs[order]
    scale = (boxes[owner, 2] - boxes[owner, 0]) / t
    points = np.stack(
        [boxes[owner, 0] + (cols + 0.5 + 0.5 * dirs[:, 0]) * scale, boxes[owner, 1] + (rows + 0.5 + 0.5 * dirs[:, 1]) * scale],
        axis=1,
    )
    grad = -np.stack([gx[owner, rows, cols], gy[owner, rows, cols]], axis=1).astype(float)
    length = np.linalg.norm(grad, axis=1, keepdims=True)
    normals = np.where(length > 1e-6, grad / np.maximum(length, 1e-12), dirs)
    return points, normals, owner


def in_image(points: np.ndarray, width: int, height: int) -> np.ndarray:
    """Whether image points ``(..., 2)`` fall on a pixel of the image (OpenCV coordinates)."""
    x, y = points[..., 0], points[..., 1]
    return (x >= -0.5) & (x < width - 0.5) & (y >= -0.5) & (y < height - 0.5)


def nearest_pixel(points: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of the pixel under each point, clipped into the image."""
    col = np.clip(np.floor(points[..., 0] + 0.5).astype(np.intp), 0, width - 1)
    row = np.clip(np.floor(points[..., 1] + 0.5).astype(np.intp), 0, height - 1)
    return row, col


class SilhouetteLikelihood(ABC):
    """Base of the §5.4.1 metrics: per-frame ``prepare``, batched ``score``; higher is better.

    Poses the renderer marks invisible, and poses with nothing of the model to compare inside
    the image, score 0. An instance is also an optimiser objective: ``likelihood(particles)``.
    """

    def __init__(self, renderer: Renderer):
        self.renderer = renderer
        self.width, self.height = renderer.width, renderer.height
        self._prepared = False

    def prepare(self, frame: np.ndarray) -> None:
        """Per-frame precomputation, once per frame, before any ``score`` on it."""
        self._prepare(check_frame(frame, self.width, self.height))
        self._prepared = True

    def score(self, quats: np.ndarray, trans: np.ndarray) -> np.ndarray:
        """Likelihoods ``(M,)`` of M poses, rendered in one batched call."""
        return self.score_batch(self.renderer.silhouettes(quats, trans))

    def score_batch(self, batch: SilhouetteBatch) -> np.ndarray:
        """Likelihoods ``(M,)`` of an already rendered batch."""
        if not self._prepared:
            raise RuntimeError(f"{type(self).__name__}: call prepare(frame) before scoring")
        out = np.zeros(len(batch.visible))
        vis = np.flatnonzero(batch.visible)
        if vis.size:
            out[vis] = self._score_visible(batch.masks[vis], batch.boxes[vis])
        return out

    def __call__(self, particles) -> np.ndarray:
        """The optimisers' objective: likelihoods of a ``ParticleSet``'s poses."""
        return self.score(particles.quat, particles.pos)

    @abstractmethod
    def _prepare(self, frame: np.ndarray) -> None:
        """Store what scoring needs from the checked frame."""

    @abstractmethod
    def _score_visible(self, masks: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """Likelihoods of visible poses from their tiles ``(V,T,T)`` and boxes ``(V,4)``."""
