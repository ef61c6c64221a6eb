"""OBB (4.2)–(4.3): synthetic rectangles, lines and rotated shapes, silhouettes in pieces, angle convention,
FAST in a frame."""

import cv2
import numpy as np
import pytest

from uav_landing_vision.boosting.obb import (
    FastConfig,
    aspect_ratio,
    check_roi,
    fast_corners,
    grow_roi,
    obb_from_frame,
    obb_from_mask,
    obb_from_points,
    to_gray,
)


def _rotated_rect_mask(cx, cy, w, h, theta_deg, size=(400, 300)):
    mask = np.zeros((size[1], size[0]), np.uint8)
    pts = cv2.boxPoints(((cx, cy), (w, h), theta_deg))
    cv2.fillPoly(mask, [np.round(pts * 16).astype(np.int32)], 1, lineType=cv2.LINE_8, shift=4)
    return mask


def _angle_diff(a, b):
    return abs((a - b + 90.0) % 180.0 - 90.0)


def test_axis_aligned_rectangle_mask_gives_exact_box():
    mask = np.zeros((100, 200), np.uint8)
    mask[20:50, 30:110] = 1  # 80 wide, 30 tall
    box = obb_from_mask(mask)
    assert box.w == pytest.approx(80.0, abs=1e-3)
    assert box.h == pytest.approx(30.0, abs=1e-3)
    assert (box.x, box.y) == pytest.approx((69.5, 34.5), abs=1e-3)
    assert _angle_diff(box.theta, 0.0) < 1e-3
    assert box.aspect == pytest.approx(80 / 30)
    assert box.area == pytest.approx(2400.0, rel=1e-4)


def test_tall_rectangle_puts_long_side_first_at_90_degrees():
    mask = np.zeros((200, 100), np.uint8)
    mask[10:150, 40:60] = 1
    box = obb_from_mask(mask)
    assert (box.w, box.h) == pytest.approx((140.0, 20.0), abs=1e-3)
    assert _angle_diff(box.theta, 90.0) < 1e-3
    assert box.aspect > 1


@pytest.mark.parametrize("horizontal", [True, False])
def test_a_one_pixel_thick_line_of_pixels_is_a_box_one_pixel_thick(horizontal):
    """Each pixel counts to its extent: a 40-pixel line is a 40 x 1 box, exactly 1 px thick, not degenerate."""
    mask = np.zeros((30, 60), np.uint8)
    if horizontal:
        mask[12, 10:50] = 1
    else:
        mask[5:25, 33] = 1
    box = obb_from_mask(mask)
    assert box is not None
    w, theta, centre = (40.0, 0.0, (29.5, 12.0)) if horizontal else (20.0, 90.0, (33.0, 14.5))
    assert (box.w, box.h, box.x, box.y) == pytest.approx((w, 1.0, *centre), abs=1e-4)
    assert _angle_diff(box.theta, theta) < 1e-4


def test_a_silhouette_in_separate_pieces_is_boxed_as_a_whole():
    """Thin parts may vanish at the pixel scale and split the UAV's silhouette: the box holds every piece
    (oracle: the axis-aligned extent of two pieces side by side, the minimum-area box)."""
    mask = np.zeros((100, 200), np.uint8)
    mask[40:60, 20:70] = 1  # a wing
    mask[45:55, 120:180] = 1  # the other, detached, and smaller
    box = obb_from_mask(mask)
    assert (box.w, box.h, box.x, box.y) == pytest.approx((160.0, 20.0, 99.5, 49.5), abs=1e-3)
    assert _angle_diff(box.theta, 0.0) < 1e-3


@pytest.mark.parametrize("theta", [0.0, 17.0, 45.0, 89.0, 91.0, 123.0, 179.0, 200.0, -30.0])
def test_rotated_rectangle_points(theta):
    pts = cv2.boxPoints(((150.0, 120.0), (120.0, 40.0), theta))
    box = obb_from_points(pts)
    assert 0.0 <= box.theta < 180.0
    assert _angle_diff(box.theta, theta % 180.0) < 1e-3
    assert (box.w, box.h) == pytest.approx((120.0, 40.0), abs=1e-3)
    assert (box.x, box.y) == pytest.approx((150.0, 120.0), abs=1e-3)


