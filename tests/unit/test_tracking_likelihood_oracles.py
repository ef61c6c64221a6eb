"""§5.4.1 likelihoods on hand-made tiles at the frame's borders and in degenerate cases, against
per-pixel loop oracles and hand-computed values: (5.14) with tiles across every side of the frame,
the outline band's city-block distance, outline sample points and their normals, the
(5.15) weights λ_v and λ_e, and (5.16)-(5.17) on a frame without edges or a silhouette outside it."""

import numpy as np
import pytest

from uav_landing_vision.render import SilhouetteBatch
from uav_landing_vision.tracking.likelihood import (
    ColourConfig,
    ColourHistogramLikelihood,
    ContourConfig,
    ContourLikelihood,
    DistanceTransformConfig,
    DistanceTransformLikelihood,
    contour_likelihood,
)
from uav_landing_vision.tracking.likelihood_base import in_image, nearest_pixel, outline_points
from uav_landing_vision.tracking.likelihood_colour import outline_band

W, H = 160, 120


class FrameSize:
    """All the likelihoods take from a renderer outside ``score``: the frame size."""

    width, height = W, H


def loop_colour(frame, mask, box, bins=8):
    """(5.14) of one tile by explicit loops: every tile pixel of the silhouette's tight box samples
    the frame pixel under its centre (when that centre lies on the frame); inside pixels fill the
    inner histogram, the others the outer one; None when either is empty."""
    t = mask.shape[0]
    h, w, _ = frame.shape
    size = (box[2] - box[0]) / t
    rows, cols = np.nonzero(mask)
    hist = {True: np.zeros(3 * bins), False: np.zeros(3 * bins)}
    for r in range(rows.min(), rows.max() + 1):
        for c in range(cols.min(), cols.max() + 1):
            x, y = box[0] + (c + 0.5) * size, box[1] + (r + 0.5) * size
            col, row = int(np.floor(x + 0.5)), int(np.floor(y + 0.5))
            if not (0 <= col < w and 0 <= row < h):
                continue
            for ch in range(3):
                hist[bool(mask[r, c])][ch * bins + int(frame[row, col, ch]) * bins // 256] += 1
    if hist[True].sum() == 0 or hist[False].sum() == 0:
        return 0.0
    inner, outer = hist[True] / hist[True].sum(), hist[False] / hist[False].sum()
    return 1.0 - float(np.sum(np.sqrt(inner * outer)))


def test_colour_metric_of_tiles_across_each_side_of_the_frame_matches_a_per_pixel_oracle():
    """Tiles hanging over the right, bottom, left and top sides and the bottom-right corner: the
    tile pixels whose centres fall off the frame count in neither histogram (a pixel past the
    right side must not wrap onto the next row, nor one past the bottom read outside the frame)."""
    rng = np.random.default_rng(11)
    frame = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    frame[:, W - 6 :] = (250, 10, 10)  # a red band along the right side ...
    frame[:, :6] = (10, 250, 10)  # ... a green one along the left: pixels wrapped from one to the other differ
    t = 16
    r, c = np.mgrid[:t, :t]
    disc = ((r - 7.5) ** 2 + (c - 7.5) ** 2 < 36).astype(np.uint8)
    wedge = ((c >= 2) & (c <= r + 2) & (r < 15)).astype(np.uint8)
    masks = np.stack([disc, wedge, disc, wedge, wedge])
    boxes = np.array([[W - 20.0, 40.0, W + 12.0, 72.0],  # over the right side
                      [50.3, H - 18.6, 82.3, H + 13.4],  # over the bottom
                      [-14.0, 30.0, 18.0, 62.0],  # over the left
                      [70.0, -12.2, 102.0, 19.8],  # over the top
                      [W - 16.0, H - 16.0, W + 16.0, H + 16.0]])  # over the bottom-right corner
    lik = ColourHistogramLikelihood(FrameSize())
    lik.prepare(frame)
    got = lik.score_batch(SilhouetteBatch(masks, boxes, np.ones(len(masks), bool)))
    want = [loop_colour(frame, masks[i], boxes[i]) for i in range(len(masks))]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert np.all(got > 0)
    shifts = np.array([[3.0, 0.0], [0.0, 4.0], [-2.5, -1.5]])
    moved = lik.score_shifted(SilhouetteBatch(masks, boxes, np.ones(len(masks), bool)), shifts)
    for j, s in enumerate(shifts):
        want = [loop_colour(frame, masks[i], boxes[i] + np.tile(s, 2)) for i in range(len(masks))]
        np.testing.assert_allclose(moved[:, j], want, rtol=0, atol=1e-12)


def brute_band(mask, scale, band_px):
    """The outline band by brute force: each tile pixel's city-block distance (in tile pixels) to
    the nearest pixel of the other region, kept below max(band_px / scale, 1) + ½, that limit
    narrowed to half the depth of the deepest inside pixel (its distance − ½) + ½."""
    inside = np.argwhere(mask > 0)
    outside = np.argwhere(mask == 0)
    # the tile's zero surround counts as outside: extend the outside set by a ring of pixels
    t = mask.shape[0]
    ring = [(r, c) for r in range(-1, t + 1) for c in range(-1, t + 1) if not (0 <= r < t and 0 <= c < t)]
    outside = np.vstack([outside, np.array(ring)])
    dist = np.zeros(mask.shape)
    for r in range(t):
        for c in range(t):
            other = outside if mask[r, c] else inside
            dist[r, c] = np.abs(other - [r, c]).sum(axis=1).min()
    core = dist[mask > 0].max() - 0.5
    limit = min(max(band_px / scale, 1.0), 0.5 * core) + 0.5
    return dist < limit


@pytest.mark.parametrize("band_px", [1.0, 3.0, 5.0])
def test_outline_band_uses_city_block_distance_to_the_outline(band_px):
    """A diamond and a disc (outlines off the axes, where city-block and chessboard distance
    differ) and a 45° slab: the band is the brute-force city-block band."""
    t = 40
    r, c = np.mgrid[:t, :t]
    masks = np.stack([np.abs(r - 19.5) + np.abs(c - 19.5) < 15,
                      (r - 19.5) ** 2 + (c - 19.5) ** 2 < 14**2,
                      np.abs(r - c) < 9]).astype(np.uint8)
    # 1, ½ and 2 frame px per tile px
    boxes = np.array([[0.0, 0.0, 40.0, 40.0], [10.0, 10.0, 30.0, 30.0], [0.0, 0.0, 80.0, 80.0]])
    band = outline_band(masks, boxes, band_px)
    for i in range(len(masks)):
        scale = (boxes[i, 2] - boxes[i, 0]) / t
        np.testing.assert_array_equal(band[i], brute_band(masks[i], scale, band_px), err_msg=f"tile {i}")


def test_an_isolated_tile_pixel_has_four_outline_points_with_the_crack_directions_as_normals():
    """One inside pixel: the smoothed mask's gradient vanishes at its centre, so each of its four
    outline points takes its crack's outward direction as normal."""
    t = 8
    masks = np.zeros((1, t, t), np.uint8)
    masks[0, 3, 5] = 1
    boxes = np.array([[100.0, 50.0, 116.0, 66.0]])  # 2 frame px per tile px
    points, normals, owner = outline_points(masks, boxes)
    centre = np.array([100.0 + 5.5 * 2, 50.0 + 3.5 * 2])
    got = sorted(zip(map(tuple, np.round(points - centre, 9)), map(tuple, normals)))
    want = sorted([((1.0, 0.0), (1.0, 0.0)), ((-1.0, 0.0), (-1.0, 0.0)),
                   ((0.0, 1.0), (0.0, 1.0)), ((0.0, -1.0), (0.0, -1.0))])
    assert got == want
    assert owner.tolist() == [0, 0, 0, 0]


def test_outline_normals_of_a_square_point_outward_and_sit_on_the_pixel_sides():
    """A 4×4 square: 16 points, each on the side of an edge pixel, its normal pointing away from
    the square's centre (x right, y down)."""
    t = 12
    masks = np.zeros((1, t, t), np.uint8)
    masks[0, 4:8, 2:6] = 1
    points, normals, _ = outline_points(masks, np.array([[0.0, 0.0, 12.0, 12.0]]))
    assert len(points) == 16
    centre = np.array([4.0, 6.0])  # columns 2..5 → x 2..6; rows 4..7 → y 4..8
    away = points - centre
    assert np.all(np.sum(away * normals, axis=1) > 0)
    on_side = np.isclose(np.abs(away[:, 0]), 2.0) | np.isclose(np.abs(away[:, 1]), 2.0)
    assert on_side.all()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0)


