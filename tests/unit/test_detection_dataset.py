"""Detection dataset: Fig. 4.4 labels (model outline → oriented box → ROI), YOLO labels, landing frames,
determinism; the random poses, photometric jitter, user-image crops and the labels of drawn samples."""

import re
from dataclasses import replace

import cv2
import numpy as np
import pytest

from uav_landing_vision.camera import CameraModel, save_camera_info_yaml
from uav_landing_vision.detection.dataset import (DatasetConfig, generate, image_rng, model_roi, oriented_box_tie,
                                                  outline_roi, photometric, random_pose, read_labels, yolo_line)
from uav_landing_vision.detection.detector import box_iou


K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 40.0], [0.0, 0.0, 1.0]])
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])  # scalar last


def _plate(half_w: float, half_h: float, angle_deg: float = 0.0) -> np.ndarray:
    """Corners of a thin plate in the body x-y plane, turned about body z."""
    a = np.radians(angle_deg)
    corners = np.array([[-half_w, -half_h], [half_w, -half_h], [half_w, half_h], [-half_w, half_h]])
    xy = corners @ np.array([[np.cos(a), np.sin(a)], [-np.sin(a), np.cos(a)]])
    return np.c_[xy, np.zeros(4)]


def _opencv_extent(vertices, trans) -> np.ndarray:
    uv = cv2.projectPoints(vertices, np.zeros(3), np.asarray(trans, float), K, None)[0].reshape(-1, 2)
    return np.r_[uv.min(axis=0), uv.max(axis=0)] + 0.5  # pixel centres → pixel edges


def test_model_roi_of_an_upright_plate_is_its_projected_extent():
    vertices = _plate(1.0, 0.05)  # 20 × 1 px at 10 m: thinner than most pixels' coverage tests
    box = model_roi(vertices, K, IDENTITY, [0.0, 0.0, 10.0], 100, 80)
    np.testing.assert_allclose(box, _opencv_extent(vertices, [0.0, 0.0, 10.0]), atol=1e-4)
    np.testing.assert_allclose(box, [40.5, 40.0, 60.5, 41.0], atol=1e-4)


def test_model_roi_of_a_turned_plate_is_the_roi_of_its_oriented_box():
    # A 45° square's oriented box is the square itself; its ROI is the diamond's extent.
    vertices = _plate(1.0, 1.0, 45.0)
    box = model_roi(vertices, K, IDENTITY, [0.0, 0.0, 10.0], 100, 80)
    np.testing.assert_allclose(box, _opencv_extent(vertices, [0.0, 0.0, 10.0]), atol=1e-3)
    np.testing.assert_allclose(box[2] - box[0], 20 * np.sqrt(2), atol=1e-3)


def _scanned_rectangles(outline: np.ndarray, step_deg: float = 0.005):
    """Oracle: enclosing rectangles of ``outline`` at every angle of a dense scan, as
    ``(angles, areas, rois)`` (ROIs in pixel edges, unclipped)."""
    a = np.radians(np.arange(0.0, 90.0, step_deg))
    c, s = np.cos(a)[:, None], np.sin(a)[:, None]
    u, v = outline[:, 0] * c + outline[:, 1] * s, -outline[:, 0] * s + outline[:, 1] * c
    lo_u, hi_u, lo_v, hi_v = u.min(1), u.max(1), v.min(1), v.max(1)
    cu = np.stack([lo_u, hi_u, hi_u, lo_u], 1)
    cv = np.stack([lo_v, lo_v, hi_v, hi_v], 1)
    x, y = cu * c - cv * s + 0.5, cu * s + cv * c + 0.5
    return a, (hi_u - lo_u) * (hi_v - lo_v), np.stack([x.min(1), y.min(1), x.max(1), y.max(1)], 1)


def test_an_acute_triangle_is_a_tie_of_the_minimum_area_rule():
    # Each side of an acute triangle gives an enclosing rectangle of twice its area, so Fig.
    # 4.4's choice between them is arbitrary; the runner-up is a rather different box.
    outline = np.array([[10.0, 20.0], [50.0, 20.0], [30.0, 45.0]])
    margin, runner_up = oriented_box_tie(outline, 100, 80)
    assert margin == pytest.approx(0.0, abs=1e-9)
    assert box_iou(runner_up[None], outline_roi(outline, 100, 80)[None])[0, 0] < 0.8


