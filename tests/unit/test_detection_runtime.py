"""Detector runtime on hand-made cases: letterbox, decode, NMS, ROIs, search window, bad input."""

import cv2
import numpy as np
import pytest

from uav_landing_vision.cli import main
from uav_landing_vision.detection.detector import (
    Detector,
    DetectorConfig,
    PAD_VALUE,
    Detections,
    box_iou,
    check_image,
    decode,
    grow_to_multiple,
    letterbox,
    nms,
    search_window,
    select_boxes,
)


def test_letterbox_full_frame_shapes_and_padding():
    image = np.full((720, 1280, 3), 200, np.uint8)
    out, lb = letterbox(image, (640, 384))
    assert out.shape == (384, 640, 3)
    assert (lb.scale, lb.pad_x, lb.pad_y) == (0.5, 0, 12)
    assert np.all(out[:12] == PAD_VALUE) and np.all(out[372:] == PAD_VALUE)
    assert np.all(out[12:372] == 200)


def test_letterbox_small_image_is_not_upscaled_and_is_centred():
    image = np.zeros((300, 100, 3), np.uint8)
    out, lb = letterbox(image, (640, 384))
    assert out.shape == (320, 128, 3)
    assert (lb.scale, lb.pad_x, lb.pad_y) == (1.0, 14, 10)
    assert np.all(out[10:310, 14:114] == 0) and np.all(out[:, :14] == PAD_VALUE)


def test_letterbox_box_round_trip():
    _, lb = letterbox(np.zeros((720, 1280, 3), np.uint8), (640, 384))
    boxes = np.array([[100.0, 50.0, 116.0, 58.0], [0.0, 0.0, 1280.0, 720.0]])
    np.testing.assert_allclose(lb.to_input(boxes), [[50, 37, 58, 41], [0, 12, 640, 372]])
    np.testing.assert_allclose(lb.to_image(lb.to_input(boxes)), boxes, atol=1e-4)


def test_letterbox_maps_boxes_with_the_scales_of_the_whole_pixel_resize():
    image = np.zeros((1080, 1440, 3), np.uint8)
    image[:, 1000:] = 255  # a bright block to the right edge
    out, lb = letterbox(image, (640, 384))
    assert (lb.scale_x, lb.scale_y) == (512 / 1440, 384 / 1080)  # 1440 x 0.3556 = 512 px, exactly
    columns = np.flatnonzero(out[lb.pad_y + 10, :, 0] > 127)
    edge = lb.to_image(np.array([[columns[-1] + 1.0, 0.0, columns[-1] + 1.0, 0.0]]))[0, 0]
    assert edge == pytest.approx(1440.0, abs=1e-3)  # the block's right edge maps back onto the image's


def test_decode_hand_made_head_map():
    raw = np.full((5, 2, 3), -10.0, np.float32)
    raw[1:, :, :] = 0.0
    raw[:, 1, 2] = [4.0, 0.25, -0.5, np.log(2.0), 0.0]
    boxes, scores = decode(raw, 8, 0.5)
    np.testing.assert_allclose(boxes, [[14.0, 4.0, 30.0, 12.0]], atol=1e-5)
    np.testing.assert_allclose(scores, [1 / (1 + np.exp(-4.0))], rtol=1e-6)
    assert decode(raw, 8, 0.99)[0].shape == (0, 4)


def test_decode_rejects_wrong_shape():
    with pytest.raises(ValueError, match=r"\(5, H, W\)"):
        decode(np.zeros((4, 2, 2)), 8, 0.5)


def test_box_iou_hand_made():
    a = np.array([[0, 0, 10, 10]])
    b = np.array([[5, 0, 15, 10], [20, 20, 30, 30], [0, 0, 10, 10]])
    np.testing.assert_allclose(box_iou(a, b), [[50 / 150, 0.0, 1.0]])


def test_nms_keeps_best_of_each_overlapping_group():
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [20, 20, 30, 30], [0, 0, 10, 10.5]], np.float32)
    scores = np.array([0.9, 0.8, 0.7, 0.95], np.float32)
    assert nms(boxes, scores, 0.45).tolist() == [3, 2]
    assert nms(boxes, scores, 0.45, limit=1).tolist() == [3]
    assert nms(boxes, scores, 0.9).tolist() == [3, 1, 2]  # B overlaps D by IoU 0.715 < 0.9
    assert nms(boxes[:0], scores[:0], 0.45).tolist() == []