@pytest.mark.parametrize("theta", [10.0, 60.0, 135.0])
def test_rotated_rectangle_mask_recovers_angle_and_size(theta):
    box = obb_from_mask(_rotated_rect_mask(200, 150, 160, 50, theta))
    assert _angle_diff(box.theta, theta) < 1.5
    assert box.w == pytest.approx(160, abs=3.5)  # filled polygons include their boundary pixels
    assert box.h == pytest.approx(50, abs=3.5)


def test_angle_is_periodic_180():
    pts = cv2.boxPoints(((100.0, 100.0), (80.0, 20.0), 30.0))
    a, b = obb_from_points(pts), obb_from_points(pts[::-1])
    c = obb_from_points(cv2.boxPoints(((100.0, 100.0), (80.0, 20.0), 210.0)))
    d = obb_from_points(cv2.boxPoints(((100.0, 100.0), (20.0, 80.0), 120.0)))  # same box, sides swapped
    for other in (b, c, d):
        assert _angle_diff(a.theta, other.theta) < 1e-3
        assert other.aspect == pytest.approx(a.aspect, rel=1e-5)


@pytest.mark.parametrize("theta", [0.0, 30.0, 45.0, 60.0, 90.0, 120.0])
def test_square_angle_does_not_follow_opencvs_corner_order(monkeypatch, theta):
    """A square's θ is defined mod 90°: it is the one in [0, 90), not the direction of whichever
    side ``cv2.boxPoints`` lists first: OpenCV 4.6 (minAreaRect angle in (0°, 90°]) starts one
    corner off from 5.0 (in [−90°, 0°)), and the same FAST corners gave θ 90° on one, 0° on the
    other. The rolled corners stand in for the other version."""
    pts = cv2.boxPoints(((100.0, 80.0), (40.0, 40.0), theta))
    box = obb_from_points(pts)
    box_points = cv2.boxPoints
    monkeypatch.setattr(cv2, "boxPoints", lambda rect: np.roll(box_points(rect), 1, axis=0))
    other_order = obb_from_points(pts)
    assert box.theta == pytest.approx(theta % 90.0, abs=1e-3)
    assert other_order.theta == pytest.approx(box.theta, abs=1e-3)
    assert obb_from_points(np.array([[3, 3], [3, 12], [12, 3], [12, 12], [7, 8]], float)).theta == 0.0


def test_non_square_angle_does_not_follow_opencvs_corner_order(monkeypatch):
    pts = cv2.boxPoints(((100.0, 80.0), (40.0, 39.9), 120.0))
    box = obb_from_points(pts)
    box_points = cv2.boxPoints
    monkeypatch.setattr(cv2, "boxPoints", lambda rect: np.roll(box_points(rect), 1, axis=0))
    assert obb_from_points(pts) == pytest.approx(box, abs=1e-3)
    assert box.theta == pytest.approx(120.0, abs=1e-3)


def test_rotated_shape_box_contains_all_points_minimally():
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(300, 2)) * [60.0, 12.0]
    rot = np.array([[np.cos(0.7), -np.sin(0.7)], [np.sin(0.7), np.cos(0.7)]])
    pts = pts @ rot.T + [200.0, 100.0]
    box = obb_from_points(pts)
    t = np.radians(box.theta)
    axes = np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])
    local = (pts - [box.x, box.y]) @ axes.T
    assert np.all(np.abs(local[:, 0]) <= box.w / 2 + 1e-3)
    assert np.all(np.abs(local[:, 1]) <= box.h / 2 + 1e-3)
    assert _angle_diff(box.theta, np.degrees(0.7)) < 5.0
    assert box.area <= cv2.boundingRect(pts.astype(np.float32))[2] * cv2.boundingRect(pts.astype(np.float32))[3]


def test_degenerate_inputs_give_none():
    assert obb_from_points(np.zeros((2, 2))) is None
    assert obb_from_points(np.array([[0, 0], [10, 0], [20, 0.0]])) is None  # collinear
    assert obb_from_mask(np.zeros((10, 10), np.uint8)) is None


def test_aspect_ratio_is_w_over_h():
    np.testing.assert_allclose(aspect_ratio(np.array([4.0, 9.0]), np.array([2.0, 3.0])), [2.0, 3.0])


