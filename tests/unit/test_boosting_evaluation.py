"""eval-boosting (§6.4): distances, view placement, sun, ROI, the hypotheses' settings, closest-hypothesis
selection, the tables recomputed from the hypotheses a run produced (scipy rotations as the oracle), the
tables' layout, JSON schema of a tiny run."""

import json
import re

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.boosting import NOMINAL_QUAT, DatabaseConfig, build_database, obb_from_mask, sample_orientations
from uav_landing_vision.boosting import evaluation
from uav_landing_vision.boosting.evaluation import (
    BoostingEvalConfig,
    check_distances,
    closest_errors,
    evaluate_boosting,
    format_tables,
    normal_backgrounds,
    rendered_hypotheses,
    sample_positions,
    silhouette_roi,
)
from uav_landing_vision.boosting.hypotheses import hypotheses_from_obb
from uav_landing_vision.boosting.obb import FastConfig
from uav_landing_vision.camera import CameraModel, load_camera_info_yaml
from uav_landing_vision.cli import main
from uav_landing_vision.evaluation.statistics import STAT_KEYS, error_statistics
from uav_landing_vision.geometry import euler_zyx_to_quat
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.resources import config_path


@pytest.fixture(scope="module")
def camera():
    return load_camera_info_yaml(config_path("camera.yaml")).rectified()


@pytest.fixture(scope="module")
def mesh():
    return fixed_wing_mesh("high")


@pytest.fixture(scope="module")
def small_db(camera, mesh, tmp_path_factory):
    """A 300-entry database over ±30° built with seed 4, saved to a file."""
    db = build_database(camera, mesh, DatabaseConfig(count=300, half_range_deg=(30.0, 30.0, 30.0), seed=4),
                        progress=False)
    return db, db.save(tmp_path_factory.mktemp("db") / "db.npz")


@pytest.mark.parametrize("distances", [(0.0,), (5.0, 0.0), (5.0, np.inf), (-1.0,), ()])
def test_distances_must_be_finite_and_positive(distances):
    with pytest.raises(ValueError, match="finite and positive"):
        check_distances(distances)


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
    alpha[39, 50:150] = 0.25  # anti-aliased coverage at the silhouette's edge is part of it
    alpha[40:60, 150] = 0.25
    assert silhouette_roi(alpha) == (50, 39, 101, 21)
    assert silhouette_roi(np.zeros((10, 10))) is None


def test_sun_is_given_in_the_optical_frame_of_the_aft_looking_deck_camera(camera):
    """Sun at azimuth 150° from the bow (to port), elevation 35°; the camera looks aft, level but
    for a 2° tilt: the sun is ahead of it (+z), above (−y) and to its right (+x, port)."""
    _, sun, _ = normal_backgrounds(camera, 1, 0)
    az, el = np.radians([150.0, 35.0])
    expected = [np.cos(el) * np.sin(az), -np.sin(el), -np.cos(el) * np.cos(az)]
    np.testing.assert_allclose(sun, expected, atol=0.04)


@pytest.fixture(scope="module")
def scene(camera, mesh):
    from uav_landing_vision.render import Renderer

    backgrounds, sun, albedo = normal_backgrounds(camera, 1, 0)
    renderer = Renderer(camera, mesh)
    yield renderer, backgrounds[0], sun, albedo
    renderer.release()


def test_the_fast_box_spans_the_silhouette_because_the_roi_is_grown(camera, small_db, scene):
    """FAST finds no corner within 3 px of its image's edge: on the silhouette's tight box the
    outline's extreme corners are lost; grown as boosting grows ROIs, the box spans the UAV."""
    renderer, background, sun, albedo = scene
    db, _ = small_db
    t = [0.0, 0.0, 15.0]
    for q in sample_orientations(6, (90, 90, 90), np.random.default_rng(5)):
        _, hyp = rendered_hypotheses(renderer, db, camera, q, t, background, sun, albedo, FastConfig(), 3)
        _, alpha = renderer.shaded(q, t, background, albedo=albedo, light_dir=sun)
        silhouette = obb_from_mask(alpha > 0)
        assert hyp is not None
        assert silhouette.w - 4.0 < hyp.obb.w <= silhouette.w + 1.0


