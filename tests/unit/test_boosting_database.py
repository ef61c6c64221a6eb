"""Pose database: entry checks, (4.1) positions, (4.4) ranking and θ periodicity, sampling, building with the
configured settings, file round trip and checks, camera and model compatibility, self-query."""

from pathlib import Path

import numpy as np
import pytest

from uav_landing_vision.boosting import (
    NOMINAL_QUAT,
    DatabaseConfig,
    DatabaseError,
    PoseDatabase,
    build_database,
    hypotheses_from_obb,
    mesh_fingerprint,
    obb_distance,
    obb_from_mask,
    sample_orientations,
)
from uav_landing_vision.camera import CameraModel, load_camera_info_yaml
from uav_landing_vision.geometry import geodesic_angle, quat_conjugate, quat_multiply, quat_to_euler_zyx, quat_to_matrix
from uav_landing_vision.model import Mesh, fixed_wing_mesh
from uav_landing_vision.resources import config_path, model_path


@pytest.fixture(scope="module")
def camera():
    return load_camera_info_yaml(config_path("camera.yaml")).rectified()


@pytest.fixture(scope="module")
def mesh():
    return fixed_wing_mesh("high")


@pytest.fixture(scope="module")
def synthetic(camera):
    rng = np.random.default_rng(9)
    n = 2000
    obbs = np.column_stack([rng.uniform(0, 180, n), rng.uniform(400, 800, n), rng.uniform(200, 500, n),
                            rng.uniform(100, 400, n), rng.uniform(30, 100, n)])
    return PoseDatabase(sample_orientations(n, (90, 90, 90), rng), obbs, distance=4.0, camera=camera, model="m")


def _entries(count=3):
    """``count`` poses, each with the box θ = 10°, centre (600, 300), 200 x 50 px: to edit."""
    quats = sample_orientations(count, (90, 90, 90), np.random.default_rng(1))
    return quats, np.tile([10.0, 600.0, 300.0, 200.0, 50.0], (count, 1))


@pytest.mark.parametrize("column, value, message", [(3, -5.0, "w >= h > 0"), (4, 0.0, "w >= h > 0"),
                                                   *[(c, v, "finite") for c in (0, 1, 2) for v in (np.nan, np.inf)],
                                                   ("quat", 0.0, "unit quaternions"), ("quat", np.nan, "unit"),
                                                   *[("quat scale", s, "unit quaternions") for s in (0.99, 1.01, 1.2)]])
def test_entries_that_cannot_be_poses_or_boxes_are_refused(camera, column, value, message):
    """Boxes with sides out of order or not positive, or a non-finite angle or centre; rotations
    that are not unit quaternions (1 % off unit length is already too far)."""
    quats, obbs = _entries()
    if column == "quat":
        quats[1] = value
    elif column == "quat scale":
        quats[1] *= value
    else:
        obbs[1, column] = value
    with pytest.raises(DatabaseError, match=message):
        PoseDatabase(quats, obbs, distance=4.0, camera=camera, model="m")


def test_an_empty_database_or_unequal_pose_and_box_counts_are_refused(camera):
    quats, obbs = _entries()
    with pytest.raises(DatabaseError, match="as many boxes as poses"):
        PoseDatabase(quats[:0], obbs[:0], distance=4.0, camera=camera, model="m")
    with pytest.raises(DatabaseError, match="as many boxes as poses"):
        PoseDatabase(quats[:2], obbs, distance=4.0, camera=camera, model="m")


def test_a_square_box_is_a_valid_entry(camera):
    """w >= h admits w == h: a silhouette whose box is square (R = 1) is a pose like any other."""
    quats, obbs = _entries(4)
    obbs[2, 3:5] = 120.0
    db = PoseDatabase(quats, obbs, distance=4.0, camera=camera, model="m")
    idx, dist = db.query(obbs[2, 0], 1.0, 1)
    assert idx[0] == 2 and dist[0] == pytest.approx(0.0, abs=1e-3)


def test_entry_positions_are_on_the_optical_axis_at_the_render_distance(camera, synthetic):
    """(4.1): every entry is at (0, 0, distance)."""
    db = PoseDatabase(synthetic.quats, synthetic.obbs, distance=6.5, camera=camera, model="m")
    np.testing.assert_array_equal(db.positions, np.tile([0.0, 0.0, 6.5], (len(db), 1)))


