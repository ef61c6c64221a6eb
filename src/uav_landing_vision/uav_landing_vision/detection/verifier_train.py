"""Box verifier training on the CPU (torch; development only): crops mined with the detector,
a small classifier, resumable.

Mining runs the detector (without a verifier) over generated datasets at a low threshold. A
box overlapping a labelled UAV by IoU ≥ ``positive_iou`` is a positive, one overlapping none
by more than ``negative_iou`` a negative (the crests, glint and cloud edges the detector
mistakes), and the ones between are left out. Each labelled UAV at least 4 px wide adds a
positive crop of its label box shifted by N(0, 10 %) of its size and scaled by e^N(0, 0.15)
per axis, so the verifier also sees the UAVs the detector scores low. Image *i* of folder *f*
draws from ``SeedSequence([seed, f, i])``, so the crops do not depend on the number of
processes. Every 10th image of each folder is validation, as in the detector's training.
"""

import hashlib
import json
import time
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
from torch.nn import functional as F

from ..config import check_seed
from .dataset import read_labels
from .detector import Detector, DetectorConfig, box_iou
from .evaluation import average_precision
from .network import BoxVerifierNet
from .train import VAL_EVERY, check_dataset_folders, check_new_run, check_optimiser_settings, restore
from .verifier import CropGeometry, box_crops, crop_blob

MINE_MAX_BOXES = 20  # candidate boxes per image


@dataclass(frozen=True)
class VerifierTrainConfig:
    data: tuple[str, ...] = ("out/detection_data",)  # dataset folders, used together
    out: str = "out/verifier_train"
    detector: str = "detector.onnx"  # the detector whose boxes are mined
    mine_threshold: float = 0.1
    positive_iou: float = 0.4
    negative_iou: float = 0.05
    epochs: int = 6
    batch: int = 128
    lr: float = 2e-3
    weight_decay: float = 1e-4
    width: int = 16
    seed: int = 0
    threads: int = 2
    workers: int = 2  # mining processes

    def __post_init__(self):
        check_seed(self.seed)
        if self.epochs < 1 or self.batch < 2 or self.width < 4 or self.threads < 1 or self.workers < 1:
            raise ValueError("need epochs ≥ 1, batch ≥ 2, width ≥ 4, threads ≥ 1, workers ≥ 1")
        check_optimiser_settings(self.lr, self.weight_decay)
        if not 0 < self.mine_threshold < 1 or not 0 <= self.negative_iou < self.positive_iou <= 1:
            raise ValueError("need 0 < mine_threshold < 1 and 0 ≤ negative_iou < positive_iou ≤ 1")
        check_dataset_folders(self.data)

    def mining(self) -> dict:
        """The settings the mined crops depend on."""
        return {k: getattr(self, k) for k in ("data", "detector", "mine_threshold", "positive_iou", "negative_iou", "seed")}


_miner: tuple = ()  # (config, detector) of a mining process, made once by _start_miner


def _mining_detector(cfg: VerifierTrainConfig) -> Detector:
    return Detector(DetectorConfig(model=cfg.detector, verifier="", score_threshold=cfg.mine_threshold,
                                   max_detections=MINE_MAX_BOXES, threads=1))


def _start_miner(cfg: VerifierTrainConfig) -> None:
    global _miner
    _miner = (cfg, _mining_detector(cfg))


def _mine_images(items) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    cfg, detector = _miner
    out = []
    for folder, i in items:
        root = Path(cfg.data[folder])
        bgr = cv2.imread(str(root / "images" / f"{i:06d}.jpg"), cv2.IMREAD_COLOR)
        if bgr is None:
            raise FileNotFoundError(f"cannot read image {i} of {root}")
        image = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        truth = read_labels(root / "labels" / f"{i:06d}.txt", image.shape[1], image.shape[0])
        found = detector.detect(image).boxes
        overlap = box_iou(found, truth).max(axis=1) if len(truth) else np.zeros(len(found))
        label = np.where(overlap >= cfg.positive_iou, 1, np.where(overlap <= cfg.negative_iou, 0, -1))
        rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, folder, i]))
        size = truth[:, 2:] - truth[:, :2]
        truth, size = truth[size[:, 0] >= 4], size[size[:, 0] >= 4]
        centre = (truth[:, :2] + truth[:, 2:]) / 2 + rng.normal(0.0, 0.1, size.shape) * size
        half = size * np.exp(rng.normal(0.0, 0.15, size.shape)) / 2
        jittered = np.concatenate([centre - half, centre + half], axis=1)
        boxes = np.concatenate([found[label >= 0], jittered])
        labels = np.concatenate([label[label >= 0], np.ones(len(jittered), int)])
        source = np.concatenate([np.zeros((label >= 0).sum(), int), np.ones(len(jittered), int)])
        out.append((box_crops(image, boxes, CropGeometry()), labels, source))
    return out


