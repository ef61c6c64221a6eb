"""``uav-landing evaluate``: a simulated bag through the tracker core, thesis-format results (§6.7.1).

Per frame, once for all variants: undistort the raw frame (3.16–3.17), find the ROI, boost
(§4.3) — detector and boosting with the settings of the graph's nodes (``config/detector.yaml``,
``config/pose_boosting.yaml``, except M and M0); then every ``CxNy`` variant's :class:`~.upf.Tracker` steps on the same frame and
hypotheses (each takes the first M or M − M0 of them, best first, as it needs). ROI sources:

- ``detector`` (default): the project's ONNX detector (§4.2) on the full frame, best box. If
  the detector module or its model is missing this fails; it never falls back to the oracle.
  Where it finds nothing, each variant gets the box of its own last pose as the detector node
  gives it (``detector.yaml`` ``track_box``, :mod:`..detection.track_box`), boosted for it alone.
- ``oracle``: the box of the model projected at the ground-truth pose (boosting grows every
  ROI alike, ``pose_boosting.yaml`` ``roi_margin``/``roi_pad_px``). Not a measurement:
  results with it say so in the table header and the JSON ``sequence``.

A frame counts as lost (NaN error) when the tracker has no estimate or reports LOST.
``ms_per_frame`` is boosting plus the whole tracker step (not undistortion, ROI or detector).

``stride`` N > 1 tracks and scores only every N-th frame, as a tracker that takes N frame intervals
per step does live: it skips the frames between, and its motion model predicts across the gap.
The thesis tracks every frame (N = 1, the default); so do paced replays (``make demo``).
"""

import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from .upf import STAGES, Tracker, TrackerConfig, TrackState, parse_variant, render_batch

ROI_SOURCES = ("detector", "oracle")
SHARED_STAGES = ("undistort", "roi", "boosting")


class EvaluationError(RuntimeError):
    """An evaluation that cannot run as asked (missing detector, bad bag, bad variants)."""


def parse_variants(text: str) -> list[str]:
    """``"C1N0,C4N2"`` → canonical names, in order, without repeats; ValueError on a bad one."""
    names = [f"{c}N{n}" for c, n in (parse_variant(p) for p in str(text).split(",") if p.strip())]
    if not names:
        raise ValueError("no variants given (expected e.g. C1N0,C4N2)")
    return list(dict.fromkeys(names))


def shipped_config(cls, node: str, group: str = ""):
    """Dataclass ``cls`` from ``config/<node>.yaml``: the keys of ``group``, or without one the
    top-level keys (the ``node`` group, the node's own settings, and ``track_box`` left out):
    the values the node of the graph runs with."""
    from ..config import from_mapping, load_node_parameters
    from ..resources import config_path

    path = config_path(f"{node}.yaml")
    params = load_node_parameters(path, node)
    if group:
        params, node = params.get(group, {}), f"{node}.{group}"
    else:
        params = {k: v for k, v in params.items() if k not in ("node", "track_box")}
    return from_mapping(cls, params, f"{path}: {node}")


def detector_rois(camera):
    """Frame → best detector ROI or None; raises :class:`EvaluationError` if there is no detector."""
    try:
        from ..detection.detector import Detector, DetectorConfig

        detector = Detector(shipped_config(DetectorConfig, "detector"))
    except (ImportError, FileNotFoundError, OSError, ValueError) as exc:
        raise EvaluationError(
            f"--roi-source detector needs the trained detector (uav_landing_vision.detection, models/detector.onnx): "
            f"{exc}. Train it with `uav-landing train-detector`, or evaluate with the ground-truth "
            "--roi-source oracle (labelled as such)") from exc

    def rois(frame, index):
        dets = detector.detect(frame)
        return tuple(int(v) for v in dets.rois(camera.width, camera.height)[0]) if len(dets.scores) else None

    return rois


@dataclass
class EvaluationResult:
    sequence: str
    roi_source: str
    frames: int
    estimates: dict  # variant -> (trans (F,3), quat (F,4)), NaN where lost
    errors: dict  # variant -> pose_errors(...)
    truth: tuple  # (trans (F,3), quat (F,4)) of the frames
    covariances: dict  # variant -> (F,6,6) published covariances, NaN where lost
    stage_ms: dict  # variant -> {stage: mean ms}, shared stages included
    ms_per_frame: dict  # variant -> mean ms of boosting + tracker step
    states: dict  # variant -> (F,) TrackState values
    stride: int = 1  # every stride-th frame of the bag was tracked and scored


