"""The moderngl renderer against an OpenCV rasterisation oracle and its own contracts."""

import cv2
import moderngl
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.camera import load_camera_info_yaml
from uav_landing_vision.geometry import matrix_to_quat
from uav_landing_vision.model import Mesh, fixed_wing_mesh
from uav_landing_vision.render import Renderer, SilhouetteBatch, gl_context
from uav_landing_vision.resources import config_path

TILE = 64
SUPERSAMPLE = 15  # odd, so that a supersampled pixel centre falls on each pixel centre


@pytest.fixture(scope="module")
def camera():
    return load_camera_info_yaml(config_path("camera.yaml")).rectified()


@pytest.fixture(scope="module")
def mesh():
    return fixed_wing_mesh("low")


@pytest.fixture(scope="module")
def renderer(camera, mesh):
    return Renderer(camera, mesh, tile=TILE, max_batch=128)


@pytest.fixture(scope="module")
def poses(camera):
    """100 random poses at 5–80 m, centred anywhere in the image, uniformly random attitude."""
    rng = np.random.default_rng(2020)
    n = 100
    z = rng.uniform(5.0, 80.0, n)
    uv = rng.uniform([100.0, 100.0], [camera.width - 100.0, camera.height - 100.0], (n, 2))
    K = camera.K
    trans = np.stack([(uv[:, 0] - K[0, 2]) / K[0, 0] * z, (uv[:, 1] - K[1, 2]) / K[1, 1] * z, z], axis=1)
    return Rotation.random(n, random_state=rng).as_quat(), trans


def side_view_quat():
    """Columns: body x → image right, body y (left wing) → away from the camera, body z → up."""
    return matrix_to_quat(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]))


