"""Covariance coverage: error vectors, NEES and the per-depth counts, against hand-made cases."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from uav_landing_vision.evaluation.consistency import coverage_by_depth, error_vectors, format_coverage, nees


def test_error_vectors_are_the_truths_offset_from_the_estimate_about_camera_axes():
    q_est = Rotation.from_euler("xyz", [10, -20, 30], degrees=True)
    turn = np.array([0.02, -0.05, 0.1])
    q_true = Rotation.from_rotvec(turn) * q_est  # q_true = exp(r) ⊗ q_est
    t_true = np.array([[1.0, 2.0, 30.0], [0.0, 0.0, 10.0]])
    t_est = np.array([[1.5, 1.0, 33.0], [np.nan] * 3])
    q = np.vstack([q_est.as_quat(), [np.nan] * 4])
    err = error_vectors(t_true, np.vstack([q_true.as_quat()] * 2), t_est, q)
    np.testing.assert_allclose(err[0], [-0.5, 1.0, -3.0, *turn], atol=1e-12)
    assert np.all(np.isnan(err[1]))  # no estimate
    err_flipped = error_vectors(t_true[:1], -q_true.as_quat()[None], t_est[:1], q[:1])  # q and -q alike
    np.testing.assert_allclose(err_flipped[0, 3:], turn, atol=1e-12)


def test_nees_matches_the_hand_computed_distance():
    cov = np.diag([4.0, 1.0, 0.25])
    e = np.array([[2.0, 1.0, 0.5], [np.nan, 0.0, 0.0]])
    out = nees(e, np.stack([cov, cov]))
    assert out[0] == pytest.approx(1.0 + 1.0 + 1.0) and np.isnan(out[1])
    unknown = nees(e[:1], np.zeros((1, 3, 3)))  # all zeros: ROS's "unknown covariance", not a region
    assert np.isnan(unknown[0])
    huge = nees(e[:1], np.stack([np.eye(3) * 1e308]))  # finite, but no statement of uncertainty
    assert np.isnan(huge[0])


def test_errors_drawn_from_the_covariance_are_inside_its_95_percent_region_95_percent_of_the_time():
    rng = np.random.default_rng(5)
    n = 4000
    a = rng.normal(size=(6, 6))
    cov = a @ a.T * 1e-3 + np.diag([0.1, 0.1, 0.5, 1e-3, 1e-3, 1e-3])
    cov[:3, 3:] = cov[3:, :3] = 0.0
    e = rng.multivariate_normal(np.zeros(6), cov, size=n)
    t_true = np.column_stack([np.zeros((n, 2)), rng.uniform(1.0, 100.0, n)])
    q_est = Rotation.random(n, random_state=6)
    q_true = Rotation.from_rotvec(e[:, 3:]) * q_est
    rows = coverage_by_depth(t_true, q_true.as_quat(), t_true + e[:, :3], q_est.as_quat(), np.tile(cov, (n, 1, 1)))
    total = rows[-1]
    assert rows[-1]["depth_m"] is None and total["frames"] == n == sum(r["frames"] for r in rows[:-1])
    assert abs(total["position"] / n - 0.95) < 0.015 and abs(total["rotation"] / n - 0.95) < 0.015
    small = coverage_by_depth(t_true, q_true.as_quat(), t_true + e[:, :3], q_est.as_quat(),
                              np.tile(cov / 4.0, (n, 1, 1)))[-1]
    assert small["position"] / n < 0.75 and small["rotation"] / n < 0.75  # an over-confident covariance shows


def test_coverage_bins_skip_lost_frames_and_check_their_input():
    t = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 12.0], [0.0, 0.0, 70.0]])
    q = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    est = t + [[0.1, 0.0, 0.0], [0.0, 0.0, 3.0], [0.0, 0.0, 0.0]]
    est[2] = np.nan  # lost
    cov = np.tile(np.eye(6) * 0.01, (3, 1, 1))
    rows = coverage_by_depth(t, q, est, q, cov, bins=(0.0, 8.0, 15.0, np.inf))
    assert [(r["frames"], r["position"], r["rotation"]) for r in rows] == [(1, 1, 1), (1, 0, 1), (0, 0, 0), (2, 1, 2)]
    assert rows[0]["depth_m"] == (0.0, 8.0)
    cov[0] = 0.0  # no usable covariance: left out of the count
    assert coverage_by_depth(t, q, est, q, cov, bins=(0.0, 8.0, 15.0, np.inf))[0]["frames"] == 0
    text = format_coverage({"C4N2": rows, "C3N0": rows}, "seq")
    assert text.splitlines()[1].split() == ["true", "depth", "C4N2", "C3N0"]
    assert text.splitlines()[2].split() == ["0-8", "m", "1/1", "|", "1/1", "1/1", "|", "1/1"]
    assert text.splitlines()[-2].split()[:2] == ["15+", "m"] and text.splitlines()[-1].split()[0] == "all"
    with pytest.raises(ValueError, match="6x6"):
        coverage_by_depth(t, q, est, q, cov[:2])
    with pytest.raises(ValueError, match="level"):
        coverage_by_depth(t, q, est, q, cov, level=1.0)


IDENTITY = [0.0, 0.0, 0.0, 1.0]


def test_a_frame_missing_its_position_or_its_orientation_has_no_error_vector_at_all():
    t = np.array([[0.0, 0.0, 10.0]] * 3)
    q = np.tile(IDENTITY, (3, 1))
    t_est = t + 0.1
    q_est = Rotation.from_rotvec([0.0, 0.0, 0.1]).as_quat()[None].repeat(3, axis=0)
    t_est[0] = [np.nan, 0.0, 10.0]  # no position
    q_est[1] = np.nan  # no orientation
    err = error_vectors(t, q, t_est, q_est)
    assert np.all(np.isnan(err[:2]))
    np.testing.assert_allclose(err[2], [-0.1, -0.1, -0.1, 0.0, 0.0, -0.1], atol=1e-12)


def test_nees_refuses_a_covariance_that_is_not_positive_definite():
    e = np.array([[1.0, 0.0, 0.0]] * 3)
    indefinite = np.diag([1.0, 1.0, -1.0])  # its largest eigenvalue is positive
    semi = np.diag([1.0, 1.0, 0.0])
    good = np.diag([4.0, 1.0, 1.0])
    out = nees(e, np.stack([indefinite, semi, good]))
    assert np.isnan(out[0]) and np.isnan(out[1]) and out[2] == pytest.approx(0.25)


def test_nees_judges_definiteness_on_the_whole_matrix_not_one_triangle():
    """An asymmetric matrix whose lower triangle alone looks positive definite but whose
    symmetric part is indefinite is no covariance."""
    c = np.array([[1.0, 5.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    assert np.isnan(nees(np.array([[1.0, 0.0, 0.0]]), c[None])[0])


def test_coverage_refuses_a_level_of_zero():
    t = np.array([[0.0, 0.0, 5.0]])
    q = np.array([IDENTITY])
    with pytest.raises(ValueError, match="level"):
        coverage_by_depth(t, q, t, q, np.eye(6)[None], level=0.0)


def test_a_frame_counts_only_when_both_its_position_and_rotation_covariances_are_usable():
    t = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 6.0]])
    q = np.tile(IDENTITY, (2, 1))
    cov = np.tile(np.eye(6) * 0.01, (2, 1, 1))
    cov[0, :3, :3] = 0.0  # frame 0: the position's covariance is "unknown"
    rows = coverage_by_depth(t, q, t, q, cov, bins=(0.0, 8.0, np.inf))
    assert (rows[0]["frames"], rows[0]["position"], rows[0]["rotation"]) == (1, 1, 1)
    assert (rows[-1]["frames"], rows[-1]["position"], rows[-1]["rotation"]) == (1, 1, 1)


def test_coverage_bins_frames_by_their_true_depth_not_their_range():
    """Depth is the camera-frame z of the true position: a UAV 5 m ahead and 30 m to the side is
    in the 0–8 m bin."""
    t = np.array([[30.0, 0.0, 5.0], [0.0, 40.0, 20.0]])
    q = np.tile(IDENTITY, (2, 1))
    rows = coverage_by_depth(t, q, t, q, np.tile(np.eye(6), (2, 1, 1)))
    by_bin = {r["depth_m"]: r["frames"] for r in rows}
    assert by_bin[(0.0, 8.0)] == 1 and by_bin[(15.0, 30.0)] == 1 and by_bin[(30.0, 60.0)] == 0


def test_coverage_counts_position_and_rotation_at_the_chi_square_quantile():
    """An error at a NEES just inside / just outside the 3-DoF 95 % quantile."""
    limit = chi2.ppf(0.95, 3)
    t = np.zeros((2, 3)) + [0.0, 0.0, 10.0]
    q = np.tile(IDENTITY, (2, 1))
    t_est = t.copy()
    t_est[:, 0] -= [np.sqrt(limit) * 0.999, np.sqrt(limit) * 1.001]  # truth − estimate along x, σ = 1
    rows = coverage_by_depth(t, q, t_est, q, np.tile(np.eye(6), (2, 1, 1)))
    assert (rows[-1]["frames"], rows[-1]["position"], rows[-1]["rotation"]) == (2, 1, 2)


def test_coverage_table_prints_position_then_rotation():
    rows = [{"depth_m": (0.0, 8.0), "frames": 4, "position": 1, "rotation": 3},
            {"depth_m": None, "frames": 4, "position": 1, "rotation": 3}]
    lines = format_coverage({"C4N2": rows}, "seq").splitlines()
    assert lines[2].split() == ["0-8", "m", "1/4", "|", "3/4"]
    assert lines[3].split() == ["all", "1/4", "|", "3/4"]


def test_errors_exactly_on_the_chi_square_quantile_are_inside():
    """"At most the quantile": a position and a rotation error of 0.1 (m, rad) along x under a
    variance chosen so that 0.1 · 0.1 / σ² is the 3-DoF 95 % quantile to the last bit count as inside."""
    limit = chi2.ppf(0.95, 3)
    s0 = 0.01 / limit
    s = next(s0 + k * np.spacing(s0) for k in range(-20, 21) if 0.1 * (0.1 / (s0 + k * np.spacing(s0))) == limit)
    cov = np.diag([s, 1.0, 1.0, s, 1.0, 1.0])[None]
    t_true, t_est = np.array([[0.1, 0.0, 10.0]]), np.array([[0.0, 0.0, 10.0]])
    q_true = Rotation.from_rotvec([0.1, 0.0, 0.0]).as_quat()[None]
    err = error_vectors(t_true, q_true, t_est, np.array([IDENTITY]))
    assert err[0, 0] == 0.1 and err[0, 3] == 0.1 and np.all(err[0, [1, 2, 4, 5]] == 0.0)
    rows = coverage_by_depth(t_true, q_true, t_est, np.array([IDENTITY]), cov)
    assert (rows[-1]["frames"], rows[-1]["position"], rows[-1]["rotation"]) == (1, 1, 1)


def test_nees_takes_a_covariance_whose_entries_reach_the_usable_maximum():
    """Entries up to USABLE_COVARIANCE_MAX (1e150) are a statement of uncertainty; only those
    beyond it are not: an error of 1e75 under 1e150 · I is one σ away."""
    e = np.array([[1e75, 0.0, 0.0]])
    assert nees(e, (np.eye(3) * 1e150)[None])[0] == pytest.approx(1.0)
    assert np.isnan(nees(e, (np.eye(3) * 1.01e150)[None])[0])


def test_coverage_table_gives_each_variant_its_own_counts_in_columns_that_keep_apart():
    """Two variants with different counts over 1000 frames: each column shows its own variant's
    ``inside/frames`` pairs, and the wide cells stay separated."""
    a = [{"depth_m": None, "frames": 1000, "position": 950, "rotation": 948}]
    b = [{"depth_m": None, "frames": 1000, "position": 20, "rotation": 7}]
    lines = format_coverage({"C4N2": a, "C1N0": b}, "seq").splitlines()
    assert lines[1].split() == ["true", "depth", "C4N2", "C1N0"]
    assert lines[2].split() == ["all", "950/1000", "|", "948/1000", "20/1000", "|", "7/1000"]
