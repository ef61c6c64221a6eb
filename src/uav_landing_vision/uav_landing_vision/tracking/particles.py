"""The particle set of the tracker as a structure of arrays (DESIGN §3).

A particle is the state (3.5): position ``pos`` and orientation ``quat`` of the UAV body in the
camera optical frame (``[x, y, z, w]``, active, stored with ``w >= 0``), linear velocity
``vel`` and body angular velocity ``omega`` (3.12), and an importance weight. ``state`` holds
any per-particle filter state (e.g. UKF covariances) as arrays with leading axis ``M``; it
travels with the particles through :meth:`ParticleSet.take` and :meth:`ParticleSet.concat`.
"""

from dataclasses import dataclass, field, replace

import numpy as np

from ..filters.bingham import mean_rotation
from ..geometry import quat_canonical

_UNIT_TOL = 1e-6


def _array(name: str, value, shape: tuple) -> np.ndarray:
    arr = np.array(value, dtype=float)
    if arr.shape != shape:
        raise ValueError(f"ParticleSet.{name}: expected shape {shape}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"ParticleSet.{name}: values must be finite")
    return arr


@dataclass(frozen=True)
class ParticleSet:
    """``M`` particles; arrays are copied and validated on construction."""

    pos: np.ndarray  # (M, 3) metres
    quat: np.ndarray  # (M, 4) unit [x, y, z, w]
    vel: np.ndarray  # (M, 3) m/s
    omega: np.ndarray  # (M, 3) rad/s, body frame
    weight: np.ndarray  # (M,) non-negative, not necessarily normalised
    state: dict = field(default_factory=dict)  # name -> (M, ...) array

    def __post_init__(self):
        pos = np.array(self.pos, dtype=float)
        if pos.ndim != 2 or pos.shape[1] != 3:
            raise ValueError(f"ParticleSet.pos: expected shape (M, 3), got {pos.shape}")
        m = pos.shape[0]
        quat = _array("quat", self.quat, (m, 4))
        if np.any(np.abs(np.linalg.norm(quat, axis=1) - 1.0) > _UNIT_TOL):
            raise ValueError("ParticleSet.quat: quaternions must have unit norm")
        weight = _array("weight", self.weight, (m,))
        if np.any(weight < 0.0):
            raise ValueError("ParticleSet.weight: weights must be non-negative")
        state = {}
        for name, value in dict(self.state).items():
            arr = np.array(value)
            if arr.ndim == 0 or arr.shape[0] != m:
                raise ValueError(f"ParticleSet.state[{name!r}]: leading axis must be {m}, got {arr.shape}")
            state[name] = arr
        object.__setattr__(self, "pos", _array("pos", pos, (m, 3)))
        object.__setattr__(self, "quat", quat_canonical(quat))
        object.__setattr__(self, "vel", _array("vel", self.vel, (m, 3)))
        object.__setattr__(self, "omega", _array("omega", self.omega, (m, 3)))
        object.__setattr__(self, "weight", weight)
        object.__setattr__(self, "state", state)

    @classmethod
    def from_poses(cls, pos, quat, weight=None, state=None) -> "ParticleSet":
        """Particles at rest (zero velocities); uniform weights ``1/M`` unless given."""
        pos = np.asarray(pos, dtype=float)
        m = len(pos)
        zeros = np.zeros((m, 3))
        weight = np.full(m, 1.0 / max(m, 1)) if weight is None else weight
        return cls(pos, quat, zeros, zeros, weight, state or {})

    def __len__(self) -> int:
        return self.pos.shape[0]

    def take(self, indices, weight=None) -> "ParticleSet":
        """The particles at ``indices`` (repeats allowed), with their weights unless ``weight`` is given."""
        idx = np.asarray(indices, dtype=np.intp)
        if idx.ndim != 1:
            raise ValueError("ParticleSet.take: indices must be one-dimensional")
        return ParticleSet(
            self.pos[idx],
            self.quat[idx],
            self.vel[idx],
            self.omega[idx],
            self.weight[idx] if weight is None else weight,
            {k: v[idx] for k, v in self.state.items()},
        )

    def with_pose(self, pos, quat) -> "ParticleSet":
        """The same particles moved to new poses (velocities, weights, state kept)."""
        return replace(self, pos=pos, quat=quat)

    def with_weight(self, weight) -> "ParticleSet":
        return replace(self, weight=weight)

    @staticmethod
    def concat(sets) -> "ParticleSet":
        """All particles of ``sets`` in order; every set must carry the same ``state`` keys."""
        sets = list(sets)
        if not sets:
            raise ValueError("ParticleSet.concat: need at least one set")
        keys = set(sets[0].state)
        if any(set(s.state) != keys for s in sets):
            raise ValueError("ParticleSet.concat: all sets must carry the same state keys")
        cat = lambda name: np.concatenate([getattr(s, name) for s in sets])  # noqa: E731
        state = {k: np.concatenate([s.state[k] for s in sets]) for k in keys}
        return ParticleSet(cat("pos"), cat("quat"), cat("vel"), cat("omega"), cat("weight"), state)

    def normalised_weights(self) -> np.ndarray:
        total = self.weight.sum()
        if not total > 0.0:
            raise ValueError("ParticleSet: weights sum to zero; cannot normalise")
        return self.weight / total

    def effective_size(self) -> float:
        """Effective number of particles (6.5): ``1 / Σ w̃²`` of the normalised weights."""
        w = self.normalised_weights()
        return float(1.0 / np.sum(w * w))

    def mean_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Weighted mean position and mean rotation: the mode of the Bingham fitted to the
        weighted quaternions (C.8)–(C.9), i.e. the principal eigenvector of their scatter matrix
        (sign-free, so ``q`` and ``−q`` count alike)."""
        w = self.normalised_weights()
        return w @ self.pos, mean_rotation(self.quat, w)

    def best_index(self) -> int:
        """Index of the highest weight (the first on ties)."""
        if len(self) == 0:
            raise ValueError("ParticleSet: an empty set has no best particle")
        return int(np.argmax(self.weight))

    def best(self) -> "ParticleSet":
        """The highest-weight particle as a one-particle set (the thesis's state estimate)."""
        return self.take([self.best_index()])