def test_rois_cover_boxes_and_are_clipped():
    det = Detections(np.array([[10.2, 5.7, 30.1, 20.0], [-4.0, 700.0, 20.0, 730.0]], np.float32), np.ones(2))
    assert det.rois(1280, 720).tolist() == [[10, 5, 21, 15], [0, 700, 20, 20]]


def test_search_window_centred_and_kept_inside():
    assert search_window((600, 300, 20, 10), 1280, 720, 3.0, 192) == (514, 209, 192, 192)
    assert search_window((1270, 700, 10, 10), 1280, 720, 3.0, 192) == (1088, 528, 192, 192)
    assert search_window((0, 0, 400, 300), 1280, 720, 3.0, 192) == (0, 0, 1200, 720)


def test_a_rejected_box_suppresses_nothing():
    boxes = np.array([[0, 0, 10, 10], [1, 1, 11, 11], [50, 50, 60, 60], [2, 0, 12, 10]], np.float32)
    scores = np.array([0.9, 0.8, 0.7, 0.6], np.float32)
    np.testing.assert_array_equal(select_boxes(boxes, scores, 0.45, 10), [0, 2])  # plain NMS
    asked = []

    def not_the_first(b):  # box 0 is a wave crest; it had hidden box 1
        asked.extend(map(tuple, b))
        return ~np.all(b == boxes[0], axis=1)

    np.testing.assert_array_equal(select_boxes(boxes, scores, 0.45, 10, not_the_first), [1, 2])
    assert len(asked) == len(set(asked)) == 3  # each box is put to the verifier once; box 3 stays hidden
    np.testing.assert_array_equal(select_boxes(boxes, scores, 0.45, 1, not_the_first), [1])
    assert not len(select_boxes(boxes, scores, 0.45, 10, lambda b: np.zeros(len(b), bool)))
    # a flood of rejected candidates: at most 4 × limit checked, in batches of at most limit
    rng = np.random.default_rng(0)
    xy = rng.uniform(0, 1000, (500, 2))
    many = np.hstack([xy, xy + 8]).astype(np.float32)
    calls = []
    none = lambda b: calls.append(len(b)) or np.zeros(len(b), bool)  # noqa: E731
    assert not len(select_boxes(many, rng.uniform(size=500).astype(np.float32), 0.45, 5, none))
    assert sum(calls) == 20 and max(calls) <= 5


def test_an_accepted_box_is_not_lost_to_one_left_unchecked():
    far = np.array([[100.0 * i, 500, 100.0 * i + 10, 510] for i in range(6)], np.float32)
    near = np.array([[0, 0, 10, 10], [3, 0, 13, 10], [6, 0, 16, 10]], np.float32)  # R, U, A: U overlaps both
    boxes = np.vstack([far, near])
    scores = np.array([0.99, 0.98, 0.97, 0.96, 0.95, 0.94, 0.90, 0.85, 0.80], np.float32)
    only_a = lambda b: np.all(b == near[2], axis=1)  # noqa: E731  (the verifier takes A alone)
    # with limit 2, four batches of two check the six far boxes, R and A; U is never checked
    np.testing.assert_array_equal(select_boxes(boxes, scores, 0.45, 2, only_a), [8])


def test_window_grows_to_whole_cells_from_the_frame():
    assert grow_to_multiple((100, 200, 200, 180), 1280, 720, 32) == (88, 194, 224, 192)
    assert grow_to_multiple((1200, 600, 70, 100), 1280, 720, 32) == (1184, 586, 96, 128)  # kept inside
    assert grow_to_multiple((0, 0, 1280, 720), 1280, 720, 32) == (0, 0, 1280, 720)  # the frame is the limit
    assert grow_to_multiple((10, 10, 192, 192), 1280, 720, 32) == (10, 10, 192, 192)


def test_letterbox_can_repeat_the_border_instead_of_grey():
    image = np.full((20, 30, 3), 7, np.uint8)
    out, lb = letterbox(image, (64, 64), multiple=32, border=cv2.BORDER_REPLICATE)
    assert out.shape == (32, 32, 3) and (lb.pad_x, lb.pad_y) == (1, 6) and np.all(out == 7)


