"""Training targets and loss (against hand-made cases and numpy oracles), the head decode, validation AP,
evaluation metrics, flipped and cropped training images, the split, warm-up and checkpoints, and a
fresh network exported to ONNX and run through the runtime."""

import json

import cv2
import numpy as np
import pytest
import torch

from uav_landing_vision.detection.detector import Detector, DetectorConfig, decode, letterbox
from uav_landing_vision.detection.evaluation import average_precision, match_frame, summarise
from uav_landing_vision.detection.export import export_onnx
from uav_landing_vision.detection.network import PRIOR, STRIDES, Head, UavDetectorNet, decode_torch
from uav_landing_vision.detection.train import build_targets, detection_loss, giou_loss, random_crop, validate


def _positives(targets):
    return [sorted(map(tuple, torch.nonzero(pos[0]).tolist())) for pos, _, _ in targets]


def test_targets_pick_the_head_by_size_and_the_cells_inside_the_box():
    small = build_targets([torch.tensor([[10.0, 10.0, 20.0, 14.0]])], 64, 64)
    assert _positives(small) == [[(1, 1)], [], []]
    medium = build_targets([torch.tensor([[0.0, 0.0, 40.0, 40.0]])], 64, 64)
    assert _positives(medium)[0] == [(i, j) for i in (1, 2, 3) for j in (1, 2, 3)]
    large = build_targets([torch.tensor([[0.0, 0.0, 100.0, 60.0]])], 128, 128)
    assert _positives(large)[0] == [] and (1, 3) in _positives(large)[1] and _positives(large)[2] == []
    pos, target, _ = medium[0]
    np.testing.assert_allclose(target[0, 2, 2].numpy(), [0, 0, 40, 40])
    assert all(not p.any() for p, _, _ in build_targets([torch.zeros((0, 4))], 64, 64))


