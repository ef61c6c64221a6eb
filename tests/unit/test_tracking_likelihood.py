"""§5.4.1 likelihoods: (5.14) against a per-pixel loop oracle, (5.15)–(5.17) against a per-point loop
oracle (OpenCV edges, scipy distances), batching, ranking, frame and configuration checks."""

import cv2
import numpy as np
import pytest
from scipy import ndimage

from uav_landing_vision.camera import load_camera_info_yaml
from uav_landing_vision.config import ConfigError
from uav_landing_vision.geometry import euler_zyx_to_quat, quat_multiply
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.render import Renderer, SilhouetteBatch
from uav_landing_vision.render.backdrop import sky_and_sea
from uav_landing_vision.resources import config_path
from uav_landing_vision.sim.trajectory import FACING_CAMERA
from uav_landing_vision.tracking.likelihood import (
    LIKELIHOODS,
    ColourConfig,
    ColourHistogramLikelihood,
    ContourConfig,
    DistanceTransformConfig,
    EdgeConfig,
    colour_similarity,
    contour_likelihood,
    dt_likelihood,
    make_likelihood,
    mean_edge_distance,
)
from uav_landing_vision.tracking.likelihood_colour import outline_band
from uav_landing_vision.tracking.optimisation import evaluate
from uav_landing_vision.tracking.particles import ParticleSet

NAMES = sorted(LIKELIHOODS)
Q_TRUE = quat_multiply(euler_zyx_to_quat(np.radians([10.0, -15.0, 20.0])), FACING_CAMERA)
T_TRUE = np.array([0.4, -0.3, 8.0])


@pytest.fixture(scope="module")
def renderer():
    camera = load_camera_info_yaml(config_path("camera.yaml")).rectified()
    return Renderer(camera, fixed_wing_mesh("low"), tile=64, max_batch=64)


@pytest.fixture(scope="module")
def frame(renderer):
    """The scoring mesh rendered shaded at the true pose over a sky/sea gradient."""
    rgb, _ = renderer.shaded(Q_TRUE, T_TRUE, sky_and_sea(renderer.width, renderer.height))
    return rgb


def perturbed_poses():
    """The true pose, then ±8° about each camera axis and ±0.25 m in X, Y, ±1 m in Z."""
    quats, trans = [Q_TRUE], [T_TRUE]
    for axis in range(3):
        for sign in (-1.0, 1.0):
            euler = np.zeros(3)
            euler[axis] = sign * np.radians(8.0)
            quats.append(quat_multiply(euler_zyx_to_quat(euler), Q_TRUE))
            trans.append(T_TRUE)
    for axis, step in ((0, 0.25), (1, 0.25), (2, 1.0)):
        for sign in (-1.0, 1.0):
            t = T_TRUE.copy()
            t[axis] += sign * step
            quats.append(Q_TRUE)
            trans.append(t)
    return np.array(quats), np.array(trans)