def oracle(camera, mesh, quat, trans, origin, scale, shape):
    """OpenCV rasterisation sampled at pixel centres, like GL.

    Every front-facing projected triangle is filled with ``cv2.fillConvexPoly`` (sub-pixel
    vertices) in an image supersampled ``SUPERSAMPLE``× and read at the centre sample of each
    pixel; ``fillConvexPoly`` also draws each triangle's outline, which makes a direct
    rasterisation about a pixel fatter than a pixel-centre rule. Target pixel (r, c) has its
    centre at image point ``origin + ((c, r) + ½) / scale``.
    """
    p = mesh.vertices.astype(float) @ Rotation.from_quat(quat).as_matrix().T + trans
    uv = camera.project_pinhole(p)
    tri = p[mesh.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    front = np.einsum("ij,ij->i", normal, tri[:, 0]) < 0
    s = SUPERSAMPLE
    pts = np.round(((uv - origin) * scale * s - 0.5) * 256).astype(np.int32)
    img = np.zeros((shape[0] * s, shape[1] * s), np.uint8)
    for face in mesh.faces[front]:
        cv2.fillConvexPoly(img, pts[face], 1, cv2.LINE_8, shift=8)
    return img[s // 2 :: s, s // 2 :: s]


def iou(a, b):
    a, b = a.astype(bool), b.astype(bool)
    return (a & b).sum() / max((a | b).sum(), 1)


def test_tiles_agree_with_opencv_rasterisation(camera, mesh, renderer, poses):
    quats, trans = poses
    batch = renderer.silhouettes(quats, trans)
    assert isinstance(batch, SilhouetteBatch) and batch.visible.all()
    assert batch.masks.shape == (100, TILE, TILE) and batch.masks.dtype == np.uint8
    assert set(np.unique(batch.masks)) <= {0, 1}
    scores = []
    for q, t, box, m in zip(quats, trans, batch.boxes, batch.masks):
        scores.append(iou(m, oracle(camera, mesh, q, t, box[:2], TILE / (box[2] - box[0]), (TILE, TILE))))
    scores = np.array(scores)
    assert scores.min() >= 0.9, np.sort(scores)[:5]
    assert np.median(scores) >= 0.97


def test_full_frame_agrees_with_opencv_rasterisation(camera, mesh, renderer, poses):
    """At image resolution a UAV at 70 m is ~30 px, so IoU is only asked of larger silhouettes;
    every pose: no GL pixel outside the oracle, oracle extras only on the GL silhouette's rim."""
    quats, trans = poses
    for q, t in zip(quats[:12], trans[:12]):
        full = renderer.silhouette_full(q, t)
        assert full.shape == (camera.height, camera.width) and full.dtype == bool
        rows, cols = np.nonzero(full)
        r0, r1, c0, c1 = max(rows.min() - 2, 0), rows.max() + 3, max(cols.min() - 2, 0), cols.max() + 3
        crop = full[r0:r1, c0:c1]
        expected = oracle(camera, mesh, q, t, np.array([c0 - 0.5, r0 - 0.5]), 1.0, crop.shape).astype(bool)
        assert not (crop & ~expected).any()
        rim = cv2.dilate(crop.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        assert not (expected & ~rim).any()
        if crop.sum() >= 150:
            assert iou(crop, expected) >= 0.9


def test_batched_equals_one_at_a_time(renderer, poses):
    """Tile slots differ only by float32 offsets of the atlas position, so an edge that passes
    within ~1e-4 px of a pixel centre may flip: allow two pixels per tile, expect almost none."""
    quats, trans = poses
    batch = renderer.silhouettes(quats, trans)
    differing = 0
    for i in range(0, 100, 5):
        one = renderer.silhouettes(quats[i : i + 1], trans[i : i + 1])
        np.testing.assert_array_equal(one.boxes[0], batch.boxes[i])
        diff = int((one.masks[0] != batch.masks[i]).sum())
        assert diff <= 2
        differing += diff
    assert differing <= 4


def test_boxes_are_square_and_contain_the_projected_model(camera, mesh, renderer, poses):
    quats, trans = poses
    batch = renderer.silhouettes(quats, trans)
    x0, y0, x1, y1 = batch.boxes.T
    np.testing.assert_allclose(x1 - x0, y1 - y0)
    for q, t, box in zip(quats, trans, batch.boxes):
        uv = camera.project_pinhole(mesh.vertices @ Rotation.from_quat(q).as_matrix().T + t)
        assert np.all(uv >= box[:2] + 0.5) and np.all(uv <= box[2:] - 0.5)
        side = box[2] - box[0]
        assert side <= 1.2 * np.ptp(uv, axis=0).max() + 3.0  # a small margin only


def test_tile_pixel_convention(camera):
    """A 1 m square facing the camera at 5 m: 220 px across (fx=1100), pixel-exact in its tile."""
    corners = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0.0]])
    square = Mesh(corners, np.array([[0, 2, 1], [0, 3, 2]]))
    r = Renderer(camera, square, tile=TILE, margin=0.0)
    t = np.array([0.0, 0.0, 5.0])
    full = r.silhouette_full([0, 0, 0, 1.0], t)
    u0, v0 = camera.project_pinhole(t + [-0.5, -0.5, 0])
    cols, rows = np.nonzero(full.any(axis=0))[0], np.nonzero(full.any(axis=1))[0]
    # Pixel centres strictly inside the square's edges are covered (integer = centre).
    assert cols.min() == np.ceil(u0) and cols.max() == np.floor(u0 + 220) and len(cols) == 220
    assert rows.min() == np.ceil(v0) and len(rows) == 220
    batch = r.silhouettes(np.array([[0, 0, 0, 1.0]]), t[None])
    box = batch.boxes[0]
    np.testing.assert_allclose(box, [u0 - 1, v0 - 1, u0 + 221, v0 + 221])
    # Tile pixel (r, c) is covered exactly when its centre x0 + (c+½)·side/T lies in the square.
    centres = (np.arange(TILE) + 0.5) * (box[2] - box[0]) / TILE
    inside_u = (box[0] + centres > u0) & (box[0] + centres < u0 + 220)
    inside_v = (box[1] + centres > v0) & (box[1] + centres < v0 + 220)
    np.testing.assert_array_equal(batch.masks[0], np.outer(inside_v, inside_u))