def evaluate_bag(bag, variants, *, particles: int | None = None, metric: str | None = None,
                 roi_source: str = "detector", frames: int | None = None, start: int = 0, seed: int = 0,
                 base: TrackerConfig | None = None, stride: int = 1, progress: bool = True,
                 remaps=None) -> EvaluationResult:
    """Run ``variants`` (``CxNy`` names) over the simulated ``bag``; see the module docstring.
    ``start``: frames skipped first (the trackers start fresh there); ``frames``: how many follow
    (default: the rest), of which every ``stride``-th is tracked. Tracker settings other than
    variant, N and seed come from ``base`` (default: :class:`TrackerConfig`'s), M and the metric
    too unless given. ``remaps`` ``{recorded: name}``: a recording of other topic names
    (:func:`..sim.bag.recorded_topics`)."""
    from ..boosting import HypothesisConfig, PoseHypothesisGenerator
    from ..detection.track_box import TrackBox, TrackBoxConfig
    from ..evaluation import pose_errors
    from ..model import fixed_wing_mesh
    from ..render import Renderer
    from ..render.boxes import projected_roi
    from ..sim import read_camera, read_poses
    from ..sim.bag import increasing_frames, recorded_topics

    if roi_source not in ROI_SOURCES:
        raise EvaluationError(f"roi source must be one of {ROI_SOURCES}, got {roi_source!r}")
    names = parse_variants(",".join(variants))
    bag = Path(bag)
    image_topic, info_topic, truth_topic = recorded_topics(remaps)
    raw_camera = read_camera(bag, info_topic)
    camera = raw_camera.rectified()
    truth = read_poses(bag, truth_topic)
    if start < 0:
        raise EvaluationError(f"start must be non-negative, got {start}")
    if isinstance(stride, bool) or int(stride) != stride or stride < 1:
        raise EvaluationError(f"stride must be a positive integer, got {stride!r}")
    stride = int(stride)
    count = max(len(truth.stamps_ns) - int(start), 0)
    count = count if frames is None else min(int(frames), count)
    rois = detector_rois(camera) if roi_source == "detector" else None
    vertices = fixed_wing_mesh("high").vertices
    maps = raw_camera.undistortion_maps()
    base = TrackerConfig() if base is None else base
    particles = base.particles if particles is None else particles
    metric = base.metric if metric is None else metric
    configs = {n: replace(base, variant=c, iterations=k, particles=particles, metric=metric, seed=seed)
               for n, (c, k) in zip(names, map(parse_variant, names))}
    boost = PoseHypothesisGenerator.from_config(replace(
        shipped_config(HypothesisConfig, "pose_boosting"), particles=particles, kept=particles - configs[names[0]].boosted),
        camera)
    renderer = Renderer(camera, fixed_wing_mesh("low"), tile=configs[names[0]].tile, max_batch=max(map(render_batch, configs.values())))
    with renderer:  # released however the run ends: moderngl frees nothing on garbage collection
        trackers = {n: Tracker(c, camera, renderer) for n, c in configs.items()}
        track_box_config = shipped_config(TrackBoxConfig, "detector", "track_box")
        track_boxes = {n: TrackBox(track_box_config, vertices) for n in names}
        index = {int(s): i for i, s in enumerate(truth.stamps_ns)}

        est_t = {n: np.full((count, 3), np.nan) for n in names}
        est_q = {n: np.full((count, 4), np.nan) for n in names}
        est_cov = {n: np.full((count, 6, 6), np.nan) for n in names}
        states = {n: np.zeros(count, int) for n in names}
        ms = {n: {s: 0.0 for s in SHARED_STAGES + STAGES} for n in names}
        gt_t, gt_q = np.full((count, 3), np.nan), np.full((count, 4), np.nan)
        done = 0
        for k, (stamp, raw) in enumerate(_frames(increasing_frames(bag, image_topic), start, count, stride, progress)):
            clock = time.perf_counter()
            frame = cv2.remap(raw, maps[0], maps[1], cv2.INTER_LINEAR)
            t_undistort = time.perf_counter()
            i = index.get(int(stamp))
            if i is None:
                raise EvaluationError(f"{bag}: frame stamp {stamp} has no ground-truth pose")
            gt_t[k], gt_q[k] = truth.trans[i], truth.quat[i]
            roi = rois(frame, k) if rois is not None else projected_roi(camera, vertices, truth.quat[i], truth.trans[i])
            t_roi = time.perf_counter()
            hyp = None if roi is None else boost.generate(frame, roi, count=particles)
            t_boost = time.perf_counter()
            shared = {"undistort": t_undistort - clock, "roi": t_roi - t_undistort, "boosting": t_boost - t_roi}
            for n, tracker in trackers.items():
                own_boost = 0.0
                if roi is not None:
                    track_boxes[n].detected()
                    own = hyp
                else:
                    t0 = time.perf_counter()
                    box = track_boxes[n].roi(camera, int(stamp))
                    own = None if box is None else boost.generate(frame, box, count=particles)
                    own_boost = time.perf_counter() - t0
                res = tracker.step(frame, int(stamp), own)
                if res.has_pose:
                    track_boxes[n].set_pose(int(stamp), res.position, res.quat)
                if res.has_pose and res.state != TrackState.LOST:
                    est_t[n][k], est_q[n][k], est_cov[n][k] = res.position, res.quat, res.covariance
                states[n][k] = int(res.state)
                for s, v in shared.items():
                    ms[n][s] += 1e3 * v
                ms[n]["boosting"] += 1e3 * own_boost
                for s, v in res.stage_ms.items():
                    ms[n][s] += v
            done = k + 1
    if done == 0:
        raise EvaluationError(f"{bag}: no frames")
    sl = slice(0, done)
    errors = {n: pose_errors(gt_t[sl], gt_q[sl], est_t[n][sl], est_q[n][sl]) for n in names}
    stage_ms = {n: {s: v / done for s, v in ms[n].items()} for n in names}
    per_frame = {n: stage_ms[n]["boosting"] + sum(stage_ms[n][s] for s in STAGES) for n in names}
    return EvaluationResult(bag.name, roi_source, done, {n: (est_t[n][sl], est_q[n][sl]) for n in names},
                            errors, (gt_t[sl], gt_q[sl]), {n: est_cov[n][sl] for n in names}, stage_ms, per_frame,
                            {n: states[n][sl] for n in names}, stride)