def test_random_crop_shifts_and_clips_boxes():
    y, x = np.mgrid[0:384, 0:640]
    img = np.stack([x % 256, y % 256, x // 256], axis=-1).astype(np.uint8)  # pixels encode their position
    boxes = np.array([[300.0, 100.0, 316.0, 108.0], [0.0, 370.0, 30.0, 384.0]])
    holds_centre = 0
    for seed in range(40):
        crop, out = random_crop(img, boxes, (320, 192), np.random.default_rng(seed))
        assert crop.shape == (192, 320, 3)
        x0, y0 = int(crop[0, 0, 0]) + 256 * int(crop[0, 0, 2]), int(crop[0, 0, 1])
        expected = np.clip(boxes - [x0, y0, x0, y0], 0, [320, 192, 320, 192])
        expected = expected[(expected[:, 2] - expected[:, 0] >= 2) & (expected[:, 3] - expected[:, 1] >= 2)]
        np.testing.assert_allclose(out, expected)
        holds_centre += bool(x0 <= 308 < x0 + 320 and y0 <= 104 < y0 + 192)
    assert holds_centre >= 28
    assert random_crop(img, boxes[:0], (320, 192), np.random.default_rng(0))[1].shape == (0, 4)


def test_giou_loss_hand_made():
    a = torch.tensor([[0.0, 0.0, 10.0, 10.0], [0.0, 0.0, 10.0, 10.0]])
    b = torch.tensor([[0.0, 0.0, 10.0, 10.0], [20.0, 0.0, 30.0, 10.0]])
    # Disjoint: IoU 0, hull 300, union 200 → 1 − 0 + 100/300.
    np.testing.assert_allclose(giou_loss(a, b).numpy(), [0.0, 1 + 1 / 3], atol=1e-5)


def test_loss_decreases_on_a_tiny_batch():
    torch.manual_seed(0)
    images = torch.full((2, 3, 64, 96), 0.5)
    images[0, :, 20:28, 30:46] = 0.1
    images[1, :, 40:52, 60:70] = 0.9
    boxes = [torch.tensor([[30.0, 20.0, 46.0, 28.0]]), torch.tensor([[60.0, 40.0, 70.0, 52.0]])]
    targets = build_targets(boxes, 64, 96)
    net = UavDetectorNet(width=16, blocks=(1, 1, 1))
    optim = torch.optim.Adam(net.parameters(), lr=5e-3)
    losses = []
    for _ in range(12):
        loss, _, _ = detection_loss(net(images), targets)
        optim.zero_grad()
        loss.backward()
        optim.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0]


def test_average_precision_hand_made():
    ap, precision, recall, _ = average_precision(np.array([0.9, 0.8, 0.7, 0.6]), np.array([1, 0, 1, 0], bool), 3)
    np.testing.assert_allclose(precision, [1, 0.5, 2 / 3, 0.5])
    np.testing.assert_allclose(recall, [1 / 3, 1 / 3, 2 / 3, 2 / 3])
    assert ap == pytest.approx(1 / 3 + 2 / 9)


def test_matching_and_summary_hand_made():
    gt = np.array([[100.0, 100.0, 120.0, 110.0]])
    tp, matched = match_frame(np.array([[101.0, 100.0, 121.0, 110.0], [100.0, 100.0, 120.0, 110.0]]),
                              np.array([0.6, 0.9]), gt)
    assert tp.tolist() == [False, True] and matched.tolist() == [True]
    frames = [
        {"boxes": np.array([[100.0, 100.0, 120.0, 110.0]]), "scores": np.array([0.9]), "gt": gt, "ms": 10.0},
        {"boxes": np.array([[0.0, 0.0, 30.0, 30.0]]), "scores": np.array([0.7]), "gt": np.zeros((0, 4)), "ms": 12.0},
        {"boxes": np.zeros((0, 4)), "scores": np.zeros(0), "gt": np.array([[0.0, 0.0, 10.0, 5.0]]), "ms": 30.0},
        {"boxes": np.array([[5.0, 5.0, 9.0, 9.0]]), "scores": np.array([0.3]), "gt": np.zeros((0, 4)), "ms": 11.0},
    ]
    r = summarise(frames, threshold=0.5)
    assert r["ap50"] == pytest.approx(0.5)
    assert (r["precision"], r["recall"]) == (0.5, 0.5)
    assert r["false_positives_per_100_frames"] == 25.0
    assert r["best_box_false_positives_per_100_frames"] == 25.0
    # a second, weaker box beside a matched best one is a false positive, but not one the graph uses
    frames[0] = {**frames[0], "boxes": np.array([[100.0, 100.0, 120.0, 110.0], [300.0, 300.0, 320.0, 310.0]]),
                 "scores": np.array([0.9, 0.6])}
    r = summarise(frames, threshold=0.5)
    assert r["false_positives_per_100_frames"] == 50.0
    assert r["best_box_false_positives_per_100_frames"] == 25.0
    # the best box off the UAV, a weaker one on it: the graph gets the wrong one
    frames[0] = {**frames[0], "scores": np.array([0.6, 0.9])}
    r = summarise(frames, threshold=0.5)
    assert r["false_positives_per_100_frames"] == 50.0
    assert r["best_box_false_positives_per_100_frames"] == 50.0
    assert r["recall_by_width_px"] == {"8-16": {"recall": 0.0, "count": 1}, "16-32": {"recall": 1.0, "count": 1}}
    assert r["recall_wider_than_16px"] == 1.0 and r["ms_per_frame"] == 11.5


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """A fresh small network, its stride-8 head made to score every cell σ(5) with the cell's
    own box (the other heads keep their initial weights), exported to ONNX."""
    torch.manual_seed(0)
    net = UavDetectorNet(width=16, blocks=(1, 1, 1)).eval()
    with torch.no_grad():
        net.heads[0].pred.weight.zero_()
        net.heads[0].pred.bias.copy_(torch.tensor([5.0, 0.0, 0.0, 0.0, 0.0]))
    return net, export_onnx(net, tmp_path_factory.mktemp("onnx") / "det.onnx", (640, 384), "test")


def test_exported_network_matches_torch_and_decodes_alike(exported):
    import onnxruntime as ort

    net, path = exported
    x = torch.rand(1, 3, 96, 160)
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    onnx_out = session.run(None, {"images": x.numpy()})
    with torch.no_grad():
        torch_out = net(x)
    for o, t, s in zip(onnx_out, torch_out, STRIDES):
        np.testing.assert_allclose(o, t.numpy(), atol=1e-4)
        logits, boxes = decode_torch(t, s)
        nb, ns = decode(o[0], s, 0.0)
        np.testing.assert_allclose(nb, boxes[0].reshape(-1, 4).numpy(), rtol=1e-4, atol=1e-3)
        np.testing.assert_allclose(ns, torch.sigmoid(logits[0]).reshape(-1).numpy(), atol=1e-5)


def test_export_drops_the_exporters_debug_records(exported):
    """No per-node stack traces (they hold the exporting machine's paths); the runtime's props stay."""
    import onnx

    model = onnx.load(str(exported[1]))
    assert not any(node.metadata_props for node in model.graph.node)
    assert not model.graph.metadata_props
    assert {p.key for p in model.metadata_props} == {"strides", "input_width", "input_height", "description"}


def test_runtime_on_the_exported_model(exported):
    _, path = exported
    det = Detector(DetectorConfig(model=str(path), verifier="", max_detections=5, threads=1))
    assert det.strides == STRIDES and det.input_size == (640, 384)
    frame = np.zeros((720, 1280, 3), np.uint8)
    result = det.detect(frame)
    assert len(result.boxes) == 5 and np.all(result.scores == pytest.approx(1 / (1 + np.exp(-5.0))))
    _, lb = letterbox(frame, (640, 384))
    # the first cells lie in the letterbox's grey band above the frame: the first box is the
    # first cell of the frame's own rows (input row 16, 4 px below the band), clipped to it
    assert lb.pad_y == 12
    np.testing.assert_allclose(result.boxes[0], [0, 0, 16, 8])
    assert np.all(result.boxes >= 0) and np.all(result.boxes[:, 2:] <= [1280, 720])
    # full resolution in the window; the boxes of its first row and column reach its sides
    # inside the frame, where it may cut the UAV: dropped
    windowed = det.detect(frame, window=(100, 200, 192, 192))
    np.testing.assert_allclose(windowed.boxes[0], [108, 208, 116, 216])
    grown = det.detect(frame, window=(100, 200, 200, 180))  # grown to 224 × 192 from the frame itself
    np.testing.assert_allclose(grown.boxes[0], [96, 202, 104, 210])
    corner = det.detect(frame, window=(0, 0, 192, 192))  # the frame's own sides cut nothing
    np.testing.assert_allclose(corner.boxes[0], [0, 0, 8, 8])
    with pytest.raises(ValueError, match="uint8"):
        det.detect(frame.astype(np.float32))


def test_training_images_are_scaled_as_the_runtime_scales_a_frame(tmp_path):
    import json

    import cv2

    from uav_landing_vision.detection.train import LetterboxedImages

    (tmp_path / "images").mkdir()
    (tmp_path / "labels").mkdir()
    (tmp_path / "dataset.json").write_text(json.dumps({"width": 96, "height": 54}))
    cv2.imwrite(str(tmp_path / "images" / "000000.jpg"), np.full((54, 96, 3), 128, np.uint8))
    (tmp_path / "labels" / "000000.txt").write_text("0 0.5 0.5 0.25 0.2\n")  # 24 x 10.8 px at the centre
    tensor, boxes = LetterboxedImages([(str(tmp_path), 0)], (192, 128), seed=0, augment=False)[0]
    _, runtime = letterbox(np.zeros((54, 96, 3), np.uint8), (192, 128), max_scale=min(192 / 96, 128 / 54))
    assert tuple(tensor.shape) == (3, 128, 192) and runtime.scale == 2.0  # a small frame is enlarged at run time
    np.testing.assert_allclose(boxes.numpy(), runtime.to_input(np.array([[36.0, 21.6, 60.0, 32.4]])), atol=1e-4)


def test_training_uses_every_folder_and_resumes_only_with_its_own_settings(tmp_path):
    from uav_landing_vision.camera import CameraModel, save_camera_info_yaml
    from uav_landing_vision.detection.dataset import DatasetConfig, generate
    from uav_landing_vision.detection.train import TrainConfig, train

    camera = CameraModel(192, 108, np.array([[165.0, 0, 96.0], [0, 165.0, 54.0], [0, 0, 1]]))
    save_camera_info_yaml(camera, tmp_path / "cam.yaml")
    folders = []
    for seed, approach in ((1, 0.0), (2, 1.0)):
        folders.append(str(tmp_path / f"data{seed}"))
        generate(DatasetConfig(count=4, seed=seed, camera_info=str(tmp_path / "cam.yaml"), families=("normal",),
                               banks_per_family=1, approach_fraction=approach), folders[-1], progress=False)
    cfg = TrainConfig(data=tuple(folders), out=str(tmp_path / "run"), epochs=1, batch=2, input_size=(192, 128),
                      crop=(96, 64), width=8, threads=1)
    log = train(cfg, progress=False)
    assert (log["train_images"], log["val_images"]) == (6, 2)  # every 10th image of each folder validates
    assert len(log["epochs"]) == 1 and np.isfinite(log["epochs"][0]["loss"])
    assert (tmp_path / "run" / "last.pt").is_file() and (tmp_path / "run" / "train_log.json").is_file()
    with pytest.raises(ValueError, match=r"other settings \(lr: 0.002 there, 0.001 here\)"):
        train(TrainConfig(**{**cfg.__dict__, "lr": 1e-3}), resume=True, progress=False)
    with pytest.raises(FileNotFoundError, match="dataset.json"):
        train(TrainConfig(**{**cfg.__dict__, "data": (str(tmp_path),), "out": str(tmp_path / "new")}), progress=False)
    # A new run into a finished one's folder would overwrite it unasked.
    before = (tmp_path / "run" / "last.pt").read_bytes()
    with pytest.raises(ValueError, match="holds a run already .*--resume"):
        train(TrainConfig(**{**cfg.__dict__, "seed": 5}), progress=False)
    assert (tmp_path / "run" / "last.pt").read_bytes() == before
    # Fine-tuning: a new run starts from the first run's network (a zero-step run keeps it as is).
    import torch

    from uav_landing_vision.detection.train import load_checkpoint

    first = load_checkpoint(cfg)["net"]
    tuned = TrainConfig(**{**cfg.__dict__, "out": str(tmp_path / "tuned"), "lr": 1e-12, "weight_decay": 0.0,
                           "init": str(tmp_path / "run" / "last.pt")})
    train(tuned, progress=False)
    state = load_checkpoint(tuned)["net"]
    assert all(torch.allclose(state[k].float(), first[k].float(), atol=1e-6) for k in first
               if "running" not in k and "num_batches" not in k)  # BatchNorm statistics move
    other = str(tmp_path / "new")
    with pytest.raises(FileNotFoundError, match="to start from"):
        train(TrainConfig(**{**tuned.__dict__, "out": other, "init": str(tmp_path / "none.pt")}), progress=False)
    # Not a checkpoint, or one of another width: named errors, not a pickle or torch traceback.
    with pytest.raises(ValueError, match=r"dataset.json is not a training checkpoint"):
        train(TrainConfig(**{**tuned.__dict__, "out": other, "init": str(tmp_path / "data1" / "dataset.json")}),
              progress=False)
    with pytest.raises(ValueError, match=r"last.pt does not fit a network of width 16"):
        train(TrainConfig(**{**tuned.__dict__, "out": other, "width": 16}), progress=False)
    assert not (tmp_path / "new").exists()  # refused runs leave no folder behind
    assert load_checkpoint(tuned)["frozen_normalisation"] is False
    (tmp_path / "run" / "last.pt").rename(tmp_path / "moved.pt")  # the start of a run is not needed to resume it
    train(tuned, resume=True, progress=False)


def test_a_checkpoint_of_a_run_from_an_exported_model_keeps_its_normalisation_frozen(tmp_path):
    """Its BatchNorm layers hold the export's folded identity: trained from its last.pt with them
    in training mode, the network no longer computed what it was (loss 0.56 became 16.9)."""
    from uav_landing_vision.detection.train import TrainConfig, folded_normalisation

    def run_from(init: str, **state) -> TrainConfig:
        torch.save({"net": {}, "config": {"init": init}, **state}, tmp_path / "last.pt")
        return TrainConfig(init=str(tmp_path / "last.pt"))

    assert folded_normalisation(TrainConfig(init="model.onnx"))
    assert folded_normalisation(run_from("model.onnx"))  # a checkpoint written before the flag
    assert folded_normalisation(run_from("earlier/last.pt", frozen_normalisation=True))
    assert not folded_normalisation(run_from("", frozen_normalisation=False))
    assert not folded_normalisation(TrainConfig())


def test_folders_whose_frames_letterbox_to_different_sizes_are_refused(tmp_path):
    """Batched together they crashed in torch.stack; refused before any image is read."""
    import json

    from uav_landing_vision.detection.train import TrainConfig, train

    for name, (w, h) in (("wide", (1280, 720)), ("tall", (1280, 960)), ("same", (1920, 1080))):
        (tmp_path / name).mkdir()
        (tmp_path / name / "dataset.json").write_text(json.dumps({"width": w, "height": h, "images": 2}))
    cfg = TrainConfig(data=(str(tmp_path / "wide"), str(tmp_path / "tall")), out=str(tmp_path / "run"),
                      input_size=(640, 384), width=8)
    with pytest.raises(ValueError, match=r"tall \(1280x960\) and of .*wide letterbox to different sizes at 640x384"):
        train(cfg, progress=False)
    with pytest.raises(FileNotFoundError, match="cannot read image"):  # one shape: it goes on to read the images
        train(TrainConfig(**{**cfg.__dict__, "data": (str(tmp_path / "wide"), str(tmp_path / "same"))}), progress=False)


def _tuned_like_the_export(path):
    """A network given the weights of the exported model ``path`` (its BatchNorms frozen), checked
    to compute the model's outputs."""
    import onnxruntime as ort

    from uav_landing_vision.detection.train import set_training, weights_from_onnx

    x = torch.rand(1, 3, 96, 160)
    expected = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, {"images": x.numpy()})
    tuned = UavDetectorNet(width=16, blocks=(1, 1, 1))
    tuned.load_state_dict(weights_from_onnx(path, tuned))
    set_training(tuned, frozen_normalisation=True)
    for o, t in zip(expected, tuned(x)):
        np.testing.assert_allclose(t.detach().numpy(), o, atol=1e-4)
    return tuned


