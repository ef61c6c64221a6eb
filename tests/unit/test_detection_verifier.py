"""The box verifier: crop geometry against hand-made cases, mining and training on tiny datasets,
the export against torch, and the verifier's product in the detector's scores."""

import numpy as np
import pytest
import torch

from uav_landing_vision.detection.detector import Detector, DetectorConfig
from uav_landing_vision.detection.export import export_onnx, export_verifier_onnx
from uav_landing_vision.detection.network import BoxVerifierNet, UavDetectorNet
from uav_landing_vision.detection.verifier import BoxVerifier, CropGeometry, box_crops


def _coded_image(width=400, height=300):
    """Pixels that encode their own position: R = x mod 256, G = y, B = x // 256."""
    y, x = np.mgrid[0:height, 0:width]
    return np.stack([x % 256, y, x // 256], axis=-1).astype(np.uint8)


def test_crop_is_the_square_around_the_box_with_context():
    image = _coded_image()
    # A 40 × 10 box centred at (200.5, 150.5): side 1.5 · 40 = 60 px → 64 px, so crop pixel c
    # samples the frame at 170.5 + (c + ½) · 60/64 − ½ (pixel centres at integer + ½).
    crop = box_crops(image, np.array([[180.5, 145.5, 220.5, 155.5]]), CropGeometry(64, 1.5, 24))[0]
    centres = 170.5 + (np.arange(64) + 0.5) * 60 / 64 - 0.5
    np.testing.assert_allclose(crop[32, :, 0].astype(float), centres, atol=0.55)  # bilinear of a ramp
    np.testing.assert_allclose(crop[:, 32, 1].astype(float), centres - 50, atol=0.55)


def test_small_boxes_get_the_minimum_side_and_the_border_repeats():
    image = _coded_image()
    crop = box_crops(image, np.array([[0.0, 0.0, 4.0, 2.0]]), CropGeometry(48, 1.5, 24))[0]
    # side max(1.5 · 4, 24) = 24 px around (2, 1): frame x −10…14, enlarged 2× (bilinear), so
    # crop pixel c samples x = −10 + (c + ½) / 2 − ½
    assert crop.shape == (48, 48, 3)
    assert (crop[:, :20, 0] == 0).all() and (crop[:20, :, 1] == 0).all()  # outside the frame: its edge
    np.testing.assert_allclose(crop[24, 20:, 0].astype(float), -10 + (np.arange(20, 48) + 0.5) / 2 - 0.5, atol=0.55)
    assert box_crops(image, np.zeros((0, 4))).shape == (0, 64, 64, 3)


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    from uav_landing_vision.camera import CameraModel, save_camera_info_yaml
    from uav_landing_vision.detection.dataset import DatasetConfig, generate

    root = tmp_path_factory.mktemp("verifier_data")
    camera = CameraModel(192, 108, np.array([[165.0, 0, 96.0], [0, 165.0, 54.0], [0, 0, 1]]))
    save_camera_info_yaml(camera, root / "cam.yaml")
    folders = []
    for seed in (1, 2):
        folders.append(str(root / f"data{seed}"))
        generate(DatasetConfig(count=11, seed=seed, camera_info=str(root / "cam.yaml"), families=("normal",),
                               banks_per_family=1, approach_fraction=1.0, negative_fraction=0.0,
                               partial_fraction=0.0), folders[-1], progress=False)
    # A detector that scores every stride-8 cell σ(5) with the cell's own box (mostly not the UAV).
    torch.manual_seed(0)
    net = UavDetectorNet(width=16, blocks=(1, 1, 1)).eval()
    with torch.no_grad():
        net.heads[0].pred.weight.zero_()
        net.heads[0].pred.bias.copy_(torch.tensor([5.0, 0.0, 0.0, 0.0, 0.0]))
    detector = export_onnx(net, root / "det.onnx", (192, 128))
    return tuple(folders), str(detector), root


def test_mining_labels_boxes_by_overlap_and_does_not_depend_on_the_processes(datasets, tmp_path):
    from uav_landing_vision.detection.verifier_train import VerifierTrainConfig, mine_crops

    folders, detector, _ = datasets
    one = mine_crops(VerifierTrainConfig(data=folders, detector=detector, out=str(tmp_path / "a"), workers=1),
                     progress=False)
    two = mine_crops(VerifierTrainConfig(data=folders, detector=detector, out=str(tmp_path / "b"), workers=2),
                     progress=False)
    for key in one:
        np.testing.assert_array_equal(one[key], two[key])
    labels, source = one["labels"], one["source"]
    assert set(np.unique(labels)) == {0, 1} and one["crops"].shape[1:] == (64, 64, 3)
    assert (labels[source == 1] == 1).all() and (source == 1).sum() == 22  # one jittered label per image
    assert (labels[source == 0] == 0).sum() > 100  # the cells off the UAV
    # images 0 and 10 of each folder validate
    assert one["validation"].sum() == 4 + (labels[one["validation"] & (source == 0)] >= 0).sum()
    cached = mine_crops(VerifierTrainConfig(data=folders, detector=detector, out=str(tmp_path / "a"),
                                            epochs=3), progress=False)  # training settings: same crops
    np.testing.assert_array_equal(cached["crops"], one["crops"])


def test_mined_crops_are_mined_again_for_another_model_in_the_same_file_or_a_damaged_cache(datasets, tmp_path):
    """The cache was keyed by the detector's path: a model retrained into the same file had the
    old model's crops reused, silently; and a damaged crops.npz ended in a traceback."""
    import shutil

    from uav_landing_vision.detection.verifier_train import VerifierTrainConfig, mine_crops

    folders, detector, _ = datasets
    model = tmp_path / "det.onnx"
    shutil.copy(detector, model)
    cfg = VerifierTrainConfig(data=folders, detector=str(model), out=str(tmp_path / "run"), workers=1)
    first = mine_crops(cfg, progress=False)
    assert (first["source"] == 0).sum() > 100
    torch.manual_seed(0)
    blind = UavDetectorNet(width=16, blocks=(1, 1, 1)).eval()
    with torch.no_grad():
        for head in blind.heads:  # scores every cell σ(-20): no box at all
            head.pred.weight.zero_()
            head.pred.bias.copy_(torch.tensor([-20.0, 0.0, 0.0, 0.0, 0.0]))
    export_onnx(blind, model, (192, 128))
    again = mine_crops(cfg, progress=False)
    assert (again["source"] == 0).sum() == 0 and (again["source"] == 1).sum() == 22  # only the jittered labels
    crops = tmp_path / "run" / "crops.npz"
    crops.write_bytes(crops.read_bytes()[:1000])
    np.testing.assert_array_equal(mine_crops(cfg, progress=False)["labels"], again["labels"])


def test_training_resumes_only_with_its_own_settings_and_exports_what_it_trained(datasets, tmp_path):
    import onnx

    from uav_landing_vision.detection.train import load_checkpoint
    from uav_landing_vision.detection.verifier_train import VerifierTrainConfig, predict, train_verifier, trained_verifier

    folders, detector, _ = datasets
    cfg = VerifierTrainConfig(data=folders, detector=detector, out=str(tmp_path / "run"), epochs=1, batch=16,
                              width=4, threads=1, workers=1)
    log = train_verifier(cfg, progress=False)
    assert len(log["epochs"]) == 1 and np.isfinite(log["epochs"][0]["loss"]) and "val_ap" in log["epochs"][0]
    with pytest.raises(ValueError, match="other settings"):
        train_verifier(VerifierTrainConfig(**{**cfg.__dict__, "lr": 1e-3}), resume=True, progress=False)
    with pytest.raises(ValueError, match="holds a run already .*--resume"):  # overwritten unasked before
        train_verifier(VerifierTrainConfig(**{**cfg.__dict__, "lr": 1e-3}), progress=False)
    longer = VerifierTrainConfig(**{**cfg.__dict__, "epochs": 2})
    with pytest.raises(ValueError, match="other settings"):
        load_checkpoint(longer)

    net = trained_verifier(cfg, load_checkpoint(cfg))
    path = export_verifier_onnx(net, tmp_path / "verifier.onnx", CropGeometry(64, 1.5, 24), "test")
    model = onnx.load(str(path))
    assert not any(node.metadata_props for node in model.graph.node)
    assert {p.key for p in model.metadata_props} == {"crop", "description"}
    verifier = BoxVerifier(str(path), threads=1)
    image = np.random.default_rng(0).integers(0, 256, (108, 192, 3), dtype=np.uint8)
    boxes = np.array([[10.0, 10.0, 40.0, 20.0], [100.0, 50.0, 108.0, 53.0], [150.0, 80.0, 190.0, 107.0]])
    expected = predict(net, box_crops(image, boxes))
    np.testing.assert_allclose(verifier.probabilities(image, boxes), expected, atol=1e-5)
    assert verifier.probabilities(image, np.zeros((0, 4))).shape == (0,)
    with pytest.raises(ValueError, match="uint8"):
        verifier.probabilities(image.astype(np.float32), boxes)
    with pytest.raises(ValueError, match="finite"):
        verifier.probabilities(image, np.array([[0.0, 0.0, np.nan, 5.0]]))


def test_the_detector_drops_the_boxes_the_verifier_rejects(datasets, tmp_path):
    _, detector, _ = datasets
    torch.manual_seed(0)
    net = BoxVerifierNet(4).eval()
    with torch.no_grad():  # every crop: logit log 3 → p = 0.75
        net.logit.weight.zero_()
        net.logit.bias.fill_(float(np.log(3.0)))
    verifier = str(export_verifier_onnx(net, tmp_path / "v.onnx"))
    image = np.zeros((108, 192, 3), np.uint8)
    alone = Detector(DetectorConfig(model=detector, verifier="", threads=1)).detect(image)
    passed = Detector(DetectorConfig(model=detector, verifier=verifier, verifier_threshold=0.7, threads=1)).detect(image)
    assert len(alone.scores) == 10
    np.testing.assert_array_equal(passed.scores, alone.scores)  # kept boxes keep their scores
    np.testing.assert_array_equal(passed.boxes, alone.boxes)
    rejected = Detector(DetectorConfig(model=detector, verifier=verifier, verifier_threshold=0.8, threads=1))
    assert not len(rejected.detect(image).scores)
    seen = []  # in a search window, the verifier still crops the whole frame: its training context
    windowed = Detector(DetectorConfig(model=detector, verifier=verifier, verifier_threshold=0.7, threads=1))
    probabilities = windowed.verifier.probabilities
    windowed.verifier.probabilities = lambda frame, boxes: seen.append(frame.shape) or probabilities(frame, boxes)
    windowed.detect(image, window=(40, 20, 64, 64))
    assert seen == [image.shape]
    with pytest.raises(ValueError, match="verifier_threshold"):
        DetectorConfig(verifier_threshold=1.0)


def test_a_model_that_is_not_a_verifier_is_refused(datasets):
    _, detector, _ = datasets
    with pytest.raises(ValueError, match="not a box verifier"):
        BoxVerifier(detector)


@pytest.mark.parametrize("kwargs", [{"lr": float("nan")}, {"lr": float("inf")}, {"weight_decay": float("nan")}])
def test_verifier_settings_that_cannot_train_are_refused(kwargs):
    from uav_landing_vision.detection.verifier_train import VerifierTrainConfig

    with pytest.raises(ValueError, match="lr"):
        VerifierTrainConfig(**kwargs)


def test_fewer_training_crops_than_a_batch_is_a_clear_error(datasets, tmp_path):
    """Not torch's 'Expected positive integer total_steps, but got 0'."""
    from uav_landing_vision.detection.verifier_train import VerifierTrainConfig, train_verifier

    folders, detector, _ = datasets
    cfg = VerifierTrainConfig(data=folders, detector=detector, out=str(tmp_path / "run"), batch=100_000,
                              width=4, threads=1, workers=1)
    with pytest.raises(ValueError, match=r"only \d+ training crops, fewer than one batch of 100000"):
        train_verifier(cfg, progress=False)
