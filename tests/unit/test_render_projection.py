"""The renderer against exact oracles: its pinhole projection, by point-in-polygon at pixel centres,
for intrinsics that the deck camera's (fx = fy, zero skew) cannot tell apart; shading, depth
order, the atlas's read-back and clearing, and poses that straddle the near plane."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.camera import CameraModel
from uav_landing_vision.model import Mesh, fixed_wing_mesh
from uav_landing_vision.render import Renderer

TILE = 64
EDGE_PX = 0.01  # pixel centres nearer an edge than this are not judged (float32 rasterisation)

# An asymmetric planar quadrilateral (metres, body z = 0): a flip or transpose of the image changes it.
QUAD = np.array([[-0.6, -0.4, 0.0], [0.7, -0.3, 0.0], [0.5, 0.5, 0.0], [-0.3, 0.35, 0.0]])
QUAD_MESH = Mesh(QUAD, np.array([[0, 1, 2], [0, 2, 3]]))


def _pose(rotvec, trans):
    return Rotation.from_rotvec(rotvec).as_quat(), np.asarray(trans, float)


POSES = [
    _pose([0.0, 0.0, 0.0], [0.0, 0.0, 5.0]),
    _pose([0.4, -0.3, 0.2], [0.8, -0.5, 6.0]),
    _pose([-0.5, 0.2, 2.5], [-1.1, 0.7, 7.5]),
]


def _projected_corners(K, quat, trans):
    p = QUAD @ Rotation.from_quat(quat).as_matrix().T + trans
    uvw = p @ np.asarray(K, float).T
    return uvw[:, :2] / uvw[:, 2:]


def _inside(corners, u, v):
    """+1 inside the convex polygon, 0 outside, -1 within EDGE_PX of an edge (not judged)."""
    n = len(corners)
    nxt = np.roll(corners, -1, axis=0)
    area = 0.5 * np.sum(corners[:, 0] * nxt[:, 1] - nxt[:, 0] * corners[:, 1])
    sign = np.sign(area)
    dist = []
    for i in range(n):
        a, b = corners[i], corners[(i + 1) % n]
        edge = b - a
        cross = edge[0] * (v - a[1]) - edge[1] * (u - a[0])
        dist.append(sign * cross / np.hypot(*edge))
    d = np.min(dist, axis=0)
    return np.where(np.abs(d) < EDGE_PX, -1, (d > 0).astype(int))


def _check_full(renderer, K, width, height, quat, trans):
    full = renderer.silhouette_full(quat, trans)
    assert full.shape == (height, width)
    v, u = np.mgrid[0:height, 0:width].astype(float)
    expected = _inside(_projected_corners(K, quat, trans), u, v)
    judged = expected >= 0
    assert expected[judged].sum() > 2000
    np.testing.assert_array_equal(full[judged], expected[judged] == 1)


def _check_tile(mask, box, K, quat, trans):
    centres = (np.arange(TILE) + 0.5) / TILE
    u = box[0] + centres[None, :] * (box[2] - box[0])
    v = box[1] + centres[:, None] * (box[3] - box[1])
    u, v = np.broadcast_arrays(u, v)
    expected = _inside(_projected_corners(K, quat, trans), u, v)
    judged = expected >= 0
    assert expected[judged].sum() > 200
    np.testing.assert_array_equal(mask[judged].astype(bool), expected[judged] == 1)


ANISOTROPIC = CameraModel(1280, 800, np.array([[900.0, 0.0, 600.3], [0.0, 1300.0, 420.8], [0.0, 0.0, 1.0]]))


@pytest.fixture(scope="module")
def anisotropic_renderer():
    with Renderer(ANISOTROPIC, QUAD_MESH, tile=TILE, max_batch=4) as r:
        yield r


@pytest.mark.parametrize("k", range(len(POSES)))
def test_full_frame_follows_fx_fy_and_a_fractional_principal_point(anisotropic_renderer, k):
    """Non-square pixels (fx ≠ fy) and a principal point off the pixel grid: every pixel
    centre (integer coordinates) is covered exactly when it lies inside K·[R|t]·quad."""
    _check_full(anisotropic_renderer, ANISOTROPIC.K, ANISOTROPIC.width, ANISOTROPIC.height, *POSES[k])


def test_tiles_follow_fx_fy_and_the_tile_pixel_centres(anisotropic_renderer):
    quats = np.array([q for q, _ in POSES])
    trans = np.array([t for _, t in POSES])
    batch = anisotropic_renderer.silhouettes(quats, trans)
    assert batch.visible.all()
    for mask, box, (q, t) in zip(batch.masks, batch.boxes, POSES):
        _check_tile(mask, box, ANISOTROPIC.K, q, t)


def test_skewed_intrinsics_are_projected_with_their_skew():
    """The renderer reads only ``width``, ``height`` and ``K`` of its camera, skew included."""
    K = np.array([[1000.0, 180.0, 640.5], [0.0, 950.0, 359.25], [0.0, 0.0, 1.0]])
    camera = SimpleNamespace(width=1280, height=720, K=K)
    with Renderer(camera, QUAD_MESH, tile=TILE, max_batch=4) as r:
        for q, t in POSES:
            _check_full(r, K, 1280, 720, q, t)
        quats = np.array([q for q, _ in POSES])
        batch = r.silhouettes(quats, np.array([t for _, t in POSES]))
        for mask, box, (q, t) in zip(batch.masks, batch.boxes, POSES):
            _check_tile(mask, box, K, q, t)


@pytest.mark.parametrize("max_batch", [3, 5, 7])
def test_every_slot_of_an_atlas_with_a_partial_last_row_is_read_back(max_batch):
    """With a tile count that is not a multiple of the atlas's columns, the last row's tiles
    equal those rendered one at a time."""
    camera = CameraModel(640, 480, np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]]))
    mesh = fixed_wing_mesh("low")
    rng = np.random.default_rng(11)
    quats = Rotation.random(max_batch, random_state=rng).as_quat()
    trans = np.column_stack([rng.uniform(-1, 1, (max_batch, 2)), rng.uniform(6, 12, max_batch)])
    with Renderer(camera, mesh, tile=32, max_batch=max_batch) as r, Renderer(camera, mesh, tile=32, max_batch=1) as one:
        batch = r.silhouettes(quats, trans)
        for i in range(max_batch):
            single = one.silhouettes(quats[i : i + 1], trans[i : i + 1])
            assert single.masks[0].sum() > 30
            assert (single.masks[0] != batch.masks[i]).sum() <= 2


def test_a_smaller_silhouette_after_a_larger_one_leaves_no_trace():
    """Each draw starts from a cleared target: a far pose after a near one in the same slot."""
    camera = CameraModel(640, 480, np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]]))
    q = np.array([[0.0, 0.0, 0.0, 1.0]])
    with Renderer(camera, QUAD_MESH, tile=TILE, max_batch=1) as r:
        near = r.silhouettes(q, np.array([[0.0, 0.0, 2.0]]))
        assert near.masks[0].mean() > 0.3
        near_full = r.silhouette_full(q[0], [0.0, 0.0, 2.0]).copy()
        # A pose shifted far to the side: the previous one must not remain in either target.
        shifted = np.array([[0.9, 0.0, 4.0]])
        after = r.silhouettes(q, shifted)
        full_after = r.silhouette_full(q[0], shifted[0])
    with Renderer(camera, QUAD_MESH, tile=TILE, max_batch=1) as fresh:
        np.testing.assert_array_equal(after.masks[0], fresh.silhouettes(q, shifted).masks[0])
        np.testing.assert_array_equal(full_after, fresh.silhouette_full(q[0], shifted[0]))
    assert near_full.sum() > 2 * full_after.sum() > 0


@pytest.mark.parametrize("light, lambert", [((0.0, 0.0, -2.0), 1.0),
                                            ((0.0, 3 * np.sin(np.pi / 3), -3 * np.cos(np.pi / 3)), 0.5),
                                            ((0.0, 0.0, 5.0), 0.0)])
def test_shading_of_a_face_is_albedo_times_ambient_plus_lambert(light, lambert):
    """A square facing the camera (normal −z in the optical frame): colour = albedo·(a + (1−a)·max(n·l, 0))
    with a = 0.35 and l the light direction normalised, whatever its given length."""
    camera = CameraModel(320, 240, np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]]))
    square = Mesh(np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0.0]]),
                  np.array([[0, 1, 2], [0, 2, 3]]))
    albedo = np.array([0.5, 0.6, 0.7])
    with Renderer(camera, square, tile=32, max_batch=1) as r:
        rgb, alpha = r.shaded([0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 4.0], np.zeros((240, 320, 3), np.uint8),
                              albedo=tuple(albedo), light_dir=light)
    inside = alpha == 1.0
    assert inside.sum() > 5000
    expected = 255 * albedo * (0.35 + 0.65 * lambert)
    np.testing.assert_allclose(rgb[inside].mean(axis=0), expected, atol=1.0)
    assert np.ptp(rgb[inside], axis=0).max() <= 1


def test_a_mesh_without_triangles_is_refused():
    camera = CameraModel(64, 48, np.array([[50.0, 0.0, 31.5], [0.0, 50.0, 23.5], [0.0, 0.0, 1.0]]))
    empty = Mesh(np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="invalid renderer settings"):
        Renderer(camera, empty)


def _cube(centre, half, yaw):
    """A closed, outward-wound cube rotated by ``yaw`` about the optical y axis."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * half
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    rot = Rotation.from_rotvec([0.0, yaw, 0.0]).as_matrix()
    return corners @ rot.T + centre, faces


