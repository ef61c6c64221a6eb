"""UAV detector runtime (§4.2): onnxruntime inference, letterbox, decode, threshold, NMS, and
the second look of the box verifier (:mod:`.verifier`).

Needs only numpy, OpenCV and onnxruntime. Frames are rectified RGB uint8 ``(H, W, 3)``.
Boxes are ``[x0, y0, x1, y1]`` in continuous pixel coordinates where pixel (u, v) covers
``[u, u+1) × [v, v+1)`` (so a box's edges are the ROI's edges; ``sensor_msgs/RegionOfInterest``
is :meth:`Detections.rois`). The network's raw head maps and their decoding are described in
:func:`decode` (same formula as :func:`.network.decode_torch`).
"""

import json
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

MAX_LOG_SIZE = 6.0  # = network.MAX_LOG_SIZE (the runtime does not import torch)
PAD_VALUE = 114
DEFAULT_MODEL = "detector.onnx"
MAX_THREADS = 256  # onnxruntime intra-op threads; more than a ship PC has cores


@dataclass(frozen=True)
class DetectorConfig:
    """Detector settings (``config/detector.yaml`` section ``detector``)."""

    model: str = DEFAULT_MODEL  # a file of the shipped models/ folder, or a path
    # Box verifier (a shipped file such as "verifier.onnx", or a path; "" for none): a box it
    # gives a probability of holding the UAV below verifier_threshold is dropped; the others
    # keep their scores. Off by default: the tracker's settings were chosen without it.
    verifier: str = ""
    verifier_threshold: float = 0.5
    score_threshold: float = 0.5  # the operating threshold
    nms_iou: float = 0.45
    max_detections: int = 10
    threads: int = 2  # onnxruntime intra-op threads
    window_grow: float = 3.0  # search window side = this × the predicted ROI's larger side
    window_min_px: int = 192  # ... and at least this

    def __post_init__(self):
        if not 0.0 < self.score_threshold < 1.0 or not 0.0 < self.nms_iou <= 1.0:
            raise ValueError("score_threshold must be in (0, 1) and nms_iou in (0, 1]")
        if not 0.0 <= self.verifier_threshold < 1.0:
            raise ValueError("verifier_threshold must be in [0, 1)")
        if not 1.0 <= self.window_grow <= 100.0:  # a larger window is the whole frame
            raise ValueError(f"window_grow must be within 1 to 100, got {self.window_grow}")
        if self.max_detections < 1 or not 1 <= self.threads <= MAX_THREADS or self.window_min_px < 32:
            raise ValueError(f"need max_detections ≥ 1, 1 ≤ threads ≤ {MAX_THREADS}, window_min_px ≥ 32")


class Detections(NamedTuple):
    """``boxes (N,4)`` float32 ``[x0,y0,x1,y1]`` (full-image pixels) and ``scores (N,)``, best first."""

    boxes: np.ndarray
    scores: np.ndarray

    def rois(self, width: int, height: int) -> np.ndarray:
        """Integer ROIs ``(N,4)`` ``[x, y, w, h]`` covering the boxes, clipped to the image."""
        x0 = np.clip(np.floor(self.boxes[:, 0]), 0, width - 1)
        y0 = np.clip(np.floor(self.boxes[:, 1]), 0, height - 1)
        x1 = np.clip(np.ceil(self.boxes[:, 2]), x0 + 1, width)
        y1 = np.clip(np.ceil(self.boxes[:, 3]), y0 + 1, height)
        return np.stack([x0, y0, x1 - x0, y1 - y0], axis=1).astype(np.int64)