def test_fine_tuning_starts_from_an_exported_model(tmp_path):
    """weights_from_onnx unfolds an export's BatchNorms: with them frozen (set_training) the torch
    network computes the model's outputs, and training steps leave their statistics alone."""
    from uav_landing_vision.detection.train import weights_from_onnx

    torch.manual_seed(1)
    net = UavDetectorNet(width=16, blocks=(1, 1, 1))
    with torch.no_grad():  # statistics and scales far from the identity, so the folding matters
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.uniform_(-0.5, 0.5)
                m.running_var.uniform_(0.5, 2.0)
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.2, 0.2)
    path = export_onnx(net.eval(), tmp_path / "det.onnx", (640, 384))
    tuned = _tuned_like_the_export(path)
    stats = {k: v.clone() for k, v in tuned.state_dict().items() if "running" in k}
    tuned(torch.rand(2, 3, 96, 160)).__getitem__(0).sum().backward()
    assert all(torch.equal(tuned.state_dict()[k], v) for k, v in stats.items())

    with pytest.raises(ValueError, match="no convolution"):
        other = UavDetectorNet(width=24, blocks=(1, 1, 1))
        weights_from_onnx(path, other)


def test_fine_tuning_starts_from_an_export_whose_convolutions_have_no_bias(tmp_path):
    """A freshly initialised network folds to zero biases, which the exporter leaves out of its
    convolutions: such a model is read with zero biases (it was refused as "no convolution")."""
    import onnx

    torch.manual_seed(2)
    path = export_onnx(UavDetectorNet(width=16, blocks=(1, 1, 1)).eval(), tmp_path / "fresh.onnx", (640, 384))
    assert any(n.op_type == "Conv" and len(n.input) == 2 for n in onnx.load(str(path)).graph.node)
    _tuned_like_the_export(path)


