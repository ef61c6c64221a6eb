"""The rotation window of the published estimate (tracking/smoothing.py)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.geometry import geodesic_angle
from uav_landing_vision.tracking.smoothing import RotationWindow

DT_NS = 34_000_000


def close_rotations(a, b, tol_deg=1e-6):
    return float(np.degrees(geodesic_angle(np.asarray(a)[None], np.asarray(b)))[0]) < tol_deg


def test_one_frame_passes_the_estimate_through():
    window = RotationWindow(1, 0.051)
    quats = Rotation.random(5, random_state=1).as_quat()
    for k, q in enumerate(quats):
        np.testing.assert_array_equal(window(k * DT_NS, q), q)


def test_the_mean_of_the_window_matches_scipy():
    rng = np.random.default_rng(3)
    window = RotationWindow(3, 0.051)
    base = Rotation.random(random_state=4)
    rots = [base * Rotation.from_rotvec(rng.normal(0.0, 0.2, 3)) for _ in range(6)]
    for k, r in enumerate(rots):
        out = window(k * DT_NS, r.as_quat())
        expected = Rotation.concatenate(rots[max(0, k - 2):k + 1]).mean()  # chordal L2 mean
        assert close_rotations(out, expected.as_quat())
        assert out[3] >= 0.0 and np.isclose(np.linalg.norm(out), 1.0)


def test_q_and_minus_q_count_alike():
    window = RotationWindow(2, 0.051)
    q = Rotation.from_rotvec([0.0, 0.0, 0.3]).as_quat()
    p = Rotation.from_rotvec([0.0, 0.0, 0.5]).as_quat()
    window(0, q)
    out = window(DT_NS, -p)
    assert close_rotations(out, Rotation.from_rotvec([0.0, 0.0, 0.4]).as_quat())


def test_an_old_estimate_and_a_reset_leave_the_window():
    window = RotationWindow(2, 0.051)
    q = Rotation.from_rotvec([0.2, 0.0, 0.0]).as_quat()
    p = Rotation.from_rotvec([0.0, 0.2, 0.0]).as_quat()
    window(0, q)
    np.testing.assert_array_equal(window(3 * DT_NS, p), p)  # a gap of two frames: q is too old
    window.reset()
    np.testing.assert_array_equal(window(4 * DT_NS, q), q)


def test_a_turn_beyond_the_limit_restarts_the_window():
    window = RotationWindow(3, 0.051, max_turn_deg=30.0)
    a = Rotation.from_rotvec([np.pi / 2, 0.0, 0.0])
    b = Rotation.from_rotvec([0.0, 0.0, np.radians(160.0)]) * a  # a whole-set flip
    c = Rotation.from_rotvec([0.0, 0.0, np.radians(10.0)]) * b
    window(0, a.as_quat())
    np.testing.assert_array_equal(window(DT_NS, b.as_quat()), b.as_quat())  # not the 80° midpoint
    expected = Rotation.concatenate([b, c]).mean()  # a is left out with the jump
    assert close_rotations(window(2 * DT_NS, c.as_quat()), expected.as_quat())


@pytest.mark.parametrize("frames, step, turn", [(0, 0.05, 30), (1.5, 0.05, 30), (2, 0.0, 30), (2, float("nan"), 30),
                                                (2, 0.05, 0.0), (2, 0.05, float("nan"))])
def test_bad_settings_are_refused(frames, step, turn):
    with pytest.raises(ValueError):
        RotationWindow(frames, step, turn)


def test_stamps_must_increase():
    window = RotationWindow(2, 0.051)
    window(DT_NS, np.array([0.0, 0.0, 0.0, 1.0]))
    with pytest.raises(ValueError, match="not after"):
        window(DT_NS, np.array([0.0, 0.0, 0.0, 1.0]))


def test_estimates_further_apart_than_the_step_are_never_averaged():
    """A 15 fps camera (67 ms > 1.5 Δt) gets every estimate through, whatever the window's length;
    a dropped frame inside a longer window empties it."""
    window = RotationWindow(3, 0.051)
    quats = [Rotation.from_rotvec([0.0, 0.0, np.radians(a)]).as_quat() for a in (0.0, 4.0, 8.0)]
    for k, q in enumerate(quats):
        np.testing.assert_array_equal(window(k * 66_666_667, q), q)
    window = RotationWindow(3, 0.051)
    window(0, quats[0])
    np.testing.assert_array_equal(window(2 * DT_NS, quats[2]), quats[2])


def test_estimates_exactly_the_step_apart_are_still_averaged():
    """The window restarts after a gap of *more than* ``max_step_s`` (0.0625 s is exact in binary)."""
    window = RotationWindow(2, 0.0625)
    q = Rotation.from_rotvec([0.0, 0.0, 0.1]).as_quat()
    p = Rotation.from_rotvec([0.0, 0.0, 0.2]).as_quat()
    window(0, q)
    assert close_rotations(window(62_500_000, p), Rotation.from_rotvec([0.0, 0.0, 0.15]).as_quat())
    np.testing.assert_array_equal(window(62_500_000 + 62_500_001, q), q)  # one ns more: restarted


def test_a_steady_turn_in_small_steps_never_restarts_the_window():
    """The turn limit is between consecutive estimates: 6° a frame against a 10° limit keeps the
    window full, though its oldest and newest estimates are 18° apart; the output is scipy's mean
    of the last four."""
    window = RotationWindow(4, 0.051, max_turn_deg=10.0)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    base = Rotation.from_euler("ZYX", [20.0, 5.0, -10.0], degrees=True)
    rots = [Rotation.from_rotvec(axis * np.radians(6.0 * k)) * base for k in range(7)]
    for k, r in enumerate(rots):
        out = window(k * DT_NS, r.as_quat())
        expected = Rotation.concatenate(rots[max(0, k - 3):k + 1]).mean()
        assert close_rotations(out, expected.as_quat()), k