class Letterbox(NamedTuple):
    """Image → network input mapping: ``x_in = scale_x · x_img + pad_x``, ``y_in = scale_y · y_img +
    pad_y``; ``scale`` is the one asked for, ``scale_x``/``scale_y`` those of the resize to whole
    pixels (they differ from it by up to half an input pixel across the frame)."""

    scale: float
    pad_x: int
    pad_y: int
    scale_x: float
    scale_y: float

    def to_image(self, boxes: np.ndarray) -> np.ndarray:
        """Boxes ``(N,4)`` from network-input to image pixels."""
        pad = np.array([self.pad_x, self.pad_y, self.pad_x, self.pad_y], np.float32)
        return (np.asarray(boxes, np.float32) - pad) / self._scales()

    def to_input(self, boxes: np.ndarray) -> np.ndarray:
        """Boxes ``(N,4)`` from image to network-input pixels."""
        pad = np.array([self.pad_x, self.pad_y, self.pad_x, self.pad_y], np.float32)
        return np.asarray(boxes, np.float32) * self._scales() + pad

    def _scales(self) -> np.ndarray:
        return np.array([self.scale_x, self.scale_y, self.scale_x, self.scale_y], np.float32)


def check_image(image) -> np.ndarray:
    """The frame as a contiguous uint8 ``(H, W, 3)`` array, or a ValueError saying what is wrong."""
    if not isinstance(image, np.ndarray):
        raise ValueError(f"image must be a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise ValueError(f"image must be uint8 RGB, got dtype {image.dtype}")
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) RGB, got shape {image.shape}")
    if image.shape[0] == 0 or image.shape[1] == 0:
        raise ValueError(f"image is empty: shape {image.shape}")
    return np.ascontiguousarray(image)


