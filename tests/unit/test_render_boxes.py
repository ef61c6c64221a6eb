"""Projected ROIs and tile boxes on hand-made poses with known answers (pure numpy)."""

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.render.boxes import NEAR, pose_matrices, project_points, projected_roi, tile_boxes

K = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 40.0], [0.0, 0.0, 1.0]])
CAMERA = SimpleNamespace(K=K, width=100, height=80)
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def _plate(half_w, half_h):
    return np.array([[-half_w, -half_h, 0.0], [half_w, -half_h, 0.0], [half_w, half_h, 0.0], [-half_w, half_h, 0.0]])


def test_project_points_matches_the_pinhole_model_with_skew_for_any_rotation():
    rng = np.random.default_rng(5)
    Ks = np.array([[120.0, 7.0, 61.0], [0.0, 95.0, 33.0], [0.0, 0.0, 1.0]])
    quats = Rotation.random(4, random_state=11).as_quat()
    trans = rng.uniform([-1, -1, 8], [1, 1, 12], (4, 3))
    points = rng.uniform(-1, 1, (7, 3))
    rot, t = pose_matrices(quats * 3.0, trans)  # not unit: normalised
    z, uv = project_points(Ks, rot, t, points)
    cam = np.einsum("mij,nj->mni", Rotation.from_quat(quats).as_matrix(), points) + trans[:, None]
    hom = cam @ Ks.T
    np.testing.assert_allclose(z, cam[..., 2], atol=1e-12)
    np.testing.assert_allclose(uv, hom[..., :2] / hom[..., 2:], atol=1e-9)


def test_projected_roi_holds_exactly_the_pixels_the_extent_touches():
    # u from 40.3 to 59.8, v from 35.2 to 44.6: pixels 40..60 and 35..45 (pixel u spans [u-½, u+½])
    vertices = np.array([[-0.97, -0.48, 0.0], [0.98, 0.46, 0.0]])
    roi = projected_roi(CAMERA, vertices, IDENTITY, [0.0, 0.0, 10.0])
    u = 100 * vertices[:, 0] / 10 + 50
    v = 100 * vertices[:, 1] / 10 + 40
    assert (u.min(), u.max()) == pytest.approx((40.3, 59.8)) and (v.min(), v.max()) == pytest.approx((35.2, 44.6))
    assert roi == (40, 35, 21, 11)


def test_projected_roi_is_clipped_to_the_image_and_none_outside_or_behind():
    plate = _plate(1.0, 0.5)  # 20 × 10 px at 10 m
    # u from 85 to 105, v from -5 to 5: pixels 85..99 and 0..5
    assert projected_roi(CAMERA, plate, IDENTITY, [4.5, -4.0, 10.0]) == (85, 0, 15, 6)
    # wider than the image on both sides
    assert projected_roi(CAMERA, plate, IDENTITY, [0.0, 0.0, 1.0]) == (0, 0, 100, 80)
    assert projected_roi(CAMERA, plate, IDENTITY, [20.0, 0.0, 10.0]) is None  # beside the image
    assert projected_roi(CAMERA, plate, IDENTITY, [0.0, 20.0, 10.0]) is None  # below it
    assert projected_roi(CAMERA, plate, IDENTITY, [0.0, 0.0, -10.0]) is None  # behind the camera
    # one vertex behind the camera, the others in front: not a box
    tilted = np.array([[0.0, 0.0, -11.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]])
    assert projected_roi(CAMERA, tilted, IDENTITY, [0.0, 0.0, 10.0]) is None


def test_projected_roi_of_a_wide_flat_model_uses_width_and_height_in_their_places():
    cam = SimpleNamespace(K=np.array([[100.0, 0.0, 100.0], [0.0, 100.0, 20.0], [0.0, 0.0, 1.0]]), width=200, height=40)
    plate = _plate(5.0, 0.5)  # u 50..150, v 15..25 at 10 m
    assert projected_roi(cam, plate, IDENTITY, [0.0, 0.0, 10.0]) == (50, 15, 101, 11)
    assert projected_roi(cam, plate, IDENTITY, [0.0, 0.0, 2.0]) == (0, 0, 200, 40)