@pytest.mark.parametrize("centre_offset, turn_orientation", [(False, True), (True, False), (False, False)])
def test_rendered_hypotheses_follow_the_centre_and_turn_settings(camera, small_db, scene, centre_offset,
                                                                 turn_orientation):
    renderer, background, sun, albedo = scene
    db, _ = small_db
    q = sample_orientations(1, (30, 30, 30), np.random.default_rng(8))[0]
    _, hyp = rendered_hypotheses(renderer, db, camera, q, [0.0, 0.0, 8.0], background, sun, albedo, FastConfig(), 5,
                                 centre_offset, turn_orientation)
    expected = hypotheses_from_obb(db, hyp.obb, 5, camera, centre_offset, turn_orientation)
    np.testing.assert_allclose(hyp.positions, expected.positions)
    np.testing.assert_allclose(hyp.quats, expected.quats)
    if not turn_orientation:
        np.testing.assert_allclose(hyp.quats, db.quats[hyp.indices], atol=1e-6)
    if not centre_offset:  # every hypothesis on the ray through the box centre
        uv = camera.project_pinhole(hyp.positions)
        np.testing.assert_allclose(uv, np.tile([hyp.obb.x, hyp.obb.y], (5, 1)), atol=1e-6)


def _recording(monkeypatch, no_box=()):
    """Record every sample's inputs and hypotheses; the samples numbered in ``no_box`` get none,
    as when FAST finds no box."""
    calls = []
    real = evaluation.rendered_hypotheses

    def spy(renderer, db, camera, quat, trans, background, sun, albedo, fast, k, centre_offset=True,
            turn_orientation=True):
        frame, hyp = real(renderer, db, camera, quat, trans, background, sun, albedo, fast, k, centre_offset,
                          turn_orientation)
        if len(calls) in no_box:
            hyp = None
        calls.append(dict(db=db, quat=np.array(quat, float), trans=np.array(trans, float), background=background,
                          k=k, centre_offset=centre_offset, turn_orientation=turn_orientation, hyp=hyp))
        return frame, hyp

    monkeypatch.setattr(evaluation, "rendered_hypotheses", spy)
    return calls


def _closest(q_true, t_true, hyp, k):
    """Oracle: the hypothesis with the least rotation angle among the first k (scipy)."""
    truth = Rotation.from_quat(q_true)
    angles = (truth.inv() * Rotation.from_quat(hyp.quats[:k])).magnitude()
    j = int(np.argmin(angles))
    euler = (truth * Rotation.from_quat(hyp.quats[j]).inv()).as_euler("ZYX")[::-1]  # [α, β, γ] of q_g ⊗ q̄_r
    return hyp.positions[j] - t_true, np.degrees(euler)


def _check_tables(result, calls, config):
    n = config.samples
    for d_i, distance in enumerate(config.distances):
        mine = calls[d_i * n:(d_i + 1) * n]
        key = f"{distance:g}"
        assert result["failures"][key] == sum(c["hyp"] is None for c in mine)
        for k in config.top:
            errs = [_closest(c["quat"], c["trans"], c["hyp"], k) for c in mine if c["hyp"] is not None]
            t = np.array([e[0] for e in errs])
            r = np.array([e[1] for e in errs])
            cell = result["stats"][key][str(k)]
            for c, a in enumerate("xyz"):
                got, want = cell["translation_m"][a], error_statistics(t[:, c])
                np.testing.assert_allclose([got[s] for s in STAT_KEYS], [want[s] for s in STAT_KEYS],
                                           rtol=1e-9, atol=1e-9)
            for c, a in enumerate(("alpha", "beta", "gamma")):
                got, want = cell["rotation_deg"][a], error_statistics(r[:, c])
                np.testing.assert_allclose([got[s] for s in STAT_KEYS], [want[s] for s in STAT_KEYS],
                                           rtol=1e-6, atol=1e-6)


@pytest.fixture(scope="module")
def view_run(camera, mesh, small_db):
    """A ``view`` run over ``small_db`` recording every sample (:func:`_recording`) and, per call of
    ``sample_positions``, the distance and radius it was given and the positions it returned."""
    _, path = small_db
    config = BoostingEvalConfig(samples=3, distances=(6.0, 12.0), top=(1, 4), seed=4, placement="view",
                                centre_offset=False, turn_orientation=True, aspect_weight=3.0)
    placements = []
    real_positions = evaluation.sample_positions

    def positions_spy(camera, distance, radius, count, rng):
        positions = real_positions(camera, distance, radius, count, rng)
        placements.append((distance, radius, positions))
        return positions

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(evaluation, "BACKGROUND_FRAMES", 2)
        mp.setattr(evaluation, "sample_positions", positions_spy)
        calls = _recording(mp)
        result = evaluate_boosting(camera, mesh, config, database_path=path, progress=False)
    return config, calls, result, placements


