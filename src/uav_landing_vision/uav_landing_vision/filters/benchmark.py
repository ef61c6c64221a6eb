"""Time one predict + update step of each motion filter for a batch of particles."""

import time

import numpy as np

from ..geometry import quat_normalise
from .motion import KINDS, MotionFilterConfig, TranslationFilter, make_rotation_filter


def run(m: int = 100, repeats: int = 200, seed: int = 0) -> dict[str, float]:
    """Median milliseconds per predict + update step of ``m`` filters, for each filter.

    Keys: ``ukf_translation``, the rotation filters ``ukf``, ``ubif``, ``ubigaf``, and the same
    with the outlier-aware update (``ukf+outliers`` …, ``outlier_prob`` 0.12).
    """
    rng = np.random.default_rng(seed)
    quat = quat_normalise(rng.standard_normal((m, 4)))
    meas = quat_normalise(quat + 0.05 * rng.standard_normal((m, 4)))
    cfg = MotionFilterConfig()
    filters = {"ukf_translation": TranslationFilter(cfg)}
    filters.update({k: make_rotation_filter(MotionFilterConfig(rotation_filter=k)) for k in KINDS})
    filters.update({f"{k}+outliers": make_rotation_filter(MotionFilterConfig(rotation_filter=k, outlier_prob=0.12))
                    for k in KINDS})
    out = {}
    for name, filt in filters.items():
        if name == "ukf_translation":
            state, z = filt.init(rng.normal(0, 10, (m, 3)), np.zeros((m, 3))), rng.normal(0, 10, (m, 3))
        else:
            state, z = filt.init(quat, rng.normal(0, 1, (m, 3))), meas
        times = []
        for _ in range(repeats + 5):
            start = time.perf_counter()
            state = filt.update(filt.predict(state), z)
            times.append(time.perf_counter() - start)
        out[name] = 1e3 * float(np.median(times[5:]))
    return out