def test_shaded_view_shows_the_nearer_of_two_overlapping_solids():
    """A cube turned 45° (its two visible faces lit at cos 45°) in front of a larger cube facing
    the camera (lit fully), the near one listed first: the near cube's colour must win."""
    near_v, near_f = _cube([0.0, 0.0, 3.0], 0.3, np.pi / 4)
    far_v, far_f = _cube([0.0, 0.0, 6.0], 1.5, 0.0)
    mesh = Mesh(np.vstack([near_v, far_v]), np.vstack([near_f, far_f + len(near_v)]))
    assert mesh.is_closed and mesh.signed_volume > 0
    camera = CameraModel(320, 240, np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]]))
    albedo = np.array([0.8, 0.7, 0.6])
    with Renderer(camera, mesh, tile=32, max_batch=1) as r:
        rgb, alpha = r.shaded([0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0], np.zeros((240, 320, 3), np.uint8),
                              albedo=tuple(albedo), light_dir=(0.0, 0.0, -1.0))
    # The near cube spans about ±0.42 m / 3 m · 300 px ≈ ±42 px around the centre; the far one ±75 px.
    centre = rgb[110:130, 140:180].reshape(-1, 3).astype(float)
    rim = rgb[119, 215:225].astype(float)  # only the far cube there
    assert np.all(alpha[100:140, 100:220] == 1.0)
    np.testing.assert_allclose(centre.mean(axis=0), 255 * albedo * (0.35 + 0.65 * np.cos(np.pi / 4)), atol=1.5)
    np.testing.assert_allclose(rim.mean(axis=0), 255 * albedo, atol=1.5)


