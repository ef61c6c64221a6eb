"""The box verifier: crop geometry against hand-made cases, mining and training on tiny datasets,
the export against torch, and the verifier's product in the detector's scores."""

import json
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
import torch

from uav_landing_vision.detection import verifier_train as vt
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


# --- training the verifier: mining labels, jittered crops, augmentation, validation metrics ---------

A = [50.0, 40.0, 90.0, 60.0]  # 40 × 20 px, area 800


def _folder(root, labels, size=(200, 100)):
    (root / "images").mkdir(parents=True)
    (root / "labels").mkdir()
    w, h = size
    png = cv2.imencode(".png", np.full((h, w, 3), 90, np.uint8))[1].tobytes()
    (root / "images" / "000000.jpg").write_bytes(png)
    lines = [f"0 {(b[0] + b[2]) / 2 / w:.6f} {(b[1] + b[3]) / 2 / h:.6f} {(b[2] - b[0]) / w:.6f} "
             f"{(b[3] - b[1]) / h:.6f}" for b in labels]
    (root / "labels" / "000000.txt").write_text("\n".join(lines) + "\n")
    (root / "dataset.json").write_text(json.dumps({"width": w, "height": h, "images": 1}))
    return str(root)


def _mine(monkeypatch, folders, found, **cfg):
    """Run the mining of image 0 of each folder with a detector that finds ``found``; returns
    per folder (boxes given to the cropper, labels, source)."""
    seen = []
    monkeypatch.setattr(vt, "box_crops", lambda image, boxes, geometry: seen.append(np.array(boxes)) or
                        np.zeros((len(boxes), 4, 4, 3), np.uint8))
    detector = SimpleNamespace(detect=lambda image: SimpleNamespace(boxes=np.array(found, float).reshape(-1, 4)))
    config = vt.VerifierTrainConfig(data=tuple(folders), detector="none.onnx", **cfg)
    monkeypatch.setattr(vt, "_miner", (config, detector))
    out = vt._mine_images([(f, 0) for f in range(len(folders))])
    return [(boxes, labels, source) for boxes, (_, labels, source) in zip(seen, out)]


def test_mining_labels_positives_from_the_positive_iou_and_negatives_up_to_the_negative_iou(tmp_path, monkeypatch):
    """Nested boxes inside the 800 px² label: IoU = their area / 800, exact at 0.4 and 0.05."""
    root = _folder(tmp_path / "d", [A, [150.0, 70.0, 153.0, 80.0]])  # the second label is 3 px wide
    assert vt.read_labels(tmp_path / "d" / "labels" / "000000.txt", 200, 100)[0].tolist() == A  # exact
    found = [A,                                  # IoU 1: positive
             [50.0, 40.0, 66.0, 60.0],           # IoU 0.4 = positive_iou: positive
             [50.0, 40.0, 52.0, 60.0],           # IoU 0.05 = negative_iou: negative
             [50.0, 40.0, 58.0, 60.0],           # IoU 0.2: between, left out
             [0.0, 0.0, 10.0, 10.0]]             # IoU 0: negative
    (boxes, labels, source), = _mine(monkeypatch, [root], found)
    assert labels.tolist() == [1, 1, 0, 0, 1] and source.tolist() == [0, 0, 0, 0, 1]
    np.testing.assert_allclose(boxes[:4], np.array(found)[[0, 1, 2, 4]])
    # one jittered copy of the 40 px label (the 3 px one adds none), around it
    jittered = boxes[4]
    assert jittered[2] > jittered[0] and jittered[3] > jittered[1]
    assert box_iou_one(jittered, A) > 0.3


def box_iou_one(a, b):
    from uav_landing_vision.detection.detector import box_iou

    return float(box_iou(np.array([a]), np.array([b]))[0, 0])


