"""Motion filters (§5.2.3–5.3, App. A, C, D, E), vectorised over a batch of filters (one per particle).

``make_rotation_filter(MotionFilterConfig(rotation_filter="ukf" | "ubif" | "ubigaf"))`` and
``TranslationFilter(cfg)`` are what the tracker uses; :mod:`.bingham` is the Bingham toolkit.
"""

from .motion import KINDS, MotionFilterConfig, RotationFilter, TranslationFilter, make_rotation_filter
from .ukf import concat_filters, take_filters

__all__ = [
    "KINDS",
    "MotionFilterConfig",
    "RotationFilter",
    "TranslationFilter",
    "concat_filters",
    "make_rotation_filter",
    "take_filters",
]