def test_tie_margin_of_a_cut_rectangle_matches_a_dense_scan():
    # A 40 × 10 px bar tilted by 17° with one corner cut: the bar's own box is the label; the
    # cut gives the runner-up, a larger box at another angle.
    a = np.radians(17.0)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    outline = np.array([[0.0, 0.0], [34.0, 0.0], [40.0, 6.0], [40.0, 10.0], [0.0, 10.0]]) @ rot.T + [30.0, 20.0]
    margin, runner_up = oriented_box_tie(outline, 100, 80)
    angles, areas, rois = _scanned_rectangles(outline)
    label = outline_roi(outline, 100, 80)
    np.testing.assert_allclose(areas.min(), 400.0, rtol=1e-6)
    distinct = box_iou(rois, label[None])[:, 0] < 0.8
    local_min = (areas <= np.roll(areas, 1)) & (areas <= np.roll(areas, -1))
    expected = areas[distinct & local_min].min() / areas.min() - 1.0
    assert margin == pytest.approx(expected, abs=1e-4)
    assert margin > 0.1  # a clear winner


def test_a_rectangle_has_no_runner_up():
    outline = np.array([[10.0, 10.0], [50.0, 10.0], [50.0, 20.0], [10.0, 20.0]])
    assert oriented_box_tie(outline, 100, 80) == (np.inf, None)


def test_model_roi_extent_skips_the_oriented_box_of_a_thin_tilted_outline():
    # A thin wing tilted by 20° with a fin over its middle: the minimum-area box follows the
    # wing, and its ROI takes in the empty corners above the wing's ends, so it is much taller
    # than the outline's own extent (the far, tilted UAV of docs/detector.md).
    a = np.radians(20.0)
    along, across = np.array([np.cos(a), np.sin(a), 0.0]), np.array([-np.sin(a), np.cos(a), 0.0])
    vertices = np.array([-1.0 * along, 1.0 * along, -1.0 * along + 0.02 * across, 1.0 * along + 0.02 * across,
                         0.3 * across])
    oriented = model_roi(vertices, K, IDENTITY, [0.0, 0.0, 10.0], 100, 80)
    extent = model_roi(vertices, K, IDENTITY, [0.0, 0.0, 10.0], 100, 80, oriented=False)
    np.testing.assert_allclose(extent, _opencv_extent(vertices, [0.0, 0.0, 10.0]), atol=1e-4)
    assert np.all(oriented[:2] <= extent[:2] + 1e-4) and np.all(oriented[2:] >= extent[2:] - 1e-4)
    # the oriented box is the wing's 20 × 3 px rectangle (fin included), turned by 20°
    np.testing.assert_allclose(oriented[3] - oriented[1], 20 * np.sin(a) + 3 * np.cos(a), atol=1e-3)
    assert (oriented[3] - oriented[1]) > 1.3 * (extent[3] - extent[1])


def test_model_roi_is_clipped_to_the_image_and_none_out_of_view():
    vertices = _plate(1.0, 0.5)
    box = model_roi(vertices, K, IDENTITY, [4.5, -4.0, 10.0], 100, 80)  # u 85..105, v -5..5
    np.testing.assert_allclose(box, [85.5, 0.0, 100.0, 5.5], atol=1e-4)
    assert model_roi(vertices, K, IDENTITY, [20.0, 0.0, 10.0], 100, 80) is None  # beside the image
    assert model_roi(vertices, K, IDENTITY, [0.0, 0.0, -10.0], 100, 80) is None  # behind the camera
    assert model_roi(vertices, K, IDENTITY, [0.0, 0.0, 0.5], 100, 80) is not None  # filling the frame


def test_a_model_across_the_image_edge_is_labelled_by_its_part_inside():
    # A small wing in view near the right edge and a tall fin beyond it: the clipped hull of the
    # whole model reaches far above and below the wing, the frame shows the wing alone.
    vertices = np.array([[3.5, -0.2, 0], [4.4, 0, 0], [3.5, 0.2, 0], [5.5, -3, 0], [6.0, 0, 0], [5.5, 3, 0]], float)
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    whole = model_roi(vertices, K, IDENTITY, [0.0, 0.0, 10.0], 100, 80, oriented=False)
    seen = model_roi(vertices, K, IDENTITY, [0.0, 0.0, 10.0], 100, 80, oriented=False, faces=faces)
    np.testing.assert_allclose(seen, [85.5, 38.5, 94.5, 42.5], atol=1e-4)  # the wing's extent
    assert whole[3] - whole[1] > 10.0  # without the faces: sky above and below it
    inside = model_roi(vertices[:3], K, IDENTITY, [0.0, 0.0, 10.0], 100, 80, faces=faces[:1])
    np.testing.assert_allclose(inside, model_roi(vertices[:3], K, IDENTITY, [0.0, 0.0, 10.0], 100, 80))  # in view: as before


