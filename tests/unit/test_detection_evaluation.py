"""eval-detector: its arguments are checked before any frame is read; Fig. 4.4 near ties are
counted; an operating threshold below the curve's floor sees its boxes; a frame recorded twice is
refused; a recording of other topic names is read with ``--remap``."""

import numpy as np
import pytest
from bag_edits import drop_messages, record_frame_twice, rename_topics

from uav_landing_vision.detection.detector import DetectorConfig
from uav_landing_vision.detection.evaluation import evaluate_bag, label_frame, match_frame, summarise


def test_unknown_truth_box_is_rejected_before_the_bag_is_opened(tmp_path):
    with pytest.raises(ValueError, match="truth_box must be one of"):
        evaluate_bag(tmp_path / "no_bag", DetectorConfig(), tmp_path / "out.json", truth_box="silhouette")


def test_near_ties_and_the_misses_they_explain_are_counted():
    triangle = np.array([[10.0, 20.0], [50.0, 20.0], [30.0, 45.0]])  # acute: a tie
    bar = np.array([[10.0, 10.0], [50.0, 10.0], [50.0, 20.0], [10.0, 20.0]])  # no runner-up
    tie = label_frame(triangle, 100, 80, "oriented")
    assert tie["tie_margin"] == pytest.approx(0.0, abs=1e-9)
    clear = label_frame(bar, 100, 80, "oriented")
    assert clear["tie_margin"] == np.inf and clear["runner_up"] is None
    assert set(label_frame(triangle, 100, 80, "extent")) == {"gt"}
    assert label_frame(None, 100, 80, "oriented")["gt"].shape == (0, 4)

    def frame(label, boxes):
        boxes = np.asarray(boxes, float).reshape(-1, 4)
        return {**label, "boxes": boxes, "scores": np.full(len(boxes), 0.9), "ms": 1.0}

    near_runner_up = tie["runner_up"] + [0.0, 1.5, 0.0, 0.0]  # IoU 0.94 with it, 0.48 with the label
    frames = [frame(tie, near_runner_up),       # misses the label, matches its runner-up
              frame(tie, tie["gt"]),            # matches the label
              frame(tie, [[0, 0, 5, 5]]),       # misses both
              frame(clear, [[0, 0, 5, 5]])]     # not a tie
    r = summarise(frames, threshold=0.5)
    assert (r["truth_near_ties"], r["runner_up_misses"]) == (3, 1)
    assert r["runner_up_miss_margins"] == [0.0]
    extent = summarise([frame(label_frame(triangle, 100, 80, "extent"), [[0, 0, 5, 5]])], threshold=0.5)
    assert "truth_near_ties" not in extent


def test_boxes_down_to_an_operating_threshold_below_the_curve_floor_are_counted(tmp_path, monkeypatch):
    """The curve's boxes are scored down to 0.01; an operating threshold below that must still
    see the boxes between it and 0.01 (a box scored 0.007 at threshold 0.005 is a false positive)."""
    from uav_landing_vision.detection import detector as runtime
    from uav_landing_vision.sim import load_scenario, simulate

    simulate(load_scenario("normal"), tmp_path / "bag", frames=2, progress=False)

    class OneWeakBox:  # a detector that honours its threshold: one box, off the UAV, scored 0.007
        def __init__(self, config):
            self.config = config

        def detect(self, image):
            keep = 0.007 >= self.config.score_threshold
            return runtime.Detections(np.array([[0.0, 0.0, 10.0, 10.0]] * keep, np.float32).reshape(-1, 4),
                                      np.array([0.007] * keep, np.float32))

    monkeypatch.setattr(runtime, "Detector", OneWeakBox)
    r = evaluate_bag(tmp_path / "bag", DetectorConfig(score_threshold=0.005), tmp_path / "out.json", progress=False)
    assert r["frames"] == 2 and r["threshold"] == 0.005
    assert r["false_positives_per_100_frames"] == 100.0 and r["precision"] == 0.0
    assert r["curve"]["thresholds"] == pytest.approx([0.007])  # both frames' boxes: one point of the curve


def test_the_time_per_frame_is_that_of_the_detector_as_configured(tmp_path, monkeypatch):
    """The curve's run (threshold 0.01, 20 boxes: with a verifier, many more crops) is not what
    ms_per_frame reports: the detector with the configured settings is timed."""
    from uav_landing_vision.detection import detector as runtime
    from uav_landing_vision.detection import evaluation
    from uav_landing_vision.sim import load_scenario, simulate

    simulate(load_scenario("normal"), tmp_path / "bag", frames=2, progress=False)
    clock = {"now": 0.0}

    class Timed:  # each detect() advances a fake clock by 1 s at the curve's threshold, 5 ms at the configured one
        def __init__(self, config):
            self.config = config

        def detect(self, image):
            clock["now"] += 1.0 if self.config.score_threshold < 0.5 else 0.005
            return runtime.Detections(np.zeros((0, 4), np.float32), np.zeros(0, np.float32))

    monkeypatch.setattr(runtime, "Detector", Timed)
    monkeypatch.setattr(evaluation.time, "perf_counter", lambda: clock["now"])
    r = evaluate_bag(tmp_path / "bag", DetectorConfig(score_threshold=0.5), tmp_path / "out.json", progress=False)
    assert r["ms_per_frame"] == pytest.approx(5.0)