@pytest.mark.parametrize("kwargs, message", [
    ({"input_size": (0, 0)}, "input_size"),
    ({"input_size": (-64, 128)}, "input_size"),
    ({"crop": (64, 0)}, "crop"),
    ({"lr": float("nan")}, "lr"),
    ({"lr": float("inf")}, "lr"),
    ({"weight_decay": -1.0}, "weight_decay"),
    ({"max_images": -3}, "max_images"),
    ({"input_size": (4128, 192)}, "at most 4096"),  # it trained, then failed in the export
    ({"data": ("data", "./data")}, "given more than once"),  # its images counted twice
])
def test_training_settings_that_cannot_train_are_refused(kwargs, message):
    """An empty input (it trained, then failed in the export with a traceback), a crop with one
    zero side (a convolution error), a NaN rate (a silently NaN network), a negative count."""
    from uav_landing_vision.detection.train import TrainConfig

    with pytest.raises(ValueError, match=message):
        TrainConfig(**kwargs)


def test_train_detector_refuses_an_empty_input_size_before_reading_data(tmp_path):
    from uav_landing_vision.cli import main

    with pytest.raises(SystemExit, match="^uav-landing train-detector: input_size"):
        main(["train-detector", "--data", str(tmp_path / "none"), "--out", str(tmp_path / "run"), "--input", "0x0"])


def test_a_resumed_run_ends_as_the_uninterrupted_one(tmp_path, interrupt_at_second_call):
    from uav_landing_vision.camera import CameraModel, save_camera_info_yaml
    from uav_landing_vision.detection import train as training
    from uav_landing_vision.detection.dataset import DatasetConfig, generate

    camera = CameraModel(192, 108, np.array([[165.0, 0, 96.0], [0, 165.0, 54.0], [0, 0, 1]]))
    save_camera_info_yaml(camera, tmp_path / "cam.yaml")
    data = str(tmp_path / "data")
    generate(DatasetConfig(count=6, seed=1, camera_info=str(tmp_path / "cam.yaml"), families=("normal",),
                           banks_per_family=1), data, progress=False)
    settings = dict(data=(data,), epochs=3, batch=2, input_size=(192, 128), crop=(96, 64), width=8, threads=1)
    whole = training.TrainConfig(out=str(tmp_path / "whole"), **settings)
    split = training.TrainConfig(out=str(tmp_path / "split"), **settings)
    training.train(whole, progress=False)
    interrupt_at_second_call(training, "validate", lambda: training.train(split, progress=False))
    training.train(split, resume=True, progress=False)
    a, b = training.load_checkpoint(whole), training.load_checkpoint(split)
    assert all(torch.equal(a["net"][k], b["net"][k]) for k in a["net"])
    assert [e["loss"] for e in a["log"]["epochs"]] == [e["loss"] for e in b["log"]["epochs"]]


