"""§5.4.1 likelihoods on hand-made tiles at the frame's borders and in degenerate cases, against
per-pixel loop oracles (scipy, OpenCV) and hand-computed values: (5.14) with tiles across every
side of the frame and with other bin counts, the silhouette's tight box, the outline band's
city-block distance and width, outline sample points and their normals (of single, noisy and
stacked tiles), the (5.15) contour search from the pixel under each sample point and the weights
λ_v and λ_e, the Canny edge map's hysteresis, and (5.16)-(5.17) on a frame without edges or a
silhouette outside it."""

import cv2
import numpy as np
import pytest
from scipy import ndimage

from test_tracking_likelihood import contour_search, oracle_outline
from uav_landing_vision.render import SilhouetteBatch
from uav_landing_vision.tracking.likelihood import (
    ColourConfig,
    ColourHistogramLikelihood,
    ContourConfig,
    ContourLikelihood,
    DistanceTransformConfig,
    DistanceTransformLikelihood,
    EdgeConfig,
    canny_edges,
    contour_likelihood,
)
from uav_landing_vision.tracking.likelihood_base import in_image, nearest_pixel, outline_points
from uav_landing_vision.tracking.likelihood_colour import outline_band, silhouette_box

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


@pytest.mark.parametrize("bins", [2, 4, 16, 64])
def test_colour_metric_with_other_bin_counts_matches_a_per_pixel_oracle(bins):
    """bins_per_channel other than the thesis's 8: each channel keeps its own block of bins."""
    rng = np.random.default_rng(45)
    frame = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
    frame[30:90, 40:120] = rng.integers(0, 256, 3, dtype=np.uint8)
    t = 16
    r, c = np.mgrid[:t, :t]
    masks = np.stack([(r - 7.5) ** 2 + (c - 7.5) ** 2 < 36, (c >= 2) & (c <= r + 2) & (r < 15)]).astype(np.uint8)
    boxes = np.array([[30.0, 20.0, 62.0, 52.0], [70.5, 60.25, 118.5, 108.25]])
    lik = ColourHistogramLikelihood(FrameSize(), ColourConfig(bins_per_channel=bins))
    lik.prepare(frame)
    got = lik.score_batch(SilhouetteBatch(masks, boxes, np.ones(2, bool)))
    np.testing.assert_allclose(got, [loop_colour(frame, masks[i], boxes[i], bins) for i in range(2)], atol=1e-12)


def test_silhouette_box_is_the_tight_box_and_empty_for_an_empty_tile():
    """A bar, scattered pixels and a sparse random tile: each tile's box is the rows and columns
    from its silhouette's first to its last; an empty tile has none."""
    rng = np.random.default_rng(43)
    t = 14
    masks = np.zeros((4, t, t), bool)
    masks[0, 3:5, 6:11] = True
    masks[1, rng.integers(0, t, 6), rng.integers(0, t, 6)] = True
    masks[2] = rng.random((t, t)) < 0.05
    # masks[3] stays empty
    got = silhouette_box(masks)
    for i in range(4):
        want = np.zeros((t, t), bool)
        if masks[i].any():
            rows, cols = np.nonzero(masks[i])
            want[rows.min() : rows.max() + 1, cols.min() : cols.max() + 1] = True
        np.testing.assert_array_equal(got[i], want, err_msg=f"tile {i}")


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


@pytest.mark.parametrize("band_px, box", [(2.55, [0.0, 0.0, 40.0, 40.0]), (1.28, [10.0, 10.0, 30.0, 30.0]),
                                          (5.15, [0.0, 0.0, 80.0, 80.0])])
def test_outline_band_width_counts_frame_pixels_of_the_tile_pixel_size(band_px, box):
    """Band widths just past a whole number of tile pixels plus a half (2.55 px at 1 px per tile
    pixel, 1.28 px at ½, 5.15 px at 2): the tile-pixel size is the box side over the tile
    side, and the ring at that distance joins the band exactly as the brute force says."""
    t = 40
    r, c = np.mgrid[:t, :t]
    masks = np.stack([(r - 19.5) ** 2 + (c - 19.5) ** 2 < 15**2,
                      np.abs(r - 19.5) + np.abs(c - 19.5) < 17]).astype(np.uint8)
    boxes = np.array([box, box])
    band = outline_band(masks, boxes, band_px)
    scale = (box[2] - box[0]) / t
    for i in range(len(masks)):
        np.testing.assert_array_equal(band[i], brute_band(masks[i], scale, band_px), err_msg=f"tile {i}")


def smoothed_gradient(mask):
    """(x, y) gradient at each tile pixel of the tile's mask, zero-padded and smoothed by the 5×5
    binomial kernel (scipy): the smoothed value one pixel before minus the one after."""
    b = np.array([1, 4, 6, 4, 1]) / 16
    smooth = ndimage.convolve(np.pad(mask.astype(float), 3), np.outer(b, b), mode="constant")
    return np.stack([smooth[3:-3, 2:-4] - smooth[3:-3, 4:-2], smooth[2:-4, 3:-3] - smooth[4:-2, 3:-3]], axis=-1)


def _sorted_rows(points, normals):
    rows = np.round(np.hstack([points, normals]), 9)
    return rows[np.lexsort(rows.T[::-1])]