def test_invisible_poses(camera, renderer, poses):
    quats, trans = poses
    behind = np.array([0.0, 0.0, -10.0])
    straddling = np.array([0.0, 0.0, 0.3])  # side view: the wing tips cross the near plane
    out_of_frame = np.array([200.0, 0.0, 20.0])
    t = np.stack([trans[0], behind, straddling, out_of_frame, trans[1]])
    q = np.stack([quats[0], quats[1], side_view_quat(), quats[3], quats[1]])
    batch = renderer.silhouettes(q, t)
    np.testing.assert_array_equal(batch.visible, [True, False, False, False, True])
    assert not batch.masks[1:4].any()
    assert np.isnan(batch.boxes[1]).all() and np.isnan(batch.boxes[2]).all()
    assert batch.boxes[3, 0] > camera.width  # a real box, outside the image
    reference = renderer.silhouettes(quats[:2], trans[:2])
    assert (reference.masks[0] != batch.masks[0]).sum() <= 2
    assert (reference.masks[1] != batch.masks[4]).sum() <= 2
    assert not renderer.silhouette_full(quats[0], behind).any()


def test_partly_out_of_frame_is_visible(camera, renderer):
    t = np.array([-0.9 * 10 * camera.cx / camera.fx, 0.0, 10.0])  # centred near the left edge
    batch = renderer.silhouettes(np.array([side_view_quat()]), t[None])
    assert batch.visible[0] and batch.masks[0].any()
    assert batch.boxes[0, 0] < -0.5 < batch.boxes[0, 2]


def test_batch_arguments(renderer, poses):
    empty = renderer.silhouettes(np.zeros((0, 4)), np.zeros((0, 3)))
    assert empty.masks.shape == (0, TILE, TILE) and empty.boxes.shape == (0, 4)
    with pytest.raises(ValueError, match="max_batch"):
        renderer.silhouettes(np.tile([0, 0, 0, 1.0], (129, 1)), np.tile([0, 0, 10.0], (129, 1)))
    with pytest.raises(ValueError):
        renderer.silhouettes(poses[0][:3], poses[1][:2])


@pytest.mark.parametrize("settings", [{"tile": 4}, {"max_batch": 0}, {"margin": -0.1}, {"margin": float("nan")},
                                      {"margin": float("inf")}])
def test_invalid_renderer_settings_are_refused(camera, mesh, settings):
    with pytest.raises(ValueError, match="invalid renderer settings"):
        Renderer(camera, mesh, **settings)


@pytest.mark.parametrize("limit, value", [("GL_MAX_RENDERBUFFER_SIZE", 1536), ("GL_MAX_VIEWPORT_DIMS", (1536, 1536))])
def test_atlas_beyond_the_context_limits_is_refused(camera, mesh, monkeypatch, limit, value):
    # 512 poses of 64 px: a 32 x 16 tile atlas, 2048 x 1024 px. A driver whose renderbuffers or viewport
    # stop at 1536 px would leave the framebuffer incomplete or clamp the viewport and misplace the tiles.
    monkeypatch.setitem(gl_context().info, limit, value)
    with pytest.raises(ValueError, match=f"atlas 2048x1024 exceeds .*{limit}.*max_batch"):
        Renderer(camera, mesh, tile=64, max_batch=512)
    Renderer(camera, mesh, tile=32, max_batch=512).release()  # 1024 x 512 fits


@pytest.mark.parametrize("limit, value", [("GL_MAX_TEXTURE_SIZE", 1024), ("GL_MAX_VIEWPORT_DIMS", (1280, 700))])
def test_image_beyond_the_context_limits_is_refused(camera, mesh, monkeypatch, limit, value):
    monkeypatch.setitem(gl_context().info, limit, value)
    with pytest.raises(ValueError, match=f"image 1280x720 exceeds .*{limit}"):
        Renderer(camera, mesh, tile=32, max_batch=16)