def test_tile_box_is_centred_square_and_sized_by_the_larger_extent_with_margin():
    hull = _plate(1.0, 0.25)  # 20 × 5 px at 10 m
    rot, t = pose_matrices(IDENTITY[None], np.array([[0.5, -0.3, 10.0]]))
    boxes, visible = tile_boxes(K, 100, 80, rot, t, hull, margin=0.25)
    centre = np.array([50.0 + 5.0, 40.0 - 3.0])
    half = 0.5 * (20.0 * 1.25 + 2.0)
    np.testing.assert_allclose(boxes[0], [centre[0] - half, centre[1] - half, centre[0] + half, centre[1] + half])
    assert visible[0]


def test_tile_box_visibility_needs_the_near_plane_and_an_overlap_with_the_image():
    hull = _plate(0.5, 0.5)  # 10 × 10 px at 10 m: box side 12 with no margin
    trans = np.array([
        [(-6.0 - 50.0) / 10.0, 0.0, 10.0],   # box right edge at u = 0: inside the pixel-0 column
        [(-6.4 - 50.0) / 10.0, 0.0, 10.0],   # right edge at −0.4: still over pixel 0
        [(-6.6 - 50.0) / 10.0, 0.0, 10.0],   # right edge at −0.6: off the image
        [(105.6 - 50.0) / 10.0, 0.0, 10.0],  # left edge at 99.6: past the last column's edge 99.5
        [(105.4 - 50.0) / 10.0, 0.0, 10.0],  # left edge at 99.4: over the last column
        [0.0, (85.4 - 40.0) / 10.0, 10.0],   # top edge at 79.4: over the last row
        [0.0, (85.6 - 40.0) / 10.0, 10.0],   # top edge at 79.6: below the image
    ])
    rot, t = pose_matrices(np.tile(IDENTITY, (len(trans), 1)), trans)
    boxes, visible = tile_boxes(K, 100, 80, rot, t, hull, margin=0.0)
    np.testing.assert_array_equal(visible, [True, True, False, False, True, True, False])
    assert not np.isnan(boxes).any()
    # a hull point between the camera and the near plane: not visible, box NaN
    near = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -10.0 + NEAR / 2]])
    rot, t = pose_matrices(IDENTITY[None], np.array([[0.0, 0.0, 10.0]]))
    boxes, visible = tile_boxes(K, 100, 80, rot, t, near, margin=0.0)
    assert not visible[0] and np.isnan(boxes[0]).all()


def test_tile_box_above_the_image_is_visible_while_its_bottom_edge_is_over_row_0():
    hull = _plate(0.5, 0.5)  # 10 × 10 px at 10 m: box side 12 with no margin
    trans = np.array([
        [0.0, (-6.4 - 40.0) / 10.0, 10.0],  # bottom edge at −0.4: over the first row
        [0.0, (-6.6 - 40.0) / 10.0, 10.0],  # bottom edge at −0.6: above the image
        [0.0, (-3.0 - 40.0) / 10.0, 10.0],  # top edge at −9, bottom edge at 3: partly inside
    ])
    rot, t = pose_matrices(np.tile(IDENTITY, (len(trans), 1)), trans)
    boxes, visible = tile_boxes(K, 100, 80, rot, t, hull, margin=0.0)
    np.testing.assert_allclose(boxes[:, 3], [-0.4, -0.6, 3.0], atol=1e-9)
    np.testing.assert_array_equal(visible, [True, False, True])


@pytest.mark.parametrize("trans", [np.zeros((1, 4)), np.zeros((2, 3)), np.zeros(3), np.array([[0.0, np.nan, 10.0]]),
                                   np.array([[np.inf, 0.0, 10.0]])])
def test_pose_matrices_refuse_translations_of_another_shape_or_not_finite(trans):
    with pytest.raises(ValueError):
        pose_matrices(IDENTITY[None], trans)