def test_the_operating_point_is_that_of_the_detector_as_configured(tmp_path, monkeypatch):
    """The curve's run keeps up to 20 boxes a frame, the configured detector max_detections: the
    precision and false positives at the operating point are those of the boxes the graph gets."""
    from uav_landing_vision.detection import detector as runtime
    from uav_landing_vision.sim import load_scenario, simulate

    simulate(load_scenario("normal"), tmp_path / "bag", frames=2, progress=False)

    class FiveBoxes:  # five boxes off the UAV above the threshold, of which the limit keeps the best
        def __init__(self, config):
            self.config = config

        def detect(self, image):
            n = min(5, self.config.max_detections)
            boxes = np.array([[20.0 * i, 0.0, 20.0 * i + 10.0, 10.0] for i in range(n)], np.float32).reshape(-1, 4)
            return runtime.Detections(boxes, np.linspace(0.9, 0.6, 5, dtype=np.float32)[:n])

    monkeypatch.setattr(runtime, "Detector", FiveBoxes)
    config = DetectorConfig(score_threshold=0.5, max_detections=2)
    r = evaluate_bag(tmp_path / "bag", config, tmp_path / "out.json", progress=False)
    assert r["false_positives_per_100_frames"] == 200.0  # 2 boxes a frame, not the curve's 5
    assert r["best_box_false_positives_per_100_frames"] == 100.0
    assert len(r["curve"]["thresholds"]) == 5  # the curve still sees every box: both frames' five scores


def _brute_force_ap(scores, tp, n_gt):
    """VOC all-point AP from first principles: the PR point of every threshold, then at each
    recall reached the best precision at that recall or beyond."""
    points = [(tp[scores >= t].sum() / n_gt, tp[scores >= t].mean()) for t in scores]
    recalls = sorted({r for r, _ in points})
    best = [max(p for r, p in points if r >= level) for level in recalls]
    return sum((hi - lo) * p for lo, hi, p in zip([0.0] + recalls[:-1], recalls, best))


def test_average_precision_matches_a_brute_force_oracle():
    from uav_landing_vision.detection.evaluation import average_precision

    rng = np.random.default_rng(0)
    for k in range(600):
        n = int(rng.integers(1, 15))
        if k % 2:  # distinct scores
            scores = rng.permutation(n) / n + 0.01
        else:  # ties: boxes of one score pass a threshold together, in whatever order the frames came
            scores = rng.integers(1, 4, n) / 4
        tp = rng.random(n) < 0.5
        n_gt = int(tp.sum() + rng.integers(0, 3))
        if n_gt:
            assert average_precision(scores, tp, n_gt)[0] == pytest.approx(_brute_force_ap(scores, tp, n_gt), abs=1e-12)


def test_matching_is_greedy_by_score_one_detection_per_truth_and_iou_0_5_counts():
    gt = np.array([[0.0, 0.0, 10.0, 10.0], [100.0, 100.0, 120.0, 110.0]])
    # a duplicate of the first truth box, a box with IoU exactly 0.5 (100 / 200) with it, one
    # with IoU 0.8 with it but scored lower, and one off both boxes
    boxes = np.array([[0.0, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 20.0],
                      [0.0, 0.0, 10.0, 12.5], [50.0, 50.0, 60.0, 60.0]])
    tp, matched = match_frame(boxes, np.array([0.9, 0.8, 0.7, 0.6, 0.95]), gt)
    assert tp.tolist() == [True, False, False, False, False] and matched.tolist() == [True, False]
    tp, matched = match_frame(boxes[3:1:-1], np.array([0.8, 0.9]), gt[:1])
    assert tp.tolist() == [False, True]  # the better-scored box takes the truth, at IoU 0.5 exactly
    assert match_frame(boxes[3:1:-1] + [0, 0, 0, 0.01], np.array([0.8, 0.9]), gt[:1])[0].tolist() == [True, False]


