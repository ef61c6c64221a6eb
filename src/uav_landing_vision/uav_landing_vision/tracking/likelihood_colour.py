"""Colour similarity metric (§5.4.1.1): inner vs. outer RGB histograms of the silhouette's box."""

from dataclasses import dataclass

import cv2
import numpy as np

from .likelihood_base import SilhouetteLikelihood, nearest_pixel, tile_centres


@dataclass(frozen=True)
class ColourConfig:
    """``bins_per_channel``: 8 in the thesis (B = 24 bins for R, G and B together).

    ``band_px``: width (frame pixels) of the band along the silhouette outline left out of
    both histograms (:func:`outline_band`); 0 is the thesis's metric, every pixel counts.
    """

    bins_per_channel: int = 8
    band_px: float = 0.0

    def __post_init__(self):
        b = self.bins_per_channel
        if not (isinstance(b, int) and 1 <= b <= 85 and 256 % b == 0):
            raise ValueError(f"bins_per_channel must divide 256 and be at most 85, got {b!r}")
        if not self.band_px >= 0.0:
            raise ValueError(f"band_px must be non-negative, got {self.band_px!r}")


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


def outline_band(masks: np.ndarray, boxes: np.ndarray, band_px: float) -> np.ndarray:
    """``(V,T,T)`` bool: tile pixels lying within the outline band of their silhouette.

    A deviation from the thesis, measured in the tracker (see ``config/tracker.yaml``): the
    frame's UAV edge is blurred (optics, motion), so pixels along the true outline hold mixed
    colours that contaminate both histograms; under the square root of (5.14) a few per cent
    of them halve the score, which makes the peak about one pixel wide. The band holds every
    tile pixel whose centre lies nearer the outline than ``max(band_px, s)`` (``s``: the tile
    pixel's size in the frame, so at least the ring next to the outline; city-block distance),
    narrowed per silhouette to half the depth of its deepest pixel, so thin far-away
    silhouettes keep their core.
    """
    v, t, _ = masks.shape
    pad = 8  # zero border: no distance within the band reaches into the next tile
    padded = np.zeros((v, t + 2 * pad, t + 2 * pad), np.uint8)
    padded[:, pad:-pad, pad:-pad] = masks
    stacked = padded.reshape(v * (t + 2 * pad), t + 2 * pad)
    inside = cv2.distanceTransform(stacked, cv2.DIST_L1, 3, dstType=cv2.CV_8U)
    outside = cv2.distanceTransform(1 - stacked, cv2.DIST_L1, 3, dstType=cv2.CV_8U)
    crop = (slice(None), slice(pad, -pad), slice(pad, -pad))
    inside, outside = inside.reshape(padded.shape)[crop], outside.reshape(padded.shape)[crop]
    scale = (boxes[:, 2] - boxes[:, 0]) / t  # frame pixels per tile pixel
    core = inside.reshape(v, -1).max(axis=1) - 0.5  # deepest pixel centre to the outline, tile px
    # centre-to-outline distance (d − ½)·s < width  ⇔  d < width / s + ½, d in tile pixels
    limit = np.minimum(np.maximum(band_px / scale, 1.0), 0.5 * core) + 0.5
    return (inside + outside) < limit[:, None, None]


class ColourHistogramLikelihood(SilhouetteLikelihood):
    """(5.14) used as the likelihood, p(y|x) ∝ d_color, as the thesis states.

    Every tile pixel samples the frame's pixel under its centre (one gather for all poses);
    inside pixels fill the inner histogram, the rest of the silhouette's tight axis-aligned
    bounding box the outer one (the thesis's outer region lies between the UAV and its OBB,
    Fig. 5.7; ours is the axis-aligned box); pixels outside the image count in neither, nor,
    with ``band_px > 0``, those of the outline band (:func:`outline_band`). A pose with an
    empty inner or outer region scores 0.
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

    def _counts(self, masks: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """Raw bin counts ``(V, 4, B)`` of V visible tiles, one bincount for all; region
        ``2·band + inside``: outer, inner, outer in the outline band, inner in the band."""
        v, t, _ = masks.shape
        xs, ys = tile_centres(boxes, t)
        rows, cols = nearest_pixel(np.stack([xs, ys], axis=-1), self.width, self.height)
        ok_x = (xs >= -0.5) & (xs < self.width - 0.5)
        ok_y = (ys >= -0.5) & (ys < self.height - 0.5)
        ok = ok_y[:, :, None] & ok_x[:, None, :] & silhouette_box(masks)
        region = masks.astype(np.intp)
        if self.config.band_px > 0.0:
            region = region + 2 * outline_band(masks, boxes, self.config.band_px)
        samples = self._bins[rows[:, :, None] * self.width + cols[:, None, :]]  # (V, T, T, 3)
        dump = 4 * v * self.bins  # keys from here on are dropped
        base = np.where(ok, (np.arange(v)[:, None, None] * 4 + region) * self.bins, dump)
        counts = np.bincount((base[..., None] + samples).ravel(), minlength=dump + self.bins)
        return counts[:dump].reshape(v, 4, self.bins).astype(float)

    def histograms(self, masks: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw inner and outer bin counts ``(V, B)`` of V visible tiles, outline band left out."""
        counts = self._counts(masks, boxes)
        return counts[:, 1], counts[:, 0]

    def _score_visible(self, masks: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """(5.14); with an outline band, the mean of (5.14) without the band and with every pixel."""
        counts = self._counts(masks, boxes)
        d = _similarity(counts[:, 1], counts[:, 0])
        if self.config.band_px > 0.0:
            d = 0.5 * (d + _similarity(counts[:, 1] + counts[:, 3], counts[:, 0] + counts[:, 2]))
        return d


def _similarity(inner: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """(5.14) of raw counts, clipped to [0, 1]; 0 where either region is empty."""
    n_in, n_out = inner.sum(axis=1, keepdims=True), outer.sum(axis=1, keepdims=True)
    ok = (n_in[:, 0] > 0) & (n_out[:, 0] > 0)
    d = colour_similarity(inner / np.maximum(n_in, 1), outer / np.maximum(n_out, 1))
    return np.where(ok, np.clip(d, 0.0, 1.0), 0.0)
