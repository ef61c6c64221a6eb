"""Detector training on the CPU (torch; development only): targets, loss, resumable loop, export.

Targets: a UAV box goes to one head by its larger side in network-input pixels (stride 8
below 48 px, 16 below 144 px, else 32); its positive cells are the cell holding its centre
and those of the 3×3 neighbourhood whose centres fall inside the box. Loss: sigmoid focal
loss on objectness (all cells) + GIoU on the positives, both per positive. Every epoch
writes ``last.pt`` (network, optimiser, scheduler, RNG states) so ``--resume`` continues
bit for bit; the validation split (every 10th image of each folder) gives AP50 after each epoch.
"""

import json
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.nn import functional as F

from ..config import check_seed
from .dataset import read_labels
from .detector import decode, letterbox, nms
from .evaluation import average_precision, match_frame
from .export import MAX_EXPORT_SIDE
from .network import STRIDES, UavDetectorNet, decode_torch

LEVEL_LIMITS = (48.0, 144.0)  # larger box side (input px) separating the stride 8/16/32 heads
VAL_EVERY = 10  # image i is validation when i % VAL_EVERY == 0


def check_optimiser_settings(lr: float, weight_decay: float) -> None:
    """ValueError unless the learning rate is finite and positive and the weight decay finite and
    non-negative (the detector's and the verifier's trainers)."""
    if not (np.isfinite(lr) and lr > 0 and np.isfinite(weight_decay) and weight_decay >= 0):
        raise ValueError(f"need a finite lr > 0 and weight_decay ≥ 0, got {lr} and {weight_decay}")


@dataclass(frozen=True)
class TrainConfig:
    data: tuple[str, ...] = ("out/detection_data",)  # dataset folders, used together
    out: str = "out/detector_train"
    epochs: int = 30
    batch: int = 16
    lr: float = 2e-3
    weight_decay: float = 5e-4
    input_size: tuple[int, int] = (640, 384)  # (width, height) of the full-frame letterbox
    crop: tuple[int, int] = (320, 192)  # training crops of the letterboxed frame (0, 0: none)
    width: int = 48
    seed: int = 0
    threads: int = 2
    loader_workers: int = 0  # processes decoding images alongside the training (0: in the loop)
    max_images: int = 0  # use only the first N images of each folder (0: all)
    # Weights that start this run (fine-tuning): another run's checkpoint (last.pt), or an exported
    # model (.onnx), whose normalisation is folded into its convolutions (see weights_from_onnx).
    init: str = ""

    def __post_init__(self):
        check_seed(self.seed)
        if (self.epochs < 1 or self.batch < 1 or self.width < 8 or self.threads < 1 or self.loader_workers < 0
                or self.max_images < 0):
            raise ValueError("need epochs ≥ 1, batch ≥ 1, width ≥ 8, threads ≥ 1, loader_workers ≥ 0 "
                             "and max_images ≥ 0")
        check_optimiser_settings(self.lr, self.weight_decay)
        if min(self.input_size) <= 0 or (min(self.crop) <= 0 and tuple(self.crop) != (0, 0)):
            raise ValueError(f"input_size must be positive and crop positive or (0, 0), got {self.input_size} "
                             f"and {self.crop}")
        if any(s % max(STRIDES) for s in self.input_size + self.crop):
            raise ValueError(f"input_size and crop must be multiples of {max(STRIDES)}")
        if max(self.input_size) > MAX_EXPORT_SIDE:
            raise ValueError(f"input_size sides must be at most {MAX_EXPORT_SIDE} (the ONNX export's), got {self.input_size}")
        check_dataset_folders(self.data)


def check_dataset_folders(data) -> None:
    """ValueError for no dataset folder, or one given twice (its images would count twice)."""
    if not data:
        raise ValueError("no dataset folder given")
    seen = [Path(d).resolve() for d in data]
    if len(set(seen)) != len(seen):
        raise ValueError(f"a dataset folder is given more than once: {[str(d) for d in data]}")


