"""ONNX export of the detector and box verifier networks (torch; development only).

The graph has one input ``images`` (1,3,H,W) float32 RGB in [0,1] with dynamic H and W
(multiples of 32) and one output per stride (``p8``, ``p16``, ``p32``). Metadata props carry
what the runtime needs: ``strides``, ``input_width``, ``input_height`` (the full-frame
letterbox size) and a free-form ``description``. The exporter's debug records (per-node stack
traces with the exporting machine's file paths, FX node dumps) are dropped.

The verifier's graph has one input ``crops`` (N,3,S,S) with dynamic N and one output
``logits`` (N,1); its metadata ``crop`` holds the :class:`.verifier.CropGeometry` it was
trained with.
"""

import json
from pathlib import Path

import torch

from .network import STRIDES
from .verifier import CropGeometry

OPSET = 18
MAX_EXPORT_SIDE = 4096  # px; the export's dynamic H and W are declared up to it (multiples of 32)


def export_onnx(net: torch.nn.Module, path, input_size: tuple[int, int], description: str = "") -> Path:
    """Write ``net`` (eval mode) as ONNX to ``path``; ``input_size`` is (width, height)."""
    width, height = input_size
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    net = net.eval()
    example = torch.zeros(1, 3, height, width)
    cells = MAX_EXPORT_SIDE // 32
    h, w = torch.export.Dim("h32", min=1, max=cells), torch.export.Dim("w32", min=1, max=cells)
    torch.onnx.export(
        net, (example,), str(path), dynamo=True, opset_version=OPSET, external_data=False,
        input_names=["images"], output_names=[f"p{s}" for s in STRIDES],
        dynamic_shapes={"x": {2: 32 * h, 3: 32 * w}}, verbose=False,
    )
    _finish(path, {"strides": json.dumps(list(STRIDES)), "input_width": str(width), "input_height": str(height),
                   "description": description})
    return path


def export_verifier_onnx(net: torch.nn.Module, path, geometry: CropGeometry = CropGeometry(),
                         description: str = "") -> Path:
    """Write the box verifier ``net`` as ONNX to ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    net = net.eval()
    example = torch.zeros(2, 3, geometry.crop_px, geometry.crop_px)
    torch.onnx.export(
        net, (example,), str(path), dynamo=True, opset_version=OPSET, external_data=False,
        input_names=["crops"], output_names=["logits"],
        dynamic_shapes={"x": {0: torch.export.Dim("n", min=1, max=4096)}}, verbose=False,
    )
    _finish(path, {"crop": json.dumps(geometry._asdict()), "description": description})
    return path


def _finish(path: Path, meta: dict) -> None:
    """Drop the exporter's debug records and store ``meta`` as metadata props."""
    import onnx

    model = strip_debug_metadata(onnx.load(str(path)))
    for key, value in meta.items():
        prop = model.metadata_props.add()
        prop.key, prop.value = key, value
    onnx.save(model, str(path))


def strip_debug_metadata(model):
    """``model`` (an ``onnx.ModelProto``) without the exporter's per-node and per-graph records."""
    for node in model.graph.node:
        del node.metadata_props[:]
    del model.graph.metadata_props[:]
    return model