def test_the_tables_are_the_statistics_of_the_closest_hypothesis_errors_per_k(view_run):
    config, calls, result, _ = view_run
    assert len(calls) == config.samples * len(config.distances)
    assert all(c["hyp"] is None or len(c["hyp"]) == max(config.top) for c in calls)
    _check_tables(result, calls, config)


def test_each_sample_uses_the_runs_settings_and_database(view_run):
    _, calls, _, _ = view_run
    for c in calls:
        assert (c["centre_offset"], c["turn_orientation"], c["k"]) == (False, True, 4)
        assert c["db"].aspect_weight == 3.0 and c["db"].half_range_deg == (30.0, 30.0, 30.0)
    # consecutive samples see the sea at different moments
    assert not np.array_equal(calls[0]["background"], calls[1]["background"])


def test_view_samples_are_the_positions_drawn_for_the_models_bounding_sphere(view_run, mesh):
    """Per distance, the samples sit where :func:`sample_positions` put the sphere through the
    model's farthest vertex (that it keeps this sphere in view is tested above)."""
    config, calls, _, placements = view_run
    radius = float(np.max(np.linalg.norm(mesh.vertices, axis=1)))
    assert [distance for distance, _, _ in placements] == list(config.distances)
    assert [r for _, r, _ in placements] == pytest.approx([radius] * len(config.distances))
    for d_i, (_, _, positions) in enumerate(placements):
        trans = [c["trans"] for c in calls[d_i * config.samples:(d_i + 1) * config.samples]]
        np.testing.assert_array_equal(trans, positions)


def test_sampled_orientations_are_in_the_database_interval_and_not_its_entries(view_run, small_db):
    """Test poses are drawn in the database's interval, independently of the database's own draws
    even when both use the same seed (else each test pose would be a stored entry)."""
    db, _ = small_db
    _, calls, _, _ = view_run
    quats = np.array([c["quat"] for c in calls])
    rel = Rotation.from_quat(quats) * Rotation.from_quat(NOMINAL_QUAT).inv()
    assert np.all(np.abs(np.degrees(rel.as_euler("ZYX"))) <= 30.0 + 1e-6)
    for q in quats:
        nearest = (Rotation.from_quat(q).inv() * Rotation.from_quat(db.quats.astype(float))).magnitude().min()
        assert nearest > 1e-3


def test_axis_placement_puts_every_sample_on_the_optical_axis_and_counts_samples_without_a_box(
        camera, mesh, small_db, monkeypatch):
    _, path = small_db
    monkeypatch.setattr(evaluation, "BACKGROUND_FRAMES", 2)
    calls = _recording(monkeypatch, no_box={1})
    config = BoostingEvalConfig(samples=3, distances=(9.0,), top=(2,), seed=1)
    result = evaluate_boosting(camera, mesh, config, database_path=path, progress=False)
    np.testing.assert_array_equal([c["trans"] for c in calls], [[0.0, 0.0, 9.0]] * 3)
    assert result["failures"] == {"9": 1}
    _check_tables(result, calls, config)


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


def fake_cell(base):
    """A table cell whose every statistic tells where it is: base + axis index (+ 10 for the
    rotation) + 0.01 × the statistic's row."""
    return {"translation_m": {a: {s: base + i + 0.01 * j for j, s in enumerate(STAT_KEYS)}
                              for i, a in enumerate("xyz")},
            "rotation_deg": {a: {s: base + 10 + i + 0.01 * j for j, s in enumerate(STAT_KEYS)}
                             for i, a in enumerate(("alpha", "beta", "gamma"))}}


def _fake_result(failures):
    return {"stats": {"5": {"10": fake_cell(100), "25": fake_cell(200)}}, "failures": {"5": failures}, "samples": 8}


def test_tables_count_the_samples_with_a_box_and_group_columns_by_axis_then_k():
    text = format_tables(_fake_result(3))
    assert "at 5 m using 10, 25 database poses (5/8 samples with a box)" in text
    lines = text.splitlines()
    first = [float(v) for v in re.findall(r"-?\d+\.\d+", lines[3])]  # 5 % percentile row of the translation table
    assert first == [100.0, 200.0, 101.0, 201.0, 102.0, 202.0]
    rot = lines[lines.index(next(line for line in lines if line.startswith("Rotation"))) + 3]
    assert [float(v) for v in re.findall(r"-?\d+\.\d+", rot)] == [110.0, 210.0, 111.0, 211.0, 112.0, 212.0]