class LetterboxedImages(torch.utils.data.Dataset):
    """Images ``(folder, index)`` of generated datasets, letterboxed to the input size; random
    horizontal flip and crop when augmenting."""

    def __init__(self, items, input_size, seed: int, augment: bool, crop=(0, 0)):
        self.items, self.input_size = list(items), input_size
        self.sizes = {}
        for root, _ in self.items:
            if root not in self.sizes:
                meta = json.loads((Path(root) / "dataset.json").read_text())
                self.sizes[root] = (meta["width"], meta["height"])
        self.folders = {root: n for n, root in enumerate(self.sizes)}
        self._contents = {}
        self.seed, self.augment, self.epoch, self.crop = seed, augment, 0, crop

    def __len__(self):
        return len(self.items)

    def content(self, k: int) -> np.ndarray:
        """``[x0, y0, x1, y1]`` of image ``k``'s picture in its letterboxed input, not augmented:
        what lies outside is padding."""
        root = self.items[k][0]
        if root not in self._contents:
            w, h = self.sizes[root]
            _, lb = letterbox(np.zeros((h, w, 3), np.uint8), self.input_size,
                              max_scale=min(self.input_size[0] / w, self.input_size[1] / h))
            self._contents[root] = lb.to_input(np.array([[0.0, 0.0, w, h]]))[0]
        return self._contents[root]

    def __getitem__(self, k):
        root, i = self.items[k]
        bgr = cv2.imread(str(Path(root) / "images" / f"{i:06d}.jpg"), cv2.IMREAD_COLOR)
        if bgr is None:
            raise FileNotFoundError(f"cannot read image {i} of {root}")
        h, w = bgr.shape[:2]  # scaled to fit the input, smaller frames enlarged, as the runtime does a frame
        img, lb = letterbox(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), self.input_size,
                            max_scale=min(self.input_size[0] / w, self.input_size[1] / h))
        boxes = lb.to_input(read_labels(Path(root) / "labels" / f"{i:06d}.txt", *self.sizes[root]))
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, self.epoch, self.folders[root], i]))
        if self.augment and rng.random() < 0.5:
            img = img[:, ::-1]
            boxes = np.stack([img.shape[1] - boxes[:, 2], boxes[:, 1], img.shape[1] - boxes[:, 0], boxes[:, 3]], 1)
        if self.augment and self.crop[0]:
            img, boxes = random_crop(img, boxes, self.crop, rng)
        tensor = torch.from_numpy(np.ascontiguousarray(img.transpose(2, 0, 1))).float().div_(255.0)
        return tensor, torch.from_numpy(boxes.astype(np.float32)).reshape(-1, 4)


def random_crop(img: np.ndarray, boxes: np.ndarray, size, rng: np.random.Generator):
    """A ``size`` = (w, h) crop holding the first box's centre 80 % of the time; boxes are
    clipped to it and dropped when less than 2 px wide or high."""
    cw, ch = min(size[0], img.shape[1]), min(size[1], img.shape[0])
    lo, hi = np.zeros(2), np.array([img.shape[1] - cw, img.shape[0] - ch], float)
    if len(boxes) and rng.random() < 0.8:
        centre = (boxes[0, :2] + boxes[0, 2:]) / 2
        lo, hi = np.maximum(lo, centre - [cw - 1, ch - 1]), np.minimum(hi, np.maximum(centre - 1, lo))
    x0, y0 = (int(rng.integers(int(a), int(max(a, b)) + 1)) for a, b in zip(lo, hi))
    out = boxes - [x0, y0, x0, y0]
    out = np.clip(out, 0, [cw, ch, cw, ch])
    keep = (out[:, 2] - out[:, 0] >= 2) & (out[:, 3] - out[:, 1] >= 2)
    return img[y0 : y0 + ch, x0 : x0 + cw], out[keep]


def collate(batch):
    return torch.stack([b[0] for b in batch]), [b[1] for b in batch]


