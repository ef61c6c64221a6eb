"""Colour similarity metric (§5.4.1.1): inner vs. outer RGB histograms of the silhouette's box."""

from dataclasses import dataclass

import numpy as np

from .likelihood_base import SilhouetteLikelihood, nearest_pixel, tile_centres


@dataclass(frozen=True)
class ColourConfig:
    """``bins_per_channel``: 8 in the thesis (B = 24 bins for R, G and B together)."""

    bins_per_channel: int = 8

    def __post_init__(self):
        b = self.bins_per_channel
        if not (isinstance(b, int) and 1 <= b <= 85 and 256 % b == 0):
            raise ValueError(f"bins_per_channel must divide 256 and be at most 85, got {b!r}")


def colour_similarity(h_inner: np.ndarray, h_outer: np.ndarray) -> np.ndarray:
    """Bhattacharyya-based colour metric d_color = 1 − Σ_b sqrt(h_in(b) h_out(b)) (5.14).

    ``h_inner``, ``h_outer``: ``(..., B)`` histograms, each normalised to sum 1 over all B
    bins (the three channels' histograms concatenated). 1 when the UAV's colours and the
    background's around it share no bin, 0 when they are identical.
    """
    return 1.0 - np.sum(np.sqrt(h_inner * h_outer), axis=-1)


def silhouette_box(masks: np.ndarray) -> np.ndarray:
    """``(V,T,T)`` bool: the tile pixels inside each silhouette's tight axis-aligned box."""
    t = masks.shape[1]
    rows, cols = masks.any(axis=2), masks.any(axis=1)
    idx = np.arange(t)

    def span(any_):
        first = np.argmax(any_, axis=1)[:, None]
        last = t - 1 - np.argmax(any_[:, ::-1], axis=1)[:, None]
        return (idx >= first) & (idx <= last) & any_.any(axis=1, keepdims=True)

    return span(rows)[:, :, None] & span(cols)[:, None, :]


class ColourHistogramLikelihood(SilhouetteLikelihood):
    """(5.14) used as the likelihood, p(y|x) ∝ d_color, as the thesis states.

    Every tile pixel samples the frame's pixel under its centre (one gather for all poses);
    inside pixels fill the inner histogram, the rest of the silhouette's tight axis-aligned
    bounding box the outer one (the thesis's outer region lies between the UAV and its OBB,
    Fig. 5.7; ours is the axis-aligned box); pixels outside the image count in neither. A pose
    with an empty inner or outer region scores 0.
    """

    def __init__(self, renderer, config: ColourConfig = ColourConfig()):
        super().__init__(renderer)
        self.config = config
        self._bins: np.ndarray | None = None

    @property
    def bins(self) -> int:
        """B: histogram bins of the three channels together."""
        return 3 * self.config.bins_per_channel

    def _prepare(self, frame: np.ndarray) -> None:
        """Bin index of every pixel (row-major) and channel: channel c's bins are c·b … c·b + b − 1."""
        width = 256 // self.config.bins_per_channel
        offsets = np.arange(3, dtype=np.uint8) * np.uint8(self.config.bins_per_channel)
        self._bins = (frame // np.uint8(width) + offsets).reshape(-1, 3)

    def histograms(self, masks: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw inner and outer bin counts ``(V, B)`` of V visible tiles, one bincount for all."""
        v, t, _ = masks.shape
        xs, ys = tile_centres(boxes, t)
        rows, cols = nearest_pixel(np.stack([xs, ys], axis=-1), self.width, self.height)
        ok_x = (xs >= -0.5) & (xs < self.width - 0.5)
        ok_y = (ys >= -0.5) & (ys < self.height - 0.5)
        ok = ok_y[:, :, None] & ok_x[:, None, :] & silhouette_box(masks)
        samples = self._bins[rows[:, :, None] * self.width + cols[:, None, :]]  # (V, T, T, 3)
        dump = 2 * v * self.bins  # keys from here on are dropped
        base = np.where(ok, (np.arange(v)[:, None, None] * 2 + masks) * self.bins, dump)
        counts = np.bincount((base[..., None] + samples).ravel(), minlength=dump + self.bins)
        counts = counts[:dump].reshape(v, 2, self.bins)
        return counts[:, 1].astype(float), counts[:, 0].astype(float)

    def _score_visible(self, masks: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        inner, outer = self.histograms(masks, boxes)
        n_in, n_out = inner.sum(axis=1, keepdims=True), outer.sum(axis=1, keepdims=True)
        ok = (n_in[:, 0] > 0) & (n_out[:, 0] > 0)
        d = colour_similarity(inner / np.maximum(n_in, 1), outer / np.maximum(n_out, 1))
        return np.where(ok, np.clip(d, 0.0, 1.0), 0.0)