def letterbox(image: np.ndarray, size: tuple[int, int], multiple: int = 32,
              max_scale: float = 1.0, border: int = cv2.BORDER_CONSTANT) -> tuple[np.ndarray, Letterbox]:
    """Resize ``image`` to fit in ``size`` = (width, height) keeping its aspect (scale ≤
    ``max_scale``), centre it and pad to the next multiple of ``multiple``: with grey, or with
    ``border`` (an OpenCV border mode such as ``cv2.BORDER_REPLICATE``)."""
    h, w = image.shape[:2]
    scale = min(size[0] / w, size[1] / h, max_scale)
    nw, nh = max(1, round(w * scale)), max(1, round(h * scale))
    pw, ph = -(-nw // multiple) * multiple, -(-nh // multiple) * multiple
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    resized = image if (nw, nh) == (w, h) else cv2.resize(image, (nw, nh), interpolation=interp)
    px, py = (pw - nw) // 2, (ph - nh) // 2
    out = cv2.copyMakeBorder(resized, py, ph - nh - py, px, pw - nw - px, border,
                             value=(PAD_VALUE,) * image.shape[2] if image.ndim == 3 else PAD_VALUE)
    return out, Letterbox(scale, px, py, nw / w, nh / h)


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 0.5 * (1.0 + np.tanh(0.5 * np.asarray(x)))  # σ without exp's overflow for large −x


def decode(raw: np.ndarray, stride: int, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """Boxes ``(K,4)`` (input pixels) and scores ``(K,)`` of the cells of one head map
    ``raw (5, H, W)`` = ``[logit, tx, ty, tw, th]`` whose score σ(logit) ≥ ``threshold``.

    Cell (i, j) → centre ``((j+½+tx)·s, (i+½+ty)·s)``, size ``(s·e^tw, s·e^th)``.
    """
    raw = np.asarray(raw, np.float32)
    if raw.ndim != 3 or raw.shape[0] != 5:
        raise ValueError(f"head output must be (5, H, W), got {raw.shape}")
    scores = sigmoid(raw[0])
    i, j = np.nonzero(scores >= threshold)
    t = raw[:, i, j]
    cx = (j + 0.5 + t[1]) * stride
    cy = (i + 0.5 + t[2]) * stride
    bw = stride * np.exp(np.clip(t[3], -MAX_LOG_SIZE, MAX_LOG_SIZE))
    bh = stride * np.exp(np.clip(t[4], -MAX_LOG_SIZE, MAX_LOG_SIZE))
    boxes = np.stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2], axis=1).astype(np.float32)
    return boxes, scores[i, j].astype(np.float32)


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """IoU matrix ``(len(a), len(b))`` of ``[x0,y0,x1,y1]`` boxes."""
    a, b = np.asarray(a, np.float64).reshape(-1, 4), np.asarray(b, np.float64).reshape(-1, 4)
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    inter = np.prod(np.clip(rb - lt, 0, None), axis=2)
    area_a = np.prod(np.clip(a[:, 2:] - a[:, :2], 0, None), axis=1)
    area_b = np.prod(np.clip(b[:, 2:] - b[:, :2], 0, None), axis=1)
    union = area_a[:, None] + area_b[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def nms(boxes: np.ndarray, scores: np.ndarray, iou: float, limit: int | None = None) -> np.ndarray:
    """Indices kept by greedy non-maximum suppression, best score first (ties: lower index first)."""
    order = np.argsort(-np.asarray(scores), kind="stable")
    keep = []
    while order.size and (limit is None or len(keep) < limit):
        best, order = order[0], order[1:]
        keep.append(best)
        order = order[box_iou(boxes[best], boxes[order])[0] <= iou]
    return np.array(keep, dtype=np.int64)


def select_boxes(boxes: np.ndarray, scores: np.ndarray, iou: float, limit: int, accept=None) -> np.ndarray:
    """Indices of the boxes kept by NMS (at most ``limit``, best first) among those ``accept``
    (a function of an ``(N,4)`` array → ``(N,)`` bool, e.g. the box verifier) does not reject.
    A rejected box suppresses nothing: NMS is run again without it. Each box is put to
    ``accept`` once, and at most ``4·limit`` boxes in all (a frame full of rejected candidates
    costs a few batched calls, not one per candidate); boxes left unchecked then are dropped."""
    rejected = np.zeros(len(boxes), bool)
    checked = np.zeros(len(boxes), bool)
    while True:
        candidates = np.flatnonzero(~rejected)
        keep = candidates[nms(boxes[candidates], scores[candidates], iou, limit)]
        new = keep[~checked[keep]]
        if accept is None or not len(new):
            return keep
        room = 4 * limit - int(checked.sum())
        if room <= 0:  # the unchecked boxes leave, and so must their suppression of accepted ones
            accepted = np.flatnonzero(checked & ~rejected)
            return accepted[nms(boxes[accepted], scores[accepted], iou, limit)]
        new = new[:room]
        checked[new] = True
        rejected[new[~np.asarray(accept(boxes[new]), bool)]] = True


def grow_to_multiple(window, width: int, height: int, multiple: int) -> tuple[int, int, int, int]:
    """``window`` ``(x, y, w, h)`` grown about its centre to the next multiple of ``multiple`` a
    side, as far as the image allows, so that the network runs on image pixels, not padding."""
    x, y, w, h = (int(v) for v in window)
    gw, gh = min(-(-w // multiple) * multiple, width), min(-(-h // multiple) * multiple, height)
    x = int(np.clip(x - (gw - w) // 2, 0, width - gw))
    y = int(np.clip(y - (gh - h) // 2, 0, height - gh))
    return x, y, gw, gh


def search_window(roi, width: int, height: int, grow: float, min_px: int) -> tuple[int, int, int, int]:
    """Square-ish window ``(x, y, w, h)`` around a predicted ROI ``(x, y, w, h)``, inside the image."""
    x, y, w, h = (float(v) for v in roi)
    side = max(grow * max(w, h), float(min_px))
    ww, wh = min(round(side), width), min(round(side), height)
    x0 = int(np.clip(round(x + w / 2 - ww / 2), 0, width - ww))
    y0 = int(np.clip(round(y + h / 2 - wh / 2), 0, height - wh))
    return x0, y0, ww, wh


def onnx_session(model, threads: int):
    """``(path, session)``: an onnxruntime CPU session of ``model``, a path or else a file of the
    shipped models/ folder, with ``threads`` intra-op threads."""
    import onnxruntime as ort

    path = Path(model)
    if not path.exists():
        from ..resources import model_path

        path = model_path(str(model))
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    try:
        return path, ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime's own exception types (InvalidProtobuf, Fail, ...)
        raise ValueError(f"{path}: not an ONNX model onnxruntime can load ({exc})") from exc


class Detector:
    """The ONNX detector; one onnxruntime session, reused for every frame."""

    def __init__(self, config: DetectorConfig = DetectorConfig()):
        self.config = config
        path, self.session = onnx_session(config.model, config.threads)
        self.model_path = path  # the file behind config.model
        meta = self.session.get_modelmeta().custom_metadata_map
        try:
            self.strides = tuple(int(s) for s in json.loads(meta["strides"]))
            self.input_size = (int(meta["input_width"]), int(meta["input_height"]))
        except (KeyError, ValueError, TypeError) as exc:
            raise ValueError(f"{path}: not a detector exported by this project (metadata {exc})") from exc
        if len(self.session.get_outputs()) != len(self.strides):
            raise ValueError(f"{path}: not a detector exported by this project "
                             f"({len(self.session.get_outputs())} outputs for strides {self.strides})")
        self.input_name = self.session.get_inputs()[0].name
        self.verifier = None
        if config.verifier:
            from .verifier import BoxVerifier

            self.verifier = BoxVerifier(config.verifier, config.threads)

    def detect(self, image: np.ndarray, window=None) -> Detections:
        """Detections in a rectified RGB frame, clipped to it; with ``window`` ``(x, y, w, h)``
        only in that region (searched at up to full resolution, so a small window is fast).

        The window is first grown to whole network cells from the image around it; what the
        image cannot give is padded with its border pixels, not the grey of the full-frame
        letterbox: at full resolution a grey band looks like a box to the network. A box that
        reaches a side of the window inside the frame (within half the finest cell of the
        network's input) is dropped:
        the window may cut the UAV there, and a cut box, scored as a whole one, would give its
        depth (4.5) far too far."""
        image = check_image(image)
        height, width = image.shape[:2]
        if window is None:
            max_scale = min(self.input_size[0] / width, self.input_size[1] / height)
            boxes, scores, _ = self._infer(image, max_scale, cv2.BORDER_CONSTANT)
        else:
            from ..boosting.obb import check_roi

            window = check_roi(window, width, height)
            ox, oy, ww, wh = grow_to_multiple(window, width, height, max(self.strides))
            boxes, scores, lb = self._infer(image[oy : oy + wh, ox : ox + ww], 1.0, cv2.BORDER_REPLICATE)
            # A cut box ends about at the side, within half the finest cell of the network's input;
            # a window larger than the input is scaled down, so that is more window pixels.
            near_x, near_y = min(self.strides) / 2 / lb.scale_x, min(self.strides) / 2 / lb.scale_y
            cut = (boxes[:, 0] <= near_x) & (ox > 0) | (boxes[:, 1] <= near_y) & (oy > 0)
            cut |= (boxes[:, 2] >= ww - near_x) & (ox + ww < width) | (boxes[:, 3] >= wh - near_y) & (oy + wh < height)
            boxes, scores = boxes[~cut] + np.array([ox, oy, ox, oy], np.float32), scores[~cut]
        cfg = self.config
        accept = None
        if self.verifier is not None:  # on the whole frame: the context it was trained on
            accept = lambda b: self.verifier.probabilities(image, b) >= cfg.verifier_threshold  # noqa: E731
        keep = select_boxes(boxes, scores, cfg.nms_iou, cfg.max_detections, accept)
        return Detections(boxes[keep], scores[keep])

    def _infer(self, image: np.ndarray, max_scale: float, border: int) -> tuple[np.ndarray, np.ndarray, Letterbox]:
        """The decoded boxes above the score threshold (in ``image``'s pixels, clipped to it;
        none wholly in the padding), their scores, before NMS, and the letterbox that fed the network."""
        cfg = self.config
        padded, lb = letterbox(image, self.input_size, max(self.strides), max_scale, border)
        blob = np.ascontiguousarray(padded.transpose(2, 0, 1)[None], np.float32) * np.float32(1 / 255)
        outputs = self.session.run(None, {self.input_name: blob})
        parts = [decode(out[0], s, cfg.score_threshold) for out, s in zip(outputs, self.strides)]
        height, width = image.shape[:2]
        boxes = np.clip(lb.to_image(np.concatenate([p[0] for p in parts])).reshape(-1, 4), 0.0,
                        np.array([width, height, width, height], np.float32))
        scores = np.concatenate([p[1] for p in parts])
        inside = (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])
        return boxes[inside], scores[inside], lb