def test_poses_too_near_the_camera_leave_the_other_tiles_of_a_large_model_untouched():
    """A 9 m model (the loader allows up to 20 m) straddling the camera's near plane in the four
    middle slots of a 4×4 atlas, its wing pointing away from the camera: such a pose is drawn
    (before its tile is blanked) from a stand-in box of one pixel that its wing overflows on every
    side. Its geometry must stay within its own tile, so every visible pose's tile equals the one
    rendered alone."""
    big = fixed_wing_mesh("low")
    big = Mesh(big.vertices * 5.0, big.faces)
    camera = CameraModel(640, 480, np.array([[500.0, 0.0, 319.5], [0.0, 500.0, 239.5], [0.0, 0.0, 1.0]]))
    rng = np.random.default_rng(7)
    n = 16
    quats = Rotation.random(n, random_state=rng).as_quat()
    trans = np.column_stack([rng.uniform(-5, 5, (n, 2)), rng.uniform(40, 80, n)])
    wing_away = Rotation.from_matrix([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]).as_quat()  # body y → depth
    bad = [5, 6, 9, 10]
    quats[bad] = wing_away
    trans[bad] = [-1.03, -0.66, 0.5]
    with Renderer(camera, big, tile=32, max_batch=n) as r, Renderer(camera, big, tile=32, max_batch=1) as one:
        batch = r.silhouettes(quats, trans)
        assert not batch.visible[bad].any() and batch.visible.sum() == n - len(bad)
        assert not batch.masks[bad].any()  # drawn into their tiles (a 1 px box), then blanked
        for i in np.nonzero(batch.visible)[0]:
            single = one.silhouettes(quats[i : i + 1], trans[i : i + 1])
            assert single.masks[0].any()
            assert (single.masks[0] != batch.masks[i]).sum() <= 2