def test_jittered_label_boxes_shift_by_a_tenth_of_their_size_and_scale_by_e_to_a_normal_015(tmp_path, monkeypatch):
    rng = np.random.default_rng(5)
    x0 = rng.uniform(0, 300, 400)
    y0 = rng.uniform(0, 200, 400)
    w, h = rng.uniform(8, 60, 400), rng.uniform(8, 40, 400)
    labels = np.stack([x0, y0, x0 + w, y0 + h], 1)
    folders = [_folder(tmp_path / name, labels, size=(400, 300)) for name in ("a", "b")]
    mined = _mine(monkeypatch, folders, [])
    truth = vt.read_labels(tmp_path / "a" / "labels" / "000000.txt", 400, 300)
    for boxes, lab, source in mined:
        assert len(boxes) == 400 and (lab == 1).all() and (source == 1).all()
        size = truth[:, 2:] - truth[:, :2]
        shift = ((boxes[:, :2] + boxes[:, 2:]) / 2 - (truth[:, :2] + truth[:, 2:]) / 2) / size
        scale = np.log((boxes[:, 2:] - boxes[:, :2]) / size)
        assert np.abs(shift.mean(axis=0)).max() < 0.02 and np.all(np.abs(shift.std(axis=0) - 0.1) < 0.015)
        assert np.abs(scale.mean(axis=0)).max() < 0.03 and np.all(np.abs(scale.std(axis=0) - 0.15) < 0.02)
    assert not np.allclose(mined[0][0], mined[1][0])  # each folder's image 0 draws its own jitter


def test_augment_flips_left_right_and_applies_a_gain_and_channel_offsets_to_zero_one_pixels():
    rng = np.random.default_rng(0)
    crops = rng.integers(0, 256, (64, 6, 6, 3), dtype=np.uint8)
    out = vt.augment(crops, np.random.default_rng(1)).numpy()
    assert out.shape == (64, 3, 6, 6)
    x = crops.astype(float) / 255.0
    flips = 0
    for k in range(64):
        y = out[k].transpose(1, 2, 0)  # back to rows, columns, channels
        fits = []
        for candidate in (x[k], x[k][:, ::-1]):
            # y = g · x + o_c: one gain for all channels, one offset per channel
            g = np.polyfit(candidate[..., 0].ravel(), y[..., 0].ravel(), 1)[0]
            resid = y - g * candidate
            fits.append((np.ptp(resid.reshape(-1, 3), axis=0).max(), g, resid.reshape(-1, 3).mean(axis=0)))
        best = min(range(2), key=lambda i: fits[i][0])
        assert fits[best][0] < 1e-5 and 0.7 <= fits[best][1] <= 1.3
        flips += best
    assert 16 < flips < 48


def test_validation_metrics_hand_made():
    prob = np.array([0.9, 0.8, 0.3, 0.4, 0.1])
    labels = np.array([1, 0, 0, 1, 0])
    m = vt.validation_metrics(prob, labels)
    # by score: T F T F F → precision 1 at recall ½, 2/3 at recall 1
    assert m["ap"] == pytest.approx(0.5 * 1 + 0.5 * 2 / 3)
    assert m["positives_kept"] == pytest.approx(0.5) and m["negatives_rejected"] == pytest.approx(2 / 3)


