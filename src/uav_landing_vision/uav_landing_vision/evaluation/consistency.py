"""Does a published pose covariance hold the errors it claims? (Ours: the thesis publishes no covariance.)

A frame's error lies inside the covariance's ``level`` region when its squared Mahalanobis
distance (the NEES) is at most the χ² quantile with 3 degrees of freedom, for the position and
for the rotation separately. The rotation error is the small rotation ``r`` with
``q_true = exp(r) ⊗ q_est``, about the camera's axes, as in the tracker's covariance.
"""

import numpy as np
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

DEPTH_BINS_M = (0.0, 8.0, 15.0, 30.0, 60.0, np.inf)


def depth_bins(depth, bins=DEPTH_BINS_M) -> list[tuple[tuple[float, float] | None, np.ndarray]]:
    """Each bin of ``depth`` (``bins``: edges in m), then all frames: the bin ``(lo, hi)``, or
    None for all, and the mask of its frames (depths in [lo, hi))."""
    depth = np.asarray(depth, float)
    return [((float(lo), float(hi)), (depth >= lo) & (depth < hi)) for lo, hi in zip(bins[:-1], bins[1:])] + [
        (None, np.ones(depth.shape, bool))]


def depth_bin_label(depth_m: tuple[float, float] | None) -> str:
    """A table row's name for a bin of :func:`depth_bins`."""
    if depth_m is None:
        return "all"
    lo, hi = depth_m
    return f"{lo:g}+ m" if np.isinf(hi) else f"{lo:g}-{hi:g} m"


def error_vectors(t_true, q_true, t_est, q_est) -> np.ndarray:
    """``(F, 6)``: position error t − t̂ and rotation error log(q_true ⊗ q̂⁻¹) per frame, in the
    order of a ROS pose covariance; NaN rows where there is no estimate. Both are the truth's
    offset from the estimate, as the tracker's covariance takes each particle's, so the cross
    terms of a 6-D covariance apply with the right sign."""
    t_true, t_est = np.asarray(t_true, float), np.asarray(t_est, float)
    q_true, q_est = np.asarray(q_true, float), np.asarray(q_est, float)
    out = np.full((len(t_true), 6), np.nan)
    ok = np.all(np.isfinite(t_est), axis=1) & np.all(np.isfinite(q_est), axis=1)
    if np.any(ok):
        out[ok, :3] = t_true[ok] - t_est[ok]
        out[ok, 3:] = (Rotation.from_quat(q_true[ok]) * Rotation.from_quat(q_est[ok]).inv()).as_rotvec()
    return out


# Larger entries are no statement of uncertainty, and the eigen-decomposition below fails on
# entries near the float64 limit.
USABLE_COVARIANCE_MAX = 1e150


def nees(errors: np.ndarray, covariances: np.ndarray) -> np.ndarray:
    """``(F,)`` squared Mahalanobis distances ``eᵀ C⁻¹ e`` of ``(F, k)`` errors under ``(F, k, k)``
    covariances; NaN where the error is not finite or the covariance is not finite and positive
    definite (e.g. all zeros, ROS's "unknown"), or has an entry beyond ``USABLE_COVARIANCE_MAX``."""
    e, c = np.asarray(errors, float), np.asarray(covariances, float)
    out = np.full(len(e), np.nan)
    ok = np.all(np.isfinite(e), axis=1) & np.all(np.isfinite(c), axis=(1, 2))
    ok[ok] = np.abs(c[ok]).max(axis=(1, 2)) <= USABLE_COVARIANCE_MAX
    ok[ok] = np.linalg.eigvalsh(0.5 * (c[ok] + np.swapaxes(c[ok], 1, 2)))[:, 0] > 0.0
    if np.any(ok):
        out[ok] = np.einsum("fi,fi->f", e[ok], np.linalg.solve(c[ok], e[ok][..., None])[..., 0])
    return out


def coverage_by_depth(t_true, q_true, t_est, q_est, covariances, bins=DEPTH_BINS_M, level: float = 0.95) -> list[dict]:
    """Per bin of true depth (``bins``: edges in m) and for all frames: ``frames`` with an
    estimate and a usable covariance (see :func:`nees`), and how many of them have their
    ``position`` and ``rotation`` error inside the covariance's ``level`` region."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"level must be in (0, 1), got {level}")
    cov = np.asarray(covariances, float)
    if cov.shape != (len(t_true), 6, 6):
        raise ValueError(f"need one 6x6 covariance per frame, got shape {cov.shape}")
    err = error_vectors(t_true, q_true, t_est, q_est)
    limit = chi2.ppf(level, 3)
    d_pos, d_rot = nees(err[:, :3], cov[:, :3, :3]), nees(err[:, 3:], cov[:, 3:, 3:])
    posed = np.isfinite(d_pos) & np.isfinite(d_rot)
    inside_pos, inside_rot = posed & (d_pos <= limit), posed & (d_rot <= limit)
    return [{"depth_m": depth_m, "frames": int((posed & sel).sum()), "position": int((inside_pos & sel).sum()),
             "rotation": int((inside_rot & sel).sum())}
            for depth_m, sel in depth_bins(np.asarray(t_true, float)[:, 2], bins)]


def format_coverage(coverage: dict[str, list[dict]], title: str) -> str:
    """A text table of :func:`coverage_by_depth` rows (its default 95 % level), one column per
    variant (same bins): ``inside/frames`` for the position, then for the rotation."""
    names = list(coverage)
    width = max(24, *(len(n) + 2 for n in names))
    lines = [f"{title}: errors inside the published covariance's 95 % region (position | rotation)",
             f"{'true depth':<16}" + "".join(f"{n:>{width}}" for n in names)]
    for i, row in enumerate(coverage[names[0]]):
        label = depth_bin_label(row["depth_m"])
        cells = (f"{c['position']}/{c['frames']} | {c['rotation']}/{c['frames']}" for c in (coverage[n][i] for n in names))
        lines.append(f"{label:<16}" + "".join(f"{c:>{width}}" for c in cells))
    return "\n".join(lines)
