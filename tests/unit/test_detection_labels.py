"""Fig. 4.4 labels against shapely: projected hull clipped to the image → minimum-area rotated
rectangle → its axis-aligned ROI (pixel edges) clipped to the image; and the runner-up rule."""

import numpy as np
import pytest
from shapely.geometry import MultiPoint, Polygon, box

from uav_landing_vision.detection.dataset import model_roi, oriented_box_tie, outline_roi, read_labels, yolo_line
from uav_landing_vision.detection.detector import box_iou


K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 40.0], [0.0, 0.0, 1.0]])
W, H = 100, 80
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def _shapely_label(uv: np.ndarray, oriented: bool):
    hull = MultiPoint([tuple(p) for p in uv]).convex_hull
    seen = hull.intersection(box(-0.5, -0.5, W - 0.5, H - 0.5))
    if seen.is_empty or seen.area <= 0:
        return None
    shape = seen.minimum_rotated_rectangle if oriented else seen
    x0, y0, x1, y1 = shape.bounds
    roi = np.array([max(x0 + 0.5, 0.0), max(y0 + 0.5, 0.0), min(x1 + 0.5, W), min(y1 + 0.5, H)])
    return roi if roi[2] > roi[0] and roi[3] > roi[1] else None


def _edge_rects(outline):
    """Areas and unclipped corner extents of the enclosing rectangle along each edge."""
    out = []
    for i in range(len(outline)):
        e = outline[(i + 1) % len(outline)] - outline[i]
        if np.hypot(*e) < 1e-9:
            continue
        c, s = e / np.hypot(*e)
        local = outline @ np.array([[c, -s], [s, c]])  # coordinates along / across the edge
        (u0, v0), (u1, v1) = local.min(0), local.max(0)
        corners = np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]]) @ np.array([[c, s], [-s, c]])
        out.append(((u1 - u0) * (v1 - v0), corners))
    return out


def _is_tie(uv):
    """Whether two edges of the clipped hull give minimum-area rectangles with different ROIs."""
    seen = MultiPoint([tuple(p) for p in uv]).convex_hull.intersection(box(-0.5, -0.5, W - 0.5, H - 0.5))
    if seen.is_empty or seen.area <= 0:
        return False
    rects = _edge_rects(np.array(seen.exterior.coords)[:-1])
    best = min(a for a, _ in rects)
    extents = [np.r_[c.min(0), c.max(0)] for a, c in rects if a <= best * (1 + 1e-6)]
    return any(np.abs(e - extents[0]).max() > 1e-3 for e in extents)


def _tilted_bar(rng, centre_px):
    """A thin 2D bar, tilted at random, with a bump on one side (no symmetric ties), at 10 m."""
    a = rng.uniform(0, np.pi)
    length, width = rng.uniform(15, 40), rng.uniform(2, 8)
    local = np.array([[-length, -width], [length, -width], [length, width], [0.3 * length, 2.2 * width],
                      [-length, width]]) / 2
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    uv = local @ rot.T + centre_px
    return np.c_[(uv - K[:2, 2]) / 10.0, np.zeros(len(uv))], uv  # body points at z = 10 (f = 100)


@pytest.mark.parametrize("where", ["inside", "left", "top", "right", "bottom", "corner"])
def test_oriented_and_extent_labels_match_shapely_for_tilted_shapes_in_and_across_the_edges(where):
    centres = {"inside": (50, 40), "left": (2, 40), "top": (50, 1), "right": (98, 40), "bottom": (50, 78),
               "corner": (1, 1)}
    rng = np.random.default_rng(list(centres).index(where))
    checked = 0
    for _ in range(25):
        vertices, uv = _tilted_bar(rng, np.array(centres[where], float) + rng.uniform(-3, 3, 2))
        for oriented in (True, False):
            got = model_roi(vertices, K, IDENTITY, [0.0, 0.0, 10.0], W, H, oriented=oriented)
            want = _shapely_label(uv, oriented)
            if oriented and _is_tie(uv):  # either rectangle is Fig. 4.4's box
                continue
            if want is None:
                assert got is None
                continue
            np.testing.assert_allclose(got, want, atol=2e-3)
            checked += 1
    assert checked >= 40


