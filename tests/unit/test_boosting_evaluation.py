"""eval-boosting pieces: table statistics, closest-hypothesis selection, JSON schema of a tiny run."""

import json
import re

import cv2
import numpy as np
import pytest

from uav_landing_vision.boosting.evaluation import (
    BoostingEvalConfig,
    closest_errors,
    evaluate_boosting,
    format_tables,
    normal_backgrounds,
    sample_positions,
    silhouette_roi,
)
from uav_landing_vision.evaluation.statistics import STAT_KEYS
from uav_landing_vision.camera import CameraModel, load_camera_info_yaml
from uav_landing_vision.cli import main
from uav_landing_vision.geometry import euler_zyx_to_quat
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.resources import config_path


@pytest.fixture(scope="module")
def camera():
    return load_camera_info_yaml(config_path("camera.yaml")).rectified()


def test_closest_hypothesis_is_chosen_by_rotation_among_the_first_k():
    q_true = euler_zyx_to_quat(np.zeros(3))
    quats = euler_zyx_to_quat(np.radians([[0, 0, 40], [0, 0, 20], [0, 0, 5], [0, 0, 1]]))
    positions = np.array([[0, 0, 1.0], [0, 0, 2.0], [0, 0, 3.0], [0, 0, 4.0]])
    t_err, r_err = closest_errors(q_true, np.zeros(3), quats, positions, (1, 2, 4))
    np.testing.assert_allclose(t_err[:, 2], [1.0, 2.0, 4.0])  # estimate − truth
    np.testing.assert_allclose(np.degrees(r_err[:, 2]), [-40.0, -20.0, -1.0], atol=1e-9)


def sphere_image_extents(camera, centres, radius):
    """Per centre, the (u, v) minima and maxima of 4 000 points of the sphere projected by OpenCV."""
    k = np.arange(4000) + 0.5
    z = 1.0 - 2.0 * k / len(k)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    points = radius * np.stack([np.sqrt(1 - z**2) * np.cos(phi), np.sqrt(1 - z**2) * np.sin(phi), z], axis=1)
    lo, hi = [], []
    for c in centres:
        uv = cv2.projectPoints(points + c, np.zeros(3), np.zeros(3), camera.K, None)[0].reshape(-1, 2)
        lo.append(uv.min(0))
        hi.append(uv.max(0))
    return np.array(lo), np.array(hi)


@pytest.mark.parametrize("distance", [5.0, 15.0])
def test_view_positions_keep_the_whole_sphere_in_the_image_and_reach_every_border(camera, distance):
    """Off the axis a sphere's image is larger than fx·R/d: the sphere at each position stays
    within the border pixel centres, and the positions spread until it nearly touches each side."""
    radius = 0.92  # the shipped model's farthest vertex from its centre of gravity
    p = sample_positions(camera, distance, radius, 400, np.random.default_rng(0))
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), distance)
    lo, hi = sphere_image_extents(camera, p, radius)
    size = np.array([camera.width - 1, camera.height - 1])
    assert np.all(lo >= -0.05) and np.all(hi <= size + 0.05)
    assert np.all(lo.min(0) < 10.0) and np.all(hi.max(0) > size - 10.0)


def test_view_positions_follow_an_off_centre_principal_point_and_unequal_focal_lengths():
    k = np.array([[900.0, 0.0, 250.0], [0.0, 700.0, 300.0], [0.0, 0.0, 1.0]])
    other = CameraModel(640, 480, k, np.zeros(5))
    p = sample_positions(other, 8.0, 1.0, 200, np.random.default_rng(1))
    lo, hi = sphere_image_extents(other, p, 1.0)
    assert np.all(lo >= -0.05) and np.all(hi <= np.array([639.05, 479.05]))
    assert np.all(lo.min(0) < 10.0) and np.all(hi.max(0) > np.array([629.0, 469.0]))


def test_view_placement_refuses_a_distance_at_which_the_sphere_does_not_fit(camera):
    with pytest.raises(ValueError, match="does not fit in the 1280x720 image"):
        sample_positions(camera, 1.0, 0.92, 5, np.random.default_rng(0))


def test_background_and_roi(camera):
    frames, sun, _ = normal_backgrounds(camera, 2, 0)
    assert frames[0].shape == (camera.height, camera.width, 3) and frames[0].dtype == np.uint8
    assert not np.array_equal(frames[0], frames[1])  # the sea moves
    assert np.linalg.norm(sun) == pytest.approx(1.0)
    alpha = np.zeros((100, 200), np.float32)
    alpha[40:60, 50:150] = 1.0
    assert silhouette_roi(alpha) == (50, 40, 100, 20)
    assert silhouette_roi(np.zeros((10, 10))) is None


def test_tiny_run_has_the_json_schema(tmp_path, camera):
    cfg = BoostingEvalConfig(samples=4, distances=(5.0, 15.0), top=(1, 3), seed=2)
    result = evaluate_boosting(camera, fixed_wing_mesh("high"), cfg, progress=False)
    assert result["failures"] == {"5": 0, "15": 0} and result["samples"] == 4  # a box in every frame at 5-15 m
    stats = result["stats"]
    assert list(stats) == ["5", "15"] and list(stats["5"]) == ["1", "3"]
    cell = stats["15"]["3"]
    assert list(cell["translation_m"]) == ["x", "y", "z"]
    assert list(cell["rotation_deg"]) == ["alpha", "beta", "gamma"]
    assert list(cell["rotation_deg"]["beta"]) == list(STAT_KEYS)
    for per_k in stats.values():  # statistics of the four samples, not of none
        for c in per_k.values():
            assert all(np.isfinite(v) for part in c.values() for axis in part.values() for v in axis.values())
    for distance, per_k in stats.items():  # errors, not poses: the depth is found to a fraction of the range
        for c in per_k.values():
            assert abs(c["translation_m"]["z"]["median"]) < 0.4 * float(distance)
            assert max(c["translation_m"][a]["mae"] for a in "xy") < 0.1 * float(distance)
    text = format_tables(result)
    assert "Rotation error (degrees) at 15 m" in text
    header, first = text.splitlines()[2], text.splitlines()[3]  # each k label ends over its column
    assert [m.end() for m in re.finditer(r"\d+", header)] == [m.end() for m in re.finditer(r"-?\d+\.\d+|nan", first)]
    out = tmp_path / "e.json"
    assert main(["eval-boosting", "--samples", "2", "--distances", "5", "--top", "1", "2", "--quiet",
                 "--json", str(out)]) == 0
    written = json.loads(out.read_text())
    assert list(written["stats"]["5"]) == ["1", "2"]  # the statistics cover the samples with a box:
    assert written["samples"] == 2 and written["failures"]["5"] == 0  # how many is written with them
    assert main(["eval-boosting", "--samples", "1", "--distances", "5", "--top", "1", "--quiet", "--json", str(out)]) == 0
    one = json.loads(out.read_text(), parse_constant=lambda name: pytest.fail(f"{name} is not JSON"))
    assert one["stats"]["5"]["1"]["translation_m"]["x"]["sd"] is None  # one sample has none: null, not NaN