def _premined(n_train_pos, n_train_neg, n_val=4, side=8):
    """Mined crops stood in for mine_crops: each crop a flat grey whose level encodes its index."""
    n = n_train_pos + n_train_neg + n_val
    crops = np.repeat(np.arange(n, dtype=np.uint8)[:, None, None, None] * 3, side * side * 3).reshape(n, side, side, 3)
    labels = np.array([1] * n_train_pos + [0] * n_train_neg + [1, 0] * (n_val // 2), np.int8)
    validation = np.array([False] * (n_train_pos + n_train_neg) + [True] * n_val)
    return {"crops": crops, "labels": labels, "source": np.zeros(n, np.int8), "validation": validation}


def _stub_mining(monkeypatch, mined):
    """mine_crops stood in: it makes the run's folder, as mining does, and gives ``mined``."""
    from pathlib import Path

    def mine(cfg, progress=True):
        Path(cfg.out).mkdir(parents=True, exist_ok=True)
        return mined

    monkeypatch.setattr(vt, "mine_crops", mine)


def test_the_verifier_loss_weights_positives_by_the_negatives_per_positive(tmp_path, monkeypatch):
    import torch

    mined = _premined(4, 12)  # a quarter of the training crops are UAVs: positives weigh 3
    _stub_mining(monkeypatch, mined)
    weights = []
    real = torch.nn.functional.binary_cross_entropy_with_logits

    def recording(logits, target, pos_weight=None):
        weights.append(float(pos_weight))
        return real(logits, target, pos_weight=pos_weight)

    monkeypatch.setattr(vt, "F", type("F", (), {"binary_cross_entropy_with_logits": staticmethod(recording)}))
    cfg = vt.VerifierTrainConfig(data=("d",), out=str(tmp_path / "run"), epochs=1, batch=8, width=4)
    vt.train_verifier(cfg, progress=False)
    assert weights and all(w == pytest.approx(3.0) for w in weights)


def test_verifier_training_needs_both_classes_among_the_training_crops(tmp_path, monkeypatch):
    _stub_mining(monkeypatch, _premined(16, 0))
    cfg = vt.VerifierTrainConfig(data=("d",), out=str(tmp_path / "run"), epochs=1, batch=8, width=4)
    with pytest.raises(ValueError, match="both UAV and non-UAV"):
        vt.train_verifier(cfg, progress=False)


def test_each_verifier_epoch_draws_its_own_order_of_the_crops(tmp_path, monkeypatch):
    mined = _premined(8, 8)
    _stub_mining(monkeypatch, mined)
    batches = []
    augment = vt.augment
    monkeypatch.setattr(vt, "augment", lambda crops, rng: batches.append(crops[:, 0, 0, 0] // 3) or augment(crops, rng))
    cfg = vt.VerifierTrainConfig(data=("d",), out=str(tmp_path / "run"), epochs=3, batch=4, width=4)
    vt.train_verifier(cfg, progress=False)
    epochs = [np.concatenate(batches[k * 4 : (k + 1) * 4]) for k in range(3)]
    assert all(sorted(e.tolist()) == list(range(16)) for e in epochs)  # every training crop once an epoch
    assert not np.array_equal(epochs[0], epochs[1]) and not np.array_equal(epochs[1], epochs[2])


def test_predict_gives_probabilities_of_the_verifier_logits():
    import torch

    from uav_landing_vision.detection.network import BoxVerifierNet

    net = BoxVerifierNet(4)
    with torch.no_grad():
        net.logit.weight.zero_()
        net.logit.bias.fill_(-2.0)
    prob = vt.predict(net, np.zeros((5, 16, 16, 3), np.uint8), batch=2)
    np.testing.assert_allclose(prob, np.full(5, 1 / (1 + np.exp(2.0))), rtol=1e-6)


def test_a_resumed_verifier_run_continues_after_its_last_epoch_and_ends_as_the_uninterrupted_one(tmp_path, monkeypatch,
                                                                                             interrupt_at_second_call):
    import torch

    _stub_mining(monkeypatch, _premined(8, 8))
    settings = dict(data=("d",), epochs=3, batch=4, width=4)
    whole = vt.VerifierTrainConfig(out=str(tmp_path / "whole"), **settings)
    split = vt.VerifierTrainConfig(out=str(tmp_path / "split"), **settings)
    vt.train_verifier(whole, progress=False)
    interrupt_at_second_call(vt, "validation_metrics", lambda: vt.train_verifier(split, progress=False))
    log = vt.train_verifier(split, resume=True, progress=False)
    assert [e["epoch"] for e in log["epochs"]] == [1, 2, 3]
    from uav_landing_vision.detection.train import load_checkpoint

    a, b = load_checkpoint(whole), load_checkpoint(split)
    assert all(torch.equal(a["net"][k], b["net"][k]) for k in a["net"])
