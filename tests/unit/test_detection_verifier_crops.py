"""The box verifier's crops against an independent bilinear sampler (numpy): the square of side
max(context · max(w, h), min_side_px) about the box centre, crop pixel centres spread evenly
over it, bilinear interpolation, the frame's border pixels repeated outside it."""

import numpy as np
import pytest

from uav_landing_vision.detection.verifier import CropGeometry, box_crops, crop_blob


def bilinear_crop(image, box, geometry):
    """Crop by explicit sampling: crop pixel (r, c) sees the continuous point
    (cx − side/2 + (c + ½)·side/S, cy − side/2 + (r + ½)·side/S), pixel u covering [u, u+1)."""
    s = geometry.crop_px
    x0, y0, x1, y1 = box
    side = max(geometry.context * max(x1 - x0, y1 - y0), geometry.min_side_px)
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    h, w = image.shape[:2]
    u = cx - side / 2 + (np.arange(s) + 0.5) * side / s - 0.5  # in pixel-centre coordinates
    v = cy - side / 2 + (np.arange(s) + 0.5) * side / s - 0.5
    fu, fv = np.floor(u), np.floor(v)
    au, av = (u - fu)[None, :, None], (v - fv)[:, None, None]
    cu = [np.clip(fu + k, 0, w - 1).astype(int) for k in (0, 1)]
    cv = [np.clip(fv + k, 0, h - 1).astype(int) for k in (0, 1)]
    img = image.astype(float)
    top = img[cv[0]][:, cu[0]] * (1 - au) + img[cv[0]][:, cu[1]] * au
    bottom = img[cv[1]][:, cu[0]] * (1 - au) + img[cv[1]][:, cu[1]] * au
    return top * (1 - av) + bottom * av


@pytest.mark.parametrize("geometry", [CropGeometry(), CropGeometry(48, 2.0, 16.0)])
def test_crops_match_an_independent_bilinear_sampler_with_the_border_repeated(geometry):
    """Boxes inside the frame, larger than the crop, tiny, and across each side of the frame
    (a frame whose border pixels are bright, so a black surround would show)."""
    rng = np.random.default_rng(21)
    image = rng.integers(100, 256, (120, 160, 3), dtype=np.uint8)
    boxes = np.array([[40.3, 30.7, 90.1, 52.2],  # inside, wider than tall
                      [60.0, 10.0, 70.0, 100.0],  # taller than wide
                      [5.0, 5.0, 150.0, 115.0],  # larger than the crop: sampled, not averaged
                      [80.2, 60.6, 82.0, 61.1],  # tiny: the minimum side
                      [-10.0, 40.0, 12.0, 60.0], [150.0, 40.0, 175.0, 60.0],  # across the left / right side
                      [60.0, -8.0, 90.0, 6.0], [60.0, 110.0, 90.0, 130.0]])  # across the top / bottom
    crops = box_crops(image, boxes, geometry)
    assert crops.shape == (len(boxes), geometry.crop_px, geometry.crop_px, 3)
    for k, box in enumerate(boxes):
        want = bilinear_crop(image, box, geometry)
        err = np.abs(crops[k].astype(float) - want)
        assert err.max() <= 5.0 and err.mean() < 1.5, (k, err.max(), err.mean())  # OpenCV's 1/32 weights


def test_crop_blob_is_channels_first_rows_then_columns_in_zero_to_one():
    rng = np.random.default_rng(22)
    crops = rng.integers(0, 256, (2, 8, 8, 3), dtype=np.uint8)
    blob = crop_blob(crops)
    assert blob.shape == (2, 3, 8, 8) and blob.dtype == np.float32
    for n in range(2):
        for ch in range(3):
            np.testing.assert_allclose(blob[n, ch], crops[n, :, :, ch] / 255.0, rtol=1e-6)


def _constant_logit_verifier(path, geometry, slope, bias):
    """A tiny ONNX verifier: logit = slope · (mean of its input crop) + bias, with the crop
    geometry in its metadata as the exporter writes it."""
    import json

    import onnx
    from onnx import TensorProto, helper

    s = geometry.crop_px
    nodes = [helper.make_node("ReduceMean", ["crops"], ["mean"], axes=[1, 2, 3], keepdims=1),
             helper.make_node("Mul", ["mean", "slope"], ["scaled"]),
             helper.make_node("Add", ["scaled", "bias"], ["logit"]),
             helper.make_node("Reshape", ["logit", "shape"], ["logits"])]
    inits = [helper.make_tensor("slope", TensorProto.FLOAT, [], [slope]),
             helper.make_tensor("bias", TensorProto.FLOAT, [], [bias]),
             helper.make_tensor("shape", TensorProto.INT64, [2], [-1, 1])]
    graph = helper.make_graph(nodes, "v", [helper.make_tensor_value_info("crops", TensorProto.FLOAT, ["n", 3, s, s])],
                              [helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["n", 1])], inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 13)])
    model.ir_version = 8
    prop = model.metadata_props.add()
    prop.key, prop.value = "crop", json.dumps(geometry._asdict())
    onnx.save(model, str(path))
    return str(path)


def test_the_verifier_takes_its_crop_geometry_from_the_model_and_gives_probabilities(tmp_path):
    """Every number of the crop geometry comes from the model's metadata, and the network's
    logit becomes a probability σ(logit)."""
    from uav_landing_vision.detection.verifier import BoxVerifier

    geometry = CropGeometry(32, 2.5, 40.0)
    verifier = BoxVerifier(_constant_logit_verifier(tmp_path / "v.onnx", geometry, 4.0, -1.0), threads=1)
    assert verifier.geometry == geometry
    image = np.full((60, 80, 3), 191, np.uint8)  # every crop's mean is 191/255
    p = verifier.probabilities(image, np.array([[10.0, 10.0, 30.0, 20.0], [50.0, 30.0, 52.0, 31.0]]))
    np.testing.assert_allclose(p, 1 / (1 + np.exp(-(4.0 * 191 / 255 - 1.0))), rtol=1e-5)
    rng = np.random.default_rng(23)
    image = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    boxes = np.array([[5.0, 5.0, 12.0, 9.0], [20.0, 10.0, 60.0, 50.0]])
    means = box_crops(image, boxes, geometry).reshape(2, -1).mean(axis=1) / 255
    np.testing.assert_allclose(verifier.probabilities(image, boxes), 1 / (1 + np.exp(-(4.0 * means - 1.0))), rtol=1e-4)


def test_the_verifier_refuses_frames_that_are_not_rgb_uint8_and_boxes_with_any_non_finite_number(tmp_path):
    from uav_landing_vision.detection.verifier import BoxVerifier

    verifier = BoxVerifier(_constant_logit_verifier(tmp_path / "v.onnx", CropGeometry(16, 1.5, 8.0), 1.0, 0.0),
                           threads=1)
    box = np.array([[10.0, 10.0, 30.0, 20.0]])
    for image, message in [(np.zeros((60, 80, 3), np.float32), "uint8"), (np.zeros((60, 80), np.uint8), r"\(H, W, 3\)")]:
        with pytest.raises(ValueError, match=message):
            verifier.probabilities(image, box)
    image = np.zeros((60, 80, 3), np.uint8)
    for bad in (np.nan, np.inf):
        boxes = np.array([[10.0, 10.0, 30.0, 20.0], [5.0, 5.0, 9.0, bad]])  # one number of two boxes
        with pytest.raises(ValueError, match="finite"):
            verifier.probabilities(image, boxes)
    assert verifier.probabilities(image, np.zeros((0, 4))).shape == (0,)