# --- training arithmetic against hand-made cases and numpy oracles ----------------------------------

# --- targets ---------------------------------------------------------------------------------

def test_a_box_whose_larger_side_is_exactly_48_px_goes_to_the_stride_16_head():
    """"stride 8 below 48 px, 16 below 144 px, else 32": 48 and 144 themselves go up a level."""
    at_48 = _positives(build_targets([torch.tensor([[8.0, 8.0, 56.0, 18.0]])], 256, 256))
    assert at_48[0] == [] and at_48[1] and at_48[2] == []
    at_144 = _positives(build_targets([torch.tensor([[8.0, 8.0, 152.0, 18.0]])], 256, 256))
    assert at_144[0] == [] and at_144[1] == [] and at_144[2]
    below = _positives(build_targets([torch.tensor([[8.0, 8.0, 55.5, 18.0]])], 256, 256))
    assert below[0] and below[1] == []


def test_the_head_is_chosen_by_the_larger_side_of_a_thin_box():
    """A 60 × 10 px box (larger side 60) belongs to the stride-16 head, not stride 8 by its 10 px."""
    cells = _positives(build_targets([torch.tensor([[20.0, 30.0, 80.0, 40.0]])], 128, 128))
    assert cells[0] == [] and cells[1] and cells[2] == []


def test_a_tiny_box_is_positive_only_in_the_cell_holding_its_centre():
    """A 2 px box at (2, 2): no cell centre (4, 4) lies inside it, yet its own cell is positive."""
    targets = build_targets([torch.tensor([[1.0, 1.0, 3.0, 3.0]])], 64, 64)
    assert _positives(targets) == [[(0, 0)], [], []]
    np.testing.assert_allclose(targets[0][1][0, 0, 0].numpy(), [1, 1, 3, 3])


def test_neighbour_cells_count_by_their_centres_at_half_a_stride():
    """Cell (i, j) of stride 8 has its centre at ((j + ½)·8, (i + ½)·8): the box 1…9 holds no
    neighbour's centre (12), only its own cell; a tall box 1…9 × 1…25 holds the centres of its
    column, rows 0–2 (x = 4, y = 4, 12, 20)."""
    small = _positives(build_targets([torch.tensor([[1.0, 1.0, 9.0, 9.0]])], 64, 64))
    assert small == [[(0, 0)], [], []]
    tall = _positives(build_targets([torch.tensor([[1.0, 1.0, 9.0, 25.0]])], 64, 64))
    assert tall == [[(0, 0), (1, 0), (2, 0)], [], []]
    wide = _positives(build_targets([torch.tensor([[1.0, 1.0, 25.0, 9.0]])], 64, 96))
    assert wide == [[(0, 0), (0, 1), (0, 2)], [], []]


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_a_smaller_box_wins_a_cell_it_shares_with_a_larger_one(order):
    big, small = torch.tensor([0.0, 0.0, 40.0, 40.0]), torch.tensor([10.0, 10.0, 20.0, 20.0])
    boxes = torch.stack([(big, small)[k] for k in order])
    pos, target, stride = build_targets([boxes], 64, 64)[0]
    assert stride == 8 and pos[0, 1, 1]
    np.testing.assert_allclose(target[0, 1, 1].numpy(), small.numpy())  # the cell of the small box's centre
    np.testing.assert_allclose(target[0, 3, 3].numpy(), big.numpy())  # a cell only the big box covers


# --- GIoU and the loss -----------------------------------------------------------------------

def _giou_oracle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = []
    for p, t in zip(a, b):
        iw = max(0.0, min(p[2], t[2]) - max(p[0], t[0]))
        ih = max(0.0, min(p[3], t[3]) - max(p[1], t[1]))
        inter = iw * ih
        union = (p[2] - p[0]) * (p[3] - p[1]) + (t[2] - t[0]) * (t[3] - t[1]) - inter
        hull = (max(p[2], t[2]) - min(p[0], t[0])) * (max(p[3], t[3]) - min(p[1], t[1]))
        out.append(1.0 - (inter / union - (hull - union) / hull))
    return np.array(out)


def test_giou_loss_matches_a_brute_force_for_overlapping_nested_and_diagonally_disjoint_boxes():
    rng = np.random.default_rng(4)
    lo = rng.uniform(0, 50, (200, 2, 2))
    size = rng.uniform(1, 30, (200, 2, 2))
    boxes = np.concatenate([lo, lo + size], axis=-1)  # (200, 2, 4)
    hand = np.array([[[0, 0, 10, 10], [20, 30, 25, 40]],     # disjoint in both x and y
                     [[0, 0, 10, 10], [2, 3, 5, 6]],         # nested
                     [[0, 0, 10, 10], [5, 5, 15, 15]]], float)
    boxes = np.concatenate([hand, boxes])
    got = giou_loss(torch.tensor(boxes[:, 0]), torch.tensor(boxes[:, 1])).numpy()
    np.testing.assert_allclose(got, _giou_oracle(boxes[:, 0], boxes[:, 1]), rtol=1e-6, atol=1e-6)
    # disjoint diagonally: IoU 0, union 100 + 50, hull 25 · 40 = 1000
    assert got[0] == pytest.approx(1.0 + (1000 - 150) / 1000, abs=1e-6)