def test_in_image_and_nearest_pixel_follow_the_pixel_under_the_point():
    """A point falls on the frame when the pixel under it (floor(x + ½), floor(y + ½)) exists."""
    xs = np.array([-0.75, -0.5, -0.25, 0.0, W - 1.0, W - 0.75, W - 0.5 - 1e-9, W - 0.5, W - 0.25])
    ys = np.array([-0.75, -0.5, -0.25, 0.0, H - 1.0, H - 0.75, H - 0.5 - 1e-9, H - 0.5, H - 0.25])
    for along_x in (True, False):
        pts = np.stack([xs, np.full_like(xs, 10.0)] if along_x else [np.full_like(ys, 10.0), ys], axis=1)
        size = W if along_x else H
        coord = pts[:, 0] if along_x else pts[:, 1]
        want = (np.floor(coord + 0.5) >= 0) & (np.floor(coord + 0.5) <= size - 1)
        np.testing.assert_array_equal(in_image(pts, W, H), want)
        row, col = nearest_pixel(pts[want], W, H)
        np.testing.assert_array_equal(col if along_x else row, np.floor(coord[want] + 0.5).astype(int))


def test_contour_weights_lambda_v_and_lambda_e_apply_to_their_own_terms():
    """(5.15): λ_v weighs the unmatched share, λ_e the mean edge distance."""
    assert contour_likelihood(10, 6, 2.0, 0.5, 3.0) == pytest.approx(np.exp(-0.5 * 0.4) * np.exp(-3.0 * 2.0))
    assert contour_likelihood(8, 2, 0.5, 2.0, 0.25) == pytest.approx(np.exp(-2.0 * 0.75) * np.exp(-0.25 * 0.5))