def test_yolo_label_round_trip(tmp_path):
    box = np.array([100.25, 50.5, 140.75, 66.0])
    (tmp_path / "l.txt").write_text(yolo_line(box, 1280, 720) + "\n")
    np.testing.assert_allclose(read_labels(tmp_path / "l.txt", 1280, 720), [box], atol=1e-3)
    (tmp_path / "empty.txt").write_text("")
    assert read_labels(tmp_path / "empty.txt", 1280, 720).shape == (0, 4)


def test_config_rejects_missing_sources():
    with pytest.raises(ValueError, match="image_dir"):
        DatasetConfig(families=("normal", "images"))
    with pytest.raises(ValueError, match="families"):
        DatasetConfig(families=("sunset",))


def test_dataset_is_deterministic_by_seed_whatever_the_workers(tmp_path):
    camera = CameraModel(192, 108, np.array([[165.0, 0, 96.0], [0, 165.0, 54.0], [0, 0, 1]]))
    save_camera_info_yaml(camera, tmp_path / "cam.yaml")
    cfg = DatasetConfig(count=4, seed=7, camera_info=str(tmp_path / "cam.yaml"), families=("normal",),
                        banks_per_family=1, negative_fraction=0.25)
    first = generate(cfg, tmp_path / "a", progress=False)
    assert generate(cfg, tmp_path / "b", progress=False, workers=2) == first  # image i: the same in any process
    assert first["width"] == 192 and first["images"] == 4 and first["positives"] >= 1
    for sub, pattern in (("images", "*.jpg"), ("labels", "*.txt")):
        a, b = sorted((tmp_path / "a" / sub).glob(pattern)), sorted((tmp_path / "b" / sub).glob(pattern))
        assert len(a) == 4 and [p.name for p in a] == [p.name for p in b]
        assert all(x.read_bytes() == y.read_bytes() for x, y in zip(a, b))
    with pytest.raises(FileExistsError):
        generate(cfg, tmp_path / "a", progress=False)
    # An interrupted run (no dataset.json, the last images missing) is continued by running it again.
    for name in ("dataset.json", "images/000003.jpg", "labels/000003.txt", "labels/000002.txt"):
        (tmp_path / "b" / name).unlink()
    assert generate(cfg, tmp_path / "b", progress=False) == first
    assert all(x.read_bytes() == y.read_bytes() for x, y in zip(sorted((tmp_path / "a").rglob("*.*")),
                                                                sorted((tmp_path / "b").rglob("*.*"))))
    with pytest.raises(ValueError, match="workers"):
        generate(cfg, tmp_path / "c", progress=False, workers=0)


def test_video_backgrounds_are_the_same_whatever_the_workers(tmp_path):
    camera = CameraModel(96, 54, np.array([[82.0, 0, 48.0], [0, 82.0, 27.0], [0, 0, 1]]))
    save_camera_info_yaml(camera, tmp_path / "cam.yaml")
    clip = tmp_path / "ramp.avi"
    writer = cv2.VideoWriter(str(clip), cv2.VideoWriter_fourcc(*"MJPG"), 10, (96, 54))
    for k in range(8):  # each frame its own grey
        writer.write(np.full((54, 96, 3), 20 + 25 * k, np.uint8))
    writer.release()
    cfg = DatasetConfig(count=60, seed=3, camera_info=str(tmp_path / "cam.yaml"), families=("video",), video=str(clip),
                        negative_fraction=0.9)  # mostly backgrounds alone
    generate(cfg, tmp_path / "one", progress=False)
    generate(cfg, tmp_path / "two", progress=False, workers=2)
    one, two = sorted((tmp_path / "one" / "images").glob("*.jpg")), sorted((tmp_path / "two" / "images").glob("*.jpg"))
    assert len(one) == 60 and all(x.read_bytes() == y.read_bytes() for x, y in zip(one, two))  # chunks of 25