def _decode_oracle(raw: np.ndarray, stride: int):
    """Docstring formula: centre ((j+½+tx)·s, (i+½+ty)·s), size (s·e^tw, s·e^th), |tw|,|th| ≤ 6."""
    n, _, h, w = raw.shape
    boxes = np.zeros((n, h, w, 4))
    for b in range(n):
        for i in range(h):
            for j in range(w):
                _, tx, ty, tw, th = raw[b, :, i, j]
                cx, cy = (j + 0.5 + tx) * stride, (i + 0.5 + ty) * stride
                bw, bh = stride * np.exp(np.clip(tw, -6, 6)), stride * np.exp(np.clip(th, -6, 6))
                boxes[b, i, j] = [cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2]
    return raw[:, 0], boxes


def test_decode_torch_matches_the_documented_cell_formula_on_a_non_square_map():
    rng = np.random.default_rng(7)
    raw = rng.normal(0.0, 1.0, (2, 5, 3, 5))
    raw[0, 3, 0, 0], raw[0, 4, 1, 2], raw[1, 3, 2, 4], raw[1, 4, 0, 1] = 5.0, -5.5, 8.0, -9.0  # near and past the clamp
    for stride in (8, 32):
        logits, boxes = decode_torch(torch.tensor(raw), stride)
        want_logits, want_boxes = _decode_oracle(raw, stride)
        np.testing.assert_allclose(logits.numpy(), want_logits)
        np.testing.assert_allclose(boxes.numpy(), want_boxes, rtol=1e-9, atol=1e-9)


def test_heads_start_at_the_focal_loss_prior():
    head = Head(8)
    assert torch.sigmoid(head.pred.bias[0]).item() == pytest.approx(PRIOR, rel=1e-5)