def test_operating_point_figures_on_hand_made_frames():
    """Three frames of one UAV each (truth widths 10, 16 and 40 px), threshold 0.5: two UAVs found,
    one box off a UAV in each of two frames, and one box below the threshold."""

    def frame(gt, boxes, scores):
        return {"gt": np.array([gt], float), "boxes": np.array(boxes, float).reshape(-1, 4),
                "scores": np.array(scores, float), "ms": 3.0}

    frames = [frame([0, 0, 10, 10], [[50, 50, 60, 60], [0, 0, 10, 10]], [0.7, 0.9]),
              frame([0, 0, 16, 16], [[50, 50, 60, 60], [0, 0, 16, 16]], [0.6, 0.3]),
              frame([0, 0, 40, 20], [[0, 0, 40, 20]], [0.8])]
    r = summarise(frames, threshold=0.5)
    assert (r["precision"], r["recall"]) == pytest.approx((2 / 4, 2 / 3))
    assert r["false_positives_per_100_frames"] == pytest.approx(200 / 3)
    assert r["best_box_false_positives_per_100_frames"] == pytest.approx(100 / 3)  # frame 2's best box
    assert r["recall_by_width_px"] == {"8-16": {"recall": 1.0, "count": 1}, "16-32": {"recall": 0.0, "count": 1},
                                       "32-64": {"recall": 1.0, "count": 1}}
    assert r["recall_wider_than_16px"] == 1.0  # only the 40 px UAV is wider than 16 px
    # every box, best first: 0.9 TP, 0.8 TP, 0.7 FP, 0.6 FP, 0.3 TP over 3 UAVs
    assert r["ap50"] == pytest.approx(1 / 3 + 1 / 3 + 1 / 3 * 3 / 5)
    assert (r["frames"], r["ground_truth_boxes"], r["ms_per_frame"]) == (3, 3, 3.0)


def test_a_frame_recorded_twice_is_refused_naming_the_bag(tmp_path):
    """It was scored twice: its box counted once more as found (or missed), its false positives too."""
    from uav_landing_vision.sim import load_scenario, simulate

    simulate(load_scenario("normal"), tmp_path / "bag", frames=3, progress=False)
    stamps = record_frame_twice(tmp_path / "bag", tmp_path / "repeated")
    with pytest.raises(ValueError) as refused:
        evaluate_bag(tmp_path / "repeated", DetectorConfig(), tmp_path / "out.json", progress=False)
    assert str(refused.value) == (f"{tmp_path / 'repeated'}: frame 2 is stamped {stamps[1]} ns, not after frame 1 "
                                  f"({stamps[1]} ns): a recording's frames must have increasing header stamps")


def test_a_recording_of_other_topic_names_is_read_with_remap(tmp_path, capsys):
    """As ``uav-landing graph --remap``: the shipped detector scores it as under the graph's names."""
    import json

    from uav_landing_vision.cli import main
    from uav_landing_vision.sim import load_scenario, simulate

    simulate(load_scenario("normal"), tmp_path / "bag", frames=2, progress=False)
    names = {"/camera/image_raw": "/deck_cam/image_raw", "/camera/camera_info": "/deck_cam/camera_info",
             "/uav/ground_truth": "/rtk/uav_pose"}
    rename_topics(tmp_path / "bag", tmp_path / "renamed", names)
    with pytest.raises(SystemExit, match="no topic /camera/camera_info; has .*/deck_cam/camera_info"):
        main(["eval-detector", "--bag", str(tmp_path / "renamed"), "--json", str(tmp_path / "r.json")])
    remaps = [a for old, new in names.items() for a in ("--remap", f"{new}:={old}")]
    assert main(["eval-detector", "--bag", str(tmp_path / "renamed"), *remaps, "--json", str(tmp_path / "r.json")]) == 0
    assert main(["eval-detector", "--bag", str(tmp_path / "bag"), "--json", str(tmp_path / "p.json")]) == 0
    renamed, plain = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("r", "p"))
    assert {k: v for k, v in renamed.items() if k not in ("ms_per_frame", "bag")} == {
        k: v for k, v in plain.items() if k not in ("ms_per_frame", "bag")}


def test_a_recording_without_frames_is_a_clear_error(tmp_path):
    """It failed inside numpy ("need at least one array to concatenate")."""
    from uav_landing_vision.sim import load_scenario, simulate

    simulate(load_scenario("normal"), tmp_path / "bag", frames=2, progress=False)
    drop_messages(tmp_path / "bag", tmp_path / "no_frames", "/camera/image_raw")
    with pytest.raises(ValueError, match=r"no_frames: no frames on /camera/image_raw"):
        evaluate_bag(tmp_path / "no_frames", DetectorConfig(), tmp_path / "out.json", progress=False)


def test_near_ties_are_under_the_margin_and_runner_up_matches_count_from_iou_0_5():
    """Hand-made labels: a margin of exactly 2.5 % is no near tie; a kept box at IoU exactly 0.5
    with the runner-up explains the miss; the misses' margins are listed in increasing order."""

    def frame(margin, runner_up, box):
        return {"gt": np.array([[0.0, 0.0, 10.0, 10.0]]), "tie_margin": margin, "runner_up": np.array(runner_up),
                "boxes": np.array([box], float), "scores": np.array([0.9]), "ms": 1.0}

    frames = [frame(0.025, [20.0, 0.0, 30.0, 10.0], [20.0, 0.0, 30.0, 10.0]),  # the runner-up itself
              frame(0.01, [20.0, 0.0, 30.0, 20.0], [20.0, 0.0, 30.0, 10.0]),  # IoU 100 / 200 with it
              frame(0.02, [20.0, 0.0, 30.0, 10.0], [0.0, 0.0, 10.0, 10.0])]  # the label found
    r = summarise(frames, threshold=0.5)
    assert (r["truth_near_ties"], r["runner_up_misses"]) == (2, 2)
    assert r["runner_up_miss_margins"] == [0.01, 0.025]