@pytest.mark.parametrize(
    "image, message",
    [
        (np.zeros((10, 10, 3), np.float32), "uint8"),
        (np.zeros((10, 10), np.uint8), r"\(H, W, 3\)"),
        (np.zeros((10, 10, 4), np.uint8), r"\(H, W, 3\)"),
        (np.zeros((0, 10, 3), np.uint8), "empty"),
        (np.zeros((10, 0, 3), np.uint8), "empty"),
        ([[1, 2, 3]], "numpy array"),
    ],
)
def test_bad_images_are_rejected_with_a_clear_error(image, message):
    with pytest.raises(ValueError, match=message):
        check_image(image)


def test_nms_matches_opencv_on_random_boxes_with_ties_and_duplicates():
    """cv2.dnn.NMSBoxes as the oracle: same boxes kept, same order (ties: lower index first)."""
    rng = np.random.default_rng(1)
    for k in range(300):
        n = int(rng.integers(0, 30))
        xy = rng.uniform(0, 100, (n, 2))
        boxes = np.hstack([xy, xy + rng.uniform(0.5, 40, (n, 2))])
        if k % 3 == 0:
            boxes[1::2] = boxes[0::2][: len(boxes[1::2])]  # exact duplicates
        scores = (rng.integers(1, 5, n) / 5 if k % 2 else rng.uniform(0.01, 1, n)).astype(np.float32)
        iou = float(rng.choice([0.3, 0.45, 0.7, 1.0]))
        xywh = [[float(x0), float(y0), float(x1 - x0), float(y1 - y0)] for x0, y0, x1, y1 in boxes]
        expected = np.array(cv2.dnn.NMSBoxes(xywh, scores.tolist(), 0.0, iou), np.int64).reshape(-1)
        np.testing.assert_array_equal(nms(boxes, scores, iou), expected)


@pytest.mark.parametrize("grow", [float("nan"), float("inf"), 1e308])  # 1e308: an OverflowError in search_window
def test_config_refuses_a_search_window_growth_that_is_not_finite(grow):
    """A NaN or infinite growth would pass the config and then fail every windowed frame."""
    with pytest.raises(ValueError, match="window_grow"):
        DetectorConfig(window_grow=grow)


@pytest.mark.parametrize("threads", [0, 2**31])
def test_config_refuses_a_thread_count_onnxruntime_cannot_take(threads):
    """2**31 passed, then failed in onnxruntime's options as if the model could not be loaded."""
    with pytest.raises(ValueError, match="threads"):
        DetectorConfig(threads=threads)


def test_a_file_that_is_not_an_onnx_model_is_a_clear_error(tmp_path):
    from uav_landing_vision.detection.verifier import BoxVerifier

    junk = tmp_path / "junk.onnx"
    junk.write_text("image_width: 640\n")
    with pytest.raises(ValueError, match=r"junk\.onnx: not an ONNX model onnxruntime can load"):
        Detector(DetectorConfig(model=str(junk)))
    with pytest.raises(ValueError, match=r"junk\.onnx: not an ONNX model onnxruntime can load"):
        BoxVerifier(str(junk))
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "dataset.json").write_text('{"images": 1}')
    with pytest.raises(SystemExit, match=r"^uav-landing train-verifier: .*junk\.onnx: not an ONNX model"):
        main(["train-verifier", "--data", str(tmp_path / "data"), "--detector", str(junk),
              "--out", str(tmp_path / "run")])


def test_a_model_with_other_metadata_or_outputs_is_refused(tmp_path):
    import onnx
    from onnx import TensorProto, helper

    graph = helper.make_graph([helper.make_node("Identity", ["images"], ["p8"])], "g",
                              [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 32, 32])],
                              [helper.make_tensor_value_info("p8", TensorProto.FLOAT, [1, 3, 32, 32])])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 8
    for key, value in {"strides": "8", "input_width": "32", "input_height": "32"}.items():
        prop = model.metadata_props.add()
        prop.key, prop.value = key, value
    onnx.save(model, str(tmp_path / "odd.onnx"))
    with pytest.raises(ValueError, match="not a detector exported by this project"):
        Detector(DetectorConfig(model=str(tmp_path / "odd.onnx")))
    model.metadata_props[0].value = "[8, 16]"  # two strides, one output
    onnx.save(model, str(tmp_path / "two.onnx"))
    with pytest.raises(ValueError, match=r"1 outputs for strides \(8, 16\)"):
        Detector(DetectorConfig(model=str(tmp_path / "two.onnx")))


