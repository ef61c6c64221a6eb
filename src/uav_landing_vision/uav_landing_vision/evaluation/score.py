"""Score estimated poses against a simulated sequence's ground truth, matched by header stamp."""

import csv
from pathlib import Path

import numpy as np

from ..sim.bag import Poses, read_poses
from .statistics import pose_errors


def align(truth: Poses, estimate: Poses) -> Poses:
    """The estimate at each ground-truth stamp (exact match); NaN where there is none (lost).
    An estimate with more than one pose at a stamp is a ValueError."""
    stamps, counts = np.unique(estimate.stamps_ns, return_counts=True)
    if np.any(counts > 1):
        raise ValueError(f"the estimate has more than one pose at stamp(s) {stamps[counts > 1][:3].tolist()}; "
                         "give one per frame")
    index = {int(s): i for i, s in enumerate(estimate.stamps_ns)}
    rows = np.array([index.get(int(s), -1) for s in truth.stamps_ns], dtype=int)
    found = rows >= 0
    trans = np.full((len(rows), 3), np.nan)
    quat = np.full((len(rows), 4), np.nan)
    trans[found] = estimate.trans[rows[found]]
    quat[found] = estimate.quat[rows[found]]
    return Poses(truth.stamps_ns, trans, quat)


def score(truth: Poses, estimate: Poses) -> dict[str, np.ndarray]:
    """Per-frame errors (see :func:`pose_errors`) over the ground-truth frames."""
    est = align(truth, estimate)
    return pose_errors(truth.trans, truth.quat, est.trans, est.quat)


def mean_ms_per_frame(path) -> float | None:
    """Mean of an estimate CSV's optional ``ms`` column (processing time per frame), else None."""
    path = Path(path)
    if path.suffix != ".csv":
        return None
    with path.open(newline="") as f:
        values = [float(r["ms"]) for r in csv.DictReader(f) if r.get("ms") not in (None, "")]
    return float(np.mean(values)) if values else None


def score_files(truth_path, estimate_path, topic: str = "") -> tuple[dict[str, np.ndarray], float | None]:
    """Errors of an estimate file (CSV, or bag topic ``topic``, default ``/uav/pose``) against a
    ground truth (bag or simulator PNG folder), and the estimate's mean ms per frame if known."""
    truth = read_poses(truth_path)
    if not len(truth.stamps_ns):
        raise ValueError(f"{truth_path} holds no ground-truth pose")
    estimate_path = Path(estimate_path)
    estimate = read_poses(estimate_path, topic or "/uav/pose")
    return score(truth, estimate), mean_ms_per_frame(estimate_path)
