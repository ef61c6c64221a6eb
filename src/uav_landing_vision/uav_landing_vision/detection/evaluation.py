"""Detector evaluation (§6.3.2): precision–recall curve, AP at IoU 0.5, recall by UAV size, speed.

The ground-truth ROI of each frame comes from the bag's ground-truth pose: the model is
projected at that pose in the rectified camera and labelled as in Fig. 4.4 (outline →
oriented box → axis-aligned ROI, :func:`.dataset.model_roi`), as the training data are, or,
on request, as the extent of the projected model. Frames are undistorted first, as the node
graph does before detection. For the Fig. 4.4 truth the report also counts its near ties (frames
whose oriented box wins over a rather different one by under 2.5 % of area) and the misses whose
box matches that runner-up instead, with the runner-up's margin.
"""

import time
from pathlib import Path

import cv2
import numpy as np

from ..evaluation.report import plot_text, strict_json
from .dataset import LABEL_BOXES, oriented_box_tie, outline_roi, projected_outline
from .detector import box_iou

WIDTH_BUCKETS = (0, 8, 16, 32, 64, 128, 256, 100000)  # px edges of the GT-width buckets
# A Fig. 4.4 truth box whose runner-up oriented box is within this much of its area is a near
# tie: which of the two the minimum-area rule picks turns on sub-pixel detail of the outline.
NEAR_TIE_MARGIN = 0.025


def match_frame(boxes: np.ndarray, scores: np.ndarray, gt: np.ndarray, iou: float = 0.5):
    """Greedy matching of one frame's detections (best score first) to its ground-truth boxes:
    ``(tp (N,) bool per detection, matched (G,) bool per GT box)``."""
    boxes, gt = np.asarray(boxes).reshape(-1, 4), np.asarray(gt).reshape(-1, 4)
    tp, matched = np.zeros(len(boxes), bool), np.zeros(len(gt), bool)
    if len(boxes) and len(gt):
        ious = box_iou(boxes, gt)
        for d in np.argsort(-np.asarray(scores), kind="stable"):
            free = np.where(matched, -1.0, ious[d])
            g = int(np.argmax(free))
            if free[g] >= iou:
                tp[d], matched[g] = True, True
    return tp, matched


def average_precision(scores: np.ndarray, tp: np.ndarray, n_gt: int):
    """Area under the all-point interpolated PR curve: ``(ap, precision, recall, thresholds)``,
    one point per distinct score (detections of equal scores pass a threshold together: one
    point each made the AP depend on the frames' order)."""
    order = np.argsort(-np.asarray(scores), kind="stable")
    tp, thresholds = np.asarray(tp, bool)[order], np.asarray(scores)[order]
    last = np.append(thresholds[1:] != thresholds[:-1], True) if len(thresholds) else np.zeros(0, bool)
    ctp, cfp, thresholds = np.cumsum(tp)[last], np.cumsum(~tp)[last], thresholds[last]
    recall = ctp / max(n_gt, 1)
    precision = ctp / np.maximum(ctp + cfp, 1)
    envelope = np.maximum.accumulate(precision[::-1])[::-1] if len(precision) else precision
    steps = np.diff(np.concatenate([[0.0], recall]))
    return float(np.sum(steps * envelope)) if n_gt else 0.0, precision, recall, thresholds


def summarise(frames: list[dict], threshold: float) -> dict:
    """Metrics of per-frame results ``{"boxes", "scores", "gt", "ms"}`` (boxes scored down to a
    low threshold, so the whole curve is seen). Frames labelled with ``tie_margin`` and
    ``runner_up`` (:func:`label_frame`) add ``truth_near_ties`` (margin < ``NEAR_TIE_MARGIN``),
    ``runner_up_misses`` (frames whose UAV is missed at the threshold while a kept box matches
    the runner-up oriented box's ROI by IoU ≥ 0.5) and those frames' margins. Frames with
    ``kept_boxes`` and ``kept_scores`` (the detector as configured: its box limit and verifier)
    take the operating point's figures from those, not from the boxes above the threshold."""
    scores, tps, widths, hits = [], [], [], []
    fp_at, tp_at, fp_best, near_ties, runner_up_margins = 0, 0, 0, 0, []
    for f in frames:
        tp, _ = match_frame(f["boxes"], f["scores"], f["gt"])
        scores.append(f["scores"])
        tps.append(tp)
        keep = f["scores"] >= threshold
        kept, kept_scores = f.get("kept_boxes", f["boxes"][keep]), f.get("kept_scores", f["scores"][keep])
        tp_kept, matched = match_frame(kept, kept_scores, f["gt"])
        fp_at += int(len(kept) - matched.sum())
        tp_at += int(matched.sum())
        if len(kept):  # the box the graph uses: the frame's best (matched first, so its own TP flag)
            fp_best += int(not tp_kept[np.argmax(kept_scores)])
        widths.extend((f["gt"][:, 2] - f["gt"][:, 0]).tolist())
        hits.extend(matched.tolist())
        if f.get("runner_up") is not None:
            near_ties += int(f["tie_margin"] < NEAR_TIE_MARGIN)
            if not matched.all() and len(kept) and box_iou(kept, f["runner_up"][None]).max() >= 0.5:
                runner_up_margins.append(f["tie_margin"])
    n_gt = len(widths)
    ap, precision, recall, thr = average_precision(np.concatenate(scores), np.concatenate(tps), n_gt)
    widths, hits = np.array(widths), np.array(hits, bool)
    by_width = {}
    for lo, hi in zip(WIDTH_BUCKETS[:-1], WIDTH_BUCKETS[1:]):
        sel = (widths >= lo) & (widths < hi)
        if sel.any():
            by_width[f"{lo}-{hi}" if hi < WIDTH_BUCKETS[-1] else f"{lo}+"] = {
                "recall": float(hits[sel].mean()), "count": int(sel.sum())}
    ties = {}
    if any("tie_margin" in f for f in frames):
        ties = {"truth_near_ties": near_ties, "runner_up_misses": len(runner_up_margins),
                "runner_up_miss_margins": sorted(round(m, 4) for m in runner_up_margins)}
    return {
        "ap50": ap,
        "threshold": threshold,
        "precision": tp_at / max(tp_at + fp_at, 1),
        "recall": tp_at / max(n_gt, 1),
        "false_positives_per_100_frames": 100.0 * fp_at / max(len(frames), 1),
        "best_box_false_positives_per_100_frames": 100.0 * fp_best / max(len(frames), 1),
        "recall_by_width_px": by_width,
        "recall_wider_than_16px": float(hits[widths > 16].mean()) if np.any(widths > 16) else None,
        "frames": len(frames),
        "ground_truth_boxes": n_gt,
        "ms_per_frame": float(np.median([f["ms"] for f in frames])) if frames else None,
        **ties,
        "curve": {"precision": precision.tolist(), "recall": recall.tolist(), "thresholds": thr.tolist()},
    }


