"""Colour similarity metric (§5.4.1.1): inner vs. outer RGB histograms of the silhouette's box."""

from dataclasses import dataclass

import cv2
import numpy as np

from .likelihood_base import SilhouetteLikelihood, tile_centres

BIN_COUNTS = (2, 4, 8, 16, 32, 64)  # bins per channel: divide 256, and 3·b < 256 packs a sample into a byte


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
        if isinstance(b, bool) or not isinstance(b, int) or b not in BIN_COUNTS:
            raise ValueError(f"bins_per_channel must be one of {BIN_COUNTS} (a power of two dividing 256), got {b!r}")
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
    pad = max(8, t // 8 + 2)  # zero border wider than half the widest band: no tile reaches the next
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
        """Bin of every pixel (row-major) in each channel, channel c's bins being c·b … c·b + b − 1,
        packed one byte per channel into an int32 (3·b ≤ 255 by the config's check)."""
        width = 256 // self.config.bins_per_channel
        bins = (frame // np.uint8(width)).reshape(-1, 3).astype(np.int32)
        b = self.config.bins_per_channel
        self._bins = bins[:, 0] | (bins[:, 1] + b) << 8 | (bins[:, 2] + 2 * b) << 16

    def _counts(self, masks: np.ndarray, boxes: np.ndarray, shifts: np.ndarray) -> np.ndarray:
        """Raw bin counts ``(V, S, 4, B)`` of V visible tiles, each sampled with its silhouette
        moved by each of the S image shifts; region ``2·band + inside``: outer, inner, outer in
        the outline band, inner in the band. Only the pixels of each silhouette's box are
        gathered; one bincount per channel for all tiles and shifts."""
        v, t, _ = masks.shape
        s = len(shifts)
        region = masks.astype(np.int32)
        if self.config.band_px > 0.0:
            region = region + 2 * outline_band(masks, boxes, self.config.band_px)
        inbox = np.flatnonzero(silhouette_box(masks))
        owner, rows, cols = inbox // (t * t), inbox // t % t, inbox % t
        xs, ys = tile_centres(boxes, t)  # frame pixel under each tile column / row, per shift:
        x = np.floor(xs + shifts[:, :1, None] + 0.5).reshape(s, -1)
        y = np.floor(ys + shifts[:, 1:, None] + 0.5).reshape(s, -1)
        x = np.where((x >= 0) & (x < self.width), x, -1).astype(np.int32)[:, owner * t + cols]  # (S, N)
        y = np.where((y >= 0) & (y < self.height), y, -1).astype(np.int32)[:, owner * t + rows]
        ok = (x >= 0) & (y >= 0)
        samples = self._bins[np.where(ok, y * self.width + x, 0)]
        dump = s * v * 4 * self.bins  # keys from here on are dropped
        tiles = np.arange(s, dtype=np.int32)[:, None] * v + owner.astype(np.int32)
        base = np.where(ok, (tiles * 4 + region.reshape(-1)[inbox]) * self.bins, dump)
        counts = sum(np.bincount((base + (samples >> 8 * c & 0xFF)).ravel(), minlength=dump + self.bins)
                     for c in range(3))
        return counts[:dump].reshape(s, v, 4, self.bins).swapaxes(0, 1).astype(float)

    def histograms(self, masks: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Raw inner and outer bin counts ``(V, B)`` of V visible tiles, outline band left out."""
        counts = self._counts(masks, boxes, np.zeros((1, 2)))[:, 0]
        return counts[:, 1], counts[:, 0]

    def _score_visible(self, masks: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        return self._score_visible_shifted(masks, boxes, np.zeros((1, 2)))[:, 0]

    def _score_visible_shifted(self, masks: np.ndarray, boxes: np.ndarray, shifts: np.ndarray) -> np.ndarray:
        """(5.14) per tile and shift ``(V, S)``; with an outline band, the mean of (5.14) without
        the band and with every pixel."""
        counts = self._counts(masks, boxes, shifts).reshape(-1, 4, self.bins)
        d = _similarity(counts[:, 1], counts[:, 0])
        if self.config.band_px > 0.0:
            d = 0.5 * (d + _similarity(counts[:, 1] + counts[:, 3], counts[:, 0] + counts[:, 2]))
        return d.reshape(len(masks), len(shifts))


def _similarity(inner: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """(5.14) of raw counts, clipped to [0, 1]; 0 where either region is empty."""
    n_in, n_out = inner.sum(axis=1, keepdims=True), outer.sum(axis=1, keepdims=True)
    ok = (n_in[:, 0] > 0) & (n_out[:, 0] > 0)
    d = colour_similarity(inner / np.maximum(n_in, 1), outer / np.maximum(n_out, 1))
    return np.where(ok, np.clip(d, 0.0, 1.0), 0.0)