def test_detection_loss_is_the_focal_objectness_plus_twice_the_giou_per_positive_cell():
    """Sigmoid focal loss, α = 0.25 on positives and 0.75 on negatives, γ = 2, summed over all
    cells; GIoU loss summed over the positives; both divided by the number of positive cells."""
    rng = np.random.default_rng(11)
    height, width = 64, 96
    boxes = [torch.tensor([[10.0, 12.0, 30.0, 24.0], [40.0, 30.0, 100.0, 60.0]]), torch.zeros((0, 4))]
    targets = build_targets(boxes, height, width)
    raw = [rng.normal(0.0, 1.5, (2, 5, height // s, width // s)) for s in STRIDES]
    total, obj, box = detection_loss([torch.tensor(r) for r in raw], targets)
    want_obj = want_box = 0.0
    n_pos = 0
    for r, (pos, target, stride) in zip(raw, targets):
        logits, decoded = _decode_oracle(r, stride)
        y = pos.numpy().astype(float)
        p = 1.0 / (1.0 + np.exp(-logits))
        ce = -(y * np.log(p) + (1 - y) * np.log(1 - p))
        p_t = np.where(y == 1, p, 1 - p)
        alpha_t = np.where(y == 1, 0.25, 0.75)
        want_obj += np.sum(alpha_t * (1 - p_t) ** 2 * ce)
        mask = pos.numpy()
        if mask.any():
            want_box += _giou_oracle(decoded[mask], target.numpy()[mask]).sum()
        n_pos += int(mask.sum())
    assert n_pos > 2
    assert float(obj) == pytest.approx(want_obj / n_pos, rel=1e-6)
    assert float(box) == pytest.approx(want_box / n_pos, rel=1e-6)
    assert float(total) == pytest.approx(want_obj / n_pos + 2.0 * want_box / n_pos, rel=1e-6)


# --- validation AP ---------------------------------------------------------------------------

class _FixedMaps(torch.nn.Module):
    """A stand-in network returning fixed head maps: every cell logit −10 except those given."""

    def __init__(self, batch, height, width, hits):
        super().__init__()
        self.maps = [torch.full((batch, 5, height // s, width // s), -10.0) for s in STRIDES]
        for level, b, i, j in hits:
            self.maps[level][b, :, i, j] = torch.tensor([6.0, 0.0, 0.0, 0.0, 0.0])

    def forward(self, images):
        return tuple(m.clone() for m in self.maps)


def test_validation_ap_decodes_each_head_with_its_stride_and_counts_every_labelled_box():
    # one confident stride-8 box at cell (2, 4): centre (36, 20), 8 px → [32, 16, 40, 24]
    net = _FixedMaps(1, 64, 64, [(0, 0, 2, 4)])
    images = torch.zeros((1, 3, 64, 64))
    found = [torch.tensor([[32.0, 16.0, 40.0, 24.0]])]
    assert validate(net, [(images, found)]) == pytest.approx(1.0)
    # a second UAV in the same image that nothing found: recall 1/2
    two = [torch.tensor([[32.0, 16.0, 40.0, 24.0], [0.0, 40.0, 12.0, 52.0]])]
    assert validate(net, [(images, two)]) == pytest.approx(0.5)


def test_validation_clips_boxes_to_the_letterboxed_picture_as_the_runtime_clips_them_to_the_frame():
    """A UAV cut by the picture's top edge: the head's box runs into the padding above (IoU 1/3
    with the label), clipped to the picture it is the label (IoU 1). A box wholly in the padding
    below is dropped, not counted as a false positive."""
    net = _FixedMaps(1, 64, 64, [(0, 0, 0, 4), (0, 0, 7, 1)])
    net.maps[0][0, 3:5, 0, 4] = float(np.log(3.0))  # 24 x 24 px at (36, 4): [24, -8, 48, 16]
    images = torch.zeros((1, 3, 64, 64))
    cut = [torch.tensor([[24.0, 8.0, 48.0, 16.0]])]
    picture = [np.array([0.0, 8.0, 64.0, 56.0])]  # 8 px of padding above and below
    assert validate(net, [(images, cut)]) == pytest.approx(0.0)
    assert validate(net, [(images, cut)], contents=picture) == pytest.approx(1.0)


def test_the_picture_of_a_letterboxed_image_is_where_the_runtime_puts_the_frame(tmp_path):
    """The content of each image of a folder: the frame's corners mapped by the runtime's letterbox;
    the padding around it is grey."""
    from uav_landing_vision.detection.detector import PAD_VALUE
    from uav_landing_vision.detection.train import LetterboxedImages

    root = tmp_path / "wide"
    _write_folder(root, 2, size=(96, 40))
    data = LetterboxedImages([(str(root), 0), (str(root), 1)], (96, 64), seed=0, augment=False)
    _, runtime = letterbox(np.zeros((40, 96, 3), np.uint8), (96, 64), max_scale=1.0)
    want = runtime.to_input(np.array([[0.0, 0.0, 96.0, 40.0]]))[0]
    for k in range(2):
        np.testing.assert_allclose(data.content(k), want)
    x0, y0, x1, y1 = (int(v) for v in want)
    tensor = data[0][0].numpy()
    assert (x0, y0, x1, y1) == (0, 12, 96, 52)
    assert np.all(np.delete(tensor, np.s_[y0:y1], axis=1) == np.float32(PAD_VALUE / 255.0))
    assert not np.any(tensor[:, y0:y1] == np.float32(PAD_VALUE / 255.0))


# --- letterboxed training images -------------------------------------------------------------

def _write_folder(root, count, size=(96, 64), rect=(16, 8, 40, 32)):
    """A dataset folder of ``count`` lossless (PNG bytes) images: grey 200 with a dark 20 rectangle
    ``rect`` = [x0, y0, x1, y1] px, labelled."""
    w, h = size
    (root / "images").mkdir(parents=True)
    (root / "labels").mkdir()
    img = np.full((h, w, 3), 200, np.uint8)
    x0, y0, x1, y1 = rect
    img[y0:y1, x0:x1] = 20
    png = cv2.imencode(".png", img)[1].tobytes()
    line = f"0 {(x0 + x1) / 2 / w:.6f} {(y0 + y1) / 2 / h:.6f} {(x1 - x0) / w:.6f} {(y1 - y0) / h:.6f}\n"
    for i in range(count):
        (root / "images" / f"{i:06d}.jpg").write_bytes(png)
        (root / "labels" / f"{i:06d}.txt").write_text(line)
    (root / "dataset.json").write_text(json.dumps({"width": w, "height": h, "images": count}))
    return str(root)


def _dark_extent(tensor):
    dark = tensor.numpy().mean(axis=0) < 0.5
    cols, rows = np.flatnonzero(dark.any(axis=0)), np.flatnonzero(dark.any(axis=1))
    return np.array([cols[0], rows[0], cols[-1] + 1, rows[-1] + 1], float)


def test_a_flipped_training_image_has_its_box_flipped_with_it_and_flips_vary_by_epoch_and_folder(tmp_path):
    from uav_landing_vision.detection.train import LetterboxedImages

    roots = [_write_folder(tmp_path / name, 1) for name in ("a", "b")]
    data = LetterboxedImages([(roots[0], 0), (roots[1], 0)], (96, 64), seed=3, augment=True)
    flips = {0: [], 1: []}
    for epoch in range(16):
        data.epoch = epoch
        for k in (0, 1):
            tensor, boxes = data[k]
            assert tuple(tensor.shape) == (3, 64, 96) and boxes.shape == (1, 4)
            np.testing.assert_allclose(boxes[0].numpy(), _dark_extent(tensor), atol=1e-4)  # box on the UAV's pixels
            flips[k].append(bool(tensor[0, 10, 20] > 0.5))  # the rectangle spans x 16…40 unflipped
    assert any(flips[0]) and not all(flips[0])  # a new draw each epoch
    assert flips[0] != flips[1]  # and for each folder


def test_validation_images_are_neither_flipped_nor_cropped(tmp_path):
    from uav_landing_vision.detection.train import LetterboxedImages

    root = _write_folder(tmp_path / "a", 1)
    data = LetterboxedImages([(root, 0)], (96, 64), seed=0, augment=False, crop=(64, 32))
    for epoch in range(10):
        data.epoch = epoch
        tensor, boxes = data[0]
        assert tuple(tensor.shape) == (3, 64, 96)
        np.testing.assert_allclose(boxes.numpy(), [[16, 8, 40, 32]], atol=1e-4)


class _EdgeDraws:
    """A generator stand-in: ``random()`` 0 (the crop holds the centre) and ``integers`` at the
    low or high end of its range."""

    def __init__(self, high: bool):
        self.high = high

    def random(self):
        return 0.0

    def integers(self, low, high):
        return high - 1 if self.high else low


def test_a_crop_holding_the_first_boxs_centre_has_it_at_least_a_pixel_inside():
    """The crop's origin is drawn from [c − (size − 1), c − 1] (within the image): the first box's
    centre c is never on the crop's edge."""
    from uav_landing_vision.detection.train import random_crop

    y, x = np.mgrid[0:384, 0:640]
    img = np.stack([x % 256, y % 256, x // 256], axis=-1).astype(np.uint8)  # pixels encode their position
    for high, boxes, origin in ((False, np.array([[490.0, 250.0, 510.0, 270.0]]), (500 - 319, 260 - 191)),
                                (True, np.array([[290.0, 90.0, 310.0, 110.0]]), (299, 99))):
        crop, out = random_crop(img, boxes, (320, 192), _EdgeDraws(high))
        assert (int(crop[0, 0, 0]) + 256 * int(crop[0, 0, 2]), int(crop[0, 0, 1])) == origin
        np.testing.assert_allclose(out, np.clip(boxes - [*origin, *origin], 0, [320, 192, 320, 192]))


# --- the training run ------------------------------------------------------------------------

def test_every_tenth_image_validates_max_images_limits_each_folder_and_the_first_step_learns(tmp_path, monkeypatch):
    from uav_landing_vision.detection import train as training

    root = _write_folder(tmp_path / "data", 12)
    seen = {True: [], False: []}

    class Recording(training.LetterboxedImages):
        def __init__(self, items, *args, augment, **kwargs):
            seen[augment].append(sorted(i for _, i in items))
            super().__init__(items, *args, augment=augment, **kwargs)

    validated, inner = [], training.validate

    def validate(net, loader, contents=None):
        validated.append(contents)
        return inner(net, loader, contents=contents)

    monkeypatch.setattr(training, "LetterboxedImages", Recording)
    monkeypatch.setattr(training, "validate", validate)
    settings = dict(data=(root,), epochs=1, batch=2, input_size=(96, 64), crop=(0, 0), width=8, threads=1)
    training.train(training.TrainConfig(out=str(tmp_path / "all"), max_images=11, **settings), progress=False)
    assert seen[False][-1] == [0, 10] and seen[True][-1] == list(range(1, 10))
    np.testing.assert_array_equal(validated[-1], [[0.0, 0.0, 96.0, 64.0]] * 2)  # each validation image's picture
    # three images: image 0 validates, one batch of images 1 and 2 trains, one optimiser step
    cfg = training.TrainConfig(out=str(tmp_path / "three"), max_images=3, **settings)
    training.train(cfg, progress=False)
    assert seen[False][-1] == [0] and seen[True][-1] == [1, 2]
    torch.manual_seed(cfg.seed)
    start = UavDetectorNet(cfg.width).state_dict()
    trained = training.load_checkpoint(cfg)["net"]
    moved = [k for k in start if k.endswith("weight") and not torch.equal(start[k], trained[k])]
    assert len(moved) > 10  # the warm-up's first step has a learning rate above zero


def test_a_checkpoint_from_before_a_setting_existed_counts_it_as_its_default(tmp_path):
    from dataclasses import asdict

    from uav_landing_vision.detection.train import TrainConfig, load_checkpoint

    cfg = TrainConfig(out=str(tmp_path))
    old = {k: v for k, v in asdict(cfg).items() if k not in ("init", "loader_workers")}
    torch.save({"net": {}, "config": old, "epoch": 0}, tmp_path / "last.pt")
    assert load_checkpoint(cfg)["epoch"] == 0
    with pytest.raises(ValueError, match="other settings"):
        load_checkpoint(TrainConfig(out=str(tmp_path), loader_workers=1))


def test_input_and_crop_sizes_must_be_multiples_of_the_largest_stride():
    from uav_landing_vision.detection.train import TrainConfig

    for kwargs in ({"input_size": (328, 192)}, {"crop": (320, 200)}):
        with pytest.raises(ValueError, match="multiples of 32"):
            TrainConfig(**kwargs)
    TrainConfig(input_size=(4096, 192))  # the export's largest side is allowed


@pytest.fixture(scope="module")
def small_export(tmp_path_factory):
    """A width-8 network with two blocks in its first stage, exported; its BatchNorm shifts made
    non-zero so that every convolution keeps a bias input."""
    from uav_landing_vision.detection.export import export_onnx

    torch.manual_seed(0)
    net = UavDetectorNet(width=8, blocks=(2, 1, 1))
    with torch.no_grad():
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.bias.uniform_(0.1, 0.2)
    return export_onnx(net.eval(), tmp_path_factory.mktemp("small") / "det.onnx", (96, 64))


def test_weights_from_an_onnx_model_with_convolutions_the_network_lacks_are_refused(small_export):
    from uav_landing_vision.detection.train import weights_from_onnx

    with pytest.raises(ValueError, match="does not have"):
        weights_from_onnx(small_export, UavDetectorNet(width=8, blocks=(1, 1, 1)))


def test_the_exported_outputs_are_named_by_their_stride(small_export):
    """``p8``, ``p16``, ``p32``: the output named p<s> is the head map of stride s."""
    import onnxruntime as ort

    session = ort.InferenceSession(str(small_export), providers=["CPUExecutionProvider"])
    outputs = session.run(None, {"images": np.zeros((1, 3, 64, 96), np.float32)})
    names = [o.name for o in session.get_outputs()]
    assert names == ["p8", "p16", "p32"]
    for name, out in zip(names, outputs):
        s = int(name[1:])
        assert out.shape == (1, 5, 64 // s, 96 // s)


def test_the_verifier_export_records_the_crop_geometry_it_was_given(tmp_path):
    import onnx

    from uav_landing_vision.detection.export import export_verifier_onnx
    from uav_landing_vision.detection.network import BoxVerifierNet
    from uav_landing_vision.detection.verifier import CropGeometry

    geometry = CropGeometry(32, 2.0, 16)
    torch.manual_seed(0)
    path = export_verifier_onnx(BoxVerifierNet(4).eval(), tmp_path / "verifier.onnx", geometry)
    meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
    assert json.loads(meta["crop"]) == geometry._asdict() != CropGeometry()._asdict()