def mine_crops(cfg: VerifierTrainConfig, progress: bool = True) -> dict:
    """Crops, labels (1 UAV, 0 not), source (0 detector box, 1 jittered label) and validation
    flags of every image of the datasets; cached in ``OUT/crops.npz`` for the same settings."""
    from multiprocessing import get_context

    from tqdm import tqdm

    path = Path(cfg.out) / "crops.npz"
    # Loaded here first: a pool whose initializer fails restarts its workers for ever.
    detector_file = _mining_detector(cfg).model_path
    items, records = [], []
    for folder, root in enumerate(cfg.data):
        meta_path = Path(root) / "dataset.json"
        if not meta_path.is_file():
            raise FileNotFoundError(f"{root} is not a dataset made by make-detection-data (no dataset.json)")
        records.append(json.loads(meta_path.read_text()))
        items += [(folder, i) for i in range(records[-1]["images"])]
    # The crops depend on the settings, and on the files behind the names: the detector's bytes
    # and each dataset's record (a model retrained, or a dataset made again, in the same place).
    mining = json.dumps({**cfg.mining(), "detector_sha256": hashlib.sha256(detector_file.read_bytes()).hexdigest(),
                         "datasets": records})
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as cached:
                if json.loads(str(cached["mining"])) == json.loads(mining):
                    return {k: cached[k] for k in ("crops", "labels", "source", "validation")}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile):  # a damaged cache is mined again
            pass
    chunks = [items[k : k + 50] for k in range(0, len(items), 50)]
    parts = []
    with get_context("spawn").Pool(cfg.workers, _start_miner, (cfg,)) as pool, \
            tqdm(total=len(items), desc="mining", unit="image", disable=not progress) as bar:
        for chunk in pool.imap(_mine_images, chunks):
            parts.append(chunk)
            bar.update(len(chunk))
    per_image = [p for chunk in parts for p in chunk]
    counts = [len(p[1]) for p in per_image]
    mined = {
        "crops": np.concatenate([p[0] for p in per_image]),
        "labels": np.concatenate([p[1] for p in per_image]).astype(np.int8),
        "source": np.concatenate([p[2] for p in per_image]).astype(np.int8),
        "validation": np.repeat([i % VAL_EVERY == 0 for _, i in items], counts),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_suffix(".tmp"), "wb") as f:
        np.savez(f, mining=mining, **mined)
    path.with_suffix(".tmp").replace(path)
    return mined


def augment(crops: np.ndarray, rng: np.random.Generator) -> torch.Tensor:
    """A batch of uint8 crops as a float tensor, flipped left–right at random, with random gain
    (×0.7–1.3) and per-channel offsets (σ 0.05)."""
    x = crops.astype(np.float32) / 255.0
    flip = rng.random(len(x)) < 0.5
    x[flip] = x[flip, :, ::-1]
    x = x * rng.uniform(0.7, 1.3, (len(x), 1, 1, 1)) + rng.normal(0.0, 0.05, (len(x), 1, 1, 3))
    return torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2), np.float32))


def predict(net: BoxVerifierNet, crops: np.ndarray, batch: int = 512) -> np.ndarray:
    """Probabilities of uint8 crops (eval mode)."""
    net.eval()
    out = []
    with torch.no_grad():
        for k in range(0, len(crops), batch):
            out.append(torch.sigmoid(net(torch.from_numpy(crop_blob(crops[k : k + batch])))[:, 0]).numpy())
    return np.concatenate(out) if out else np.zeros(0, np.float32)


