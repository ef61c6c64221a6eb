"""eval-detector: its arguments are checked before any frame is read; Fig. 4.4 near ties are
counted."""

import numpy as np
import pytest

from uav_landing_vision.detection.detector import DetectorConfig
from uav_landing_vision.detection.evaluation import evaluate_bag, label_frame, summarise


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
