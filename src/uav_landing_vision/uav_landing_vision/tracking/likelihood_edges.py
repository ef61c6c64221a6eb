"""Edge-based similarity metrics: contour (§5.4.1.2, 5.15) and distance transform (§5.4.1.3, 5.16–5.17).

Both compare the frame's Canny edges, found once per frame in ``prepare``, with the outline
of each rendered silhouette (:func:`.likelihood_base.outline_points`): the silhouette tiles
carry no interior creases, so the outline stands for the model's visible edges.
"""

from dataclasses import dataclass

import cv2
import numpy as np

from .likelihood_base import SilhouetteLikelihood, in_image, nearest_pixel, outline_points


@dataclass(frozen=True)
class EdgeConfig:
    """Canny on the grey frame after a Gaussian blur of ``blur_sigma`` px (0: none)."""

    canny_low: float = 50.0
    canny_high: float = 150.0
    blur_sigma: float = 1.0

    def __post_init__(self):
        if not 0 <= self.canny_low <= self.canny_high:
            raise ValueError(f"need 0 <= canny_low <= canny_high, got {self.canny_low}, {self.canny_high}")
        if not 0 <= self.blur_sigma <= 10:
            raise ValueError(f"blur_sigma must be in [0, 10] px, got {self.blur_sigma}")


@dataclass(frozen=True)
class ContourConfig:
    """§6.5.1: search distances of 15 and 25 px were tested, with λ_v = λ_e = 1."""

    search_px: int = 15
    lambda_v: float = 1.0
    lambda_e: float = 1.0
    edges: EdgeConfig = EdgeConfig()

    def __post_init__(self):
        if isinstance(self.search_px, bool) or not (isinstance(self.search_px, int) and 1 <= self.search_px <= 200):
            raise ValueError(f"search_px must be an integer in [1, 200], got {self.search_px!r}")
        if not (self.lambda_v >= 0 and self.lambda_e >= 0):
            raise ValueError(f"lambda_v and lambda_e must be non-negative, got {self.lambda_v}, {self.lambda_e}")


@dataclass(frozen=True)
class DistanceTransformConfig:
    """§6.5.1: σ of 25, 50 and 100 were tested; d is in units of the image diagonal (ours)."""

    sigma: float = 50.0
    edges: EdgeConfig = EdgeConfig()

    def __post_init__(self):
        if not 0 < self.sigma <= 1e4:
            raise ValueError(f"sigma must be in (0, 1e4], got {self.sigma}")


def canny_edges(frame: np.ndarray, config: EdgeConfig) -> np.ndarray:
    """Canny edge map (bool, H×W) of an RGB frame."""
    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    if config.blur_sigma > 0:
        grey = cv2.GaussianBlur(grey, (0, 0), config.blur_sigma)
    return cv2.Canny(grey, config.canny_low, config.canny_high, L2gradient=True) > 0


def contour_likelihood(p_v, p_m, e_mean, lambda_v: float, lambda_e: float):
    """Contour metric L = exp(−λ_v (p_v − p_m)/p_v) · exp(−λ_e ē) (5.15), elementwise.

    ``p_v`` visible sample points (> 0), ``p_m`` matched ones, ``e_mean`` their mean distance
    to the matched edge (px).
    """
    return np.exp(-lambda_v * (p_v - p_m) / p_v) * np.exp(-lambda_e * e_mean)


def dt_likelihood(d, sigma: float):
    """Distance-transform metric L_DT = exp(−σ d) (5.16), elementwise."""
    return np.exp(-sigma * d)