@pytest.mark.parametrize("limit, value", [("GL_MAX_TEXTURE_SIZE", 1024), ("GL_MAX_RENDERBUFFER_SIZE", 1536)])
def test_a_refused_renderer_leaves_no_gl_objects(camera, mesh, monkeypatch, limit, value):
    """The tracker node builds a renderer at every camera_info until one works: each refused
    one left its programs, buffers and a 2048x1024 atlas behind (moderngl frees none itself)."""
    ctx = gl_context()
    monkeypatch.setitem(ctx.info, limit, value)
    made = []
    for name in ("program", "buffer", "vertex_array", "renderbuffer", "framebuffer", "texture", "depth_renderbuffer"):
        def record(*args, _make=getattr(ctx, name), **kwargs):
            made.append(_make(*args, **kwargs))
            return made[-1]

        monkeypatch.setattr(ctx, name, record)
    with pytest.raises(ValueError, match=f"exceeds .*{limit}"):
        Renderer(camera, mesh, tile=64, max_batch=512)
    assert [type(obj).__name__ for obj in made if type(obj.mglo).__name__ != "InvalidObject"] == []


@pytest.mark.parametrize("failing", ["texture", "vertex_array"])
def test_a_renderer_failing_partway_releases_what_it_made(camera, mesh, monkeypatch, failing):
    """Out of GPU memory halfway through the constructor (the tracker node catches moderngl.Error
    and retries at the next camera_info): the objects made before the failure are released."""
    ctx = gl_context()
    made = []
    for name in ("program", "buffer", "vertex_array", "renderbuffer", "framebuffer", "texture"):
        def record(*args, _make=getattr(ctx, name), _name=name, **kwargs):
            if _name == failing and len(made) > 8:
                raise moderngl.Error("out of memory")
            made.append(_make(*args, **kwargs))
            return made[-1]

        monkeypatch.setattr(ctx, name, record)
    with pytest.raises(moderngl.Error, match="out of memory"):
        Renderer(camera, mesh, tile=64, max_batch=16)
    assert len(made) > 8
    assert [type(obj).__name__ for obj in made if type(obj.mglo).__name__ != "InvalidObject"] == []


def test_side_view_is_upright_and_not_mirrored(camera, renderer):
    full = renderer.silhouette_full(side_view_quat(), [0.0, 0.0, 6.0])
    rows, cols = np.nonzero(full)
    centre = camera.cx
    assert cols.max() - centre > 0.4 * camera.fx / 6.0  # the nose (+0.45 m) to the right
    top = cols[rows == rows.min()]
    assert top.mean() < centre - 0.5 * camera.fx / 6.0  # the fin top is at the tail, left


def test_shaded_alpha_matches_silhouette_and_is_antialiased(camera, renderer):
    rng = np.random.default_rng(3)
    background = rng.integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8)
    q, t = side_view_quat(), np.array([0.3, -0.2, 8.0])
    rgb, alpha = renderer.shaded(q, t, background)
    assert rgb.shape == background.shape and rgb.dtype == np.uint8
    assert alpha.dtype == np.float32 and alpha.min() >= 0.0 and alpha.max() <= 1.0
    silhouette = renderer.silhouette_full(q, t)
    assert iou(alpha >= 0.5, silhouette) >= 0.95
    fractional = (alpha > 0) & (alpha < 1)
    assert fractional.sum() > 0.2 * cv2.Canny(silhouette.astype(np.uint8) * 255, 1, 1).astype(bool).sum()
    untouched = alpha == 0
    np.testing.assert_array_equal(rgb[untouched], background[untouched])
    _, hard = renderer.shaded(q, t, background, samples=1)
    assert set(np.unique(hard)) == {0.0, 1.0}
    np.testing.assert_array_equal(hard > 0, silhouette)


def test_shading_is_lit_from_above(camera, renderer):
    background = np.zeros((camera.height, camera.width, 3), np.uint8)
    rgb, alpha = renderer.shaded(side_view_quat(), [0.0, 0.0, 4.0], background, light_dir=(0.0, -1.0, 0.0))
    nose = np.abs(np.arange(camera.width) - camera.cx - 75) < 15  # body x ≈ 0.2–0.33 m: fuselage only
    body = (alpha == 1) & nose[None, :]
    rows = np.nonzero(body.any(axis=1))[0]
    mid = 0.5 * (rows.min() + rows.max())
    grey = rgb.mean(axis=2)
    upper = grey[body & (np.arange(camera.height) < mid)[:, None]].mean()
    lower = grey[body & (np.arange(camera.height) > mid)[:, None]].mean()
    assert upper > lower + 30
    with pytest.raises(ValueError):
        renderer.shaded(side_view_quat(), [0.0, 0.0, 4.0], background[:10])


