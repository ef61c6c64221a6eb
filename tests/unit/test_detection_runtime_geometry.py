"""Detector runtime end to end with a stand-in network: the shipped model's metadata (strides,
input size) and a head that reports each white rectangle of its input as a box, so where a box
lands in the frame is known exactly. Covers the full-frame letterbox and its inverse, the search
window (grown to whole cells from the frame, border pixels repeated, offsets back to the frame,
the cut-box rule), the verifier's threshold, and hand-made ROI and decode cases."""

import cv2
import numpy as np
import pytest

from uav_landing_vision.detection.detector import (
    MAX_LOG_SIZE,
    Detections,
    Detector,
    DetectorConfig,
    Letterbox,
    decode,
    letterbox,
    search_window,
    select_boxes,
)


class WhiteRectangleHead:
    """A stand-in onnxruntime session: each 4-connected group of white input pixels (all three
    channels ≥ 0.99) becomes one box, exactly its pixel extent in input pixels, scored σ(4) in
    the stride-8 map (cell of its centre); every other cell scores σ(−20). Records its inputs."""

    def __init__(self, strides):
        self.strides = strides
        self.blobs = []

    def run(self, _names, feeds):
        (blob,) = feeds.values()
        self.blobs.append(blob.copy())
        _, _, h, w = blob.shape
        outs = []
        for s in self.strides:
            out = np.zeros((1, 5, h // s, w // s), np.float32)
            out[0, 0] = -20.0
            outs.append(out)
        white = (blob[0] >= 0.99).all(axis=0).astype(np.uint8)
        n, _, stats, _ = cv2.connectedComponentsWithStats(white, connectivity=4)
        head = outs[self.strides.index(8)][0]
        for x, y, bw, bh, _ in stats[1:n]:
            cx, cy = x + bw / 2, y + bh / 2
            j, i = int(cx // 8), int(cy // 8)
            head[:, i, j] = [4.0, cx / 8 - j - 0.5, cy / 8 - i - 0.5, np.log(bw / 8), np.log(bh / 8)]
        return outs


@pytest.fixture(scope="module")
def shipped():
    return Detector(DetectorConfig(threads=1))


@pytest.fixture
def detector(shipped):
    """The shipped detector's settings and metadata with the stand-in head."""
    det = Detector.__new__(Detector)
    det.__dict__.update(shipped.__dict__)
    det.session = WhiteRectangleHead(shipped.strides)
    det.verifier = None
    return det


def frame_with(rects, width=1280, height=720, value=60):
    image = np.full((height, width, 3), value, np.uint8)
    for x0, y0, x1, y1 in rects:
        image[y0:y1, x0:x1] = 255
    return image


def test_the_stand_in_network_matches_the_shipped_metadata(shipped):
    assert shipped.strides == (8, 16, 32) and shipped.input_size == (960, 544)


def test_full_frame_boxes_map_back_to_the_frame(detector):
    """1280×720 → 960×540 (scale ¾) + 2 px of padding top and bottom: a white rectangle whose
    edges are whole input pixels comes back at its own place."""
    rect = (400, 200, 480, 264)  # ¾ → input x 300..360, y 150..198 (+2)
    det = detector.detect(frame_with([rect]))
    assert detector.session.blobs[-1].shape == (1, 3, 544, 960)
    assert len(det.scores) == 1
    np.testing.assert_allclose(det.boxes[0], rect, atol=1.5)


def test_a_tall_frame_is_letterboxed_on_its_own_axes(detector):
    """A 600×900 portrait frame: scale 544/900 from its height; the box comes back in place."""
    rect = (150, 450, 300, 600)
    det = detector.detect(frame_with([rect], width=600, height=900))
    assert len(det.scores) == 1
    np.testing.assert_allclose(det.boxes[0], rect, atol=2.5)


def test_a_frame_smaller_than_the_input_is_enlarged_to_fill_it(detector):
    """As in training (train.py): the full frame is scaled to the network input, smaller frames
    enlarged, and its boxes come back in the frame's own pixels."""
    rect = (100, 60, 140, 92)
    det = detector.detect(frame_with([rect], width=480, height=272))
    assert detector.session.blobs[-1].shape == (1, 3, 544, 960)  # 2× exactly
    assert len(det.scores) == 1
    np.testing.assert_allclose(det.boxes[0], rect, atol=0.6)


def test_window_boxes_come_back_in_frame_pixels(detector):
    """Searched at full resolution in a window: the box is exactly the rectangle, in the frame."""
    rect = (630, 300, 671, 333)
    det = detector.detect(frame_with([rect]), window=(560, 240, 200, 160))
    assert len(det.scores) == 1
    np.testing.assert_allclose(det.boxes[0], rect, atol=1e-4)


def test_the_window_is_grown_to_whole_coarsest_cells_from_the_frame_not_padded(detector):
    """A 200×180 window is grown about its centre to 224×192 (multiples of the 32 px cell) of
    frame pixels: the network's input is exactly that crop of the frame."""
    rng = np.random.default_rng(5)
    image = rng.integers(0, 200, (720, 1280, 3), dtype=np.uint8)
    detector.detect(image, window=(100, 200, 200, 180))
    blob = detector.session.blobs[-1]
    assert blob.shape == (1, 3, 192, 224)
    np.testing.assert_allclose(blob[0].transpose(1, 2, 0) * 255, image[194:386, 88:312], atol=1e-3)


def test_a_window_the_frame_cannot_fill_is_padded_with_repeated_border_pixels(detector):
    """A 100×70 frame searched whole: the 128×96 input repeats the frame's border pixels (a grey
    band looked like a box to the network at full resolution)."""
    rng = np.random.default_rng(6)
    image = rng.integers(0, 200, (70, 100, 3), dtype=np.uint8)
    detector.detect(image, window=(0, 0, 100, 70))
    blob = detector.session.blobs[-1]
    want = cv2.copyMakeBorder(image, 13, 13, 14, 14, cv2.BORDER_REPLICATE)
    assert blob.shape == (1, 3, 96, 128)
    np.testing.assert_allclose(blob[0].transpose(1, 2, 0) * 255, want, atol=1e-3)


def test_a_box_ending_within_half_a_fine_cell_of_a_window_side_inside_the_frame_is_dropped(detector):
    """The 224×192 window at (88, 194): a rectangle starting 2 px inside its left side, or ending
    2 px inside its bottom, may be a cut UAV and is dropped; 8 px inside, it is kept."""
    window = (100, 200, 200, 180)  # → x 88..312, y 194..386
    for rect, kept in [((90, 250, 130, 280), False), ((96, 250, 130, 280), True),
                       ((200, 350, 240, 384), False), ((200, 350, 240, 378), True),
                       ((200, 196, 240, 230), False), ((270, 250, 310, 280), False),
                       ((260, 250, 304, 280), True)]:
        det = detector.detect(frame_with([rect]), window=window)
        assert len(det.scores) == int(kept), (rect, kept)
        if kept:
            np.testing.assert_allclose(det.boxes[0], rect, atol=1e-4)


def test_a_box_at_a_window_side_that_is_the_frames_side_is_kept(detector):
    """The UAV entering the frame: a window on the frame's corner does not cut it there."""
    for rect, window in [((0, 300, 40, 330), (0, 250, 160, 160)), ((1250, 300, 1280, 330), (1120, 250, 160, 160)),
                         ((500, 0, 540, 20), (450, 0, 160, 160)), ((500, 700, 540, 720), (450, 560, 160, 160))]:
        det = detector.detect(frame_with([rect]), window=window)
        assert len(det.scores) == 1, (rect, window)
        np.testing.assert_allclose(det.boxes[0], rect, atol=1e-4)


def test_the_cut_rule_measures_each_side_of_a_wide_window_on_its_own_axis(detector):
    """A 320×128 window: a box ending at x = 180 of it lies well inside (its height is 128)."""
    window = (400, 300, 320, 128)
    rect = (500, 330, 580, 360)  # window x 100..180 of 320, y 30..60 of 128
    det = detector.detect(frame_with([rect]), window=window)
    assert len(det.scores) == 1
    np.testing.assert_allclose(det.boxes[0], rect, atol=1e-4)


class FixedBoxesHead(WhiteRectangleHead):
    """Reports the given boxes (input pixels) in the stride-8 map, whatever the input."""

    def __init__(self, strides, boxes):
        super().__init__(strides)
        self.boxes = boxes

    def run(self, names, feeds):
        outs = super().run(names, {"images": np.zeros_like(next(iter(feeds.values())))})
        head = outs[self.strides.index(8)][0]
        for x0, y0, x1, y1 in self.boxes:
            cx, cy, bw, bh = (x0 + x1) / 2, (y0 + y1) / 2, x1 - x0, y1 - y0
            j, i = int(cx // 8), int(cy // 8)
            head[:, i, j] = [4.0, cx / 8 - j - 0.5, cy / 8 - i - 0.5, np.log(bw / 8), np.log(bh / 8)]
        return outs


def test_boxes_wholly_in_the_letterbox_padding_are_dropped(detector):
    """1280×720 → input rows 2…541 hold the frame: a box in rows 0…2 lies off the frame (no
    height once clipped) and is dropped; one reaching into the frame is kept, clipped to it.
    Likewise a box in the side padding of a portrait frame."""
    detector.session = FixedBoxesHead(detector.strides, [(100, 0, 140, 2), (300, 0, 340, 14)])
    det = detector.detect(frame_with([]))
    assert len(det.scores) == 1
    np.testing.assert_allclose(det.boxes[0], [400, 0, 400 + 40 / 0.75, 16], atol=1e-3)
    detector.session = FixedBoxesHead(detector.strides, [(0, 100, 10, 140), (0, 300, 30, 340)])
    det = detector.detect(frame_with([], width=600, height=900))  # 363 px wide in the input, from x = 10
    assert len(det.scores) == 1 and det.boxes[0, 0] == 0 and det.boxes[0, 2] > 0


def test_the_cut_margin_of_a_window_larger_than_the_input_is_half_a_cell_of_the_input(detector):
    """A 1216×704 window of a 1600×900 frame is scaled by 544/704 into the 960×544 input (940 px
    wide from x = 10): half the finest cell, 4 input px, is 5.2 window px. A box 3.5 input px
    (4.5 window px) from the window's left, top or right side is cut; one 4.5 input px in is kept.
    Measured in window pixels (4), the cut boxes were kept."""
    frame = frame_with([], width=1600, height=900)
    window = (100, 50, 1216, 704)
    for box in [(13.5, 200, 53.5, 230), (300, 3.5, 340, 33.5), (906.5, 200, 946.5, 230)]:
        detector.session = FixedBoxesHead(detector.strides, [box])
        assert len(detector.detect(frame, window=window).scores) == 0, box
    detector.session = FixedBoxesHead(detector.strides, [(14.5, 200, 54.5, 230)])
    det = detector.detect(frame, window=window)
    assert len(det.scores) == 1
    np.testing.assert_allclose(det.boxes[0, :2], [100 + 4.5 * 1216 / 940, 50 + 200 * 704 / 544], rtol=1e-5)


class Verifier:
    def __init__(self, p):
        self.p = p

    def probabilities(self, image, boxes):
        return np.full(len(boxes), self.p, np.float32)


def test_the_verifier_keeps_boxes_at_or_above_its_threshold(detector):
    image = frame_with([(400, 200, 480, 264)])
    for p, kept in ((0.49, 0), (0.5, 1), (0.9, 1)):
        detector.verifier = Verifier(p)
        assert len(detector.detect(image).scores) == kept, p


def test_when_the_check_budget_runs_out_the_accepted_boxes_come_best_first():
    """limit 3 → at most 12 boxes put to the verifier: box 1 (0.9) is accepted first, ten boxes
    (0.85 … 0.40) are rejected, box 0 (0.3) is accepted with the last of the budget, and box 12
    (0.2) is left unchecked and dropped. The result is best first: [1, 0]."""
    boxes = np.array([[20.0 * k, 0.0, 20.0 * k + 10.0, 10.0] for k in range(13)], np.float32)
    scores = np.array([0.3, 0.9, *np.linspace(0.85, 0.40, 10), 0.2], np.float32)
    asked = []

    def only_0_and_1(b):
        asked.extend(b[:, 0] // 20)
        return np.isin(b[:, 0] // 20, [0, 1])

    np.testing.assert_array_equal(select_boxes(boxes, scores, 0.45, 3, only_0_and_1), [1, 0])
    assert sorted(asked) == list(range(12))


def test_config_refuses_a_window_smaller_than_the_predicted_roi():
    with pytest.raises(ValueError, match="window_grow"):
        DetectorConfig(window_grow=0.5)


def test_rois_of_boxes_off_or_on_the_image_edges_are_whole_pixels_inside_it():
    boxes = np.array([[-20.0, -10.0, -5.0, -2.0],  # wholly above-left: the corner pixel
                      [100.0, 730.0, 120.0, 740.0],  # below the image: its last row
                      [1300.0, 100.0, 1310.0, 110.5],  # right of it: its last column
                      [50.0, 60.0, 50.0, 60.0],  # a point on a pixel corner: that pixel
                      [10.5, 20.25, 11.0, 21.0]], np.float32)
    rois = Detections(boxes, np.ones(len(boxes))).rois(1280, 720)
    assert rois.tolist() == [[0, 0, 1, 1], [100, 719, 20, 1], [1279, 100, 1, 11], [50, 60, 1, 1], [10, 20, 1, 1]]


def test_decode_limits_the_log_size_and_reads_each_offset_from_its_own_channel():
    raw = np.full((5, 3, 4), -10.0, np.float32)
    raw[1:] = 0.0
    raw[:, 2, 1] = [3.0, 0.1, -0.2, 50.0, -50.0]  # huge log-width, tiny log-height
    raw[:, 0, 3] = [3.0, -0.25, 0.25, np.log(3.0), np.log(0.5)]
    boxes, scores = decode(raw, 16, 0.5)
    big, small = 16 * np.exp(MAX_LOG_SIZE), 16 * np.exp(-MAX_LOG_SIZE)
    cx, cy = (1.5 + 0.1) * 16, (2.5 - 0.2) * 16
    want = sorted([[cx - big / 2, cy - small / 2, cx + big / 2, cy + small / 2],
                   [(3.25 - 0.5 * 3) * 16, (0.75 - 0.25) * 16, (3.25 + 1.5) * 16, (0.75 + 0.25) * 16]])
    np.testing.assert_allclose(sorted(boxes.tolist()), want, rtol=1e-5)
    assert MAX_LOG_SIZE == 6.0  # = network.MAX_LOG_SIZE, which training clamps to


def test_decode_keeps_a_cell_scored_exactly_at_the_threshold():
    raw = np.zeros((5, 1, 2), np.float32)
    raw[0] = [0.0, -1e-3]  # σ(0) = 0.5 exactly; σ(−0.001) just under
    boxes, scores = decode(raw, 8, 0.5)
    np.testing.assert_allclose(boxes, [[0.0, 0.0, 8.0, 8.0]])
    assert scores.tolist() == [0.5]


@pytest.mark.parametrize("seed", range(3))
def test_letterbox_maps_the_resized_frame_edges_back_onto_the_frame_edges(seed):
    """For frames of many shapes (the resize to whole pixels makes each axis's scale differ from
    the one asked for, by up to half an input pixel across the frame): the content's edges in the
    input, [pad_x, pad_y, pad_x + nw, pad_y + nh], map back to [0, 0, w, h], and the frame's edges
    to the content's."""
    rng = np.random.default_rng(seed)
    for _ in range(40):
        w, h = (int(v) for v in rng.integers(3, 2000, 2))
        size = (int(rng.choice([320, 640, 960])), int(rng.choice([256, 384, 544])))
        image = np.zeros((h, w, 3), np.uint8)
        out, lb = letterbox(image, size, max_scale=float(rng.choice([1.0, 4.0])))
        image[:] = 255
        out = letterbox(image, size, max_scale=lb.scale)[0]
        cols, rows = np.flatnonzero(out[:, :, 0].max(axis=0) == 255), np.flatnonzero(out[:, :, 0].max(axis=1) == 255)
        content = np.array([[cols[0], rows[0], cols[-1] + 1.0, rows[-1] + 1.0]])
        np.testing.assert_allclose(lb.to_image(content), [[0, 0, w, h]], atol=1e-2, rtol=0)
        np.testing.assert_allclose(lb.to_input(np.array([[0.0, 0.0, w, h]])), content, atol=1e-3, rtol=0)


def test_letterbox_downscaling_averages_areas_so_a_thin_line_keeps_its_mass():
    """At ⅓ scale a one-pixel line must not vanish between samples: area averaging spreads it
    over its input pixel at a third of its brightness, and the image's total brightness scales by ⅑."""
    image = np.zeros((1080, 1920, 3), np.uint8)
    image[:, 900] = 255  # a thin vertical line, e.g. a far wing
    image[600] = 255  # and a horizontal one
    out, lb = letterbox(image, (640, 384))
    assert lb.scale == pytest.approx(1 / 3) and (lb.pad_x, lb.pad_y) == (0, 12)
    content = out[12:372].astype(float)
    assert content[:, 300, 0].min() == pytest.approx(85, abs=1)
    assert content[200, :, 0].min() == pytest.approx(85, abs=1)
    assert content.sum() == pytest.approx(image.astype(float).sum() / 9, rel=0.01)


def test_search_window_is_square_about_the_roi_centre_and_sized_by_its_larger_side():
    assert search_window((600, 300, 100, 40), 1280, 720, 3.0, 192) == (500, 170, 300, 300)
    assert search_window((600, 300, 40, 100), 1280, 720, 3.0, 192) == (470, 200, 300, 300)
    assert search_window((100, 100, 300, 300), 1280, 400, 2.0, 64) == (0, 0, 600, 400)  # taller than the frame


def test_rois_start_at_the_pixel_holding_the_boxs_top_left_corner():
    """Corners past a pixel's middle still belong to that pixel: [10.7, 20.9, 30.2, 40.1] covers
    pixels 10…30 by 20…40."""
    det = Detections(np.array([[10.7, 20.9, 30.2, 40.1]], np.float32), np.ones(1))
    assert det.rois(1280, 720).tolist() == [[10, 20, 21, 21]]


def test_decode_limits_a_huge_log_height_and_a_tiny_log_width_too():
    raw = np.zeros((5, 1, 1), np.float32)
    raw[:, 0, 0] = [3.0, 0.0, 0.0, -50.0, 50.0]
    boxes, _ = decode(raw, 8, 0.5)
    tiny, huge = 8 * np.exp(-MAX_LOG_SIZE), 8 * np.exp(MAX_LOG_SIZE)
    np.testing.assert_allclose(boxes, [[4 - tiny / 2, 4 - huge / 2, 4 + tiny / 2, 4 + huge / 2]], rtol=1e-5)


def test_a_box_exactly_half_a_fine_cell_from_a_window_side_is_dropped(detector):
    """The cut rule is inclusive: in the 224×192 window at (88, 194), boxes (window pixels) that
    end exactly 4 px from a side are dropped, 4.01 px from it kept (network output stubbed)."""
    window = (100, 200, 200, 180)  # → x 88..312, y 194..386
    cases = [([4.0, 50.0, 40.0, 80.0], False), ([4.01, 50.0, 40.0, 80.0], True),
             ([50.0, 4.0, 90.0, 40.0], False), ([50.0, 4.01, 90.0, 40.0], True),
             ([150.0, 50.0, 220.0, 80.0], False), ([150.0, 50.0, 219.99, 80.0], True),
             ([50.0, 100.0, 90.0, 188.0], False), ([50.0, 100.0, 90.0, 187.99], True)]
    for box, kept in cases:
        detector._infer = lambda image, scale, border, box=box: (np.array([box], np.float32),
                                                                 np.array([0.9], np.float32), Letterbox(1.0, 0, 0, 1.0, 1.0))
        det = detector.detect(frame_with([]), window=window)
        assert len(det.scores) == int(kept), (box, kept)
        if kept:
            np.testing.assert_allclose(det.boxes[0], np.add(box, [88, 194, 88, 194]), atol=1e-4)


def test_the_detector_applies_its_configured_threshold_overlap_and_box_limit(detector):
    """Seven boxes scored σ(4) ≈ 0.982, two of them overlapping by IoU ⅔: NMS at 0.45 keeps six,
    at 0.7 all seven; a limit of 3 keeps three; a threshold of 0.99 keeps none."""
    from dataclasses import replace

    row = [(16 + 48 * k, 100, 56 + 48 * k, 140) for k in range(5)]
    pair = [(16, 300, 56, 340), (24, 300, 64, 340)]  # 32×40 px shared of 40×40 each: IoU 1280 / 1920
    detector.session = FixedBoxesHead(detector.strides, row + pair)
    image = frame_with([])
    for changes, count in [({}, 6), ({"nms_iou": 0.7}, 7), ({"max_detections": 3}, 3),
                           ({"score_threshold": 0.99}, 0), ({"score_threshold": 0.98}, 6)]:
        detector.config = replace(DetectorConfig(threads=1), **changes)
        assert len(detector.detect(image).scores) == count, changes