def test_an_unfinished_dataset_is_continued_only_with_its_own_settings(tmp_path):
    camera = CameraModel(192, 108, np.array([[165.0, 0, 96.0], [0, 165.0, 54.0], [0, 0, 1]]))
    save_camera_info_yaml(camera, tmp_path / "cam.yaml")
    cfg = DatasetConfig(count=2, seed=7, camera_info=str(tmp_path / "cam.yaml"), families=("normal",),
                        banks_per_family=1)
    out = tmp_path / "data"
    generate(cfg, out, progress=False)
    (out / "dataset.json").unlink()  # as if interrupted
    with pytest.raises(ValueError, match=re.escape(f"{out} holds part of a dataset made with other settings (seed)")):
        generate(replace(cfg, seed=8), out, progress=False)
    (out / "settings.json").unlink()
    with pytest.raises(ValueError, match=re.escape(f"{out} holds images but no settings.json")):
        generate(cfg, out, progress=False)
    with pytest.raises(FileNotFoundError, match="nosuch.yaml"):  # before anything is written
        generate(replace(cfg, camera_info="nosuch.yaml"), tmp_path / "other", progress=False)
    assert not (tmp_path / "other").exists()
    # No user images: refused before settings.json is written (a corrected retry into the same
    # folder was refused as "other settings"), and by name with workers (a broken process pool).
    (tmp_path / "empty").mkdir()
    for workers in (1, 2):
        with pytest.raises(ValueError, match="no images"):
            generate(replace(cfg, families=("images",), image_dir=str(tmp_path / "empty")), tmp_path / "imgs",
                     progress=False, workers=workers)
        assert not (tmp_path / "imgs").exists()


def test_an_image_that_cannot_be_written_stops_the_run(tmp_path, monkeypatch):
    """cv2.imwrite returns False instead of raising: the label was written, the image missing."""
    camera = CameraModel(192, 108, np.array([[165.0, 0, 96.0], [0, 165.0, 54.0], [0, 0, 1]]))
    save_camera_info_yaml(camera, tmp_path / "cam.yaml")
    cfg = DatasetConfig(count=1, seed=7, camera_info=str(tmp_path / "cam.yaml"), families=("normal",), banks_per_family=1)
    monkeypatch.setattr(cv2, "imwrite", lambda *args: False)
    with pytest.raises(OSError, match=r"cannot write the image .*000000.jpg"):
        generate(cfg, tmp_path / "data", progress=False)
    assert not (tmp_path / "data" / "labels" / "000000.txt").exists()


def test_approach_attitudes_point_the_nose_at_the_camera():
    from scipy.spatial.transform import Rotation

    from uav_landing_vision.detection.dataset import random_pose

    camera = CameraModel(1280, 720, np.array([[1100.0, 0, 640.0], [0, 1100.0, 360.0], [0, 0, 1]]))
    rng = np.random.default_rng(0)
    noses = {}
    for fraction in (1.0, 0.0):
        cfg = DatasetConfig(approach_fraction=fraction)
        quats = np.array([random_pose(rng, camera, cfg)[0] for _ in range(300)])
        noses[fraction] = Rotation.from_quat(quats).apply([1.0, 0.0, 0.0])[:, 2]  # nose · optical axis
    assert np.all(noses[1.0] < -np.cos(np.radians(26.0)))  # head-on: within ±15° and ±20°
    assert np.mean(noses[0.0] > 0) > 0.1  # the default mix also flies away from the camera
    with pytest.raises(ValueError, match="approach_fraction"):
        DatasetConfig(approach_fraction=1.5)


def test_landing_frames_are_labelled_where_the_model_projects_through_the_lens():
    """Frames of simulated landings: the label agrees with the model's vertices projected through
    the distorted camera by OpenCV and then undistorted (the frame's own geometry)."""
    from uav_landing_vision.camera import load_camera_info_yaml
    from uav_landing_vision.detection.dataset import LandingFrames, dataset_camera
    from uav_landing_vision.geometry import quat_to_matrix
    from uav_landing_vision.model import fixed_wing_mesh
    from uav_landing_vision.resources import config_file

    cfg = DatasetConfig(families=("complex",), banks_per_family=1, landing_fraction=1.0)
    mesh = fixed_wing_mesh("high")
    frames = LandingFrames(cfg, dataset_camera(cfg), mesh)
    raw_camera = load_camera_info_yaml(config_file("camera.yaml"))
    rng = np.random.default_rng(3)
    ranges = []
    for _ in range(4):
        image, box, (quat, trans) = frames.sample(rng)
        assert image.shape == (720, 1280, 3) and image.dtype == np.uint8 and box is not None
        ranges.append(np.linalg.norm(trans))
        rvec = cv2.Rodrigues(quat_to_matrix(quat))[0]
        raw_uv = cv2.projectPoints(mesh.vertices, rvec, trans, raw_camera.K, raw_camera.dist)[0]
        uv = cv2.undistortPoints(raw_uv, raw_camera.K, raw_camera.dist, P=raw_camera.K).reshape(-1, 2)
        extent = np.r_[uv.min(axis=0), uv.max(axis=0) + 1.0]  # pixel edges
        assert np.all(np.abs(box - extent) < 2.5), (box, extent)
    assert 5.0 < min(ranges) and max(ranges) < 105.0  # along the scenario's approach