def test_oriented_box_reaching_past_the_image_is_clipped_at_zero():
    # A bar tilted by 30° whose corner touches the top-left: its rotated rectangle reaches
    # beyond the image edge, the ROI stops at 0.
    a = np.radians(30.0)
    rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    uv = np.array([[-20.0, -3.0], [20.0, -3.0], [20.0, 3.0], [-20.0, 3.0]]) @ rot.T + [18.0, 12.0]
    roi = outline_roi(uv, W, H)
    assert roi[0] == 0.0 and roi[1] == 0.0
    want = _shapely_label(uv, True)
    np.testing.assert_allclose(roi, want, atol=2e-3)


def test_a_sliver_that_clips_to_nothing_has_no_label():
    # wholly to the right of the image's last pixel edge
    uv = np.array([[W - 0.5, 10.0], [W + 5.0, 10.0], [W + 5.0, 20.0]])
    vertices = np.c_[(uv - K[:2, 2]) / 10.0, np.zeros(3)]
    assert model_roi(vertices, K, IDENTITY, [0.0, 0.0, 10.0], W, H) is None
    assert outline_roi(np.array([[W + 1.0, 10.0], [W + 2.0, 10.0], [W + 2.0, 12.0]]), W, H) is None


def _brute_tie(outline, width, height, distinct_iou=0.8):
    """Oracle: every edge's enclosing rectangle, its corners by explicit rotation."""
    label = outline_roi(outline, width, height)
    cands = []
    for area, corners in _edge_rects(outline):
        lo = np.maximum(corners.min(0) + 0.5, 0)
        hi = np.minimum(corners.max(0) + 0.5, (width, height))
        if np.all(hi > lo):
            cands.append((area, np.r_[lo, hi]))
    areas = np.array([a for a, _ in cands])
    distinct = [(a, r) for a, r in cands if box_iou(r[None], label[None])[0, 0] < distinct_iou]
    if not distinct:
        return np.inf, None
    a, r = min(distinct, key=lambda x: x[0])
    return a / areas.min() - 1.0, r


@pytest.mark.parametrize("seed", range(6))
def test_oriented_box_tie_matches_a_brute_force_over_the_edges(seed):
    rng = np.random.default_rng(100 + seed)
    pts = rng.uniform([10, 10], [90, 70], (9, 2))
    hull = MultiPoint([tuple(p) for p in pts]).convex_hull
    outline = np.array(hull.exterior.coords)[:-1]
    # a repeated vertex (zero-length edge) must not matter
    outline = np.insert(outline, 2, outline[2], axis=0)
    margin, roi = oriented_box_tie(outline, W, H)
    want_margin, want_roi = _brute_tie(outline, W, H)
    assert np.isfinite(margin) == np.isfinite(want_margin)
    if np.isfinite(want_margin):
        assert margin == pytest.approx(want_margin, abs=1e-6)
        np.testing.assert_allclose(roi, want_roi, atol=1e-6)


def test_oriented_box_tie_of_a_shape_in_the_image_corner_uses_clipped_rois():
    # an acute triangle in the top-left corner: its edge rectangles reach outside the image
    outline = np.array([[2.0, -4.0], [45.0, 6.0], [10.0, 35.0]])
    margin, roi = oriented_box_tie(outline, W, H)
    want_margin, want_roi = _brute_tie(outline, W, H)
    assert np.isfinite(want_margin)
    assert margin == pytest.approx(want_margin, abs=1e-6)
    np.testing.assert_allclose(roi, want_roi, atol=1e-6)


def test_yolo_lines_normalise_x_by_the_width_and_y_by_the_height(tmp_path):
    line = yolo_line(np.array([10.0, 20.0, 50.0, 30.0]), 200, 100)
    assert line == "0 0.150000 0.250000 0.200000 0.100000"
    (tmp_path / "l.txt").write_text(line + "\n")
    np.testing.assert_allclose(read_labels(tmp_path / "l.txt", 200, 100), [[10.0, 20.0, 50.0, 30.0]], atol=1e-4)