def _square_frame():
    """A bright square on a dark frame: Canny finds its four sides."""
    frame = np.full((H, W, 3), 20, np.uint8)
    frame[40:80, 60:100] = 230
    return frame


def test_contour_score_of_a_silhouette_far_from_every_edge_weighs_its_terms_by_lambda_v_and_lambda_e():
    """A silhouette 35 px from the only edges matches no sample point within search_px = 8: the
    unmatched share is 1 and ē = search_px, so the score is exp(−λ_v) · exp(−8 λ_e)."""
    t = 20
    full = np.ones((1, t, t), np.uint8)
    far = np.array([[5.0, 5.0, 25.0, 25.0]])  # 20 px from the square: nothing within 8 px
    for lv, le in ((1.0, 1.0), (0.5, 0.2), (2.0, 0.05)):
        lik = ContourLikelihood(FrameSize(), ContourConfig(search_px=8, lambda_v=lv, lambda_e=le))
        lik.prepare(_square_frame())
        score = lik.score_batch(SilhouetteBatch(full, far, np.ones(1, bool)))[0]
        assert score == pytest.approx(np.exp(-lv * 1.0) * np.exp(-le * 8.0))


def test_a_silhouette_whose_outline_lies_off_the_frame_scores_zero():
    """A visible pose (its box overlaps the frame) whose silhouette lies wholly in the part off the
    frame has no sample point to compare: both edge metrics score 0, not exp(0) = 1 or e^(−λ)."""
    t = 16
    mask = np.zeros((1, t, t), np.uint8)
    mask[0, 4:12, 2:8] = 1  # left half of the tile
    box = np.array([[-20.0, 30.0, 12.0, 62.0]])  # 2 px per tile px: the silhouette spans x −16 … −4
    batch = SilhouetteBatch(mask, box, np.ones(1, bool))
    for lik in (ContourLikelihood(FrameSize()), DistanceTransformLikelihood(FrameSize())):
        lik.prepare(_square_frame())
        assert lik.score_batch(batch)[0] == 0.0


def test_distance_transform_of_a_frame_without_edges_is_one_diagonal():
    """No edge in the frame: D = 1 (an image diagonal) everywhere, so L_DT = exp(−σ)."""
    t = 16
    mask = np.zeros((1, t, t), np.uint8)
    mask[0, 3:13, 3:13] = 1
    batch = SilhouetteBatch(mask, np.array([[40.0, 30.0, 72.0, 62.0]]), np.ones(1, bool))
    for sigma in (0.5, 2.0):
        lik = DistanceTransformLikelihood(FrameSize(), DistanceTransformConfig(sigma=sigma))
        lik.prepare(np.full((H, W, 3), 90, np.uint8))
        assert lik.score_batch(batch)[0] == pytest.approx(np.exp(-sigma))


def test_histograms_are_the_inner_then_the_outer_counts():
    """Inner: three channel counts per inside tile pixel; outer: per other pixel of the tight box."""
    t = 16
    mask = np.zeros((1, t, t), np.uint8)
    mask[0, 4:10, 3:7] = 1  # 24 inside pixels
    mask[0, 10:12, 3:13] = 1  # 20 more: tight box rows 4..11, columns 3..12 → 80 pixels, 36 outside
    lik = ColourHistogramLikelihood(FrameSize())
    lik.prepare(np.random.default_rng(12).integers(0, 256, (H, W, 3), dtype=np.uint8))
    inner, outer = lik.histograms(mask, np.array([[20.0, 20.0, 52.0, 52.0]]))
    assert inner.sum() == 3 * 44 and outer.sum() == 3 * 36


def test_a_pose_marked_invisible_scores_zero_whatever_its_tile_holds():
    t = 16
    r, c = np.mgrid[:t, :t]
    masks = np.repeat(((c >= 2) & (c <= r) & (r < 14)).astype(np.uint8)[None], 2, axis=0)  # a triangle
    boxes = np.array([[50.0, 30.0, 82.0, 62.0]] * 2)  # across the square's corner
    batch = SilhouetteBatch(masks, boxes, np.array([True, False]))
    frame = _square_frame()
    for lik in (ColourHistogramLikelihood(FrameSize()), ContourLikelihood(FrameSize()),
                DistanceTransformLikelihood(FrameSize())):
        lik.prepare(frame)
        scores = lik.score_shifted(batch, np.array([[0.0, 0.0], [25.0, 15.0]]))
        assert np.all(scores[0] > 0) and np.all(scores[1] == 0.0), type(lik).__name__