def test_open_mesh_is_drawn_without_culling(camera):
    square = Mesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]]), np.array([[0, 1, 2], [0, 2, 3]]))
    r = Renderer(camera, square, tile=32)
    assert not r.cull
    assert r.silhouette_full([0, 0, 0, 1.0], [0, 0, 5.0]).sum() == 220 * 220  # its back, facing us


def test_reduced_mesh_has_the_same_silhouette(camera, renderer, poses):
    high = Renderer(camera, fixed_wing_mesh("high"), tile=TILE, max_batch=128)
    quats, trans = poses
    a, b = renderer.silhouettes(quats, trans), high.silhouettes(quats, trans)
    np.testing.assert_allclose(a.boxes, b.boxes, atol=2.0)
    scores = [iou(x, y) for x, y in zip(a.masks, b.masks)]
    assert np.median(scores) >= 0.93 and min(scores) >= 0.8


def test_one_context_per_process(renderer):
    assert renderer.ctx is gl_context()
    assert isinstance(renderer.gl_renderer, str) and renderer.gl_renderer


def test_releasing_twice_does_nothing_the_second_time(camera, mesh):
    """`with Renderer(...) as r: ... r.release()` raised TypeError on leaving the block."""
    with Renderer(camera, mesh, tile=TILE, max_batch=2) as r:
        r.shaded(np.array([[0.0, 0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 10.0]]),
                 np.zeros((camera.height, camera.width, 3), np.uint8), samples=4)
        r.release()


def test_returned_masks_are_not_overwritten_by_the_next_batch(camera, mesh, poses):
    """With max_batch=1 the atlas is one tile wide, so the masks were a view of the renderer's
    readback buffer: the next call rewrote the previous batch's masks."""
    quats, trans = poses
    for max_batch in (1, 2):
        r = Renderer(camera, mesh, tile=TILE, max_batch=max_batch)
        first = r.silhouettes(quats[:1], trans[:1])
        kept = first.masks.copy()
        assert kept.any()
        r.silhouettes(quats[:1], np.array([[0.0, 0.0, -10.0]]))  # behind the camera: an empty tile
        np.testing.assert_array_equal(first.masks, kept)
        r.release()


@pytest.mark.parametrize("margin", [0.1, 0.3])
def test_box_side_is_the_larger_projected_extent_with_the_margin_plus_two_pixels(camera, mesh, poses, margin):
    """Against cv2.projectPoints of every vertex: the square box is centred on the projected extent,
    its side the larger extent times 1 + margin, plus 2 px."""
    quats, trans = poses
    with Renderer(camera, mesh, tile=TILE, max_batch=16, margin=margin) as r:
        boxes = r.silhouettes(quats[:16], trans[:16]).boxes
    for q, t, box in zip(quats[:16], trans[:16], boxes):
        uv, _ = cv2.projectPoints(mesh.vertices.astype(float), Rotation.from_quat(q).as_rotvec(), t, camera.K, None)
        lo, hi = uv[:, 0].min(axis=0), uv[:, 0].max(axis=0)
        half = 0.5 * ((hi - lo).max() * (1 + margin) + 2.0)
        np.testing.assert_allclose(box, [*(0.5 * (lo + hi) - half), *(0.5 * (lo + hi) + half)], atol=1e-6)


def test_full_frame_silhouettes_are_not_overwritten_by_the_next_call(renderer, poses):
    quats, trans = poses
    first = renderer.silhouette_full(quats[0], trans[0])
    kept = first.copy()
    assert kept.any()
    renderer.silhouette_full(quats[0], [0.0, 0.0, -10.0])  # behind the camera: an empty frame
    np.testing.assert_array_equal(first, kept)


def test_shaded_images_are_not_overwritten_by_the_next_call(camera, renderer):
    background = np.full((camera.height, camera.width, 3), 40, np.uint8)
    rgb, alpha = renderer.shaded(side_view_quat(), [0.0, 0.0, 6.0], background)
    kept_rgb, kept_alpha = rgb.copy(), alpha.copy()
    assert (kept_alpha > 0).any()
    renderer.shaded(side_view_quat(), [0.0, 0.0, -6.0], np.zeros_like(background))
    np.testing.assert_array_equal(rgb, kept_rgb)
    np.testing.assert_array_equal(alpha, kept_alpha)