def random_tiles(rng, v=4, t=12):
    """Noisy tiles (many pixels where the smoothed gradient is small but not zero) whose
    silhouettes touch every side of their tile, so neighbouring tiles of a stack meet."""
    masks = (rng.random((v, t, t)) < 0.55).astype(np.uint8)
    masks[:, 0, :] = masks[:, -1, :] = 1
    masks[:, :, 0] = 1
    return masks


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


def test_outline_normals_of_noisy_tiles_are_the_smoothed_mask_gradient_wherever_it_is_not_zero():
    """Every outline point and its normal equal the loop oracle's, including the many points of a
    noisy tile where the smoothed mask's gradient is small: only an exactly vanishing gradient
    falls back to the crack's direction."""
    rng = np.random.default_rng(41)
    masks = random_tiles(rng)
    boxes = np.array([[10.0, 20.0, 34.0, 44.0], [-5.5, 3.25, 18.5, 27.25], [100.0, 90.0, 112.0, 102.0],
                      [40.0, 40.0, 76.0, 76.0]])
    points, normals, owner = outline_points(masks, boxes)
    small = 0
    for i in range(len(masks)):
        want = oracle_outline(masks[i], boxes[i])
        wp = np.array([p for p, _ in want])
        wn = np.array([n for _, n in want])
        got = owner == i
        np.testing.assert_allclose(_sorted_rows(points[got], normals[got]), _sorted_rows(wp, wn), atol=1e-6,
                                   err_msg=f"tile {i}")
        mag = np.linalg.norm(smoothed_gradient(masks[i]), axis=-1)[masks[i] > 0]
        small += np.count_nonzero((mag > 1e-9) & (mag < 0.2))
    assert small > 0  # the case the test is about does occur


def test_outline_points_of_a_tile_do_not_depend_on_the_other_tiles_of_the_stack():
    """Tiles whose silhouettes touch their tile's sides, stacked: each tile's points and normals,
    in order, are those of the tile scored alone (the smoothing never mixes two tiles)."""
    rng = np.random.default_rng(42)
    masks = random_tiles(rng, v=5, t=10)
    masks[:, :, -1] = 1
    boxes = np.array([[0.0, 0.0, 20.0, 20.0]] * 5) + np.arange(5)[:, None] * 7.0
    points, normals, owner = outline_points(masks, boxes)
    for i in range(len(masks)):
        p1, n1, _ = outline_points(masks[i : i + 1], boxes[i : i + 1])
        np.testing.assert_array_equal(points[owner == i], p1, err_msg=f"tile {i}")
        np.testing.assert_array_equal(normals[owner == i], n1, err_msg=f"tile {i}")


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


def opencv_edges(frame, low, high, blur_sigma):
    """OpenCV's Canny (L2 gradient) of the RGB frame's grey, blurred by ``blur_sigma`` px."""
    grey = cv2.GaussianBlur(cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY), (0, 0), blur_sigma)
    return cv2.Canny(grey, low, high, L2gradient=True) > 0


def loop_contour(edges, mask, box, search):
    """(5.15) for one tile on the loop oracle's outline: the score and each match's distance."""
    score, _, found = contour_search(edges, oracle_outline(mask, box), search)
    return score, found


def test_contour_search_starts_at_the_pixel_under_the_sample_point():
    """A silhouette laid on the bright square's outline, and moved by up to two pixels: sample
    points whose own pixel is an edge pixel match at distance 0; the scores are the loop
    oracle's on the OpenCV edge map."""
    frame = _square_frame()
    edges = opencv_edges(frame, 50.0, 150.0, 1.0)
    t = 50
    mask = np.zeros((t, t), np.uint8)
    mask[5:45, 5:45] = 1  # 40 × 40 tile pixels at 1 px each: the square when the box starts at (55, 35)
    offsets = [(0.0, 0.0), (-1.0, 0.0), (1.0, 1.0), (0.5, -2.0), (-2.0, 0.5)]
    boxes = np.array([[55.0 + dx, 35.0 + dy, 105.0 + dx, 85.0 + dy] for dx, dy in offsets])
    masks = np.repeat(mask[None], len(boxes), axis=0)
    lik = ContourLikelihood(FrameSize(), ContourConfig(search_px=6))
    lik.prepare(frame)
    got = lik.score_batch(SilhouetteBatch(masks, boxes, np.ones(len(boxes), bool)))
    want = [loop_contour(edges, mask, b, 6) for b in boxes]
    assert any(0 in found for _, found in want)  # some sample points sit on an edge pixel
    np.testing.assert_allclose(got, [s for s, _ in want], rtol=1e-9, atol=0)


def test_canny_edges_keep_weak_edges_only_where_they_join_strong_ones():
    """A smooth random frame holds gradients between the two thresholds: the edge map is OpenCV's
    Canny with both thresholds (hysteresis), after the configured blur, of the RGB frame's grey."""
    rng = np.random.default_rng(44)
    small = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    frame = cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC)
    for cfg in (EdgeConfig(), EdgeConfig(canny_low=20.0, canny_high=120.0, blur_sigma=2.0)):
        want = opencv_edges(frame, cfg.canny_low, cfg.canny_high, cfg.blur_sigma)
        loose = opencv_edges(frame, cfg.canny_low, cfg.canny_low, cfg.blur_sigma)
        assert np.count_nonzero(loose & ~want) > 0  # hysteresis drops some weak edges here
        np.testing.assert_array_equal(canny_edges(frame, cfg), want)


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
