"""``detection.track_box``: the last pose's box for frames without a detection, and its bounds."""

import numpy as np
import pytest

from uav_landing_vision.camera import CameraModel
from uav_landing_vision.detection.track_box import TrackBox, TrackBoxConfig, grow_roi
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.render.boxes import projected_roi

CAMERA = CameraModel(640, 360, [[550.0, 0, 320.0], [0, 550.0, 180.0], [0, 0, 1]])
VERTICES = fixed_wing_mesh("high").vertices
POSITION, QUAT = np.array([1.0, -0.5, 30.0]), np.array([0.0, 0.0, 0.0, 1.0])
FRAME_NS = 34_000_000


def track_box(**kwargs) -> TrackBox:
    box = TrackBox(TrackBoxConfig(**{"enabled": True, **kwargs}), VERTICES)
    box.set_pose(0, POSITION, QUAT)
    return box


@pytest.mark.parametrize("roi, grow, expected", [
    ((100, 50, 40, 20), 0.0, (100, 50, 40, 20)),
    ((100, 50, 40, 20), 0.25, (90, 45, 60, 30)),
    ((100, 50, 40, 20), 0.5, (80, 40, 80, 40)),
    ((2, 1, 40, 20), 0.25, (0, 0, 52, 26)),  # clipped at the top left ...
    ((610, 340, 20, 10), 1.0, (590, 330, 50, 30)),  # ... and at the bottom right of 640 x 360
])
def test_grow_roi_moves_each_side_out_and_clips(roi, grow, expected):
    assert grow_roi(roi, grow, 640, 360) == expected


def test_the_box_is_the_grown_box_of_the_projected_model():
    roi = projected_roi(CAMERA, VERTICES, QUAT, POSITION)
    assert roi is not None and min(roi[2:]) > 5
    assert track_box(grow=0.25).roi(CAMERA, FRAME_NS) == grow_roi(roi, 0.25, 640, 360)
    assert track_box(grow=0.0).roi(CAMERA, FRAME_NS) == roi


def test_nothing_when_off_without_a_pose_or_out_of_view():
    assert TrackBox(TrackBoxConfig(), VERTICES).roi(CAMERA, FRAME_NS) is None
    off = TrackBox(TrackBoxConfig(enabled=False), VERTICES)
    off.set_pose(0, POSITION, QUAT)
    assert off.roi(CAMERA, FRAME_NS) is None
    behind = track_box()
    behind.set_pose(0, -POSITION, QUAT)
    assert behind.roi(CAMERA, FRAME_NS) is None


@pytest.mark.parametrize("max_age_ns", [300_000_000, 500_000_000, 700_000_000])  # 0.3e9 * 1e-9 > 0.3
def test_the_pose_must_be_recent_and_not_newer_than_the_frame(max_age_ns):
    box = track_box(max_age_s=max_age_ns / 1e9)
    assert box.roi(CAMERA, max_age_ns) is not None
    assert box.roi(CAMERA, max_age_ns + 1) is None
    box.set_pose(2 * FRAME_NS, POSITION, QUAT)
    assert box.roi(CAMERA, FRAME_NS) is None


def test_at_most_max_frames_in_a_row_until_the_network_finds_the_uav_again():
    box = track_box(max_frames=3)
    given = [box.roi(CAMERA, FRAME_NS) is not None for _ in range(5)]
    assert given == [True, True, True, False, False]
    box.detected()
    assert box.roi(CAMERA, FRAME_NS) is not None


def test_frames_without_a_box_do_not_count_towards_the_limit():
    box = track_box(max_frames=2, max_age_s=0.1)
    assert box.roi(CAMERA, 10 * FRAME_NS) is None  # stale pose: no box, no count
    box.set_pose(10 * FRAME_NS, POSITION, QUAT)
    assert box.roi(CAMERA, 11 * FRAME_NS) is not None
    assert box.roi(CAMERA, 12 * FRAME_NS) is not None
    assert box.roi(CAMERA, 13 * FRAME_NS) is None


@pytest.mark.parametrize("kwargs, message", [
    ({"grow": -0.1}, "grow must be in"),
    ({"grow": float("nan")}, "grow must be in"),
    ({"max_frames": 0}, "max_frames must be at least 1"),
    ({"max_age_s": 0.0}, "max_age_s must be finite and > 0"),
    ({"max_age_s": float("inf")}, "max_age_s must be finite and > 0"),
])
def test_bad_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        TrackBoxConfig(**kwargs)


def test_a_pose_far_beyond_the_image_gives_no_box():
    for position in ([1e200, 0.0, 1.0], [-1e200, 0.0, 1.0], [0.0, 1e300, 1e-300]):
        assert projected_roi(CAMERA, VERTICES, QUAT, position) is None


def test_track_box_grow_has_an_upper_bound():
    with pytest.raises(ValueError, match="grow must be in"):
        TrackBoxConfig(grow=2.5)


@pytest.mark.parametrize("roi, grow, expected", [
    ((100, 50, 43, 10), 0.25, (89, 48, 65, 14)),  # 10.75 px rounds to 11
    ((10, 340, 20, 20), 0.5, (0, 330, 40, 30)),  # clipped at the bottom (360), not the width (640)
])
def test_track_box_grow_rounds_and_clips_by_height(roi, grow, expected):
    assert grow_roi(roi, grow, 640, 360) == expected


def test_frames_with_the_model_out_of_view_do_not_count_towards_the_limit():
    box = TrackBox(TrackBoxConfig(max_frames=2), VERTICES)
    box.set_pose(0, [-1.0, 0.5, -30.0], QUAT)  # behind the camera
    assert [box.roi(CAMERA, FRAME_NS) for _ in range(3)] == [None] * 3
    box.set_pose(0, [1.0, -0.5, 30.0], QUAT)
    assert [box.roi(CAMERA, FRAME_NS) is not None for _ in range(3)] == [True, True, False]


def test_track_box_on_the_right_of_a_wide_image_is_clipped_by_its_width():
    """A box right of x = 360 in a 640 x 360 image."""
    position = np.array([8.0, 0.0, 30.0])
    roi = projected_roi(CAMERA, VERTICES, QUAT, position)
    assert roi[0] > 360
    box = TrackBox(TrackBoxConfig(), VERTICES)
    box.set_pose(0, position, QUAT)
    assert box.roi(CAMERA, FRAME_NS) == grow_roi(roi, 0.25, 640, 360)


def test_track_box_grow_of_exactly_two_is_allowed():
    """The bound is inclusive: each side moved out by twice the box's size."""
    assert TrackBoxConfig(grow=2.0).grow == 2.0
    assert grow_roi((100, 50, 40, 20), 2.0, 640, 360) == (20, 10, 200, 100)