def oracle_colour(frame, mask, box, bins=8):
    """(5.14) for one tile by explicit loops over its pixels."""
    t = mask.shape[0]
    h, w, _ = frame.shape
    size = (box[2] - box[0]) / t
    rows, cols = np.nonzero(mask)
    r0, r1, c0, c1 = rows.min(), rows.max(), cols.min(), cols.max()
    hist = {True: np.zeros(3 * bins), False: np.zeros(3 * bins)}
    for r in range(r0, r1 + 1):
        for c in range(c0, c1 + 1):
            x, y = box[0] + (c + 0.5) * size, box[1] + (r + 0.5) * size
            if not (-0.5 <= x < w - 0.5 and -0.5 <= y < h - 0.5):
                continue
            pixel = frame[int(np.floor(y + 0.5)), int(np.floor(x + 0.5))]
            for ch in range(3):
                hist[bool(mask[r, c])][ch * bins + int(pixel[ch]) * bins // 256] += 1
    inner, outer = hist[True] / hist[True].sum(), hist[False] / hist[False].sum()
    return 1.0 - sum(np.sqrt(inner[b] * outer[b]) for b in range(3 * bins))


def hand_made_tiles(renderer):
    """A red object on noise, and three 16 px tiles (triangle, cross, diamond) placed over it,
    beside it and across the frame's corner."""
    rng = np.random.default_rng(3)
    frame = rng.integers(0, 256, (renderer.height, renderer.width, 3), dtype=np.uint8)
    frame[200:400, 300:700] = (200, 40, 40)
    t = 16
    r, c = np.mgrid[:t, :t]
    masks = np.stack([(c >= 2) & (c <= r) & (r < 14),
                      ((r >= 2) & (r < 9) & (c >= 5) & (c < 7)) | ((r >= 6) & (r < 8) & (c >= 2) & (c < 14)),
                      np.abs(r - 7.5) + np.abs(c - 7.5) < 6]).astype(np.uint8)
    boxes = np.array([[250.0, 150.0, 650.0, 550.0], [660.3, 330.7, 730.3, 400.7], [-30.0, 600.0, 50.0, 680.0]])
    return frame, masks, boxes


def test_colour_metric_matches_a_per_pixel_oracle(renderer):
    frame, masks, boxes = hand_made_tiles(renderer)
    lik = ColourHistogramLikelihood(renderer)
    lik.prepare(frame)
    got = lik.score_batch(SilhouetteBatch(masks, boxes, np.ones(3, bool)))
    want = [oracle_colour(frame, masks[i], boxes[i]) for i in range(3)]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert np.all((got > 0) & (got < 1))


def test_a_tile_with_an_empty_region_scores_zero(renderer):
    """A silhouette filling its box has no outer region; one whose inside pixels all fall off the
    frame has no inner region: (5.14) is undefined for both, which score 0, not 1."""
    frame, _, _ = hand_made_tiles(renderer)
    t = 16
    gamma = np.zeros((t, t), np.uint8)
    gamma[0, :] = gamma[:, 0] = 1  # row 0 and column 0 fall just above and left of the frame
    masks = np.stack([np.ones((t, t), np.uint8), gamma])
    boxes = np.array([[300.0, 200.0, 332.0, 232.0], [-2.0, -2.0, 30.0, 30.0]])
    lik = ColourHistogramLikelihood(renderer)
    lik.prepare(frame)
    np.testing.assert_array_equal(lik.score_batch(SilhouetteBatch(masks, boxes, np.ones(2, bool))), [0.0, 0.0])


def edge_frame(width, height):
    """A flat grey frame with a bright rectangle, a dark disc and a thin bright bar: sparse edges."""
    frame = np.full((height, width, 3), 128, np.uint8)
    frame[200:420, 300:650] = (230, 220, 200)
    cv2.circle(frame, (900, 300), 90, (20, 30, 40), -1)
    cv2.line(frame, (100, 600), (500, 700), (250, 250, 250), 3)
    return frame


def oracle_edges(frame):
    """The thesis's edge map by OpenCV: Canny (50, 150, L2 gradient) of the grey frame blurred by σ = 1 px."""
    grey = cv2.cvtColor(frame, cv2.COLOR_RGB2GRAY)
    return cv2.Canny(cv2.GaussianBlur(grey, (0, 0), 1.0), 50.0, 150.0, L2gradient=True) > 0


def oracle_outline(mask, box):
    """[(point, outward normal)] of a tile by explicit loops: a point mid-way between each inside
    tile pixel and each outside 4-neighbour; the normal is the gradient of the mask smoothed by the
    5×5 binomial kernel (scipy), at the inside pixel, or the crack's direction where it vanishes."""
    t = mask.shape[0]
    b = np.array([1, 4, 6, 4, 1]) / 16
    smooth = ndimage.convolve(np.pad(mask.astype(float), 3), np.outer(b, b), mode="constant")
    scale = (box[2] - box[0]) / t
    out = []
    for r in range(t):
        for c in range(t):
            for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
                if not mask[r, c] or (0 <= r + dr < t and 0 <= c + dc < t and mask[r + dr, c + dc]):
                    continue
                g = np.array([smooth[r + 3, c + 2] - smooth[r + 3, c + 4], smooth[r + 2, c + 3] - smooth[r + 4, c + 3]])
                n = g / np.linalg.norm(g) if np.linalg.norm(g) > 1e-6 else np.array([dc, dr], float)
                out.append((np.array([box[0] + (c + 0.5 + 0.5 * dc) * scale, box[1] + (r + 0.5 + 0.5 * dr) * scale]), n))
    return out


def _pixel(point):
    return int(np.floor(point[1] + 0.5)), int(np.floor(point[0] + 0.5))


def oracle_distance_transform(frame, mask, box, sigma=50.0):
    """(5.16)–(5.17) for one tile: D the exact Euclidean distance to the nearest edge pixel (scipy)
    in image diagonals, at most 1, read at the pixel under each outline point inside the frame."""
    h, w = frame.shape[:2]
    dist = np.minimum(ndimage.distance_transform_edt(~oracle_edges(frame)) / np.hypot(w, h), 1.0)
    d = [dist[_pixel(p)] for p, _ in oracle_outline(mask, box) if -0.5 <= p[0] < w - 0.5 and -0.5 <= p[1] < h - 0.5]
    return np.exp(-sigma * np.mean(d)) if d else 0.0


def contour_search(edges, outline, search):
    """(5.15) for one tile (λ_v = λ_e = 1): each point of ``outline`` inside the frame looks along
    its normal at 0, ±1, ±2, … ±search px for the nearest edge pixel (ē is search where none is
    found). The score, the number of visible points and each match's distance."""
    h, w = edges.shape
    visible, found = 0, []
    for p, n in outline:
        if not (-0.5 <= p[0] < w - 0.5 and -0.5 <= p[1] < h - 0.5):
            continue
        visible += 1
        for step in [0] + [s for k in range(1, search + 1) for s in (k, -k)]:
            row, col = _pixel(p + step * n)
            if 0 <= col < w and 0 <= row < h and edges[row, col]:
                found.append(abs(step))
                break
    if not visible:
        return 0.0, 0, found
    score = np.exp(-(visible - len(found)) / visible) * np.exp(-(np.mean(found) if found else float(search)))
    return score, visible, found


def oracle_contour(frame, mask, box, search=15):
    """:func:`contour_search` on the oracle's edges and outline."""
    return contour_search(oracle_edges(frame), oracle_outline(mask, box), search)[0]


def test_edge_metrics_match_a_per_point_oracle(renderer):
    """Tiles over the corner of the rectangle, on the disc, across the frame's corner and along the
    rectangle: the distance-transform and contour scores are those of the loop oracles."""
    frame = edge_frame(renderer.width, renderer.height)
    _, masks, _ = hand_made_tiles(renderer)
    r, c = np.mgrid[:16, :16]
    masks = np.concatenate([masks, (r < 10).astype(np.uint8)[None]])  # a band: the rectangle, roughly
    boxes = np.array([[280.3, 190.7, 440.3, 350.7], [820.0, 210.0, 1000.0, 390.0], [-30.0, 600.0, 50.0, 680.0],
                      [296.0, 196.0, 656.0, 556.0]])
    batch = SilhouetteBatch(masks, boxes, np.ones(4, bool))
    for name, oracle in (("distance_transform", oracle_distance_transform), ("contour", oracle_contour)):
        lik = make_likelihood(name, renderer)
        lik.prepare(frame)
        want = [oracle(frame, masks[i], boxes[i]) for i in range(4)]
        np.testing.assert_allclose(lik.score_batch(batch), want, rtol=1e-6, atol=0, err_msg=name)


def test_distance_transform_is_exact_on_one_thread_or_several(renderer):
    """D is the exact Euclidean distance to the nearest edge pixel (scipy), in image diagonals, bit
    for bit, whether OpenCV runs on one thread or several (its float32 distances differ in their
    last bits between the two, so scores differed from one machine to another)."""
    frame = edge_frame(renderer.width, renderer.height)
    exact = ndimage.distance_transform_edt(~oracle_edges(frame)) / np.hypot(renderer.width, renderer.height)
    lik = make_likelihood("distance_transform", renderer)
    threads = cv2.getNumThreads()
    try:
        for n in (1, 2):
            cv2.setNumThreads(n)
            lik.prepare(frame)
            np.testing.assert_array_equal(lik._dt, np.minimum(exact, 1.0).astype(np.float32))
    finally:
        cv2.setNumThreads(threads)


SHIFTS = np.array([[0.0, 0.0], [0.5, 0.0], [-1.25, 0.75], [30.0, -20.0]])


def test_colour_scores_at_image_shifts_match_the_oracle_on_moved_boxes(renderer):
    frame, masks, boxes = hand_made_tiles(renderer)
    lik = ColourHistogramLikelihood(renderer)
    lik.prepare(frame)
    got = lik.score_shifted(SilhouetteBatch(masks, boxes, np.ones(3, bool)), SHIFTS)
    assert got.shape == (3, len(SHIFTS))
    for j, shift in enumerate(SHIFTS):
        moved = boxes + np.tile(shift, 2)
        np.testing.assert_allclose(got[:, j], [oracle_colour(frame, masks[i], moved[i]) for i in range(3)],
                                   rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_scores_at_image_shifts_equal_scores_of_the_moved_boxes(renderer, frame, name):
    """Each metric (the colour one with its outline band) scores a shifted silhouette as the same
    tile placed at the shifted box; no shift is the plain score; invisible poses score 0."""
    lik = make_likelihood(name, renderer, ColourConfig(band_px=1.5) if name == "colour" else None)
    lik.prepare(frame)
    quats, trans = perturbed_poses()
    trans[-1] = [0.0, 0.0, -5.0]  # behind the camera
    batch = renderer.silhouettes(quats, trans)
    got = lik.score_shifted(batch, SHIFTS)
    np.testing.assert_array_equal(got[:, 0], lik.score_batch(batch))
    np.testing.assert_array_equal(got[-1], 0.0)
    for j, shift in enumerate(SHIFTS[1:], start=1):
        moved = SilhouetteBatch(batch.masks, batch.boxes + np.tile(shift, 2), batch.visible)
        np.testing.assert_allclose(got[:, j], lik.score_batch(moved), rtol=0, atol=1e-12)


def test_a_pose_one_pixel_off_scores_best_shifted_back():
    """The true pose moved one pixel right in the image (X += Z/f_x) scores best at the shift of
    one pixel left, about as high there as the true pose itself (perspective and rasterisation
    differ a little). A 256 px tile resolves the 8 m UAV's ~250 px box to a pixel."""
    camera = load_camera_info_yaml(config_path("camera.yaml")).rectified()
    fine = Renderer(camera, fixed_wing_mesh("low"), tile=256, max_batch=4)
    frame, _ = fine.shaded(Q_TRUE, T_TRUE, sky_and_sea(fine.width, fine.height))
    lik = make_likelihood("colour", fine, ColourConfig(band_px=1.5))
    lik.prepare(frame)
    off = T_TRUE + [T_TRUE[2] / fine.K[0, 0], 0.0, 0.0]
    cross = np.array([[0.0, 0.0], [-1.0, 0.0], [1.0, 0.0], [0.0, -1.0], [0.0, 1.0]])
    scores = lik.score_shifted(fine.silhouettes(Q_TRUE[None], off[None]), cross)[0]
    assert np.argmax(scores) == 1 and scores[0] < scores[1]
    assert scores[1] == pytest.approx(lik.score(Q_TRUE[None], T_TRUE[None])[0], rel=0.05)


def test_formulas_on_known_values():
    h = np.array([0.5, 0.5, 0.0, 0.0])
    assert colour_similarity(h, h) == pytest.approx(0.0)
    assert colour_similarity(h, h[::-1]) == pytest.approx(1.0)
    assert contour_likelihood(10, 10, 0.0, 1.0, 1.0) == pytest.approx(1.0)
    assert contour_likelihood(10, 5, 2.0, 1.0, 1.0) == pytest.approx(np.exp(-0.5) * np.exp(-2.0))
    d, k = mean_edge_distance(np.array([0.1, 0.3, 0.5]), np.array([0, 0, 2]), 3)
    np.testing.assert_allclose(d, [0.2, 0.0, 0.5])
    np.testing.assert_array_equal(k, [2, 0, 1])
    assert dt_likelihood(0.02, 50.0) == pytest.approx(np.exp(-1.0))


@pytest.mark.parametrize("name", NAMES)
def test_true_pose_beats_perturbed_poses(renderer, frame, name):
    lik = make_likelihood(name, renderer)
    lik.prepare(frame)
    scores = lik.score(*perturbed_poses())
    assert scores[0] > 0
    assert scores[0] > scores[1:].max(), scores


@pytest.mark.parametrize("name", NAMES)
def test_batched_scores_equal_one_at_a_time(renderer, frame, name):
    lik = make_likelihood(name, renderer)
    lik.prepare(frame)
    quats, trans = perturbed_poses()
    batched = lik.score(quats, trans)
    single = np.array([lik.score(q[None], t[None])[0] for q, t in zip(quats, trans)])
    np.testing.assert_array_equal(batched, single)
    np.testing.assert_array_equal(lik.score(quats, trans), batched)  # deterministic


@pytest.mark.parametrize("name", NAMES)
def test_invisible_poses_score_zero(renderer, frame, name):
    lik = make_likelihood(name, renderer)
    lik.prepare(frame)
    quats = np.tile(Q_TRUE, (4, 1))
    trans = np.array([T_TRUE, [0.0, 0.0, -5.0], [0.0, 0.0, 0.01], [40.0, 0.0, 5.0]])
    scores = lik.score(quats, trans)
    assert scores[0] > 0
    np.testing.assert_array_equal(scores[1:], 0.0)


def test_particle_set_objective(renderer, frame):
    lik = make_likelihood("colour", renderer)
    lik.prepare(frame)
    quats, trans = perturbed_poses()
    particles = ParticleSet.from_poses(trans, quats)
    np.testing.assert_array_equal(evaluate(lik, particles), lik.score(quats, trans))


def test_edges_and_distance_transform_once_per_frame(renderer, frame, monkeypatch):
    calls = {"Canny": 0, "distanceTransform": 0}
    for fn in calls:
        original = getattr(cv2, fn)

        def spy(*args, _original=original, _fn=fn, **kwargs):
            calls[_fn] += 1
            return _original(*args, **kwargs)

        monkeypatch.setattr(cv2, fn, spy)
    dt, contour = make_likelihood("distance_transform", renderer), make_likelihood("contour", renderer)
    quats, trans = perturbed_poses()
    for _ in range(2):
        dt.prepare(frame)
        contour.prepare(frame)
        for _ in range(3):
            dt.score(quats, trans)
            contour.score(quats, trans)
    assert calls == {"Canny": 4, "distanceTransform": 2}


@pytest.mark.parametrize(
    "bad",
    [
        np.zeros((720, 1280, 3), np.float32),
        np.zeros((720, 1280), np.uint8),
        np.zeros((720, 1280, 4), np.uint8),
        np.zeros((360, 640, 3), np.uint8),
        np.zeros((0, 0, 3), np.uint8),
        [[0, 0, 0]],
    ],
    ids=["float", "grey", "rgba", "size", "empty", "list"],
)
@pytest.mark.parametrize("name", NAMES)
def test_bad_frames_are_refused(renderer, name, bad):
    with pytest.raises(ValueError, match="frame"):
        make_likelihood(name, renderer).prepare(bad)


def test_scoring_needs_a_frame(renderer):
    with pytest.raises(RuntimeError, match="prepare"):
        make_likelihood("colour", renderer).score(Q_TRUE[None], T_TRUE[None])


def test_factory_configs(renderer):
    assert make_likelihood("contour", renderer, {"search_px": 25}).config == ContourConfig(search_px=25)
    assert make_likelihood("colour", renderer).config == ColourConfig(bins_per_channel=8)
    with pytest.raises(ValueError, match="unknown likelihood"):
        make_likelihood("edges", renderer)
    with pytest.raises(ConfigError, match="unknown key"):
        make_likelihood("distance_transform", renderer, {"sigma": 50.0, "lambda": 1.0})
    with pytest.raises(ConfigError, match="sigma"):
        make_likelihood("distance_transform", renderer, {"sigma": -1.0})
    with pytest.raises(ConfigError, match="ContourConfig"):
        make_likelihood("contour", renderer, ColourConfig())
    with pytest.raises(ValueError, match="bins_per_channel"):
        ColourConfig(bins_per_channel=7)
    with pytest.raises(ValueError, match="canny"):
        make_likelihood("contour", renderer, {"edges": {"canny_low": 200.0, "canny_high": 100.0}})


def test_contour_and_distance_transform_configs_refuse_negative_weights_and_a_zero_sigma():
    """λ_v, λ_e ≥ 0 (0 allowed) and σ in (0, 1e4]."""
    ContourConfig(lambda_v=0.0, lambda_e=0.0)
    DistanceTransformConfig(sigma=1e4)
    for bad in ({"lambda_v": -0.1}, {"lambda_e": -0.1}):
        with pytest.raises(ValueError, match="lambda"):
            ContourConfig(**bad)
    for sigma in (0.0, -1.0, 1e4 * (1 + 1e-9)):
        with pytest.raises(ValueError, match="sigma"):
            DistanceTransformConfig(sigma=sigma)


def test_edge_config_takes_blur_up_to_ten_pixels_and_an_integer_search_distance():
    """blur_sigma in [0, 10] px, ten included; search_px an int in [1, 200], not a float even when whole."""
    EdgeConfig(blur_sigma=10.0)
    EdgeConfig(blur_sigma=0.0)
    with pytest.raises(ValueError, match="blur_sigma"):
        EdgeConfig(blur_sigma=10.0 + 1e-9)
    for bad in (2.5, 15.0, 0, 201, True):
        with pytest.raises(ValueError, match="search_px"):
            ContourConfig(search_px=bad)


def test_outline_band_leaves_out_the_outline_and_keeps_thin_cores():
    t = 32
    masks = np.zeros((2, t, t), np.uint8)
    masks[0, 8:24, 8:24] = 1  # a 16-tile-pixel square
    masks[1, 13:19, 4:28] = 1  # a bar six tile pixels (12 px) thick
    boxes = np.array([[0.0, 0.0, 64.0, 64.0], [0.0, 0.0, 64.0, 64.0]])  # 2 frame px per tile px
    band = outline_band(masks, boxes, 3.5)
    # square: pixel centres nearer the outline than 3.5 px (1.75 tile px) are in the band
    assert band[0, 8, 16] and band[0, 9, 16] and not band[0, 10, 16]
    assert band[0, 7, 16] and band[0, 6, 16] and not band[0, 5, 16]
    # the bar's deepest pixel centres lie 5 px inside: the band narrows to 2.5 px there
    assert band[1, 13, 16] and band[1, 12, 16] and not band[1, 14, 16] and not band[1, 11, 16]
    # a band narrower than a tile pixel still takes the ring next to the outline
    ring = outline_band(masks[:1], boxes[:1], 0.1)
    assert ring[0, 8, 16] and ring[0, 7, 16] and not ring[0, 9, 16] and not ring[0, 6, 16]


def test_outline_band_widens_the_colour_peak_on_a_blurred_frame(renderer, frame):
    """The frame's UAV edge blurred as the simulator's optics do: a three-pixel shift costs the
    thesis metric (band 0) much more of its peak than the banded metric, and the true pose
    still wins under both."""
    blurred = cv2.GaussianBlur(frame, (0, 0), 1.0)
    shift = 3.0 * T_TRUE[2] / renderer.K[0, 0]  # three pixels at the true depth
    trans = T_TRUE + np.array([[0.0, 0.0, 0.0], [shift, 0.0, 0.0], [0.0, shift, 0.0]])
    ratios = []
    for cfg in (ColourConfig(), ColourConfig(band_px=1.5)):
        lik = make_likelihood("colour", renderer, cfg)
        lik.prepare(blurred)
        s = lik.score(np.repeat(Q_TRUE[None], 3, axis=0), trans)
        ratios.append(s[1:].mean() / s[0])
        scores = lik.score(*perturbed_poses())
        assert scores[0] > scores[1:].max(), scores
    assert 1.0 - ratios[1] < 0.5 * (1.0 - ratios[0]), ratios


def test_band_zero_is_the_thesis_metric_and_band_mixes_both(renderer, frame):
    """band_px = 0 scores exactly as (5.14) over every pixel; with a band the score is the mean
    of the banded and the full (5.14)."""
    quats, trans = perturbed_poses()
    plain = make_likelihood("colour", renderer)
    banded = make_likelihood("colour", renderer, ColourConfig(band_px=1.5))
    plain.prepare(frame)
    banded.prepare(frame)
    batch = renderer.silhouettes(quats, trans)
    full = plain.score_batch(batch)
    inner, outer = banded.histograms(batch.masks, batch.boxes)
    core = np.clip(colour_similarity(inner / inner.sum(1, keepdims=True), outer / outer.sum(1, keepdims=True)), 0, 1)
    np.testing.assert_allclose(banded.score_batch(batch), 0.5 * (core + full), atol=1e-12)
    with pytest.raises(ValueError, match="band_px"):
        ColourConfig(band_px=-1.0)


def test_outline_band_of_large_tiles_does_not_reach_the_next_tile():
    t = 128
    a = np.zeros((t, t), np.uint8)
    a[60:, 10:120] = 1  # touches the bottom of its tile
    b = np.zeros((t, t), np.uint8)
    b[40:, :] = 1
    boxes = np.array([[0.0, 0.0, t, t]] * 2)
    for band in (1.5, 20.0, 25.0):
        both = outline_band(np.array([a, b]), boxes, band)
        np.testing.assert_array_equal(both[0], outline_band(a[None], boxes[:1], band)[0])
        np.testing.assert_array_equal(both[1], outline_band(b[None], boxes[:1], band)[0])


def test_colour_bin_counts_below_two_or_overflowing_a_byte_are_refused():
    """One bin per channel is refused; the three channels' bins share one byte each of the packed
    sample, so 3·b must stay below 256: 64 bins are taken, 128 and 256 refused. So are counts that
    do not divide 256 and ones that are no int (a float, or True for 1)."""
    ColourConfig(bins_per_channel=64)
    for bad in (1, 128, 256, 12, 8.0, True):
        with pytest.raises(ValueError, match=r"bins_per_channel must be one of \(2, 4, 8, 16, 32, 64\)"):
            ColourConfig(bins_per_channel=bad)