def _frames(iterator, start: int, count: int, stride: int, progress: bool):
    from itertools import islice

    from tqdm import tqdm

    return tqdm(islice(iterator, start, start + count, stride), total=-(-count // stride), desc="evaluate",
                unit="frame", disable=not progress)


def sequence_label(result: EvaluationResult) -> str:
    """The sequence name with the ROI source (and the stride, when not 1), as printed and stored
    in the JSON summary."""
    stride = f", stride={result.stride}" if result.stride != 1 else ""
    return f"{result.sequence} (roi_source={result.roi_source}{stride})"


def summary(result: EvaluationResult) -> dict:
    """The JSON summary (schema of :mod:`uav_landing_vision.evaluation.report`)."""
    from ..evaluation import make_summary, variant_summary

    return make_summary(sequence_label(result), result.frames,
                        {n: variant_summary(e, result.ms_per_frame[n]) for n, e in result.errors.items()})


def format_results(result: EvaluationResult) -> str:
    """Thesis-format tables (the statistics of Tables 6.12–6.22, laid out as 6.12–6.19: Euclidean
    translation in m, geodesic rotation in deg, one column per variant), then (ours) the median errors by true depth, lost frames and
    ms per frame by stage, and how many errors lie inside the published covariance's 95 % region,
    by true depth."""
    from ..evaluation import format_errors_by_depth, format_table, statistics_table
    from ..evaluation.consistency import coverage_by_depth, format_coverage

    label = sequence_label(result)
    head = f"{label}, {result.frames} frames"
    parts = [format_table(statistics_table(result.errors, ("euclidean",)), f"{head}: translation error (m)"),
             format_table(statistics_table(result.errors, ("geodesic",)), f"{head}: rotation error (deg)"),
             format_errors_by_depth(result.errors, result.truth[0][:, 2], head)]
    names = list(result.errors)
    width = max(10, *(len(n) + 2 for n in names))
    rows = [f"{head}: lost frames and time per frame (ms)", f"{'':<16}" + "".join(f"{n:>{width}}" for n in names)]
    lost = [100.0 * np.mean(~np.isfinite(result.errors[n]["euclidean"])) for n in names]
    rows.append(f"{'Lost %':<16}" + "".join(f"{v:>{width}.2f}" for v in lost))
    for stage in SHARED_STAGES + STAGES:
        rows.append(f"{stage:<16}" + "".join(f"{result.stage_ms[n][stage]:>{width}.1f}" for n in names))
    rows.append(f"{'ms/frame':<16}" + "".join(f"{result.ms_per_frame[n]:>{width}.1f}" for n in names))
    parts.append("\n".join(rows))
    parts.append(format_coverage({n: coverage_by_depth(*result.truth, *result.estimates[n], result.covariances[n])
                                  for n in names}, head))
    return "\n\n".join(parts)