def test_fast_box_of_a_drawn_rectangle_over_a_gradient():
    rows = np.linspace(60, 180, 300)[:, None, None] * np.ones((1, 400, 3))
    frame = rows.astype(np.uint8)
    pts = cv2.boxPoints(((220.0, 140.0), (150.0, 50.0), 25.0))
    cv2.fillPoly(frame, [np.round(pts).astype(np.int32)], (230, 230, 230))
    box = obb_from_frame(frame, (100, 50, 250, 200))
    assert _angle_diff(box.theta, 25.0) < 3.0
    assert (box.x, box.y) == pytest.approx((220.0, 140.0), abs=3.0)
    assert box.w == pytest.approx(150.0, abs=6.0)
    assert box.h == pytest.approx(50.0, abs=6.0)


def test_pixel_extent_measures_the_corners_as_the_database_measures_its_masks():
    """A filled 40 x 10 block: its mask's box is 40 x 10 (obb_from_mask, as the database's), the
    FAST box through its corner pixels' centres 39 x 9, and with ``pixel_extent`` 40 x 10."""
    frame = np.full((60, 80), 200, np.uint8)
    frame[25:35, 20:60] = 40
    assert obb_from_mask(frame == 40)[3:] == pytest.approx((40.0, 10.0))
    assert obb_from_frame(frame, (10, 15, 60, 30))[3:] == pytest.approx((39.0, 9.0))
    extent = obb_from_frame(frame, (10, 15, 60, 30), FastConfig(pixel_extent=True))
    assert extent[1:] == pytest.approx((39.5, 29.5, 40.0, 10.0))


def test_flat_roi_or_too_few_corners_has_no_box():
    frame = np.full((100, 100), 128, np.uint8)
    assert obb_from_frame(frame, (10, 10, 50, 50)) is None
    frame[30:40, 30:40] = 250  # four corners
    assert obb_from_frame(frame, (10, 10, 50, 50), FastConfig(min_corners=3)) is not None
    assert obb_from_frame(frame, (10, 10, 50, 50), FastConfig(min_corners=50)) is None


def test_grow_roi_adds_margin_and_pad_outward_and_clips():
    assert grow_roi((100, 50, 40, 10), 0.10, 2.0, 640, 480) == (94, 47, 52, 16)  # 4 px / 3 px each side
    assert grow_roi((100, 50, 40, 10), 0.0, 0.0, 640, 480) == (100, 50, 40, 10)
    assert grow_roi((1, 2, 636, 470), 0.10, 2.0, 640, 480) == (0, 0, 640, 480)
    with pytest.raises(ValueError, match="non-negative"):
        grow_roi((1, 2, 3, 4), -0.1, 0.0, 640, 480)
    with pytest.raises(ValueError, match="outside"):
        grow_roi((700, 2, 3, 4), 0.1, 2.0, 640, 480)


def test_fast_finds_no_corner_at_a_tight_roi_edge():
    """Why boosting grows ROIs: in a ROI tight on a thin bright bar, FAST (radius-3 ring) finds
    no corner at all; grown, the box is whole."""
    frame = np.full((100, 200), 90, np.uint8)
    frame[48:53, 40:160] = 230  # a 120 x 5 px "wing"
    tight = obb_from_frame(frame, (40, 48, 120, 5), FastConfig(min_corners=3))
    grown = obb_from_frame(frame, (40, 48, 120, 5), margin=0.10, pad_px=2.0)
    assert tight is None
    assert grown.w == pytest.approx(120.0, abs=3.0)


@pytest.mark.parametrize(
    "frame, roi, message",
    [
        (np.zeros((100, 100), np.float32), (0, 0, 10, 10), "uint8"),
        (np.zeros((100, 100, 2), np.uint8), (0, 0, 10, 10), "shape"),
        (np.zeros((100, 100), np.uint8), (0, 0, 0, 10), "empty"),
        (np.zeros((100, 100), np.uint8), (200, 10, 20, 20), "outside"),
        (np.zeros((100, 100), np.uint8), (1, 2, 3), "four numbers"),
        (np.zeros((100, 100), np.uint8), (float("inf"), 2, 3, 4), "four numbers"),
        (np.zeros((100, 100), np.uint8), (1, 2, float("-inf"), 4), "four numbers"),
        (np.zeros((100, 100), np.uint8), (1, 2, 3, float("nan")), "four numbers"),
    ],
)
def test_bad_frame_or_roi_is_a_clear_error(frame, roi, message):
    with pytest.raises(ValueError, match=message):
        obb_from_frame(frame, roi)


