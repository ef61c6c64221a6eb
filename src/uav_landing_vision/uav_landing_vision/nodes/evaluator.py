"""``evaluator``: scores the tracked poses of a replayed sequence against its ground truth (§6.7).

Subscribes ``uav/pose`` (PoseWithCovarianceStamped) and ``uav/ground_truth`` (PoseStamped),
both reliable and keep-all (a stalled process loses none), and pairs them by exact
``header.stamp`` (``evaluation.align``); a ground-truth frame without a pose counts as lost.
Of the poses without ground truth only the newest :data:`POSES_WITHOUT_TRUTH` are kept (a live
graph, which has none, runs for hours). The report is written to ``out_dir`` when the node ends:

- on shutdown (Ctrl-C, SIGTERM; e.g. when ``uav-landing graph`` stops after the bag), or
- when done: ``frames`` > 0 ground-truth frames have been received and then ``settle_s``
  seconds passed (for the last poses), or ``idle_timeout_s`` > 0 seconds passed without any
  ground truth after the first. The node then exits with code 0.

Report (``evaluation.write_report`` / ``make_summary``): ``tables.txt``, ``translation_error.csv``,
``rotation_error.csv``, the two error plots (PNG), ``summary.json`` (the schema of every
evaluation command, ``ms_per_frame`` null) and ``estimates.csv`` (the poses, for
``uav-landing score``). ``tables.txt`` ends with how many errors lie inside the published
covariance's 95 % region, by true depth (``evaluation.consistency``; poses whose covariance is
not positive definite, e.g. all zeros, are left out of that count). Without any ground truth
nothing is written (logged); with fewer than ``frames`` ground-truth frames (a run stopped
early), the report says so near its end (INCOMPLETE) and the log warns, as it does for poses
that never met their ground truth (UNSCORED, the report's last line). Non-finite poses, non-unit
quaternions and repeated stamps are logged, counted and dropped.
"""

import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import rclpy
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped

from ..config import ConfigError
from ..evaluation import (
    align,
    format_errors_by_depth,
    make_summary,
    pose_errors,
    save_summary,
    variant_summary,
    write_report,
)
from ..evaluation.consistency import coverage_by_depth, format_coverage
from ..sim import Poses, write_pose_csv
from ..stamps import stamp_ns
from .base import SHUTDOWN_ERRORS, LandingNode, run_node, stopped_by_shutdown
from .poses import pose_to_numpy
from .qos import KEEP_ALL_QOS

SPIN_S = 0.1
# Poses kept while their ground truth has not come (the newest): a live graph runs this node too, and
# without ground truth it would hold every pose of a run of hours. A replay's truth precedes its pose.
POSES_WITHOUT_TRUTH = 300


@dataclass(frozen=True)
class EvaluatorConfig:
    out_dir: str = "out/evaluation"  # report folder (created); relative to the working directory
    sequence: str = "sequence"  # name in the tables and the JSON summary
    variant: str = "tracker"  # column name of the estimates (e.g. C4N2)
    frames: int = 0  # > 0: done after this many ground-truth frames (+ settle_s); 0: until shutdown
    settle_s: float = 2.0
    idle_timeout_s: float = 0.0  # > 0: done after this long without ground truth; 0: off

    def __post_init__(self):
        if not self.out_dir or not self.sequence or not self.variant:
            raise ValueError("out_dir, sequence and variant must not be empty")
        if self.frames < 0 or self.settle_s < 0.0 or self.idle_timeout_s < 0.0:
            raise ValueError("need frames >= 0, settle_s >= 0 and idle_timeout_s >= 0")