def validation_metrics(prob: np.ndarray, labels: np.ndarray) -> dict:
    """Average precision, and the share of positives kept and negatives rejected at 0.5."""
    positive = labels == 1
    return {"ap": average_precision(prob, positive, int(positive.sum()))[0],
            "positives_kept": float((prob[positive] >= 0.5).mean()) if positive.any() else None,
            "negatives_rejected": float((prob[~positive] < 0.5).mean()) if (~positive).any() else None}


def train_verifier(cfg: VerifierTrainConfig, resume: bool = False, progress: bool = True) -> dict:
    """Mine (or reuse) the crops, then train (or continue) into ``cfg.out``; returns the log."""
    from tqdm import tqdm

    out = Path(cfg.out)
    check_new_run(out, resume)
    mined = mine_crops(cfg, progress)  # writes out/crops.npz, making the folder
    train_idx, val_idx = np.flatnonzero(~mined["validation"]), np.flatnonzero(mined["validation"])
    crops, labels = mined["crops"], (mined["labels"] == 1).astype(np.float32)
    if not len(train_idx) or labels[train_idx].min() == labels[train_idx].max():
        raise ValueError("the mined training crops need both UAV and non-UAV boxes")
    if len(train_idx) < cfg.batch:
        raise ValueError(f"only {len(train_idx)} training crops, fewer than one batch of {cfg.batch}; lower the batch")
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    net = BoxVerifierNet(cfg.width)
    optim = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    steps = len(train_idx) // cfg.batch
    sched = torch.optim.lr_scheduler.OneCycleLR(optim, cfg.lr, total_steps=cfg.epochs * steps)
    share = labels[train_idx].mean()
    pos_weight = torch.tensor((1.0 - share) / share)  # balances the classes
    log = {"config": asdict(cfg), "train_crops": len(train_idx), "val_crops": len(val_idx),
           "train_positive_share": float(share), "epochs": []}
    start = 0
    if resume:
        state = restore(cfg, net, optim, sched)
        start, log = state["epoch"] + 1, state["log"]
    for epoch in range(start, cfg.epochs):
        rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, epoch]))
        order = rng.permutation(train_idx)
        net.train()
        t0, total = time.perf_counter(), 0.0
        bar = tqdm(range(steps), desc=f"epoch {epoch + 1}/{cfg.epochs}", unit="batch", disable=not progress)
        for k in bar:
            idx = np.sort(order[k * cfg.batch : (k + 1) * cfg.batch])
            loss = F.binary_cross_entropy_with_logits(net(augment(crops[idx], rng))[:, 0],
                                                      torch.from_numpy(labels[idx]), pos_weight=pos_weight)
            optim.zero_grad(set_to_none=True)
            loss.backward()
            optim.step()
            sched.step()
            total += float(loss.detach())
            bar.set_postfix(loss=f"{total / (k + 1):.3f}")
        entry = {"epoch": epoch + 1, "loss": total / max(steps, 1), "seconds": time.perf_counter() - t0}
        if len(val_idx):
            entry.update({f"val_{k}": v for k, v in validation_metrics(predict(net, crops[val_idx]),
                                                                       mined["labels"][val_idx]).items()})
        log["epochs"].append(entry)
        print(json.dumps(entry))
        torch.save({"config": asdict(cfg), "epoch": epoch, "net": net.state_dict(), "optim": optim.state_dict(),
                    "sched": sched.state_dict(), "torch_rng": torch.get_rng_state(), "log": log}, out / "last.tmp")
        (out / "last.tmp").replace(out / "last.pt")
    (out / "train_log.json").write_text(json.dumps(log, indent=2))
    return log


def trained_verifier(cfg: VerifierTrainConfig, state: dict) -> BoxVerifierNet:
    """The network of a checkpoint ``state`` of the run ``cfg``, in eval mode."""
    net = BoxVerifierNet(cfg.width)
    net.load_state_dict(state["net"])
    return net.eval()