def _near_uav(wing_contrast: int) -> np.ndarray:
    """A near UAV seen head-on: a dark, high-contrast fuselage and long wings of low contrast."""
    frame = np.full((200, 400), 120, np.uint8)
    frame[96:104, 60:340] = 120 + wing_contrast  # wings, 280 x 8 px
    cv2.circle(frame, (200, 104), 12, 30, -1)  # fuselage
    return frame


LADDER = FastConfig(thresholds=(20, 16, 12, 10, 8), min_cover=0.9)


def test_threshold_ladder_finds_low_contrast_wings():
    """At the thesis's single threshold the box holds the fuselage only; the ladder goes down
    until the corners span the ROI, and the box takes in the wings."""
    frame, roi = _near_uav(wing_contrast=14), (60, 90, 280, 28)
    thesis = obb_from_frame(frame, roi, FastConfig(thresholds=(20,)), 0.10, 2.0)
    ladder = obb_from_frame(frame, roi, LADDER, 0.10, 2.0)
    assert thesis.w < 40.0
    assert ladder.w == pytest.approx(280.0, abs=4.0)
    assert obb_from_frame(frame, roi, FastConfig(thresholds=LADDER.thresholds, min_cover=0.0), 0.10, 2.0) == thesis
    assert obb_from_frame(frame, roi, FastConfig(), 0.10, 2.0) == thesis  # the default is the thesis's


def test_threshold_ladder_stops_at_the_first_threshold_that_spans_the_roi():
    frame, roi = _near_uav(wing_contrast=60), (60, 90, 280, 28)
    assert obb_from_frame(frame, roi, LADDER, 0.10, 2.0) == obb_from_frame(frame, roi, FastConfig(), 0.10, 2.0)


def test_threshold_ladder_falls_back_to_the_widest_box():
    """No threshold spans enough (the ROI is far larger than the UAV): the widest box is used."""
    frame, roi = _near_uav(wing_contrast=14), (0, 0, 400, 200)
    box = obb_from_frame(frame, roi, FastConfig(thresholds=LADDER.thresholds, min_cover=1.0))
    assert box.w == pytest.approx(280.0, abs=4.0)


def test_threshold_ladder_only_for_rois_up_to_its_size_limit():
    """With ``ladder_max_px`` a ROI longer than the limit gets the first threshold alone."""
    frame, roi = _near_uav(wing_contrast=14), (60, 90, 280, 28)
    thesis = obb_from_frame(frame, roi, FastConfig(), 0.10, 2.0)
    for limit, expected_w in [(0.0, 280.0), (280.0, 280.0), (279.0, thesis.w), (64.0, thesis.w)]:
        box = obb_from_frame(frame, roi, FastConfig(LADDER.thresholds, LADDER.min_cover, ladder_max_px=limit), 0.10, 2.0)
        assert box.w == pytest.approx(expected_w, abs=4.0), limit
    assert FastConfig(LADDER.thresholds, ladder_max_px=64.0).thresholds_for(64.0) == LADDER.thresholds
    assert FastConfig(LADDER.thresholds, ladder_max_px=64.0).thresholds_for(64.5) == (20,)


@pytest.mark.parametrize("kwargs", [{"thresholds": (0,)}, {"thresholds": (256,)}, {"thresholds": ()},
                                    {"thresholds": (8, 20)}, {"min_cover": 1.5}, {"min_corners": 2},
                                    {"ladder_max_px": -1.0}, {"ladder_max_px": float("nan")}])
def test_fast_config_validation(kwargs):
    with pytest.raises(ValueError):
        FastConfig(**kwargs)


