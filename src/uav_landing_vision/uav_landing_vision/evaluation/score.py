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


def _refuse_unusable(poses: Poses, what: str, lost_allowed: bool) -> None:
    """ValueError naming the stamps of a zero quaternion or, unless ``lost_allowed`` (an estimate's
    lost frames), of a value that is not finite."""
    norm = np.linalg.norm(poses.quat, axis=1)
    bad = norm < 1e-12
    if not lost_allowed:
        bad |= ~(np.isfinite(norm) & np.all(np.isfinite(poses.trans), axis=1))
    if np.any(bad):
        raise ValueError(f"the {what} has no usable pose (a zero quaternion or a value that is not finite) "
                         f"at stamp(s) {poses.stamps_ns[bad][:3].tolist()}")


def score(truth: Poses, estimate: Poses) -> dict[str, np.ndarray]:
    """Per-frame errors (see :func:`pose_errors`) over the ground-truth frames. An estimate none of
    whose stamps is a ground-truth stamp is a ValueError: its clock, not its tracker, is off."""
    est = align(truth, estimate)
    if len(estimate.stamps_ns) and len(truth.stamps_ns) and not np.isin(estimate.stamps_ns, truth.stamps_ns).any():
        raise ValueError(f"none of the estimate's {len(estimate.stamps_ns)} stamps is a ground-truth stamp (first "
                         f"{int(estimate.stamps_ns[0])} ns against {int(truth.stamps_ns[0])} ns): the estimate "
                         "must carry the stamps of the frames it was made from")
    _refuse_unusable(truth, "ground truth", lost_allowed=False)
    _refuse_unusable(est, "estimate", lost_allowed=True)
    return pose_errors(truth.trans, truth.quat, est.trans, est.quat)


def mean_ms_per_frame(path) -> float | None:
    """Mean of an estimate CSV's optional ``ms`` column (processing time per frame), else None."""
    path = Path(path)
    if path.suffix != ".csv":
        return None
    values = []
    with path.open(newline="") as f:
        reader = csv.DictReader(f)
        for row in reader:
            if row.get("ms") not in (None, ""):
                try:
                    values.append(float(row["ms"]))
                except ValueError:
                    raise ValueError(f"{path}: line {reader.line_num}: ms {row['ms']!r} is not a number") from None
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
