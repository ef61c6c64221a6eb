"""ParticleSet: validation, selection with per-particle state, weights and (6.5)."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from uav_landing_vision.tracking import ParticleSet


def make(m=5, seed=0, **state):
    rng = np.random.default_rng(seed)
    quat = Rotation.random(m, random_state=rng).as_quat()
    return ParticleSet(
        rng.normal(size=(m, 3)), quat, rng.normal(size=(m, 3)), rng.normal(size=(m, 3)), rng.random(m), state
    )


def test_quaternions_are_stored_sign_canonical():
    q = np.array([[0.0, 0.0, 0.6, -0.8]])
    p = ParticleSet.from_poses(np.zeros((1, 3)), q)
    np.testing.assert_allclose(p.quat, -q)


def test_arrays_are_copied():
    pos = np.zeros((2, 3))
    p = ParticleSet.from_poses(pos, np.tile([0, 0, 0, 1.0], (2, 1)))
    pos[0, 0] = 9.0
    assert p.pos[0, 0] == 0.0


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("pos", np.zeros((5, 2)), "pos"),
        ("quat", np.zeros((5, 4)), "unit norm"),
        ("quat", np.zeros((4, 4)), "quat"),
        ("vel", np.full((5, 3), np.nan), "finite"),
        ("omega", np.zeros((5,)), "omega"),
        ("weight", -np.ones(5), "non-negative"),
        ("weight", np.full(5, np.inf), "finite"),
    ],
)
def test_invalid_fields_raise(field, value, message):
    p = make()
    fields = dict(pos=p.pos, quat=p.quat, vel=p.vel, omega=p.omega, weight=p.weight)
    fields[field] = value
    with pytest.raises(ValueError, match=message):
        ParticleSet(**fields)


def test_state_must_have_leading_axis_m():
    with pytest.raises(ValueError, match="leading axis"):
        make(cov=np.zeros((4, 3, 3)))


def test_take_moves_every_array_and_the_state_together():
    p = make(m=6, cov=np.arange(6)[:, None, None] * np.ones((6, 2, 2)))
    idx = np.array([3, 3, 0, 5])
    t = p.take(idx)
    for name in ("pos", "quat", "vel", "omega", "weight"):
        np.testing.assert_array_equal(getattr(t, name), getattr(p, name)[idx])
    np.testing.assert_array_equal(t.state["cov"][:, 0, 0], idx)
    np.testing.assert_array_equal(p.take(idx, weight=np.ones(4)).weight, np.ones(4))


def test_concat_keeps_order_and_requires_matching_state():
    a, b = make(m=2, seed=1, tag=np.array([1, 2])), make(m=3, seed=2, tag=np.array([3, 4, 5]))
    c = ParticleSet.concat([a, b])
    assert len(c) == 5
    np.testing.assert_array_equal(c.state["tag"], [1, 2, 3, 4, 5])
    np.testing.assert_array_equal(c.pos, np.vstack([a.pos, b.pos]))
    with pytest.raises(ValueError, match="state keys"):
        ParticleSet.concat([a, make(m=2)])


def test_effective_size_is_6_5():
    p = make(m=8)
    w = p.weight / p.weight.sum()
    assert p.effective_size() == pytest.approx(1.0 / np.sum(w**2))
    assert p.with_weight(np.full(8, 3.0)).effective_size() == pytest.approx(8.0)
    assert p.with_weight(np.eye(8)[2]).effective_size() == pytest.approx(1.0)


def test_normalised_weights_and_zero_sum():
    p = make()
    assert p.normalised_weights().sum() == pytest.approx(1.0)
    with pytest.raises(ValueError, match="sum to zero"):
        p.with_weight(np.zeros(5)).normalised_weights()


def test_best_is_the_highest_weight():
    p = make(m=7)
    b = p.best()
    assert len(b) == 1 and p.best_index() == int(np.argmax(p.weight))
    np.testing.assert_array_equal(b.pos[0], p.pos[np.argmax(p.weight)])
    with pytest.raises(ValueError, match="empty"):
        p.take(np.array([], dtype=int)).best()


def test_mean_pose_is_the_weighted_mean_and_the_scatter_matrix_mode():
    """Position: the weighted mean; rotation: scipy's weighted quaternion mean (the same
    eigenvector, Markley et al. 2007), blind to the signs of the stored quaternions."""
    rng = np.random.default_rng(3)
    centre = Rotation.from_rotvec([0.4, -1.2, 2.0])
    rot = Rotation.from_rotvec(rng.normal(0.0, 0.3, (30, 3))) * centre
    weight, pos = rng.random(30), rng.normal(size=(30, 3))
    p = ParticleSet.from_poses(pos, rot.as_quat(), weight)
    mean_pos, mean_quat = p.mean_pose()
    np.testing.assert_allclose(mean_pos, weight @ pos / weight.sum(), rtol=1e-12)
    oracle = rot.mean(weights=weight).as_quat()
    assert abs(np.dot(mean_quat, oracle)) == pytest.approx(1.0, abs=1e-12)
    assert mean_quat[3] >= 0.0
    flipped = rot.as_quat() * np.where(rng.random(30) < 0.5, -1.0, 1.0)[:, None]
    np.testing.assert_allclose(ParticleSet.from_poses(pos, flipped, weight).mean_pose()[1], mean_quat, atol=1e-12)


def test_quaternions_off_unit_norm_by_more_than_a_rounding_error_are_refused():
    """A quaternion 0.1 % off unit norm is no rotation; one off by a rounding error is kept."""
    q = np.array([[0.0, 0.0, 0.0, 1.001]])
    with pytest.raises(ValueError, match="unit norm"):
        ParticleSet.from_poses(np.zeros((1, 3)), q)
    p = ParticleSet.from_poses(np.zeros((1, 3)), np.array([[0.0, 0.0, 0.0, 1.0 + 1e-9]]))
    assert len(p) == 1


def test_state_with_more_rows_than_particles_is_refused():
    """Every state array has exactly M rows, one per particle."""
    with pytest.raises(ValueError, match="leading axis"):
        make(m=5, tag=np.arange(6))


def test_state_arrays_are_copied():
    """The set owns its per-particle state: changing the caller's array afterwards changes nothing."""
    tag = np.arange(5)
    p = make(m=5, tag=tag)
    tag[0] = 99
    np.testing.assert_array_equal(p.state["tag"], np.arange(5))