def test_config_accepts_the_edges_of_its_ranges():
    """nms_iou 1 (only exact duplicates suppress), a verifier threshold of 0 (keep all) and a
    32 px minimum window are allowed; a 31 px minimum window is not."""
    cfg = DetectorConfig(nms_iou=1.0, verifier_threshold=0.0, window_min_px=32)
    assert (cfg.nms_iou, cfg.verifier_threshold, cfg.window_min_px) == (1.0, 0.0, 32)
    with pytest.raises(ValueError, match="window_min_px"):
        DetectorConfig(window_min_px=31)


def test_check_image_gives_a_contiguous_array_of_a_strided_view():
    """A view with strides (every other column, as a decimated frame) comes back C-contiguous
    with the same pixels."""
    rng = np.random.default_rng(3)
    frame = rng.integers(0, 256, (40, 60, 3), dtype=np.uint8)
    view = frame[:, ::2]
    assert not view.flags["C_CONTIGUOUS"]
    out = check_image(view)
    assert out.flags["C_CONTIGUOUS"]
    np.testing.assert_array_equal(out, view)


def test_letterbox_resizes_to_the_nearest_whole_pixel():
    """1003×999 into 640×384: scale 384/999, so the width becomes 385.54 → 386 px, not 385."""
    image = np.full((999, 1003, 3), 255, np.uint8)
    out, lb = letterbox(image, (640, 384))
    want = round(1003 * 384 / 999)
    assert want == 386
    cols = np.flatnonzero(out[200, :, 0] == 255)
    assert len(cols) == want and lb.scale_x == want / 1003
    assert out.shape == (384, 416, 3)


def test_letterbox_odd_padding_leaves_the_extra_pixel_right_and_below_in_grey_114():
    """A 101×301 frame in a 128×320 input: 27 columns and 19 rows of padding, 13 left and 14
    right, 9 above and 10 below, in the grey 114 the shipped model was trained with."""
    image = np.full((301, 101, 3), 7, np.uint8)
    out, lb = letterbox(image, (640, 384))
    assert out.shape == (320, 128, 3) and (lb.pad_x, lb.pad_y) == (13, 9)
    inside = np.zeros(out.shape[:2], bool)
    inside[9:310, 13:114] = True
    assert np.all(out[inside] == 7) and np.all(out[~inside] == 114)


def test_letterbox_a_frame_that_rounds_back_to_its_width_is_still_resized_in_height():
    """A 100×1000 frame into 640×996: scale 0.996, the width rounds back to 100 px while the
    height becomes 996 px; the input is 128×1024 with the content's rows in place."""
    image = np.full((1000, 100, 3), 255, np.uint8)
    out, lb = letterbox(image, (640, 996))
    assert out.shape == (1024, 128, 3)
    rows = np.flatnonzero(out[:, 64, 0] == 255)
    assert len(rows) == 996 and rows[0] == lb.pad_y == 14
    assert (lb.scale_x, lb.scale_y) == (1.0, 996 / 1000)


def test_window_growth_stays_inside_the_frame_and_holds_the_window():
    """Random windows: the grown window is whole cells a side (or the frame's side), lies inside
    the frame and contains the window asked for, also at the frame's bottom and right edges."""
    assert grow_to_multiple((100, 610, 200, 100), 1280, 720, 32) == (88, 592, 224, 128)
    assert grow_to_multiple((1230, 100, 50, 60), 1280, 720, 32) == (1216, 98, 64, 64)
    rng = np.random.default_rng(8)
    for _ in range(300):
        width, height = (int(v) for v in rng.integers(64, 1500, 2))
        w, h = int(rng.integers(1, width + 1)), int(rng.integers(1, height + 1))
        x, y = int(rng.integers(0, width - w + 1)), int(rng.integers(0, height - h + 1))
        gx, gy, gw, gh = grow_to_multiple((x, y, w, h), width, height, 32)
        assert gw == min(-(-w // 32) * 32, width) and gh == min(-(-h // 32) * 32, height)
        assert 0 <= gx <= x and x + w <= gx + gw <= width
        assert 0 <= gy <= y and y + h <= gy + gh <= height


def test_search_window_side_is_the_nearest_whole_pixel_of_the_grown_side():
    """3 × 100.3 px = 300.9 → a 301 px window about the ROI's centre (650.15, 320.0)."""
    assert search_window((600, 300, 100.3, 40), 1280, 720, 3.0, 192) == (500, 170, 301, 301)