def test_landing_negatives_are_the_same_frame_without_the_uav():
    """A landing frame drawn without the UAV is, from the same generator state, the frame with it
    outside the UAV's box, and carries no label."""
    from uav_landing_vision.detection.dataset import LandingFrames, dataset_camera
    from uav_landing_vision.model import fixed_wing_mesh

    cfg = DatasetConfig(families=("normal",), banks_per_family=1, landing_fraction=1.0)
    frames = LandingFrames(cfg, dataset_camera(cfg), fixed_wing_mesh("high"))
    for seed in (5, 6):
        with_uav, box, pose = frames.sample(np.random.default_rng(seed))
        without, no_box, same_pose = frames.sample(np.random.default_rng(seed), with_uav=False)
        assert no_box is None and box is not None
        np.testing.assert_array_equal(pose[1], same_pose[1])
        x0, y0, x1, y1 = np.round(box).astype(int)
        outside = np.ones(with_uav.shape[:2], bool)
        outside[max(y0 - 12, 0) : y1 + 12, max(x0 - 12, 0) : x1 + 12] = False  # blur and lens margin
        np.testing.assert_array_equal(with_uav[outside], without[outside])
        inside = (slice(y0, y1), slice(x0, x1))
        assert np.abs(with_uav[inside].astype(int) - without[inside]).max() > 30  # the UAV is drawn


def test_landing_frames_keep_their_scenarios_sun_within_the_spread():
    """``landing_sun_spread_deg`` keeps each background's sun near the scenario's azimuth (the
    sun vector the frames are shaded with), at the family's elevations."""
    from uav_landing_vision.detection.dataset import LandingFrames, dataset_camera
    from uav_landing_vision.model import fixed_wing_mesh
    from uav_landing_vision.sim.config import load_scenario

    cfg = DatasetConfig(families=("complex",), banks_per_family=3, landing_fraction=1.0, landing_sun_spread_deg=20.0)
    banks = LandingFrames(cfg, dataset_camera(cfg), fixed_wing_mesh("low")).parts["complex"][2]
    scenario_az = load_scenario("complex").background.sun_azimuth_deg
    for _, sun in banks:
        off = (np.degrees(np.arctan2(sun[1], sun[0])) - scenario_az + 180.0) % 360.0 - 180.0
        assert abs(off) <= 20.0
        assert 1.0 <= np.degrees(np.arcsin(sun[2])) <= 12.0
    with pytest.raises(ValueError, match="landing_sun_spread_deg"):
        DatasetConfig(landing_sun_spread_deg=0.0)


def test_landing_frames_need_a_simulator_family_and_the_scenario_camera(tmp_path):
    with pytest.raises(ValueError, match="landing_fraction"):
        DatasetConfig(landing_fraction=-0.1)
    with pytest.raises(ValueError, match="landing_negative_fraction"):
        DatasetConfig(landing_fraction=0.5, landing_negative_fraction=1.5)
    with pytest.raises(ValueError, match="'normal' or 'complex'"):
        DatasetConfig(families=("images",), image_dir=str(tmp_path), landing_fraction=0.5)
    camera = CameraModel(192, 108, np.array([[165.0, 0, 96.0], [0, 165.0, 54.0], [0, 0, 1]]))
    save_camera_info_yaml(camera, tmp_path / "cam.yaml")
    cfg = DatasetConfig(count=1, camera_info=str(tmp_path / "cam.yaml"), families=("complex",),
                        banks_per_family=1, landing_fraction=1.0)
    with pytest.raises(ValueError, match="camera_info must be the same"):
        generate(cfg, tmp_path / "d", progress=False)


@pytest.mark.parametrize("shape", [(1, 1), (1, 300), (2, 3)])
def test_a_user_image_of_a_pixel_or_two_still_gives_a_background(tmp_path, shape):
    """Its crop keeps at least one pixel a side (it was empty, and cv2.resize failed mid-dataset)."""
    from uav_landing_vision.detection.dataset import BackgroundSource

    camera = CameraModel(64, 36, np.array([[60.0, 0, 32.0], [0, 60.0, 18.0], [0, 0, 1]]))
    save_camera_info_yaml(camera, tmp_path / "cam.yaml")
    (tmp_path / "images").mkdir()
    cv2.imwrite(str(tmp_path / "images" / "tiny.png"), np.full((*shape, 3), (10, 20, 30), np.uint8))  # BGR
    cfg = DatasetConfig(camera_info=str(tmp_path / "cam.yaml"), families=("images",), image_dir=str(tmp_path / "images"))
    source = BackgroundSource(camera, cfg)
    for seed in range(20):
        background = source.draw(np.random.default_rng(seed), seed)
        assert background.shape == (36, 64, 3) and (background == (30, 20, 10)).all()


