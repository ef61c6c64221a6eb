"""Shared machinery of the §5.4.1 likelihoods: frame checks, the batched render, tile geometry.

A likelihood is built once per process around a :class:`~uav_landing_vision.render.Renderer`.
``prepare(frame)`` does the per-frame work once; ``score(quats, trans)`` renders all poses in
one instanced draw and scores them together; ``score_batch`` scores a batch already rendered.
Tile pixel (row r, column c) of a box ``[x0, y0, x1, y1]`` samples the image at
``(x0 + (c+½)s, y0 + (r+½)s)`` with ``s = (x1 − x0)/T`` (boxes are square, :mod:`render.boxes`).
"""

from abc import ABC, abstractmethod

import cv2
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


_BINOMIAL = np.array([1, 4, 6, 4, 1], np.float32) / 16
_CRACKS = ((0, 1), (0, -1), (1, 0), (-1, 0))  # (row, column) step to the outside neighbour


def outline_points(masks: np.ndarray, boxes: np.ndarray):
    """Sample points on the silhouette outline of every tile, with outward unit normals.

    A point sits on each crack between an inside tile pixel and an outside 4-neighbour
    (mid-way between their centres), so the outline is found to half a tile pixel. The normal
    is the outward gradient of the mask smoothed by a 5×5 binomial kernel, at the inside pixel
    (the crack's direction where that gradient vanishes). Returns image points ``(N, 2)``,
    normals ``(N, 2)`` and the owning tile of each point ``(N,)``; a tile's points come in an
    order that does not depend on the other tiles of the batch.
    """
    v, t, _ = masks.shape
    p = 3  # zero border per tile: the 5×5 kernel never mixes two tiles of the stack
    padded = np.zeros((v, t + 2 * p, t + 2 * p), np.uint8)
    padded[:, p:-p, p:-p] = masks
    inside = padded[:, p:-p, p:-p].astype(bool)
    cracks = np.stack([inside & (padded[:, p + dr : p + dr + t, p + dc : p + dc + t] == 0) for dr, dc in _CRACKS])
    d, owner, rows, cols = np.unravel_index(np.flatnonzero(cracks), cracks.shape)
    stacked = padded.reshape(v * (t + 2 * p), t + 2 * p).astype(np.float32)
    smooth = cv2.sepFilter2D(stacked, -1, _BINOMIAL, _BINOMIAL, borderType=cv2.BORDER_CONSTANT)
    flat = (owner * (t + 2 * p) + rows + p) * (t + 2 * p) + cols + p
    smooth = smooth.ravel()
    row = t + 2 * p
    grad = np.stack([smooth[flat - 1] - smooth[flat + 1], smooth[flat - row] - smooth[flat + row]], axis=1)
    steps = np.array(_CRACKS, float)[d][:, ::-1]  # (dx, dy)
    length = np.linalg.norm(grad, axis=1, keepdims=True).astype(float)
    normals = np.where(length > 1e-6, grad / np.maximum(length, 1e-12), steps)
    scale = ((boxes[owner, 2] - boxes[owner, 0]) / t)[:, None]
    centre = np.stack([cols, rows], axis=1) + 0.5 + 0.5 * steps
    return boxes[owner, :2] + centre * scale, normals, owner


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
        return self.score_shifted(batch, np.zeros((1, 2)))[:, 0]

    def score_shifted(self, batch: SilhouetteBatch, shifts) -> np.ndarray:
        """Likelihoods ``(M, S)`` of an already rendered batch with every silhouette moved in
        the image by each shift ``(S, 2)`` (frame pixels, x right, y down), the frame sampled
        there without rendering again. Poses invisible unshifted score 0 at every shift."""
        if not self._prepared:
            raise RuntimeError(f"{type(self).__name__}: call prepare(frame) before scoring")
        shifts = np.asarray(shifts, float).reshape(-1, 2)
        out = np.zeros((len(batch.visible), len(shifts)))
        vis = np.flatnonzero(batch.visible)
        if vis.size:
            out[vis] = self._score_visible_shifted(batch.masks[vis], batch.boxes[vis], shifts)
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

    def _score_visible_shifted(self, masks: np.ndarray, boxes: np.ndarray, shifts: np.ndarray) -> np.ndarray:
        """``(V, S)`` likelihoods with the silhouettes moved by each shift: by default one
        :meth:`_score_visible` per shift, on the moved boxes."""
        return np.stack([self._score_visible(masks, boxes + np.tile(s, 2)) for s in shifts], axis=1)