def test_a_box_under_a_pixel_thick_is_degenerate():
    """Not collinear, but 0.5 px thick: no box (its area, hence the depth (4.5), is meaningless);
    exactly 1 px thick is a box."""
    assert obb_from_points(np.array([[0.0, 0.0], [100.0, 0.0], [50.0, 0.5]])) is None
    assert obb_from_points(np.array([[0.0, 0.0], [100.0, 0.0], [50.0, 1.5]])) is not None
    exactly_one = obb_from_points(np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 1.0], [0.0, 1.0]]))
    assert exactly_one is not None and (exactly_one.w, exactly_one.h) == pytest.approx((100.0, 1.0))


def test_check_roi_rounds_and_clips_each_side():
    """Fractional ROIs round; a ROI hanging off the left is clipped; one that only
    touches the image's right edge is outside."""
    assert check_roi((10.6, 20.4, 30.7, 40.2), 100, 100) == (11, 20, 31, 40)
    assert check_roi((-5, 10, 30, 20), 100, 100) == (0, 10, 25, 20)
    with pytest.raises(ValueError, match="outside"):
        check_roi((100, 10, 20, 20), 100, 100)
    with pytest.raises(ValueError, match="outside"):
        obb_from_frame(np.zeros((100, 100), np.uint8), (100, 10, 20, 20))


def test_grow_roi_refuses_negative_pad_and_grows_to_whole_pixels_outward():
    """A fractional growth (2.25 px left and right, 0.5 px top and bottom) takes
    in the whole pixel."""
    with pytest.raises(ValueError, match="non-negative"):
        grow_roi((100, 50, 40, 10), 0.0, -1.0, 640, 480)
    assert grow_roi((100, 50, 45, 10), 0.05, 0.0, 640, 480) == (97, 49, 51, 12)


def test_to_gray_weights_rgb_as_rgb():
    """Frames are RGB (nodes/image.py): red weighs 0.299, blue 0.114."""
    frame = np.zeros((1, 2, 3), np.uint8)
    frame[0, 0] = (255, 0, 0)
    frame[0, 1] = (0, 0, 255)
    np.testing.assert_array_equal(to_gray(frame), [[76, 29]])


def test_min_corners_is_a_least_count():
    """Exactly ``min_corners`` corners give a box."""
    frame = np.full((100, 100), 128, np.uint8)
    frame[30:40, 30:40] = 250
    n = len(fast_corners(frame[10:60, 10:60], 20))
    assert obb_from_frame(frame, (10, 10, 50, 50), FastConfig(min_corners=n)) is not None
    assert obb_from_frame(frame, (10, 10, 50, 50), FastConfig(min_corners=n + 1)) is None


def _bar_and_blob(blob_cols):
    frame = np.full((200, 300), 100, np.uint8)
    frame[100:106, 50:150] = 200  # high contrast: threshold 20 finds it, spans 99 px
    frame[60:70, blob_cols] = 112  # low contrast: threshold 8 only
    return frame


def test_ladder_ties_keep_the_higher_threshold():
    """No threshold spans the ROI; both span 99 px: the first (highest) one's box, not the
    one that also takes in a faint blob 35 px above the bar."""
    frame = _bar_and_blob(slice(95, 105))
    box = obb_from_frame(frame, (20, 40, 260, 100), FastConfig(thresholds=(20, 8), min_cover=1.0))
    assert box.h < 10.0


def test_ladder_stops_at_a_span_exactly_min_cover():
    """"at least ``min_cover``": a span of exactly 0.5 × 198 px stops the ladder."""
    frame = _bar_and_blob(slice(160, 170))
    box = obb_from_frame(frame, (40, 50, 198, 70), FastConfig(thresholds=(20, 8), min_cover=0.5))
    assert box == obb_from_frame(frame, (40, 50, 198, 70), FastConfig(thresholds=(20,)))
    assert box.w < 101.0


def test_threshold_ladder_measures_the_span_along_the_longer_axis():
    """The near UAV of the ladder's test above, turned upright: the ladder still finds its wings."""
    frame = np.full((200, 400), 120, np.uint8)
    frame[96:104, 60:340] = 134
    cv2.circle(frame, (200, 104), 12, 30, -1)
    upright = np.ascontiguousarray(frame.T)
    box = obb_from_frame(upright, (90, 60, 28, 280), FastConfig(thresholds=(20, 16, 12, 10, 8), min_cover=0.9), 0.10, 2.0)
    assert box.w == pytest.approx(280.0, abs=4.0)