def test_the_default_camera_is_the_shipped_one_not_a_camera_yaml_in_the_working_directory(tmp_path, monkeypatch):
    from uav_landing_vision.camera import load_camera_info_yaml
    from uav_landing_vision.detection.dataset import dataset_camera
    from uav_landing_vision.resources import config_path

    save_camera_info_yaml(CameraModel(192, 108, K), tmp_path / "camera.yaml")
    monkeypatch.chdir(tmp_path)
    shipped = load_camera_info_yaml(config_path("camera.yaml")).rectified()
    camera = dataset_camera(DatasetConfig())
    assert (camera.width, camera.height) == (shipped.width, shipped.height)
    np.testing.assert_array_equal(camera.K, shipped.K)
    assert dataset_camera(DatasetConfig(camera_info="camera.yaml")).width == 192  # named: read as given


# --- outlines behind the camera, per-image seeds, the pose mix, jitter, user crops, drawn labels ----

def test_a_model_reaching_behind_the_camera_has_no_label():
    vertices = np.array([[-0.1, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.0, -2.0]])
    assert model_roi(vertices, K, IDENTITY, [0.0, 0.0, 1.0], 100, 80) is None  # one vertex at z = −1
    assert model_roi(vertices, K, IDENTITY, [0.0, 0.0, 3.0], 100, 80) is not None  # all in front


@pytest.mark.parametrize("oriented", [True, False])
def test_an_outline_beside_the_image_in_one_axis_only_has_no_label(oriented):
    """Left of the image (x −20…−10) though within its rows: the clipped ROI is empty."""
    outline = np.array([[-20.0, 10.0], [-10.0, 10.0], [-10.0, 20.0], [-20.0, 20.0]])
    assert outline_roi(outline, 100, 80, oriented) is None
    below = np.array([[10.0, 90.0], [20.0, 90.0], [20.0, 95.0], [10.0, 95.0]])  # below the 80 rows
    assert outline_roi(below, 100, 80, oriented) is None


def test_each_image_draws_from_its_own_seed_and_index():
    first = [image_rng(3, i).random(4) for i in range(3)]
    assert not np.allclose(first[0], first[1]) and not np.allclose(first[1], first[2])
    assert not np.allclose(image_rng(3, 1).random(4), image_rng(4, 1).random(4))
    np.testing.assert_array_equal(image_rng(3, 1).random(4), first[1])


CAMERA = CameraModel(1280, 720, np.array([[1100.0, 0, 640.0], [0, 1100.0, 360.0], [0, 0, 1]]))


def _poses(cfg, n, seed=0):
    rng = np.random.default_rng(seed)
    return zip(*[random_pose(rng, CAMERA, cfg) for _ in range(n)])


def test_pose_range_is_log_uniform_and_the_centre_projects_into_the_image():
    quats, trans = _poses(DatasetConfig(range_m=(5.0, 150.0), partial_fraction=0.0), 2000)
    trans = np.array(trans)
    r = np.linalg.norm(trans, axis=1)
    assert r.min() >= 5.0 - 1e-9 and r.max() <= 150.0 + 1e-9
    # log r uniform on [ln 5, ln 150]: mean 3.31 (a uniform r would give ≈ 4.0), sd 0.98
    assert np.mean(np.log(r)) == pytest.approx((np.log(5) + np.log(150)) / 2, abs=0.1)
    assert np.median(r) == pytest.approx(np.sqrt(5 * 150), rel=0.15)
    u = 1100.0 * trans[:, 0] / trans[:, 2] + 640.0
    v = 1100.0 * trans[:, 1] / trans[:, 2] + 360.0
    assert u.min() >= 0 and u.max() <= 1280 and v.min() >= 0 and v.max() <= 720
    assert u.min() < 0.05 * 1280 and u.max() > 0.95 * 1280  # the whole width, not only the left
    assert v.min() < 0.05 * 720 and v.max() > 0.95 * 720


