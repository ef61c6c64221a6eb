"""Approximate likelihoods of §5.4.1 (colour 5.14, contour 5.15, distance transform 5.16–5.17).

Usage: ``lik = make_likelihood("colour", renderer)``, then per frame ``lik.prepare(frame)``
and per iteration ``lik.score(quats, trans)`` (or ``lik(particles)`` as an optimiser
objective): one batched render and one vectorised scoring pass for all particles.
"""

from ..config import ConfigError, from_mapping
from .likelihood_base import SilhouetteLikelihood, check_frame
from .likelihood_colour import ColourConfig, ColourHistogramLikelihood, colour_similarity
from .likelihood_edges import (
    ContourConfig,
    ContourLikelihood,
    DistanceTransformConfig,
    DistanceTransformLikelihood,
    EdgeConfig,
    canny_edges,
    contour_likelihood,
    dt_likelihood,
    mean_edge_distance,
)

LIKELIHOODS = {
    "colour": (ColourHistogramLikelihood, ColourConfig),
    "contour": (ContourLikelihood, ContourConfig),
    "distance_transform": (DistanceTransformLikelihood, DistanceTransformConfig),
}


def make_likelihood(name: str, renderer, config=None) -> SilhouetteLikelihood:
    """The metric ``name`` (a key of :data:`LIKELIHOODS`) around ``renderer``.

    ``config``: None (the thesis's values), the metric's config dataclass, or a mapping of its
    fields (strictly checked, as the YAML loader does).
    """
    if name not in LIKELIHOODS:
        raise ValueError(f"unknown likelihood {name!r}; known: {sorted(LIKELIHOODS)}")
    cls, config_cls = LIKELIHOODS[name]
    if config is None:
        config = config_cls()
    elif isinstance(config, dict):
        config = from_mapping(config_cls, config, f"likelihood {name}")
    elif not isinstance(config, config_cls):
        raise ConfigError(f"likelihood {name!r} takes a {config_cls.__name__}, got {type(config).__name__}")
    return cls(renderer, config)


__all__ = [
    "LIKELIHOODS",
    "ColourConfig",
    "ColourHistogramLikelihood",
    "ContourConfig",
    "ContourLikelihood",
    "DistanceTransformConfig",
    "DistanceTransformLikelihood",
    "EdgeConfig",
    "SilhouetteLikelihood",
    "canny_edges",
    "check_frame",
    "colour_similarity",
    "contour_likelihood",
    "dt_likelihood",
    "make_likelihood",
    "mean_edge_distance",
]
