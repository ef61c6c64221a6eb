"""Second look at the detector's boxes: a small classifier scores a crop around each box.

The one-stage detector takes bright, motion-blurred wave crests and thin cloud edges for a
distant UAV (model card). The verifier sees each candidate again in a square crop of the
rectified frame at up to full resolution, with context around the box, and gives the
probability that the box holds the UAV. :class:`.detector.Detector` drops the boxes below
``verifier_threshold`` and keeps the scores of the others. Needs only numpy, OpenCV and
onnxruntime.

Crop of a box ``[x0,y0,x1,y1]``: the square of side ``max(context · max(w, h), min_side_px)``
centred on the box, resampled bilinearly to ``crop_px × crop_px`` (``cv2.warpAffine`` has no
area averaging, so a box larger than the crop is sampled, not averaged; the shipped verifier was
trained so), the frame's border pixels repeated outside it. The three numbers travel in the
ONNX metadata, so a model is always fed the crops it was trained on.
"""

import json
from typing import NamedTuple

import cv2
import numpy as np


class CropGeometry(NamedTuple):
    """How a box becomes the verifier's input (stored in the ONNX metadata)."""

    crop_px: int = 64
    context: float = 1.5
    min_side_px: float = 24.0


def box_crops(image: np.ndarray, boxes: np.ndarray, geometry: CropGeometry = CropGeometry()) -> np.ndarray:
    """Crops ``(N, crop_px, crop_px, 3)`` uint8 of an RGB frame around boxes ``(N,4)``."""
    side_px = geometry.crop_px
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    out = np.empty((len(boxes), side_px, side_px, image.shape[2]), np.uint8)
    for k, (x0, y0, x1, y1) in enumerate(boxes):
        side = max(geometry.context * max(x1 - x0, y1 - y0), geometry.min_side_px)
        a = side_px / side
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        # continuous pixel coordinates (pixel u covers [u, u+1)) → OpenCV's (pixel u at u)
        affine = np.array([[a, 0.0, a * (side / 2 - cx + 0.5) - 0.5], [0.0, a, a * (side / 2 - cy + 0.5) - 0.5]])
        out[k] = cv2.warpAffine(image, affine, (side_px, side_px),
                                flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_REPLICATE)
    return out


def crop_blob(crops: np.ndarray) -> np.ndarray:
    """The network's input ``(N, 3, S, S)`` float32 in [0, 1] of uint8 crops ``(N, S, S, 3)``."""
    return np.ascontiguousarray(crops.transpose(0, 3, 1, 2), np.float32) * np.float32(1 / 255)


class BoxVerifier:
    """The ONNX verifier; one onnxruntime session, reused for every frame."""

    def __init__(self, model, threads: int = 2):
        from .detector import onnx_session

        path, self.session = onnx_session(model, threads)
        meta = self.session.get_modelmeta().custom_metadata_map
        try:
            crop = json.loads(meta["crop"])
            self.geometry = CropGeometry(int(crop["crop_px"]), float(crop["context"]), float(crop["min_side_px"]))
        except (KeyError, ValueError, TypeError) as exc:
            raise ValueError(f"{path}: not a box verifier exported by this project (metadata {exc})") from exc
        self.input_name = self.session.get_inputs()[0].name

    def probabilities(self, image: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """Probability ``(N,)`` that each box ``(N,4)`` of the RGB frame holds the UAV; a
        ValueError for a frame that is not RGB uint8 or boxes that are not finite."""
        from .detector import check_image, sigmoid

        image = check_image(image)
        boxes = np.asarray(boxes, np.float32).reshape(-1, 4)
        if not np.isfinite(boxes).all():
            raise ValueError("boxes must be finite [x0, y0, x1, y1]")
        if not len(boxes):
            return np.zeros(0, np.float32)
        blob = crop_blob(box_crops(image, boxes, self.geometry))
        return sigmoid(self.session.run(None, {self.input_name: blob})[0].reshape(-1))