def test_partial_cases_put_the_centre_up_to_a_third_of_the_frame_outside():
    _, trans = _poses(DatasetConfig(partial_fraction=1.0), 2000, seed=1)
    trans = np.array(trans)
    u = (1100.0 * trans[:, 0] / trans[:, 2] + 640.0) / 1280
    v = (1100.0 * trans[:, 1] / trans[:, 2] + 360.0) / 720
    assert u.min() >= -0.3 - 1e-9 and u.max() <= 1.3 + 1e-9 and v.min() >= -0.3 - 1e-9 and v.max() <= 1.3 + 1e-9
    assert u.min() < -0.25 and u.max() > 1.25 and v.min() < -0.25 and v.max() > 1.25
    outside = (u < 0) | (u > 1) | (v < 0) | (v > 1)
    assert np.mean(outside) == pytest.approx(1 - (1 / 1.6) ** 2, abs=0.05)
    _, none = _poses(DatasetConfig(partial_fraction=0.0), 300, seed=2)
    none = np.array(none)
    assert np.all(np.abs(1100.0 * none[:, 0] / none[:, 2]) <= 640.0 + 1e-6)


def test_sixty_percent_of_the_non_approach_attitudes_are_landing_like():
    """Landing-like attitudes (±60° about x, ±30° about y from facing the camera) keep the nose's
    optical-axis component ≤ −cos 60° cos 30°; uniformly random ones pass it 71.7 % of the time,
    so 40 % random gives 0.4 · 0.717 ≈ 0.29 beyond it."""
    from scipy.spatial.transform import Rotation

    quats, _ = _poses(DatasetConfig(approach_fraction=0.0), 4000, seed=3)
    nose_z = Rotation.from_quat(np.array(quats)).apply([1.0, 0.0, 0.0])[:, 2]
    beyond = np.mean(nose_z > -np.cos(np.radians(60)) * np.cos(np.radians(30)) + 1e-9)
    assert beyond == pytest.approx(0.4 * (1 + np.cos(np.radians(60)) * np.cos(np.radians(30))) / 2, abs=0.03)


def _jitter_cfg(**kwargs):
    return DatasetConfig(**{"blur_probability": 0.0, "noise_sigma": (0.0, 0.0), **kwargs})


def test_photometric_jitter_keeps_the_order_of_the_colour_channels():
    image = np.empty((8, 8, 3), np.uint8)
    image[:] = (200, 120, 40)
    for seed in range(20):
        out = photometric(image, np.random.default_rng(seed), _jitter_cfg()).astype(int)
        assert np.all(out[..., 0] > out[..., 1]) and np.all(out[..., 1] > out[..., 2])


def test_no_blur_probability_leaves_a_step_edge_sharp():
    image = np.full((32, 32, 3), 60, np.uint8)
    image[:, 16:] = 190
    for seed in range(20):
        out = photometric(image, np.random.default_rng(seed), _jitter_cfg())
        assert len(np.unique(out[..., 0])) <= 2
        assert len(np.unique(out[:, :16, 0])) == 1 and len(np.unique(out[:, 16:, 0])) == 1


def test_sensor_noise_sigma_is_in_grey_levels():
    image = np.full((64, 64, 3), 128, np.uint8)
    for seed in range(5):
        out = photometric(image, np.random.default_rng(seed), _jitter_cfg(noise_sigma=(3.0, 3.0))).astype(float)
        assert 2.0 < out.std() < 4.0


def test_user_image_crops_keep_the_cameras_aspect_and_reach_the_whole_image(tmp_path):
    """Crops of the largest camera-shaped window, scaled by 0.4–1: over many draws one spans
    nearly the whole width of a 4:3 picture, and each has the camera's 16:9 shape."""
    from uav_landing_vision.detection.dataset import BackgroundSource

    y, x = np.mgrid[0:150, 0:200]
    coded = np.stack([x, y, np.zeros_like(x)], axis=-1).astype(np.uint8)  # B = x, G = y (BGR file)
    cv2.imwrite(str(tmp_path / "pic.png"), coded)
    camera = CameraModel(96, 54, np.array([[82.0, 0, 48.0], [0, 82.0, 27.0], [0, 0, 1]]))
    source = BackgroundSource(camera, DatasetConfig(families=("images",), image_dir=str(tmp_path)))
    spans = []
    for seed in range(40):
        rgb = source.draw(np.random.default_rng(seed), 0).astype(float)
        assert rgb.shape == (54, 96, 3) and np.all(rgb[..., 0] == 0)  # RGB: the B code is last
        xs, ys = rgb[27, :, 2], rgb[:, 48, 1]
        span_x, span_y = abs(xs[-1] - xs[0]) * 96 / 95, abs(ys[-1] - ys[0]) * 54 / 53
        assert span_x / span_y == pytest.approx(96 / 54, rel=0.08)
        spans.append(span_x)
    assert max(spans) > 0.9 * 200 and min(spans) > 0.38 * 200


