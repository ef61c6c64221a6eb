"""eval-detector's arguments are checked before any frame is read."""

import pytest

from uav_landing_vision.detection.detector import DetectorConfig
from uav_landing_vision.detection.evaluation import evaluate_bag


def test_unknown_truth_box_is_rejected_before_the_bag_is_opened(tmp_path):
    with pytest.raises(ValueError, match="truth_box must be one of"):
        evaluate_bag(tmp_path / "no_bag", DetectorConfig(), tmp_path / "out.json", truth_box="silhouette")