def build_targets(boxes_per_image, height: int, width: int):
    """Per stride: positive mask (B,h,w) bool and target boxes (B,h,w,4) in input pixels."""
    out = []
    for stride in STRIDES:
        h, w = height // stride, width // stride
        pos = torch.zeros(len(boxes_per_image), h, w, dtype=torch.bool)
        target = torch.zeros(len(boxes_per_image), h, w, 4)
        out.append((pos, target, stride))
    for b, boxes in enumerate(boxes_per_image):
        # Larger boxes first, so a smaller one that shares a cell wins it.
        order = torch.argsort(-(boxes[:, 2:] - boxes[:, :2]).prod(1)) if len(boxes) else []
        for box in boxes[order] if len(boxes) else []:
            side = float((box[2:] - box[:2]).max())
            pos, target, stride = out[int(side >= LEVEL_LIMITS[0]) + int(side >= LEVEL_LIMITS[1])]
            h, w = pos.shape[1:]
            cx, cy = float(box[0] + box[2]) / 2, float(box[1] + box[3]) / 2
            ci, cj = min(max(int(cy // stride), 0), h - 1), min(max(int(cx // stride), 0), w - 1)
            for i in range(max(ci - 1, 0), min(ci + 2, h)):
                for j in range(max(cj - 1, 0), min(cj + 2, w)):
                    mx, my = (j + 0.5) * stride, (i + 0.5) * stride
                    inside = box[0] < mx < box[2] and box[1] < my < box[3]
                    if (i, j) == (ci, cj) or inside:
                        pos[b, i, j] = True
                        target[b, i, j] = box
    return out


def giou_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """1 − GIoU of matching ``[x0,y0,x1,y1]`` boxes (N,4)."""
    lt, rb = torch.maximum(pred[:, :2], target[:, :2]), torch.minimum(pred[:, 2:], target[:, 2:])
    inter = (rb - lt).clamp(min=0).prod(1)
    area_p, area_t = (pred[:, 2:] - pred[:, :2]).prod(1), (target[:, 2:] - target[:, :2]).prod(1)
    union = area_p + area_t - inter + 1e-7
    hull = (torch.maximum(pred[:, 2:], target[:, 2:]) - torch.minimum(pred[:, :2], target[:, :2])).prod(1) + 1e-7
    return 1.0 - inter / union + (hull - union) / hull


def detection_loss(outputs, targets, alpha: float = 0.25, gamma: float = 2.0):
    """(total, objectness, box) losses, each normalised by the number of positive cells."""
    obj_loss, box_loss, n_pos = 0.0, 0.0, 0
    for raw, (pos, target, stride) in zip(outputs, targets):
        logits, boxes = decode_torch(raw, stride)
        y = pos.float()
        p = torch.sigmoid(logits)
        ce = F.binary_cross_entropy_with_logits(logits, y, reduction="none")
        p_t = p * y + (1 - p) * (1 - y)
        obj_loss = obj_loss + ((alpha * y + (1 - alpha) * (1 - y)) * (1 - p_t) ** gamma * ce).sum()
        if pos.any():
            box_loss = box_loss + giou_loss(boxes[pos], target[pos]).sum()
        n_pos += int(pos.sum())
    n = max(n_pos, 1)
    obj_loss, box_loss = obj_loss / n, box_loss / n
    return obj_loss + 2.0 * box_loss, obj_loss, box_loss


def validate(net, loader, threshold: float = 0.01, contents=None) -> float:
    """AP50 of the network on a loader (numpy decode + NMS, as the runtime); leaves the network
    in eval mode, and the training loop restores its training mode (:func:`set_training`).

    ``contents``: per image in the loader's order, the ``[x0, y0, x1, y1]`` of its picture in the
    letterbox (:meth:`LetterboxedImages.content`); boxes are clipped to it and those left empty
    dropped before NMS, as the runtime clips them to the frame."""
    net.eval()
    scores, tps, n_gt, k = [], [], 0, 0
    with torch.no_grad():
        for images, boxes in loader:
            outputs = [o.numpy() for o in net(images)]
            for b, gt in enumerate(boxes):
                parts = [decode(o[b], s, threshold) for o, s in zip(outputs, STRIDES)]
                pb, ps = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
                if contents is not None:
                    x0, y0, x1, y1 = contents[k]
                    pb = np.clip(pb, [x0, y0, x0, y0], [x1, y1, x1, y1]).astype(np.float32)
                    inside = (pb[:, 2] > pb[:, 0]) & (pb[:, 3] > pb[:, 1])
                    pb, ps = pb[inside], ps[inside]
                k += 1
                keep = nms(pb, ps, 0.45, 10)
                tp, _ = match_frame(pb[keep], ps[keep], gt.numpy())
                scores.append(ps[keep])
                tps.append(tp)
                n_gt += len(gt)
    return average_precision(np.concatenate(scores), np.concatenate(tps), n_gt)[0] if scores else 0.0


def train(cfg: TrainConfig, resume: bool = False, progress: bool = True) -> dict:
    """Train (or continue training) into ``cfg.out``; returns the training log."""
    from tqdm import tqdm

    out = Path(cfg.out)
    check_new_run(out, resume)
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    val_items, train_items, shapes = [], [], {}
    for root in cfg.data:
        meta_path = Path(root) / "dataset.json"
        if not meta_path.is_file():
            raise FileNotFoundError(f"{root} is not a dataset made by make-detection-data (no dataset.json)")
        meta = json.loads(meta_path.read_text())
        shape = letterbox(np.zeros((meta["height"], meta["width"], 3), np.uint8), cfg.input_size,
                          max_scale=min(cfg.input_size[0] / meta["width"], cfg.input_size[1] / meta["height"]))[0].shape
        shapes.setdefault(shape[:2], root)
        if len(shapes) > 1:
            raise ValueError(f"the frames of {root} ({meta['width']}x{meta['height']}) and of {shapes[next(iter(shapes))]} "
                             f"letterbox to different sizes at {cfg.input_size[0]}x{cfg.input_size[1]}: "
                             "train on folders of one frame shape")
        images = meta["images"]
        count = images if cfg.max_images <= 0 else min(cfg.max_images, images)
        val_items += [(root, i) for i in range(count) if i % VAL_EVERY == 0]
        train_items += [(root, i) for i in range(count) if i % VAL_EVERY != 0]
    train_set = LetterboxedImages(train_items, cfg.input_size, cfg.seed, augment=True, crop=cfg.crop)
    val_set = LetterboxedImages(val_items, cfg.input_size, cfg.seed, augment=False)
    shuffle = torch.Generator().manual_seed(cfg.seed)
    train_loader = torch.utils.data.DataLoader(train_set, cfg.batch, shuffle=True, generator=shuffle,
                                               collate_fn=collate, drop_last=len(train_set) > cfg.batch,
                                               num_workers=cfg.loader_workers)
    val_loader = torch.utils.data.DataLoader(val_set, cfg.batch, collate_fn=collate, num_workers=cfg.loader_workers)
    val_contents = [val_set.content(k) for k in range(len(val_set))]

    net = UavDetectorNet(cfg.width)
    if cfg.init and not resume:
        try:
            net.load_state_dict(initial_weights(cfg.init, net))
        except RuntimeError as exc:  # torch's size mismatches
            raise ValueError(f"{cfg.init} does not fit a network of width {cfg.width}: {exc}") from exc
    optim = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    total = cfg.epochs * len(train_loader)
    warm = max(1, total // 20)
    sched = torch.optim.lr_scheduler.LambdaLR(  # linear warm-up over 5 %, then cosine decay
        optim, lambda k: (k + 1) / warm if k < warm else 0.5 * (1 + np.cos(np.pi * (k - warm) / max(1, total - warm))))
    log = {"config": asdict(cfg), "train_images": len(train_items), "val_images": len(val_items), "epochs": []}
    start_epoch, ckpt = 0, out / "last.pt"
    if resume:
        state = restore(cfg, net, optim, sched)
        shuffle.set_state(state["shuffle_rng"])
        start_epoch, log = state["epoch"] + 1, state["log"]

    # A resumed run keeps its own (its start may be gone); a checkpoint older than the flag asks its start.
    frozen = state["frozen_normalisation"] if resume and "frozen_normalisation" in state else folded_normalisation(cfg)
    set_training(net, frozen)
    out.mkdir(parents=True, exist_ok=True)  # now that the inputs are known good
    for epoch in range(start_epoch, cfg.epochs):
        train_set.epoch = epoch
        t0, totals, n = time.perf_counter(), np.zeros(3), 0
        bar = tqdm(train_loader, desc=f"epoch {epoch + 1}/{cfg.epochs}", unit="batch", disable=not progress)
        for images, boxes in bar:
            targets = build_targets(boxes, images.shape[2], images.shape[3])
            loss, obj, box = detection_loss(net(images), targets)
            optim.zero_grad(set_to_none=True)
            loss.backward()
            optim.step()
            sched.step()
            totals += [float(torch.as_tensor(v).detach()) for v in (loss, obj, box)]
            n += 1
            bar.set_postfix(loss=f"{totals[0] / n:.3f}")
        seconds = time.perf_counter() - t0
        ap50 = validate(net, val_loader, contents=val_contents)
        set_training(net, frozen)
        log["epochs"].append({"epoch": epoch + 1, "loss": totals[0] / max(n, 1), "obj": totals[1] / max(n, 1),
                              "box": totals[2] / max(n, 1), "val_ap50": ap50, "seconds": seconds,
                              "images_per_s": len(train_set) / seconds})
        print(json.dumps(log["epochs"][-1]))
        torch.save({"config": asdict(cfg), "epoch": epoch, "net": net.state_dict(), "frozen_normalisation": frozen,
                    "optim": optim.state_dict(),
                    "sched": sched.state_dict(), "shuffle_rng": shuffle.get_state(),
                    "torch_rng": torch.get_rng_state(), "log": log}, out / "last.tmp")
        (out / "last.tmp").replace(ckpt)
    (out / "train_log.json").write_text(json.dumps(log, indent=2))
    return log


def check_new_run(out: Path, resume: bool) -> None:
    """ValueError when a run that is not a resumption would overwrite the checkpoint in ``out``."""
    if not resume and (out / "last.pt").exists():
        raise ValueError(f"{out} holds a run already (last.pt): give --resume to continue it, or choose a new folder")


def folded_normalisation(cfg: TrainConfig) -> bool:
    """Whether the run's batch normalisation stays frozen: it starts from an exported model, or
    from the checkpoint of a run that did (whose BatchNorm layers still hold the folded identity;
    set training, they normalised by batch statistics and the starting network was lost)."""
    if not cfg.init:
        return False
    if Path(cfg.init).suffix == ".onnx":
        return True
    state = _checkpoint(Path(cfg.init))
    return bool(state.get("frozen_normalisation", Path(state["config"].get("init", "")).suffix == ".onnx"))


def set_training(net: UavDetectorNet, frozen_normalisation: bool) -> None:
    """Training mode; with ``frozen_normalisation`` the BatchNorm layers keep their running
    statistics and normalise with them (their scale and shift still learn)."""
    net.train()
    if frozen_normalisation:
        for module in net.modules():
            if isinstance(module, torch.nn.BatchNorm2d):
                module.eval()


def initial_weights(path, net: UavDetectorNet) -> dict:
    """The weights to fine-tune ``net`` from: another run's checkpoint or an exported model."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint {path} to start from")
    if path.suffix == ".onnx":
        return weights_from_onnx(path, net)
    return _checkpoint(path)["net"]


def _checkpoint(path: Path) -> dict:
    """A training checkpoint (``last.pt``); ValueError naming the file for anything else."""
    try:
        state = torch.load(path, weights_only=False)
    except Exception as exc:  # pickle, zip and torch errors of a file that is no checkpoint
        raise ValueError(f"{path} is not a training checkpoint: {exc}") from exc
    if not (isinstance(state, dict) and "net" in state and "config" in state):
        raise ValueError(f"{path} is not a training checkpoint (no network and settings in it)")
    return state


def weights_from_onnx(path, net: UavDetectorNet) -> dict:
    """``net``'s state dict holding the weights of an exported model of the same architecture.

    The export folds each BatchNorm into the convolution before it (weight ``W``, new bias
    ``b``). Here the convolution takes ``W`` and the BatchNorm becomes the identity plus ``b``
    (running mean 0, variance 1, scale √(1 + eps)), so the network computes what the model does
    as long as that BatchNorm is in eval mode (:func:`set_training`). Each ONNX convolution is
    matched to the module named by its weight; the exporter may share equal biases between
    convolutions, so those are read through the node's inputs, and leaves out a bias that is all
    zeros (a BatchNorm at its initial state), so a convolution without one has a zero bias."""
    import onnx
    from onnx import numpy_helper

    graph = onnx.load(str(path)).graph
    arrays = {i.name: numpy_helper.to_array(i) for i in graph.initializer}
    convs = {}
    for node in graph.node:
        if node.op_type == "Conv" and node.input[1].endswith(".weight"):
            weight = arrays[node.input[1]]
            bias = arrays[node.input[2]] if len(node.input) == 3 and node.input[2] else np.zeros(len(weight), weight.dtype)
            convs[node.input[1].removesuffix(".weight")] = (weight, bias)
    state = {k: v.clone() for k, v in net.state_dict().items()}
    modules = dict(net.named_modules())
    for name, module in modules.items():
        if not isinstance(module, torch.nn.Conv2d):
            continue
        weight, bias = convs.pop(name, (None, None))
        if weight is None or weight.shape != tuple(state[f"{name}.weight"].shape):
            raise ValueError(f"{path}: no convolution {name} of shape {tuple(state[f'{name}.weight'].shape)}")
        state[f"{name}.weight"] = torch.from_numpy(weight.copy())
        bias = torch.from_numpy(bias.copy())
        if module.bias is not None:
            state[f"{name}.bias"] = bias
            continue
        parent, _, index = name.rpartition(".")
        norm = f"{parent}.{int(index) + 1}"  # conv_bn: Conv2d, then its BatchNorm2d
        if not isinstance(modules.get(norm), torch.nn.BatchNorm2d):
            raise ValueError(f"{name} has no bias and no BatchNorm after it")
        state[f"{norm}.weight"] = torch.full_like(bias, float(np.sqrt(1.0 + modules[norm].eps)))
        state[f"{norm}.bias"] = bias
        state[f"{norm}.running_mean"] = torch.zeros_like(bias)
        state[f"{norm}.running_var"] = torch.ones_like(bias)
    if convs:
        raise ValueError(f"{path}: convolutions this network does not have: {sorted(convs)[:5]}")
    return state


def restore(cfg, net, optim, sched) -> dict:
    """Load the run's checkpoint (:func:`load_checkpoint`) into the network, optimiser,
    scheduler and torch's RNG; returns it for the rest of its state."""
    state = load_checkpoint(cfg)
    net.load_state_dict(state["net"])
    optim.load_state_dict(state["optim"])
    sched.load_state_dict(state["sched"])
    torch.set_rng_state(state["torch_rng"])
    return state


def load_checkpoint(cfg) -> dict:
    """The ``last.pt`` of the run ``cfg`` (a training config with ``out``: this module's or the
    verifier's); FileNotFoundError without one, ValueError if other settings made it."""
    ckpt = Path(cfg.out) / "last.pt"
    if not ckpt.exists():
        raise FileNotFoundError(f"no checkpoint {ckpt}")
    state = _checkpoint(ckpt)
    # Settings added since the checkpoint was written count as their defaults.
    saved, given = {**{f.name: f.default for f in fields(cfg)}, **state["config"]}, asdict(cfg)
    differ = [f"{k}: {saved.get(k)!r} there, {given.get(k)!r} here" for k in sorted(saved.keys() | given.keys())
              if saved.get(k) != given.get(k)]
    if differ:
        raise ValueError(f"{ckpt} was made with other settings ({'; '.join(differ)}); give the same to use it")
    return state


def trained_network(cfg: TrainConfig, state: dict) -> UavDetectorNet:
    """The network of a checkpoint ``state`` of the run ``cfg``, in eval mode."""
    net = UavDetectorNet(cfg.width)
    net.load_state_dict(state["net"])
    return net.eval()