def _small_camera_yaml(tmp_path):
    from uav_landing_vision.camera import save_camera_info_yaml

    save_camera_info_yaml(CameraModel(192, 108, np.array([[165.0, 0, 96.0], [0, 165.0, 54.0], [0, 0, 1]])),
                          tmp_path / "cam.yaml")
    return str(tmp_path / "cam.yaml")


@pytest.mark.parametrize("label_box, partial", [("extent", 1.0), ("oriented", 1.0)])
def test_a_drawn_sample_is_labelled_by_the_model_roi_of_its_pose_once_enough_pixels_pass_the_coverage(
        tmp_path, monkeypatch, label_box, partial):
    """The label is model_roi of the pose drawn last (with the configured box kind and the mesh's
    faces for a model across the edge), and that pose has ≥ min_visible_px pixels of coverage ≥
    coverage_threshold; every pose redrawn before it had fewer."""
    from uav_landing_vision.detection import dataset

    cfg = DatasetConfig(count=1, seed=2, camera_info=_small_camera_yaml(tmp_path), families=("normal",),
                        banks_per_family=1, negative_fraction=0.0, partial_fraction=partial, range_m=(8.0, 120.0),
                        min_visible_px=12, label_box=label_box)
    gen = dataset.SampleGenerator(cfg)
    try:
        poses, alphas = [], []
        draw, shade = dataset.random_pose, gen.renderer.shaded
        monkeypatch.setattr(dataset, "random_pose", lambda *a: poses.append(draw(*a)) or poses[-1])

        def shaded(*args, **kwargs):
            rgb, alpha = shade(*args, **kwargs)
            alphas.append(alpha)
            return rgb, alpha

        monkeypatch.setattr(gen.renderer, "shaded", shaded)
        labelled = 0
        for index in range(10):
            poses.clear(), alphas.clear()
            _, box = gen.sample(index)
            passing = [int(np.count_nonzero(a >= cfg.coverage_threshold)) for a in alphas]
            if box is None:
                continue
            labelled += 1
            assert passing[-1] >= cfg.min_visible_px and all(p < cfg.min_visible_px for p in passing[:-1])
            quat, trans = poses[-1]
            want = model_roi(gen.mesh.vertices, gen.camera.K, quat, trans, 192, 108,
                             oriented=label_box == "oriented", faces=gen.mesh.faces)
            np.testing.assert_allclose(box, want)
        assert labelled >= 6
    finally:
        gen.release()


def test_the_summary_counts_the_images_with_a_label(tmp_path):
    from uav_landing_vision.detection.dataset import generate

    cfg = DatasetConfig(count=6, seed=4, camera_info=_small_camera_yaml(tmp_path), families=("normal",),
                        banks_per_family=1, negative_fraction=0.5)
    summary = generate(cfg, tmp_path / "data", progress=False)
    labelled = sum(bool(p.read_text().strip()) for p in (tmp_path / "data" / "labels").glob("*.txt"))
    assert 0 < labelled < 6 and summary["positives"] == labelled


class _StubLanding:
    def __init__(self):
        self.calls = []

    def sample(self, rng, with_uav=True):
        self.calls.append(with_uav)
        return np.zeros((4, 4, 3), np.uint8), (np.array([0.0, 0.0, 2.0, 2.0]) if with_uav else None), None


def test_landing_frames_and_their_negatives_come_in_the_configured_fractions(monkeypatch):
    """The decisions alone: landing frames and backgrounds stubbed; a background image stops where
    it would draw a pose."""
    from uav_landing_vision.detection import dataset

    class BackgroundImage(Exception):
        pass

    def no_pose(*args):
        raise BackgroundImage

    monkeypatch.setattr(dataset, "random_pose", no_pose)
    gen = object.__new__(dataset.SampleGenerator)
    gen.cfg = DatasetConfig(landing_fraction=0.3, landing_negative_fraction=0.2, negative_fraction=0.0)
    gen.landing, gen.camera, gen.renderer = _StubLanding(), None, None
    gen.backgrounds = type("Backgrounds", (), {"draw": lambda self, rng, index: np.zeros((4, 4, 3), np.uint8)})()
    backgrounds = 0
    for index in range(600):
        try:
            _, box = gen.sample(index)
            assert (box is not None) == gen.landing.calls[-1]
        except BackgroundImage:
            backgrounds += 1
    assert backgrounds + len(gen.landing.calls) == 600
    assert len(gen.landing.calls) / 600 == pytest.approx(0.3, abs=0.06)
    assert np.mean([not c for c in gen.landing.calls]) == pytest.approx(0.2, abs=0.1)
