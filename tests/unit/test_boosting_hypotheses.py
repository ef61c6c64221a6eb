"""Weak-perspective relations (4.5)–(4.7) against exact pinhole projection; hypothesis generation."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.boosting import (
    HypothesisConfig,
    Obb,
    PoseDatabase,
    PoseHypothesisGenerator,
    hypotheses_from_obb,
    weak_perspective_depth,
    weak_perspective_position,
)
from uav_landing_vision.boosting.obb import obb_from_mask, obb_from_points
from uav_landing_vision.camera import CameraModel, load_camera_info_yaml
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.render import Renderer
from uav_landing_vision.resources import config_path, model_file


@pytest.fixture(scope="module")
def camera():
    return load_camera_info_yaml(config_path("camera.yaml")).rectified()


def _square_box(camera, centre, side, depth):
    """Exact pinhole box of a fronto-parallel square (side metres) centred at ``centre`` (3,)."""
    h = side / 2
    corners = np.array(centre) + np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0.0]]) * [1, 0.5, 1]
    return obb_from_points(camera.project_pinhole(corners))


@pytest.mark.parametrize("depth", [2.0, 5.0, 15.0, 30.0, 80.0])
def test_depth_4_5_is_exact_for_a_fronto_parallel_plate(camera, depth):
    ref = _square_box(camera, [0.0, 0.0, 4.0], 1.5, 4.0)
    obs = _square_box(camera, [0.7, -0.3, depth], 1.5, depth)
    assert weak_perspective_depth(4.0, ref.area, obs.area) == pytest.approx(depth, rel=1e-4)


def test_position_4_6_4_7_inverts_the_pinhole_projection(camera):
    rng = np.random.default_rng(2)
    points = rng.uniform([-5, -3, 4], [5, 3, 60], size=(50, 3))
    uv = camera.project_pinhole(points)
    np.testing.assert_allclose(weak_perspective_position(uv, points[:, 2], camera), points, atol=1e-9)
    x, y, z = weak_perspective_position(np.array([900.0, 100.0]), 10.0, camera)
    assert (x, y, z) == pytest.approx((10 * (900 - camera.cx) / camera.fx, 10 * (100 - camera.cy) / camera.fy, 10))


def _database(camera, obbs, quats=None):
    obbs = np.asarray(obbs, dtype=float)
    if quats is None:
        quats = np.tile([0.0, 0.0, 0.0, 1.0], (len(obbs), 1))
    return PoseDatabase(quats, obbs, distance=4.0, camera=camera, model="test")


@pytest.mark.parametrize("centre_offset", [True, False])
def test_hypothesis_translation_of_a_scaled_entry(camera, centre_offset):
    # The entry's box centre is 40 px right of and 10 px below the projected body origin.
    entry = [30.0, camera.cx + 40.0, camera.cy + 10.0, 200.0, 50.0]
    db = _database(camera, [entry, [120.0, camera.cx, camera.cy, 100.0, 90.0]])
    origin = np.array([1.5, -0.8, 8.0])  # at twice the depth: half the size, half the offset
    u, v = camera.project_pinhole(origin)
    obs = Obb(30.0, u + 20.0, v + 5.0, 100.0, 25.0)
    hyp = hypotheses_from_obb(db, obs, 1, camera, centre_offset=centre_offset)
    assert hyp.indices.tolist() == [0]
    assert hyp.positions[0, 2] == pytest.approx(8.0)
    expected = origin if centre_offset else weak_perspective_position(np.array([obs.x, obs.y]), 8.0, camera)
    np.testing.assert_allclose(hyp.positions[0], expected, atol=1e-6)


def test_centre_offset_turns_with_the_box(camera):
    db = _database(camera, [[0.0, camera.cx + 40.0, camera.cy, 200.0, 50.0]])
    origin = np.array([0.0, 0.0, 4.0])
    turn = np.radians(30.0)  # the box turned by 30° (x towards y): so is the offset
    obs = Obb(30.0, camera.cx + 40.0 * np.cos(turn), camera.cy + 40.0 * np.sin(turn), 200.0, 50.0)
    hyp = hypotheses_from_obb(db, obs, 1, camera)
    np.testing.assert_allclose(hyp.positions[0], origin, atol=1e-6)  # float32 entries


def test_turned_orientation_puts_each_hypothesis_box_at_the_observed_angle(camera):
    """``turn_orientation``: each entry's orientation turned about the optical axis by the
    observed angle − the entry's (scipy oracle); rendered where the database's entries were, the
    hypotheses' boxes lie at the observed angle, with the entries' aspect ratios."""
    shipped = PoseDatabase.load(model_file("pose_database.npz"), camera=camera)
    entry = shipped.obbs[123].astype(float)
    obs = Obb(float(entry[0] + 17.0) % 180.0, camera.cx, camera.cy, float(entry[3]), float(entry[4]))
    off = np.abs((shipped.obbs[:, 0] - obs.theta + 90.0) % 180.0 - 90.0) > 8.0  # none near the observed angle
    db = PoseDatabase(shipped.quats[off], shipped.obbs[off], distance=shipped.distance, camera=camera, model="test")
    plain = hypotheses_from_obb(db, obs, 5, camera, turn_orientation=False)
    turned = hypotheses_from_obb(db, obs, 5, camera)
    np.testing.assert_array_equal(turned.indices, plain.indices)
    np.testing.assert_array_equal(turned.positions, plain.positions)
    turns = (obs.theta - db.obbs[turned.indices, 0] + 90.0) % 180.0 - 90.0
    assert np.all(np.abs(turns) > 8.0)
    oracle = Rotation.from_rotvec(np.radians(turns)[:, None] * [0.0, 0.0, 1.0]) * Rotation.from_quat(plain.quats)
    assert np.allclose(np.abs(np.sum(oracle.as_quat() * turned.quats, axis=1)), 1.0, atol=1e-12)
    with Renderer(camera, fixed_wing_mesh("low")) as renderer:
        for q, i in zip(turned.quats, turned.indices):
            box = obb_from_mask(renderer.silhouette_full(q, np.array([0.0, 0.0, db.distance])))
            assert (box.theta - obs.theta + 90.0) % 180.0 - 90.0 == pytest.approx(0.0, abs=0.5)
            assert box.aspect == pytest.approx(db.obbs[i, 3] / db.obbs[i, 4], rel=0.02)


def test_hypotheses_are_sorted_and_carry_their_entries(camera):
    rng = np.random.default_rng(4)
    n = 300
    obbs = np.column_stack([rng.uniform(0, 180, n), np.full(n, camera.cx), np.full(n, camera.cy),
                            rng.uniform(60, 300, n), rng.uniform(20, 60, n)])
    quats = rng.normal(size=(n, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    db = _database(camera, obbs, quats)
    hyp = hypotheses_from_obb(db, Obb(45.0, 500.0, 300.0, 150.0, 40.0), 25, camera, turn_orientation=False)
    assert len(hyp) == 25
    assert np.all(np.diff(hyp.distances) >= 0)
    np.testing.assert_allclose(hyp.quats, db.quats[hyp.indices].astype(float))
    assert np.all(hyp.positions[:, 2] > 0)


def test_generator_counts_and_errors(camera):
    db = _database(camera, [[float(a), camera.cx, camera.cy, 300.0, 60.0] for a in range(0, 180, 2)])
    gen = PoseHypothesisGenerator(db, camera, HypothesisConfig(particles=40, kept=30))
    frame = np.full((camera.height, camera.width, 3), 200, np.uint8)
    frame[300:340, 500:700] = 60
    roi = (450, 250, 300, 140)
    assert len(gen.generate(frame, roi, first_frame=True)) == 40
    assert len(gen.generate(frame, roi)) == 10
    assert len(gen.generate(frame, roi, count=7)) == 7
    assert gen.generate(np.full_like(frame, 200), roi) is None
    # a ROI tight on the dark box is grown before its corners are taken: the same box either way
    tight = gen.generate(frame, (500, 300, 200, 40), count=1).obb
    assert (tight.w, tight.h) == pytest.approx((gen.generate(frame, roi, count=1).obb.w, 40.0), abs=2.0)
    # a box spanning under min_roi_cover (0.6) of the ROI's longer side is part of the UAV only: no hypotheses
    wide = (400, 250, 400, 140)  # the 200 px box spans half of it
    assert gen.generate(frame, wide) is None
    thesis = PoseHypothesisGenerator(db, camera, HypothesisConfig(particles=40, kept=30, min_roi_cover=0.0))
    assert len(thesis.generate(frame, wide)) == 10
    # no hypotheses from a ROI within FAST's radius (3 px) of an edge; at 4 px, some
    inside = np.full_like(frame, 200)
    inside[300:340, camera.width - 160:camera.width - 10] = 60
    assert gen.generate(inside, (camera.width - 165, 290, 162, 60)) is None  # 3 px from the right edge
    assert len(gen.generate(inside, (camera.width - 165, 290, 161, 60))) == 10  # 4 px
    bare = PoseHypothesisGenerator(db, camera, HypothesisConfig(particles=40, kept=30, roi_margin=0.0, roi_pad_px=0.0))
    assert bare.generate(frame, (500, 300, 200, 40), count=1) is None  # ungrown: no corner in reach
    with pytest.raises(ValueError, match="camera is"):
        gen.generate(frame[:100], roi)
    other = CameraModel(camera.width, camera.height, np.diag([900.0, 900.0, 1.0]) + [[0, 0, 640], [0, 0, 360], [0, 0, 0]])
    with pytest.raises(ValueError, match="rebuild"):
        PoseHypothesisGenerator(db, other)


@pytest.mark.parametrize("kwargs", [{"particles": 0, "kept": 0}, {"particles": 10, "kept": 10},
                                    {"kept": -1}, {"aspect_weight": 0.0}, {"roi_margin": -0.1},
                                    {"roi_pad_px": -1.0}, {"min_roi_cover": -0.1}, {"min_roi_cover": 1.5},
                                    {"roi_margin": np.inf}, {"roi_pad_px": np.inf}, {"roi_margin": np.nan},
                                    {"particles": 10.5, "kept": 3}, {"kept": 2.5}, {"particles": True, "kept": 0},
                                    # passed before, then crashed on the first box (ROI of infinite size;
                                    # the index's distances overflowing to "no neighbour" indices)
                                    {"roi_margin": 1e306}, {"roi_pad_px": 1e306}, {"aspect_weight": 1e300}])
def test_hypothesis_config_validation(kwargs):
    with pytest.raises(ValueError):
        HypothesisConfig(**kwargs)


def test_generator_from_config_loads_the_shipped_database(camera):
    from uav_landing_vision.model import fixed_wing_mesh

    gen = PoseHypothesisGenerator.from_config(HypothesisConfig(aspect_weight=3.0), camera, fixed_wing_mesh("high"))
    assert len(gen.database) == 11000 and gen.database.aspect_weight == 3.0
    with pytest.raises(ValueError, match="not found"):
        PoseHypothesisGenerator.from_config(HypothesisConfig(database="/nonexistent/db.npz"), camera)


def test_a_uav_cut_by_the_frame_edge_gives_no_hypotheses(camera):
    """Its ROI is cut by the edge like its box, so the box passed min_roi_cover, and its depth
    (4.5) came out 48 % too far (22 m for 15 m)."""
    from uav_landing_vision.boosting.database import NOMINAL_QUAT

    db = PoseDatabase.load(model_file("pose_database.npz"), camera=camera)
    gen = PoseHypothesisGenerator(db, camera, HypothesisConfig())
    quat = (Rotation.from_euler("xyz", [10, -15, 5], degrees=True) * Rotation.from_quat(NOMINAL_QUAT)).as_quat()
    renderer = Renderer(camera, fixed_wing_mesh("high"))

    def shot(x_m):
        mask = renderer.silhouette_full(quat, np.array([x_m, 0.0, 15.0]))
        frame = np.full((camera.height, camera.width, 3), 190, np.uint8)
        frame[mask] = 50
        ys, xs = np.nonzero(mask)
        return frame, (xs.min(), ys.min(), xs.max() + 1 - xs.min(), ys.max() + 1 - ys.min())

    assert gen.generate(*shot(0.0), count=25) is not None  # whole, on the axis
    frame, roi = shot(-8.9)  # half of it left of the frame
    assert roi[0] == 0 and gen.generate(frame, roi, count=25) is None
    renderer.release()


def _database(camera, obbs, quats=None):
    obbs = np.asarray(obbs, dtype=float)
    if quats is None:
        quats = np.tile([0.0, 0.0, 0.0, 1.0], (len(obbs), 1))
    return PoseDatabase(quats, obbs, distance=4.0, camera=camera, model="test")


def test_a_box_without_height_is_refused(camera):
    db = _database(camera, [[0.0, camera.cx, camera.cy, 200.0, 50.0]])
    with pytest.raises(ValueError, match="positive sides"):
        hypotheses_from_obb(db, Obb(30.0, 100.0, 100.0, 50.0, 0.0), 1, camera)


def test_the_turn_is_wrapped_to_the_nearer_of_the_two_box_directions(camera):
    """Entry at 170°, observed at 10°: the box turned by +20° (not −160°, which flips the
    UAV nose for tail and moves the centre offset to the other side)."""
    db = _database(camera, [[170.0, camera.cx + 40.0, camera.cy, 200.0, 50.0]])
    turn = np.radians(20.0)
    offset = 40.0 * np.array([np.cos(turn), np.sin(turn)])  # the entry's (40, 0) offset turned by 20°
    obs = Obb(10.0, camera.cx + offset[0], camera.cy + offset[1], 200.0, 50.0)
    hyp = hypotheses_from_obb(db, obs, 1, camera)
    np.testing.assert_allclose(hyp.positions[0], [0.0, 0.0, 4.0], atol=1e-6)
    expected = Rotation.from_rotvec([0.0, 0.0, turn]).as_quat()
    assert abs(np.dot(hyp.quats[0], expected)) == pytest.approx(1.0, abs=1e-9)


def _generator_frame(camera, rows=slice(300, 340), cols=slice(500, 700)):
    frame = np.full((camera.height, camera.width, 3), 200, np.uint8)
    frame[rows, cols] = 60
    return frame


def _angle_db(camera):
    return _database(camera, [[float(a), camera.cx, camera.cy, 300.0, 60.0] for a in range(0, 180, 2)])


def test_no_hypotheses_within_fast_radius_of_the_top_or_bottom_edge(camera):
    """As for the right edge in test_boosting_hypotheses: 3 px from an edge, none."""
    gen = PoseHypothesisGenerator(_angle_db(camera), camera, HypothesisConfig(particles=40, kept=30))
    top = _generator_frame(camera, rows=slice(10, 50))
    assert gen.generate(top, (495, 3, 210, 52)) is None
    assert len(gen.generate(top, (495, 4, 210, 52))) == 10
    h = camera.height
    bottom = _generator_frame(camera, rows=slice(h - 50, h - 10))
    assert gen.generate(bottom, (495, h - 55, 210, 52)) is None  # 3 px above the bottom
    assert len(gen.generate(bottom, (495, h - 56, 210, 52))) == 10


def test_a_box_spanning_exactly_min_roi_cover_gives_hypotheses(camera):
    """"less than this fraction": a box of exactly the fraction passes."""
    frame = _generator_frame(camera)
    roi = (472, 250, 256, 140)
    w = PoseHypothesisGenerator(_angle_db(camera), camera, HypothesisConfig(min_roi_cover=0.0)).generate(frame, roi).obb.w
    cover = w / 256.0
    assert cover * 256.0 == w
    gen = PoseHypothesisGenerator(_angle_db(camera), camera, HypothesisConfig(particles=40, kept=30, min_roi_cover=cover))
    assert gen.generate(frame, roi) is not None


def test_the_generator_honours_centre_offset_and_turn_orientation(camera):
    """Both switches reach hypotheses_from_obb (the thesis's settings are False)."""
    quat = Rotation.from_euler("xyz", [10, 20, 30], degrees=True).as_quat()
    db = _database(camera, [[20.0, camera.cx + 40.0, camera.cy + 10.0, 200.0, 40.0]], [quat])
    frame, roi = _generator_frame(camera), (450, 250, 300, 140)
    for centre_offset in (True, False):
        for turn in (True, False):
            gen = PoseHypothesisGenerator(db, camera, HypothesisConfig(
                particles=2, kept=1, centre_offset=centre_offset, turn_orientation=turn))
            hyp = gen.generate(frame, roi, count=1)
            ref = hypotheses_from_obb(db, hyp.obb, 1, camera, centre_offset, turn)
            np.testing.assert_allclose(hyp.positions, ref.positions)
            np.testing.assert_allclose(hyp.quats, ref.quats)
    plain = PoseHypothesisGenerator(db, camera, HypothesisConfig(particles=2, kept=1, turn_orientation=False))
    np.testing.assert_allclose(plain.generate(frame, roi, count=1).quats[0], quat, atol=1e-7)


def test_the_roi_grows_by_margin_of_its_size_plus_pad(camera):
    """A faint-free dark blob 20 px below the UAV's box lies outside the ROI grown by 10 % +
    2 px, so it is not part of the box."""
    frame = _generator_frame(camera)
    frame[360:370, 590:610] = 60
    gen = PoseHypothesisGenerator(_angle_db(camera), camera, HypothesisConfig(particles=40, kept=30))
    box = gen.generate(frame, (500, 300, 200, 40), count=1).obb
    assert box.h == pytest.approx(39.0, abs=1.0)


def test_the_generator_validates_the_roi(camera):
    """A ROI outside the image or with an infinite side is a ValueError, not a silent None
    or an OverflowError."""
    gen = PoseHypothesisGenerator(_angle_db(camera), camera, HypothesisConfig(particles=40, kept=30))
    frame = _generator_frame(camera)
    with pytest.raises(ValueError, match="outside"):
        gen.generate(frame, (camera.width + 100, 10, 20, 20))
    with pytest.raises(ValueError, match="four numbers"):
        gen.generate(frame, (500, 300, 200, float("inf")))


def test_a_distorted_camera_is_held_rectified(camera):
    """Frames come rectified: the generator holds the rectified camera (only its intrinsics are used)."""
    raw = load_camera_info_yaml(config_path("camera.yaml"))
    assert raw.is_distorted
    assert not PoseHypothesisGenerator(_angle_db(camera), raw).camera.is_distorted


def test_each_hypothesis_takes_the_depth_at_which_its_own_entry_has_the_observed_size(camera):
    """Entries of fronto-parallel plates of three sizes at the database's 4 m, all of the
    observed shape: each hypothesis lies at the depth where its own plate projects (pinhole) to
    the observed box's area, so only the plate of the observed size is at the true 12 m."""
    sides = [1.0, 1.5, 2.25]
    db = _database(camera, [list(_square_box(camera, [0.0, 0.0, 4.0], s, 4.0)) for s in sides])
    obs = _square_box(camera, [0.4, 0.2, 12.0], 1.5, 12.0)
    hyp = hypotheses_from_obb(db, obs, 3, camera, centre_offset=False)
    assert sorted(hyp.indices.tolist()) == [0, 1, 2]
    for i, z in zip(hyp.indices, hyp.positions[:, 2]):
        assert _square_box(camera, [0.0, 0.0, z], sides[i], z).area == pytest.approx(obs.area, rel=1e-4)
    depth = dict(zip(hyp.indices.tolist(), hyp.positions[:, 2]))
    assert depth[1] == pytest.approx(12.0, rel=1e-4) and depth[0] < 12.0 < depth[2]


def test_centre_offset_turns_both_of_its_image_components_with_the_box(camera):
    """The entry's box centre lies 30 px right of and 40 px below the projected body origin; the
    UAV observed at twice the depth with its box turned by 60° (image x towards y): the offset is
    halved and turned by 60° about the optical axis (scipy oracle), and the body origin is found."""
    db = _database(camera, [[0.0, camera.cx + 30.0, camera.cy + 40.0, 200.0, 50.0]])
    origin = np.array([0.5, -0.3, 8.0])
    turned = Rotation.from_euler("z", 60.0, degrees=True).apply([30.0, 40.0, 0.0])[:2]
    centre = camera.project_pinhole(origin) + 0.5 * turned
    hyp = hypotheses_from_obb(db, Obb(60.0, centre[0], centre[1], 100.0, 25.0), 1, camera, turn_orientation=False)
    np.testing.assert_allclose(hyp.positions[0], origin, atol=1e-6)


def test_min_roi_cover_is_of_the_roi_s_longer_side_when_the_roi_is_tall(camera):
    """A UAV seen nose-on gives a tall ROI: a 200 px-tall box spans half of a 400 px-tall,
    80 px-wide ROI (no hypotheses), and most of a 220 px-tall one (hypotheses)."""
    gen = PoseHypothesisGenerator(_angle_db(camera), camera, HypothesisConfig(particles=40, kept=30))
    frame = _generator_frame(camera, rows=slice(150, 350), cols=slice(600, 640))
    assert gen.generate(frame, (580, 140, 80, 220)).obb.w == pytest.approx(200.0, abs=3.0)
    assert gen.generate(frame, (580, 100, 80, 400)) is None


def test_a_box_without_width_is_refused(camera):
    db = _database(camera, [[0.0, camera.cx, camera.cy, 200.0, 50.0]])
    with pytest.raises(ValueError, match="positive sides"):
        hypotheses_from_obb(db, Obb(30.0, 100.0, 100.0, 0.0, 50.0), 1, camera)


def test_hypothesis_config_takes_the_ends_of_its_documented_ranges():
    """min_roi_cover in [0, 1], 0 <= M0 < M and the ROI growth up to 10 x its size and 1e4 px
    are closed ranges; numpy integers are integers; a growth just past its limit is refused."""
    for cover in (0.0, 1.0):
        assert HypothesisConfig(min_roi_cover=cover).min_roi_cover == cover
    fresh = HypothesisConfig(particles=1, kept=0)  # no particle kept: every one boosted afresh
    assert (fresh.count(True), fresh.count(False)) == (1, 1)
    HypothesisConfig(roi_margin=10.0, roi_pad_px=1e4)
    assert HypothesisConfig(particles=np.int64(40), kept=np.int32(30)).count(False) == 10
    for kwargs in ({"roi_margin": 10.5}, {"roi_pad_px": 1.05e4}):
        with pytest.raises(ValueError, match="roi_margin and roi_pad_px"):
            HypothesisConfig(**kwargs)