@pytest.mark.parametrize("rotvec, lit_side", [([0.0, np.pi / 4, 0.0], "right"),
                                              ([np.pi / 4, 0.0, 0.0], "top"),
                                              ([0.0, 0.0, 0.0], "front")])
def test_the_default_light_is_above_right_and_behind_the_camera(rotvec, lit_side):
    """A cube showing two faces: of those turned 45° right and left, the right one is brighter; of
    those turned up and down, the upper one; a face towards the camera is lit beyond the ambient."""
    corners, faces = _cube([0.0, 0.0, 0.0], 0.5, 0.0)
    camera = CameraModel(320, 240, np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]]))
    albedo = np.array([0.8, 0.7, 0.6])
    with Renderer(camera, Mesh(corners, faces), tile=32, max_batch=1) as r:
        rgb, alpha = r.shaded(Rotation.from_rotvec(rotvec).as_quat(), [0.0, 0.0, 4.0],
                              np.zeros((240, 320, 3), np.uint8), albedo=tuple(albedo))
    grey = np.where(alpha == 1.0, rgb.mean(axis=2), np.nan)
    if lit_side == "right":
        assert np.nanmean(grey[:, 165:]) > np.nanmean(grey[:, :155]) + 20
    elif lit_side == "top":
        assert np.nanmean(grey[:115]) > np.nanmean(grey[125:]) + 20
    else:
        assert np.nanmin(grey) > 255 * albedo.mean() * 0.35 + 20


def test_a_model_a_few_centimetres_beyond_the_near_plane_is_drawn():
    """The near plane is 5 cm from the camera: a 6.5 cm quadrilateral 10–14 cm away is visible,
    in its tile and exactly at image resolution."""
    small = Mesh(0.05 * QUAD, QUAD_MESH.faces)
    quat, trans = _pose([0.4, -0.3, 0.2], [0.004, -0.002, 0.12])
    p = 0.05 * QUAD @ Rotation.from_quat(quat).as_matrix().T + trans
    assert 0.1 < p[:, 2].min() and p[:, 2].max() < 0.14
    uvw = p @ ANISOTROPIC.K.T
    corners = uvw[:, :2] / uvw[:, 2:]
    with Renderer(ANISOTROPIC, small, tile=TILE, max_batch=1) as r:
        batch = r.silhouettes(quat[None], trans[None])
        full = r.silhouette_full(quat, trans)
    assert batch.visible[0] and batch.masks[0].sum() > 200
    v, u = np.mgrid[0 : ANISOTROPIC.height, 0 : ANISOTROPIC.width].astype(float)
    expected = _inside(corners, u, v)
    judged = expected >= 0
    assert expected[judged].sum() > 2000
    np.testing.assert_array_equal(full[judged], expected[judged] == 1)


def test_a_model_straddling_the_near_plane_is_cut_there_at_image_resolution():
    """A tilted 6.5 cm quadrilateral 3.5–7.5 cm from the camera: the full frame holds exactly the
    projection of its part beyond the 5 cm near plane (the polygon clipped at z = 0.05 m)."""
    quat, trans = _pose([np.pi / 3, 0.0, 0.0], [0.0, 0.0, 0.055])
    p = 0.05 * QUAD @ Rotation.from_quat(quat).as_matrix().T + trans
    assert p[:, 2].min() < 0.04 and p[:, 2].max() > 0.07
    kept = []
    for a, b in zip(p, np.roll(p, -1, axis=0)):  # Sutherland–Hodgman against z >= 0.05
        if a[2] >= 0.05:
            kept.append(a)
        if (a[2] - 0.05) * (b[2] - 0.05) < 0:
            kept.append(a + (0.05 - a[2]) / (b[2] - a[2]) * (b - a))
    uvw = np.array(kept) @ ANISOTROPIC.K.T
    with Renderer(ANISOTROPIC, Mesh(0.05 * QUAD, QUAD_MESH.faces), tile=TILE, max_batch=1) as r:
        full = r.silhouette_full(quat, trans)
    v, u = np.mgrid[0 : ANISOTROPIC.height, 0 : ANISOTROPIC.width].astype(float)
    expected = _inside(uvw[:, :2] / uvw[:, 2:], u, v)
    judged = expected >= 0
    assert expected[judged].sum() > 2000 and (expected[judged] == 0).sum() > 2000
    np.testing.assert_array_equal(full[judged], expected[judged] == 1)