def test_box_areas_are_long_side_times_short_side(synthetic):
    obbs = synthetic.obbs.astype(float)
    np.testing.assert_allclose(synthetic.areas, obbs[:, 3] * obbs[:, 4], rtol=1e-6)


def test_distance_4_4_wraps_theta_every_180_degrees():
    assert obb_distance(179.0, 2.0, 1.0, 2.0) == pytest.approx(2.0)
    assert obb_distance(0.0, 2.0, 180.0, 2.0) == pytest.approx(0.0)
    assert obb_distance(10.0, 2.0, 100.0, 2.0) == pytest.approx(90.0)
    assert obb_distance(30.0, 3.0, 34.0, 6.0) == pytest.approx(5.0)
    assert obb_distance(30.0, 3.0, 34.0, 6.0, aspect_weight=10.0) == pytest.approx(np.hypot(4.0, 30.0))


@pytest.mark.parametrize("weight", [1.0, 10.0])
def test_index_ranks_exactly_as_the_distance(camera, synthetic, weight):
    db = PoseDatabase(synthetic.quats, synthetic.obbs, distance=4.0, camera=camera, model="m", aspect_weight=weight)
    obbs = db.obbs.astype(float)
    aspect = obbs[:, 3] / obbs[:, 4]
    for theta, r in [(0.3, 3.0), (179.8, 2.2), (90.0, 8.0), (-10.0, 1.5), (370.0, 4.0)]:
        idx, dist = db.query(theta, r, 50)
        brute = obb_distance(theta, r, obbs[:, 0], aspect, weight)
        np.testing.assert_allclose(dist, np.sort(brute)[:50], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(brute[idx], dist, rtol=1e-9, atol=1e-9)


def test_query_near_0_finds_entries_near_180(camera):
    obbs = [[179.5, 0, 0, 200, 100], [90.0, 0, 0, 200, 100], [20.0, 0, 0, 200, 100]]
    db = PoseDatabase(np.tile(NOMINAL_QUAT, (3, 1)), obbs, distance=4.0, camera=camera, model="m")
    idx, dist = db.query(0.5, 2.0, 3)
    assert idx.tolist() == [0, 2, 1]
    assert dist[0] == pytest.approx(1.0, abs=1e-4)


def test_an_angle_just_below_zero_is_stored_as_zero_and_found_at_zero(camera):
    """-1e-15 mod 180 rounds to exactly 180 in floating point, outside the periodic index's [0, 180)."""
    quats, obbs = _entries(4)
    obbs[0, 0] = -1e-15
    db = PoseDatabase(quats, obbs, distance=4.0, camera=camera, model="m")
    aspect = obbs[0, 3] / obbs[0, 4]
    for theta in (0.0, 179.9999):
        idx, dist = db.query(theta, aspect, 1)
        assert idx[0] == 0
        assert dist[0] == pytest.approx(obb_distance(theta, aspect, 0.0, aspect, db.aspect_weight), abs=1e-3)


def test_query_clips_k_and_rejects_bad_input(synthetic):
    idx, _ = synthetic.query(10.0, 2.0, 10**6)
    assert len(idx) == len(synthetic) and len(set(idx.tolist())) == len(synthetic)
    with pytest.raises(ValueError):
        synthetic.query(10.0, 2.0, 0)
    for theta, aspect in [(np.nan, 2.0), (np.inf, 2.0), (10.0, np.nan), (10.0, np.inf)]:
        with pytest.raises(ValueError, match="finite"):
            synthetic.query(theta, aspect, 5)


def test_orientations_are_uniform_euler_inside_the_interval():
    rng = np.random.default_rng(1)
    q = sample_orientations(4000, (90, 30, 60), rng)
    euler = np.degrees(quat_to_euler_zyx(quat_multiply(q, quat_conjugate(NOMINAL_QUAT))))
    assert np.all(np.abs(euler) <= np.array([90, 30, 60]) + 1e-6)
    assert np.all(np.abs(euler).max(axis=0) > np.array([85, 28, 57]))
    assert np.all(q[:, 3] >= 0)
    # Nominal attitude: nose towards the camera, left wing to image right, up to image up.
    np.testing.assert_allclose(quat_to_matrix(NOMINAL_QUAT), [[0, 1, 0], [0, 0, -1], [-1, 0, 0]], atol=1e-12)


def test_small_built_database_round_trips(tmp_path, camera, mesh):
    db = build_database(camera, mesh, DatabaseConfig(count=30, seed=3), command="test", progress=False)
    assert len(db) == 30
    assert np.all(db.obbs[:, 3] >= db.obbs[:, 4])
    path = db.save(tmp_path / "db.npz")
    back = PoseDatabase.load(path, camera=camera, mesh=mesh)
    np.testing.assert_array_equal(back.quats, db.quats)
    np.testing.assert_array_equal(back.obbs, db.obbs)
    assert (back.distance, back.model, back.command, back.half_range_deg) == (4.0, db.model, "test", (90.0, 90.0, 90.0))
    np.testing.assert_array_equal(back.camera.K, camera.K)
    assert back.quats.dtype == np.float32
    # Each entry is the box of its own silhouette at (0, 0, 4).
    from uav_landing_vision.render import Renderer

    box = obb_from_mask(Renderer(camera, mesh).silhouette_full(db.quats[7], [0.0, 0.0, 4.0]))
    np.testing.assert_allclose(box, db.obbs[7], rtol=1e-5, atol=1e-3)


def test_file_round_trip_keeps_the_image_size_range_and_weight(tmp_path, synthetic):
    """A non-square image, unequal half-ranges and the aspect weight of load() survive the file."""
    camera = CameraModel(640, 480, [[500.0, 0, 330.0], [0, 520.0, 230.0], [0, 0, 1]])
    obbs = synthetic.obbs[:50].astype(float)
    db = PoseDatabase(synthetic.quats[:50], obbs, distance=5.0, camera=camera, model="m",
                      half_range_deg=(10.0, 20.0, 30.0))
    back = PoseDatabase.load(db.save(tmp_path / "db.npz"), camera=camera, aspect_weight=2.5)
    assert (back.camera.width, back.camera.height) == (640, 480)
    assert back.half_range_deg == (10.0, 20.0, 30.0)
    assert back.aspect_weight == 2.5
    _, dist = back.query(40.0, 3.0, 50)
    brute = obb_distance(40.0, 3.0, obbs[:, 0], obbs[:, 3] / obbs[:, 4], 2.5)
    np.testing.assert_allclose(dist, np.sort(brute), rtol=1e-5)


def test_build_uses_the_configured_distance_range_and_seed(camera, mesh):
    """Entries are the seed's draws in the configured interval, rendered at the configured depth,
    and the database records that depth and interval."""
    from uav_landing_vision.render import Renderer

    config = DatabaseConfig(count=6, distance=7.0, half_range_deg=(20.0, 30.0, 40.0), seed=11)
    db = build_database(camera, mesh, config, progress=False)
    assert db.distance == 7.0 and db.half_range_deg == (20.0, 30.0, 40.0) and len(db) == 6
    expected = sample_orientations(6, (20.0, 30.0, 40.0), np.random.default_rng(11))
    np.testing.assert_allclose(db.quats, expected, atol=1e-6)
    euler = np.degrees(quat_to_euler_zyx(quat_multiply(db.quats.astype(float), quat_conjugate(NOMINAL_QUAT))))
    assert np.all(np.abs(euler) <= np.array([20.0, 30.0, 40.0]) + 1e-3)
    with Renderer(camera, mesh) as renderer:
        box = obb_from_mask(renderer.silhouette_full(db.quats[2], [0.0, 0.0, 7.0]))
    np.testing.assert_allclose(box, db.obbs[2], rtol=1e-5, atol=1e-3)
    other = build_database(camera, mesh, DatabaseConfig(count=6, distance=7.0, half_range_deg=(20.0, 30.0, 40.0),
                                                         seed=12), progress=False)
    assert not np.allclose(other.quats, db.quats)


class _OneSilhouette:
    """Stands in for the OpenGL renderer: one hand-made silhouette for every pose."""

    mask = None

    def __init__(self, camera, mesh):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def silhouette_full(self, quat, trans):
        return self.mask.copy()


def test_silhouettes_leaving_the_image_are_refused_not_stored_clipped(camera, mesh, monkeypatch):
    """At 1.5 m the 1.8 m span of the model exceeds the 720 px image height in some poses: their
    boxes would be clipped by the image border, so their area A^i and the depth (4.5) wrong. A
    silhouette touching any one border is refused; one a pixel off every border is kept."""
    import uav_landing_vision.render as render
    from uav_landing_vision.render import Renderer

    renderer = Renderer(camera, mesh)
    quats = sample_orientations(30, (90, 90, 90), np.random.default_rng(3))
    masks = [renderer.silhouette_full(q, [0.0, 0.0, 1.5]) for q in quats]
    assert any(m[[0, -1]].any() or m[:, [0, -1]].any() for m in masks)  # the oracle: some touch the border
    with pytest.raises(ValueError, match="leaves the 1280x720 image at Z = 1.5 m.*larger distance"):
        build_database(camera, mesh, DatabaseConfig(count=30, distance=1.5, seed=3), progress=False)
    monkeypatch.setattr(render, "Renderer", _OneSilhouette)
    for reach in [(slice(0, 400), slice(500, 700)), (slice(300, None), slice(500, 700)),  # top, bottom
                  (slice(300, 400), slice(0, 700)), (slice(300, 400), slice(500, None))]:  # left, right
        mask = np.zeros((camera.height, camera.width), bool)
        mask[300:400, 500:700] = True
        mask[reach] = True
        monkeypatch.setattr(_OneSilhouette, "mask", mask)
        with pytest.raises(ValueError, match="leaves the 1280x720 image at Z = 4 m"):
            build_database(camera, mesh, DatabaseConfig(count=2), progress=False)
    inside = np.zeros((camera.height, camera.width), bool)
    inside[1:-1, 1:-1] = True
    monkeypatch.setattr(_OneSilhouette, "mask", inside)
    db = build_database(camera, mesh, DatabaseConfig(count=2), progress=False)
    np.testing.assert_allclose(db.obbs[:, 3:], [[camera.width - 2, camera.height - 2]] * 2, atol=1e-3)


@pytest.mark.parametrize("kwargs", [{"count": 0}, {"distance": 0.0}, {"distance": np.nan}, {"distance": np.inf},
                                    {"half_range_deg": (90.0, 0.0, 90.0)}, {"half_range_deg": (90.0, 90.0)}])
def test_database_config_validation(kwargs):
    with pytest.raises(ValueError):
        DatabaseConfig(**kwargs)


@pytest.mark.parametrize("distance", [0.0, -4.0, np.nan, np.inf])
def test_database_distance_must_be_positive_and_finite(tmp_path, camera, synthetic, distance):
    with pytest.raises(DatabaseError, match="distance"):
        PoseDatabase(synthetic.quats, synthetic.obbs, distance=distance, camera=camera, model="m")
    z = dict(np.load(synthetic.save(tmp_path / "ok.npz")))
    z["distance"] = np.float64(distance)
    np.savez(tmp_path / "bad.npz", **z)
    with pytest.raises(DatabaseError, match="distance"):
        PoseDatabase.load(tmp_path / "bad.npz")


def test_truncated_or_damaged_files_are_clear_errors(tmp_path, synthetic):
    data = synthetic.save(tmp_path / "ok.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(DatabaseError, match="corrupt"):
        PoseDatabase.load(tmp_path / "cut.npz")
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0xFF
    (tmp_path / "flip.npz").write_bytes(bytes(flipped))
    with pytest.raises(DatabaseError, match="corrupt"):
        PoseDatabase.load(tmp_path / "flip.npz")
    z = dict(np.load(tmp_path / "ok.npz"))
    z["format_version"] = np.int32(2)
    np.savez(tmp_path / "v2.npz", **z)
    with pytest.raises(DatabaseError, match="format 2, expected 1"):
        PoseDatabase.load(tmp_path / "v2.npz")
    for half_range in ([np.nan, 1.0, 1.0], [-90.0, 90.0, 90.0], [90.0, 90.0]):  # eval-boosting's sampling failed
        np.savez(tmp_path / "range.npz", **{**z, "format_version": np.int32(1), "half_range_deg": np.array(half_range)})
        with pytest.raises(DatabaseError, match="half_range_deg must be three angles"):
            PoseDatabase.load(tmp_path / "range.npz")


def test_an_unreadable_database_is_not_called_corrupt(tmp_path, synthetic, monkeypatch):
    """A root-owned 0600 file needs its permissions fixed, not a rebuild."""
    path = synthetic.save(tmp_path / "ok.npz")
    real_open = Path.open

    def denied(self, *args, **kwargs):
        if self == path:
            raise PermissionError(13, "Permission denied", str(self))
        return real_open(self, *args, **kwargs)

    monkeypatch.setattr(Path, "open", denied)
    with pytest.raises(DatabaseError, match="unreadable or corrupt: .*Permission denied"):
        PoseDatabase.load(path)


def test_the_mesh_fingerprint_covers_the_faces_not_only_the_vertices(mesh):
    """The same vertices joined by other faces are another model, with other silhouettes."""
    half = Mesh(mesh.vertices, mesh.faces[: len(mesh.faces) // 2])
    assert mesh_fingerprint(mesh) != mesh_fingerprint(half)
    assert mesh_fingerprint(mesh) == mesh_fingerprint(Mesh(mesh.vertices.copy(), mesh.faces.copy()))


@pytest.mark.parametrize("index, factor", [(0, 1.005), (1, 1.005), (2, 1.005), (3, 1.005), (1, 0.99)])
def test_a_camera_differing_in_any_one_intrinsic_is_incompatible(camera, synthetic, index, factor):
    """fx, fy, cx, cy each enter the boxes: a 0.5 % change of any one means another database."""
    synthetic.check_compatible(camera)
    k = camera.K.copy()
    k[[0, 1, 0, 1][index], [0, 1, 2, 2][index]] *= factor
    with pytest.raises(DatabaseError, match="camera"):
        synthetic.check_compatible(CameraModel(camera.width, camera.height, k))


def test_missing_corrupt_or_mismatched_files_are_clear_errors(tmp_path, camera, synthetic):
    with pytest.raises(DatabaseError, match="not found"):
        PoseDatabase.load(tmp_path / "none.npz")
    with pytest.raises(DatabaseError, match="is a folder, not a file"):
        PoseDatabase.load(tmp_path)
    bad = tmp_path / "bad.npz"
    for junk in (b"not a zip file", b"\x93NUMPY" + bytes(120), b"\x80\x04K\x01."):  # numpy advised unpickling the last
        bad.write_bytes(junk)
        with pytest.raises(DatabaseError, match="corrupt") as error:
            PoseDatabase.load(bad)
        assert "pickle" not in str(error.value)
    path = synthetic.save(tmp_path / "ok.npz")
    other = CameraModel(camera.width, camera.height, [[900.0, 0, 640], [0, 900.0, 360], [0, 0, 1]])
    with pytest.raises(DatabaseError, match="camera"):
        PoseDatabase.load(path, camera=other)
    with pytest.raises(DatabaseError, match="model"):
        PoseDatabase.load(path, camera=camera, mesh=fixed_wing_mesh("low"))
    z = dict(np.load(path))
    z.pop("obbs")
    np.savez(tmp_path / "partial.npz", **z)
    with pytest.raises(DatabaseError, match="corrupt"):
        PoseDatabase.load(tmp_path / "partial.npz")


@pytest.fixture(scope="module")
def shipped(camera, mesh):
    return PoseDatabase.load(model_path("pose_database.npz"), camera=camera, mesh=mesh)


def test_shipped_database_is_the_default_one(shipped):
    assert len(shipped) == 11000
    assert shipped.distance == 4.0 and shipped.half_range_deg == (90.0, 90.0, 90.0)
    assert "build-database" in shipped.command


def test_rendered_entry_finds_itself_in_the_top_10(camera, mesh, shipped):
    from uav_landing_vision.render import Renderer

    renderer = Renderer(camera, mesh)
    t = np.array([0.0, 0.0, 4.0])
    for i in np.random.default_rng(0).choice(len(shipped), 20, replace=False):
        q = shipped.quats[i].astype(float)
        box = obb_from_mask(renderer.silhouette_full(q, t))
        hyp = hypotheses_from_obb(shipped, box, 10, camera)
        err = np.degrees(geodesic_angle(np.broadcast_to(q, hyp.quats.shape), hyp.quats))
        j = int(np.argmin(err))
        assert err[j] < 1e-3 or _is_twin(renderer, q, hyp.quats[j], t)
        np.testing.assert_allclose(hyp.positions[j], t, atol=1e-3)


def _is_twin(renderer, q, other, t) -> bool:
    """Another pose with (nearly) the same silhouette."""
    a, b = renderer.silhouette_full(q, t), renderer.silhouette_full(other, t)
    return np.sum(a ^ b) < 0.02 * np.sum(a)
