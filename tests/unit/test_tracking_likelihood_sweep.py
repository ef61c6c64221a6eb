"""§6.5 metric sweep: Table 6.4's tests, the swept poses and ``uav-landing eval-metrics``."""

import csv
import json

import numpy as np
import pytest

from uav_landing_vision.cli import main
from uav_landing_vision.geometry import quat_to_matrix
from uav_landing_vision.tracking.metric_sweep import nominal_pose, swept_poses, table_6_4, truth_value


def test_table_6_4_intervals_and_steps():
    tests = table_6_4(5.0)
    assert [(t.number, t.kind, "XYZ"[t.axis]) for t in tests] == [
        (1, "rotation", "Z"), (2, "rotation", "X"), (3, "rotation", "Y"),
        (4, "translation", "Z"), (5, "translation", "Y"), (6, "translation", "X"),
    ]  # fmt: skip
    spans = [(-180, 180, 1)] * 3 + [(3, 7, 0.01), (-0.24, 0.24, 0.01), (-0.74, 0.74, 0.01)]
    for t, (lo, hi, step) in zip(tests, spans):
        assert t.values[0] == pytest.approx(lo) and t.values[-1] == pytest.approx(hi)
        np.testing.assert_allclose(np.diff(t.values), step, atol=1e-9)
    assert table_6_4(10.0)[5].values[-1] == pytest.approx(1.48)  # scaled with the distance


def test_swept_poses_move_one_coordinate():
    q0, t0 = nominal_pose(5.0)
    np.testing.assert_allclose(quat_to_matrix(q0[None])[0][:, 1], [1, 0, 0], atol=1e-12)  # left wing → image right
    rot_z = table_6_4()[0]
    quats, trans = swept_poses(rot_z)
    at90 = quat_to_matrix(quats[rot_z.values == 90.0])[0]
    np.testing.assert_allclose(at90[:, 1], [0, 1, 0], atol=1e-12)  # rolled 90° about the optical axis
    np.testing.assert_allclose(at90[:, 0], [0, 0, -1], atol=1e-12)  # still facing the camera
    np.testing.assert_array_equal(trans, np.tile(t0, (361, 1)))
    along_x = table_6_4()[5]
    quats, trans = swept_poses(along_x)
    np.testing.assert_allclose(trans[:, 0], along_x.values)
    np.testing.assert_array_equal(trans[:, 1:], np.tile(t0[1:], (149, 1)))
    np.testing.assert_array_equal(quats, np.tile(q0, (149, 1)))
    assert truth_value(table_6_4()[3]) == 5.0 and truth_value(along_x) == 0.0


def test_eval_metrics_command_peaks_at_the_true_pose(tmp_path, capsys):
    assert main(["eval-metrics", "--metric", "colour", "--out", str(tmp_path), "--seed", "1"]) == 0
    assert "Test 6 - Translation along X" in capsys.readouterr().out
    doc = json.loads((tmp_path / "metric_sweep.json").read_text())
    tolerance = {1: 2.0, 2: 2.0, 3: 2.0, 4: 0.3, 5: 0.02, 6: 0.02}
    for t in doc["tests"]:
        assert list(t["curves"]) == ["colour"]
        assert abs(t["peaks"]["colour"]["at"] - t["truth"]) <= tolerance[t["number"]], t["title"]
    with (tmp_path / "metric_sweep.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 * 361 + 401 + 49 + 149
    for kind in ("rotation", "translation"):
        assert (tmp_path / f"metric_sweep_{kind}_normal.png").stat().st_size > 10_000


def test_eval_metrics_refuses_bad_distance(tmp_path):
    with pytest.raises(SystemExit, match="distance"):
        main(["eval-metrics", "--distance", "0.2", "--out", str(tmp_path)])
    # So far that the UAV is a few pixels: curves of noise written as results before.
    with pytest.raises(SystemExit, match=r"at 10000 m the UAV spans 0.\d px, under 16: choose a smaller distance"):
        main(["eval-metrics", "--distance", "1e4", "--out", str(tmp_path / "far")])
    assert not (tmp_path / "far").exists()


def test_eval_metrics_checks_the_span_before_making_the_frame(monkeypatch, tmp_path):
    from uav_landing_vision.tracking import metric_sweep

    def no_frame(*args):
        raise AssertionError("the frame was made before the span check")

    monkeypatch.setattr(metric_sweep, "sweep_frame", no_frame)
    with pytest.raises(SystemExit, match="choose a smaller distance"):
        main(["eval-metrics", "--distance", "1e4", "--out", str(tmp_path)])
