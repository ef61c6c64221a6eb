"""Detection dataset: Fig. 4.4 annotation (binarise → oriented box → ROI), YOLO labels, determinism."""

import numpy as np
import pytest

from uav_landing_vision.camera import CameraModel, save_camera_info_yaml
from uav_landing_vision.detection.dataset import DatasetConfig, annotate, generate, read_labels, yolo_line


def test_annotation_of_an_upright_rectangle_is_its_pixel_extent():
    coverage = np.zeros((80, 100), np.float32)
    coverage[30:34, 20:30] = 0.9
    coverage[50, 50] = 0.4  # below the binarisation threshold
    np.testing.assert_allclose(annotate(coverage), [20, 30, 30, 34], atol=1e-4)


def test_annotation_of_a_diagonal_is_the_roi_of_its_oriented_box():
    # Pixels (i, i), i = 10..19: the oriented box lies along 45°, 14.14 × 1.41 px; its corners
    # reach half a pixel beyond the tight axis-aligned box [10, 10, 20, 20] on every side.
    coverage = np.zeros((40, 40), np.float32)
    idx = np.arange(10, 20)
    coverage[idx, idx] = 1.0
    np.testing.assert_allclose(annotate(coverage), [9.5, 9.5, 20.5, 20.5], atol=1e-3)


def test_annotation_is_clipped_to_the_image_and_empty_masks_give_none():
    coverage = np.zeros((40, 60), np.float32)
    coverage[0:5, 50:60] = 1.0
    np.testing.assert_allclose(annotate(coverage), [50, 0, 60, 5], atol=1e-4)
    assert annotate(np.zeros((40, 60), np.float32)) is None
    assert annotate(coverage, min_pixels=51) is None


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
    with pytest.raises(ValueError, match="workers"):
        generate(cfg, tmp_path / "c", progress=False, workers=0)


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