class EvaluatorNode(LandingNode):
    def __init__(self, **kwargs):
        super().__init__("evaluator", **kwargs)
        self.config = self.load_config(EvaluatorConfig)
        out = Path(self.config.out_dir).absolute()  # checked now, not once the replay is over and the report lost
        existing = next(p for p in (out, *out.parents) if p.exists())
        if not (existing.is_dir() and os.access(existing, os.W_OK | os.X_OK)):
            raise ConfigError(f"out_dir: cannot write the report into '{self.config.out_dir}': "
                              f"{existing} is not a writable folder")
        self.truth: dict[int, tuple] = {}
        self.estimates: dict[int, tuple] = {}
        self.covariances: dict[int, np.ndarray] = {}
        self._without_truth: dict[int, None] = {}  # stamps of the poses whose ground truth has not come, oldest first
        self._last_truth = None  # monotonic time of the last ground truth
        self.report_dir: Path | None = None
        self.create_subscription(PoseWithCovarianceStamped, "uav/pose", self._on_pose, KEEP_ALL_QOS)
        self.create_subscription(PoseStamped, "uav/ground_truth", self._on_truth, KEEP_ALL_QOS)

    def _store(self, into: dict, what: str, stamp: int, pose) -> bool:
        try:
            value = pose_to_numpy(pose)
        except ValueError as exc:
            self.drop(f"{what} rejected: {exc}")
            return False
        if stamp in into:
            self.drop(f"{what}: a second message stamped {stamp} ns")
            return False
        into[stamp] = value
        return True

    def _on_pose(self, msg: PoseWithCovarianceStamped) -> None:
        self.counters["received"] += 1
        stamp = stamp_ns(msg.header.stamp)
        if self._store(self.estimates, "uav/pose", stamp, msg.pose.pose):
            self.covariances[stamp] = np.asarray(msg.pose.covariance, float).reshape(6, 6)
            if stamp not in self.truth:
                self._hold_without_truth(stamp)

    def _hold_without_truth(self, stamp: int) -> None:
        """Keep the pose of ``stamp`` among the last :data:`POSES_WITHOUT_TRUTH` without ground truth;
        the oldest beyond them is forgotten (counted)."""
        self._without_truth[stamp] = None
        while len(self._without_truth) > POSES_WITHOUT_TRUTH:
            oldest = next(iter(self._without_truth))
            del self._without_truth[oldest], self.estimates[oldest], self.covariances[oldest]
            self.counters["poses_without_truth_dropped"] += 1

    def _on_truth(self, msg: PoseStamped) -> None:
        self.counters["truth_received"] += 1
        stamp = stamp_ns(msg.header.stamp)
        if self._store(self.truth, "uav/ground_truth", stamp, msg.pose):
            self._without_truth.pop(stamp, None)
            self._last_truth = time.monotonic()

    def done(self) -> bool:
        """Whether the sequence is over by ``frames`` (+ ``settle_s``) or ``idle_timeout_s``."""
        if self._last_truth is None:
            return False
        quiet_s = time.monotonic() - self._last_truth
        cfg = self.config
        return (0 < cfg.frames <= len(self.truth) and quiet_s >= cfg.settle_s) or (0 < cfg.idle_timeout_s <= quiet_s)

    def write(self) -> Path | None:
        """Write the report of what was received; its folder, or None without ground truth."""
        cfg = self.config
        if not self.truth:
            self.get_logger().warn("no ground truth received: no report written")
            return None
        truth = _poses(self.truth)
        estimates = _poses(self.estimates)
        est = align(truth, estimates)
        errors = pose_errors(truth.trans, truth.quat, est.trans, est.quat)
        out = Path(cfg.out_dir)
        by_depth = format_errors_by_depth({cfg.variant: errors}, truth.trans[:, 2], cfg.sequence)
        appendix = f"{by_depth}\n\n{self._coverage(truth, est)}"
        if len(truth.stamps_ns) < cfg.frames:  # stopped before the sequence ended
            short = f"INCOMPLETE: {len(truth.stamps_ns)} of the {cfg.frames} ground-truth frames expected were received"
            self.get_logger().warn(short)
            appendix = f"{appendix}\n\n{short}"
        stamps, forgotten = list(self._without_truth), self.counters["poses_without_truth_dropped"]
        if stamps or forgotten:  # a replay's truth precedes its pose: these truths were lost or never recorded
            unscored = (f"UNSCORED: {len(stamps) + forgotten} poses without ground truth"
                        f"{f' (the oldest {forgotten} forgotten)' if forgotten else ''}"
                        f"{', stamped (ns) ' if stamps else ''}{', '.join(map(str, stamps[:5]))}"
                        f"{' ...' if len(stamps) > 5 else ''}")
            self.get_logger().warn(unscored)
            appendix = f"{appendix}\n\n{unscored}"
        out.mkdir(parents=True, exist_ok=True)  # the poses and the summary first, the plots last
        write_pose_csv(out / "estimates.csv", estimates)
        save_summary(out / "summary.json", make_summary(cfg.sequence, len(truth.stamps_ns), {cfg.variant: variant_summary(errors)}))
        text = write_report(out, cfg.sequence, {cfg.variant: errors}, appendix=appendix)
        matched = int(np.isfinite(errors["euclidean"]).sum())
        self.counters["matched"] = matched
        self.report_dir = out
        self.get_logger().info(f"{len(truth.stamps_ns)} ground-truth frames, {matched} with a pose; report in {out}\n{text}")
        return out

    def _coverage(self, truth: Poses, est: Poses) -> str:
        """The covariance-coverage table of the estimates ``est`` aligned to the ground truth."""
        unknown = np.full((6, 6), np.nan)
        cov = np.array([self.covariances.get(int(s), unknown) for s in truth.stamps_ns])
        rows = coverage_by_depth(truth.trans, truth.quat, est.trans, est.quat, cov)
        return format_coverage({self.config.variant: rows}, self.config.sequence)


def _poses(by_stamp: dict) -> Poses:
    stamps = np.array(sorted(by_stamp), dtype=np.int64)
    trans = np.array([by_stamp[s][0] for s in stamps]).reshape(-1, 3)
    quat = np.array([by_stamp[s][1] for s in stamps]).reshape(-1, 4)
    return Poses(stamps, trans, quat)


def run_until_done(node: EvaluatorNode, executor) -> int:
    """Spin until done or shut down, then write the report."""
    try:
        while rclpy.ok(context=node.context) and not node.done():
            executor.spin_once(timeout_sec=SPIN_S)
    except SHUTDOWN_ERRORS as exc:
        if not stopped_by_shutdown(exc, node.context):
            raise
    node.write()
    return 0


def main(args=None) -> int:
    return run_node(EvaluatorNode, args, run=run_until_done)


if __name__ == "__main__":
    sys.exit(main())