def test_from_poses_is_at_rest_with_uniform_normalised_weights_and_keeps_state():
    """``from_poses``: zero velocities, weights 1/M and the given per-particle state."""
    pos = np.arange(12.0).reshape(4, 3)
    quat = Rotation.random(4, random_state=2).as_quat()
    p = ParticleSet.from_poses(pos, quat, state={"id": np.arange(4)})
    np.testing.assert_array_equal(p.weight, np.full(4, 0.25))
    np.testing.assert_array_equal(p.vel, np.zeros((4, 3)))
    np.testing.assert_array_equal(p.omega, np.zeros((4, 3)))
    np.testing.assert_array_equal(p.state["id"], np.arange(4))


def test_concat_stacks_every_array_and_refuses_a_set_with_extra_state():
    """Positions, rotations, velocities, rates and weights in order; a later set carrying a state
    key the first lacks is refused as well as one lacking a key."""
    a, b = make(m=2, seed=1), make(m=3, seed=2)
    c = ParticleSet.concat([a, b])
    for name in ("pos", "quat", "vel", "omega"):
        np.testing.assert_array_equal(getattr(c, name), np.vstack([getattr(a, name), getattr(b, name)]))
    np.testing.assert_array_equal(c.weight, np.concatenate([a.weight, b.weight]))
    with pytest.raises(ValueError, match="state keys"):
        ParticleSet.concat([make(m=2), make(m=2, tag=np.array([1, 2]))])