def mean_edge_distance(dt_at_edges: np.ndarray, owner: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """d = (1/k) Σ_i E(ȳ)(i) D(y)(i) (5.17) for ``count`` hypotheses at once.

    ``dt_at_edges``: D of the frame at each hypothesis edge pixel, ``owner``: its hypothesis.
    Returns d and k per hypothesis (d is 0 where k is 0).
    """
    k = np.bincount(owner, minlength=count)
    total = np.bincount(owner, weights=dt_at_edges, minlength=count)
    return total / np.maximum(k, 1), k


class ContourLikelihood(SilhouetteLikelihood):
    """(5.15) on the silhouette outline; p(y|x) ∝ L_contour as in the thesis.

    Sample points: the outline points of each tile; visible (p_v): those inside the image. Each
    searches its normal line, ±``search_px`` image pixels in 1 px steps, for the nearest frame
    edge pixel; a hit is a match (p_m) at distance |step|. With no match, ē is taken as
    ``search_px`` (the thesis leaves it undefined). No visible sample point: likelihood 0.
    """

    def __init__(self, renderer, config: ContourConfig = ContourConfig()):
        super().__init__(renderer)
        self.config = config
        r = config.search_px
        self._steps = np.array([0] + [s for k in range(1, r + 1) for s in (k, -k)], dtype=float)
        self._edges: np.ndarray | None = None

    def _prepare(self, frame: np.ndarray) -> None:
        """The edge map, padded by ``search_px + 1`` non-edge pixels and flattened, so that a
        search line from any point inside the image needs no bounds check."""
        pad = self.config.search_px + 1
        self._edges = np.pad(canny_edges(frame, self.config.edges), pad).ravel()

    def _score_visible(self, masks: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        v, cfg = len(masks), self.config
        points, normals, owner = outline_points(masks, boxes)
        visible = in_image(points, self.width, self.height)
        points, normals, owner = points[visible], normals[visible], owner[visible]
        pad, wp = self.config.search_px + 1, self.width + 2 * self.config.search_px + 2
        line_x = np.floor(points[:, :1] + self._steps * normals[:, :1] + (0.5 + pad)).astype(np.intp)
        line_y = np.floor(points[:, 1:] + self._steps * normals[:, 1:] + (0.5 + pad)).astype(np.intp)
        hits = self._edges[line_y * wp + line_x]  # nearest steps first
        matched = hits.any(axis=1)
        dist = np.abs(self._steps[np.argmax(hits, axis=1)])
        p_v = np.bincount(owner, minlength=v).astype(float)
        p_m = np.bincount(owner, weights=matched, minlength=v)
        e_sum = np.bincount(owner, weights=np.where(matched, dist, 0.0), minlength=v)
        e_mean = np.where(p_m > 0, e_sum / np.maximum(p_m, 1), float(cfg.search_px))
        out = contour_likelihood(np.maximum(p_v, 1), p_m, e_mean, cfg.lambda_v, cfg.lambda_e)
        return np.where(p_v > 0, out, 0.0)


class DistanceTransformLikelihood(SilhouetteLikelihood):
    """(5.16)–(5.17) on the silhouette outline; p(y|x) ∝ L_DT as in the thesis.

    ``prepare`` computes the frame's Canny edges and their Euclidean distance transform once,
    divided by the image diagonal so that the thesis's σ (25–100) gives usable values (ours:
    the thesis does not state the unit of d). Hypothesis edge pixels E(ȳ): the outline points
    inside the image; D is read at the pixel under each. A frame without edges has D = 1.
    No edge pixel in the image (k = 0): likelihood 0.
    """

    def __init__(self, renderer, config: DistanceTransformConfig = DistanceTransformConfig()):
        super().__init__(renderer)
        self.config = config
        self._dt: np.ndarray | None = None

    def _prepare(self, frame: np.ndarray) -> None:
        edges = canny_edges(frame, self.config.edges)
        diagonal = float(np.hypot(self.width, self.height))
        if not edges.any():
            self._dt = np.ones(edges.shape, np.float32)
            return
        dt = cv2.distanceTransform(np.where(edges, 0, 255).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE)
        # OpenCV's float32 distances differ in their last bits between one thread and several; the
        # exact squared distances are integers: round them and take the root again, so D is exact
        # and the same on every machine.
        dt = dt.astype(np.float64)
        np.sqrt(np.rint(np.square(dt, out=dt), out=dt), out=dt)
        self._dt = np.minimum(dt / diagonal, 1.0).astype(np.float32)

    def _score_visible(self, masks: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        points, _, owner = outline_points(masks, boxes)
        visible = in_image(points, self.width, self.height)
        points, owner = points[visible], owner[visible]
        rows, cols = nearest_pixel(points, self.width, self.height)
        d, k = mean_edge_distance(self._dt[rows, cols].astype(float), owner, len(masks))
        return np.where(k > 0, dt_likelihood(d, self.config.sigma), 0.0)