def label_frame(outline: np.ndarray | None, width: int, height: int, truth_box: str) -> dict:
    """A frame's truth from the projected outline: ``gt`` (0 or 1 box) and, for the Fig. 4.4
    truth, the runner-up oriented box's ROI and area margin (:func:`.dataset.oriented_box_tie`)."""
    box = outline_roi(outline, width, height, oriented=truth_box == "oriented")
    if box is None:
        return {"gt": np.zeros((0, 4))}
    if truth_box == "extent":
        return {"gt": box[None]}
    margin, runner_up = oriented_box_tie(outline, width, height)
    return {"gt": box[None], "tie_margin": margin, "runner_up": runner_up}


def plot_pr(result: dict, path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 4.5))
    ax.plot(result["curve"]["recall"], result["curve"]["precision"], lw=1.5)
    ax.set(xlim=(0, 1.01), ylim=(0, 1.01), xlabel="recall", ylabel="precision",
           title=f"{plot_text(title)}  AP50 = {result['ap50']:.3f}")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def evaluate_bag(bag, config, json_path, png_path=None, progress: bool = True, truth_box: str = "oriented",
                 remaps=None) -> dict:
    """Run the detector (``config``: :class:`.detector.DetectorConfig`, its threshold the operating
    point) over a simulated bag; write the metrics JSON (and PR curve PNG).

    ``truth_box``: ``oriented`` labels the truth as the training data are (Fig. 4.4);
    ``extent`` takes the extent of the projected model instead (:func:`.dataset.model_roi`).
    ``remaps`` ``{recorded: name}``: a recording of other topic names (:func:`..sim.bag.recorded_topics`)."""
    from dataclasses import replace

    from tqdm import tqdm

    from ..model import fixed_wing_mesh
    from ..sim.bag import increasing_frames, read_camera, read_poses, recorded_topics
    from .detector import Detector

    if truth_box not in LABEL_BOXES:
        raise ValueError(f"truth_box must be one of {LABEL_BOXES}, got {truth_box!r}")
    image_topic, info_topic, truth_topic = recorded_topics(remaps)
    camera = read_camera(bag, info_topic)
    rect = camera.rectified()
    map1, map2 = camera.undistortion_maps()
    poses = read_poses(bag, truth_topic)
    truth = {int(s): (q, t) for s, q, t in zip(poses.stamps_ns, poses.quat, poses.trans)}
    mesh = fixed_wing_mesh("high")
    # scored down to 0.01 for the curve, or to the operating threshold when that is lower
    detector = Detector(replace(config, score_threshold=min(0.01, config.score_threshold), max_detections=20))
    timed = Detector(config)  # the operating point and ms per frame: as configured (threshold, limit, verifier)
    frames = []
    for stamp, raw in tqdm(increasing_frames(bag, image_topic), desc="eval-detector", unit="frame", total=len(truth),
                           disable=not progress):
        if stamp not in truth:
            raise ValueError(f"{bag}: frame {stamp} has no ground-truth pose")
        image = cv2.remap(raw, map1, map2, cv2.INTER_LINEAR)
        outline = projected_outline(mesh.vertices, rect.K, *truth[stamp], rect.width, rect.height, mesh.faces)
        frame = label_frame(outline, rect.width, rect.height, truth_box)
        det = detector.detect(image)
        t0 = time.perf_counter()
        kept = timed.detect(image)
        frame.update(boxes=det.boxes, scores=det.scores, kept_boxes=kept.boxes, kept_scores=kept.scores,
                     ms=1000.0 * (time.perf_counter() - t0))
        frames.append(frame)
    if not frames:
        raise ValueError(f"{bag}: no frames on {image_topic}")
    result = summarise(frames, config.score_threshold)
    result.update(bag=str(bag), model=str(config.model), verifier=str(config.verifier),
                  verifier_threshold=config.verifier_threshold, truth_box=truth_box)
    if png_path:  # first: a figure that fails leaves no metrics file that looks complete
        Path(png_path).parent.mkdir(parents=True, exist_ok=True)
        plot_pr(result, png_path, Path(str(bag)).name)
    Path(json_path).parent.mkdir(parents=True, exist_ok=True)
    Path(json_path).write_text(strict_json({k: v for k, v in result.items() if k != "curve"}))
    return result