@pytest.mark.parametrize("light", [(0.0, 0.0, 0.0), (np.nan, 0.0, -1.0), (0.0, -1.0), (0.0, -1.0, 0.0, 1.0)])
def test_shaded_refuses_a_light_direction_that_is_not_a_non_zero_3_vector(camera, renderer, light):
    background = np.zeros((camera.height, camera.width, 3), np.uint8)
    with pytest.raises(ValueError, match="light_dir"):
        renderer.shaded(side_view_quat(), [0.0, 0.0, 6.0], background, light_dir=light)


@pytest.mark.parametrize("dtype", [np.float32, np.uint16])
def test_shaded_refuses_a_background_that_is_not_uint8(camera, renderer, dtype):
    background = np.zeros((camera.height, camera.width, 3), dtype)
    with pytest.raises(ValueError, match="background must be"):
        renderer.shaded(side_view_quat(), [0.0, 0.0, 6.0], background)


@pytest.mark.parametrize("tile", [8, 1024])
def test_the_smallest_and_largest_tiles_are_accepted(camera, mesh, poses, tile):
    quats, trans = poses
    with Renderer(camera, mesh, tile=tile, max_batch=1) as r:
        batch = r.silhouettes(quats[:1], trans[:1])
    assert batch.masks.shape == (1, tile, tile) and batch.masks.any()


@pytest.mark.parametrize("tile", [7, 1025])
def test_tiles_outside_8_to_1024_pixels_are_refused(camera, mesh, tile):
    with pytest.raises(ValueError, match="invalid renderer settings"):
        Renderer(camera, mesh, tile=tile, max_batch=1)


def test_an_atlas_exactly_at_the_context_limits_is_accepted(camera, mesh, monkeypatch):
    """512 tiles of 64 px make a 2048 x 1024 atlas: limits of exactly that size allow it."""
    ctx = gl_context()
    monkeypatch.setitem(ctx.info, "GL_MAX_RENDERBUFFER_SIZE", 2048)
    monkeypatch.setitem(ctx.info, "GL_MAX_VIEWPORT_DIMS", (2048, 1024))
    Renderer(camera, mesh, tile=64, max_batch=512).release()


def test_the_texture_limit_applies_to_the_image_only(camera, mesh, monkeypatch):
    """The atlas is a renderbuffer: a texture limit below its 2048 px but above the 1280 x 720
    image allows the renderer."""
    monkeypatch.setitem(gl_context().info, "GL_MAX_TEXTURE_SIZE", 1536)
    Renderer(camera, mesh, tile=64, max_batch=512).release()


def test_shaded_refuses_sample_counts_outside_one_to_the_context_maximum(camera, renderer):
    background = np.zeros((camera.height, camera.width, 3), np.uint8)
    for samples in (0, renderer.ctx.max_samples + 1):
        with pytest.raises(ValueError, match="samples must be"):
            renderer.shaded(side_view_quat(), [0.0, 0.0, 6.0], background, samples=samples)


def test_release_frees_the_multisampled_targets_of_shaded_views(camera, mesh, monkeypatch):
    """Each sample count used by ``shaded`` makes a colour + depth target: released with the renderer."""
    ctx = gl_context()
    made = []
    for name in ("framebuffer", "renderbuffer", "depth_renderbuffer"):
        def record(*args, _make=getattr(ctx, name), **kwargs):
            made.append(_make(*args, **kwargs))
            return made[-1]

        monkeypatch.setattr(ctx, name, record)
    r = Renderer(camera, mesh, tile=TILE, max_batch=2)
    background = np.zeros((camera.height, camera.width, 3), np.uint8)
    for samples in (1, 4):
        r.shaded(side_view_quat(), [0.0, 0.0, 6.0], background, samples=samples)
    r.release()
    assert [type(obj).__name__ for obj in made if type(obj.mglo).__name__ != "InvalidObject"] == []
