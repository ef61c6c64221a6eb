"""Detector evaluation (§6.3.2) on hand-made frames with known answers: frames without a UAV
count for the false positives per frame but not for the recall, the time per frame is the
median, the two truth boxes (Fig. 4.4 oriented box, model extent) are what they say, and the
detector sees the frames undistorted."""

import cv2
import numpy as np
import pytest

from uav_landing_vision.detection.detector import DetectorConfig
from uav_landing_vision.detection.evaluation import evaluate_bag, label_frame, summarise


def _frame(gt, boxes, scores, ms):
    return {"gt": np.asarray(gt, float).reshape(-1, 4), "boxes": np.asarray(boxes, float).reshape(-1, 4),
            "scores": np.asarray(scores, float), "ms": ms}


def test_frames_without_a_uav_count_per_frame_but_not_in_the_recall():
    """Two frames with a UAV (one found), two without (one false positive): recall 1/2 of the
    UAVs, false positives 1 in 4 frames, the median time of 1, 2, 3 and 40 ms."""
    frames = [_frame([0, 0, 20, 20], [[0, 0, 20, 20]], [0.9], 1.0),
              _frame([50, 50, 90, 70], [], [], 2.0),
              _frame(np.zeros((0, 4)), [[5, 5, 15, 15]], [0.8], 3.0),
              _frame(np.zeros((0, 4)), [], [], 40.0)]
    r = summarise(frames, threshold=0.5)
    assert (r["frames"], r["ground_truth_boxes"]) == (4, 2)
    assert r["recall"] == pytest.approx(0.5) and r["precision"] == pytest.approx(0.5)
    assert r["false_positives_per_100_frames"] == pytest.approx(25.0)
    assert r["best_box_false_positives_per_100_frames"] == pytest.approx(25.0)
    assert r["ms_per_frame"] == pytest.approx(2.5)
    assert r["ap50"] == pytest.approx(0.5)  # 0.9 TP then 0.8 FP, over 2 UAVs
    assert r["recall_by_width_px"] == {"16-32": {"recall": 1.0, "count": 1}, "32-64": {"recall": 0.0, "count": 1}}


def test_recall_by_width_is_that_of_the_boxes_kept_at_the_operating_threshold():
    """A UAV matched only by a box below the threshold is missed at the operating point, in the
    recall by width as in the recall."""
    frames = [_frame([0, 0, 40, 20], [[0, 0, 40, 20]], [0.3], 1.0),
              _frame([0, 0, 40, 20], [[0, 0, 40, 20]], [0.7], 1.0)]
    r = summarise(frames, threshold=0.5)
    assert r["recall"] == pytest.approx(0.5)
    assert r["recall_by_width_px"] == {"32-64": {"recall": 0.5, "count": 2}}
    assert r["recall_wider_than_16px"] == pytest.approx(0.5)


def test_truth_boxes_oriented_and_extent_of_a_tilted_obtuse_triangle():
    """A 100 × 10 obtuse triangle turned by 30°: its minimum-area oriented box is the turned
    100 × 10 rectangle on its long side, whose axis-aligned box is wider than the triangle's
    extent; ROIs are in pixel edges (corner points at pixel centres, + ½)."""
    c, s = np.cos(np.radians(30)), np.sin(np.radians(30))
    turn = np.array([[c, -s], [s, c]])
    origin = np.array([150.0, 100.0])
    triangle = np.array([[0.0, 0.0], [100.0, 0.0], [50.0, 10.0]]) @ turn.T + origin
    rectangle = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 10.0], [0.0, 10.0]]) @ turn.T + origin
    extent = label_frame(triangle, 400, 300, "extent")["gt"][0]
    oriented = label_frame(triangle, 400, 300, "oriented")["gt"][0]
    np.testing.assert_allclose(extent, np.r_[triangle.min(0), triangle.max(0)] + 0.5, atol=1e-9)
    np.testing.assert_allclose(oriented, np.r_[rectangle.min(0), rectangle.max(0)] + 0.5, atol=1e-3)
    assert oriented[0] < extent[0] - 4  # the rectangle's far corner reaches beyond the triangle


def test_the_detector_sees_each_frame_undistorted(tmp_path, monkeypatch):
    """The simulated camera has radial distortion; the detector is run on the undistorted frame
    (its truth boxes are those of the rectified camera): each image it gets is the bag's frame
    remapped through OpenCV's undistortion of the camera (float maps, an independent path)."""
    from uav_landing_vision.detection import detector as runtime
    from uav_landing_vision.sim import load_scenario, simulate
    from uav_landing_vision.sim.bag import iter_frames, read_camera

    simulate(load_scenario("normal"), tmp_path / "bag", frames=2, progress=False)
    seen = []

    class Recorder:
        def __init__(self, config):
            self.config = config

        def detect(self, image):
            seen.append(image.copy())
            return runtime.Detections(np.zeros((0, 4), np.float32), np.zeros(0, np.float32))

    monkeypatch.setattr(runtime, "Detector", Recorder)
    evaluate_bag(tmp_path / "bag", DetectorConfig(), tmp_path / "out.json", progress=False)
    camera = read_camera(tmp_path / "bag")
    assert np.any(camera.dist != 0)
    mx, my = cv2.initUndistortRectifyMap(camera.K, camera.dist, None, camera.K, (camera.width, camera.height),
                                         cv2.CV_32FC1)
    raws = [image for _, image in iter_frames(tmp_path / "bag")]
    assert len(seen) == 2 * len(raws)  # the curve's detector and the timed one
    for k, raw in enumerate(raws):
        want = cv2.remap(raw, mx, my, cv2.INTER_LINEAR).astype(float)
        for got in seen[2 * k : 2 * k + 2]:
            assert np.abs(got.astype(float) - want).mean() < 0.5
            assert np.abs(got.astype(float) - want).mean() < 0.2 * np.abs(raw.astype(float) - want).mean()


def test_a_box_scored_exactly_at_the_operating_threshold_is_kept():
    frames = [_frame([0, 0, 20, 20], [[0, 0, 20, 20]], [0.5], 1.0),
              _frame(np.zeros((0, 4)), [[40, 40, 50, 50]], [0.5], 1.0)]
    r = summarise(frames, threshold=0.5)
    assert (r["recall"], r["precision"], r["false_positives_per_100_frames"]) == pytest.approx((1.0, 0.5, 50.0))


def test_recall_by_width_names_the_upper_buckets_and_the_open_last_one():
    """Truth widths 100, 200, 300 and 5000 px fall in 64-128, 128-256 and the open 256+ bucket;
    each UAV is found except the 300 px one."""
    frames = [_frame([0, 0, w, 20], [[0, 0, w, 20]] if w != 300 else [], [0.9] if w != 300 else [], 1.0)
              for w in (100, 200, 300, 5000)]
    r = summarise(frames, threshold=0.5)
    assert r["recall_by_width_px"] == {"64-128": {"recall": 1.0, "count": 1}, "128-256": {"recall": 1.0, "count": 1},
                                       "256+": {"recall": 0.5, "count": 2}}
