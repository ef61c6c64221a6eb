"""One motion filter per particle (§5.2.3–5.2.4): translational UKF + rotational UKF/UBiF/UBiGaF.

:class:`MotionBank` keeps the batched filter states of all particles aligned with the particle
order, and :func:`recentre` moves a filter onto a pose chosen elsewhere (the pose optimisation
of §5.5 refines a particle after its filter update; the refined pose is what the filter must
carry to the next frame). Recentring keeps each filter's velocity and spread and moves its
mean/mode: position ``x[:3] = p``; orientation by the body rotation ``δ = q̂⁻¹ ⊗ q`` applied
to the whole distribution (C.4), so the covariance turns with it.
"""

from dataclasses import fields, replace

import numpy as np

from ..filters import bingham
from ..filters.motion import MotionFilterConfig, TranslationFilter, make_rotation_filter
from ..geometry import quat_canonical, quat_conjugate, quat_multiply


def _concat(a, b):
    """Concatenate two batched filter states of one type; cached sigma points are dropped."""
    out = {}
    for f in fields(a):
        va, vb = getattr(a, f.name), getattr(b, f.name)
        out[f.name] = None if va is None or vb is None else np.concatenate([va, vb])
    return type(a)(**out)


def recentre(kind: str, state, quat: np.ndarray):
    """The rotation filter state ``state`` of kind ``kind`` moved so that its estimate is ``quat``."""
    if kind == "ukf":  # reference q with zero error d (the state after an update): q ← quat
        return replace(state, q=quat_canonical(quat), x=np.concatenate([np.zeros_like(quat[:, :3]), state.x[:, 3:]], 1),
                       sigmas=None)
    if kind == "ubif":
        delta = quat_multiply(quat_conjugate(bingham.mode(state.m)), quat)
        return replace(state, m=bingham.rotate(state.m, delta, "right"))
    quat = quat_canonical(quat)  # the mode's hemisphere, which P_qω's sign goes with
    delta = quat_multiply(quat_conjugate(state.q), quat)  # ubigaf: mode, P_q and P_qω turn by δ
    p_q = bingham.rotate(np.swapaxes(bingham.rotate(state.p_q, delta, "right"), -1, -2), delta, "right")
    return replace(state, q=quat, p_q=p_q, p_qw=bingham.rotate(state.p_qw, delta, "right"),
                   sig_q=None, sig_w=None, weights=None)


class MotionBank:
    """Batched filters of ``M`` particles; ``kind`` is the rotation filter (``ukf``/``ubif``/``ubigaf``)."""

    def __init__(self, config: MotionFilterConfig):
        self.kind = config.rotation_filter
        self.translation = TranslationFilter(config)
        self.rotation = make_rotation_filter(config)
        self.trans_state = self.rot_state = None

    def __len__(self) -> int:
        return 0 if self.trans_state is None else len(self.trans_state.x)

    def init(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """New filters at rest (zero velocities, §6.7.1.1) at the given poses."""
        zeros = np.zeros((len(pos), 3))
        self.trans_state = self.translation.init(pos, zeros)
        self.rot_state = self.rotation.init(quat, zeros)

    def clear(self) -> None:
        self.trans_state = self.rot_state = None

    def extend(self, other: "MotionBank") -> None:
        """Append the filters of ``other`` (same configuration) after these."""
        if len(self) == 0:
            self.trans_state, self.rot_state = other.trans_state, other.rot_state
        else:
            self.trans_state = _concat(self.trans_state, other.trans_state)
            self.rot_state = _concat(self.rot_state, other.rot_state)

    def take(self, idx) -> None:
        self.trans_state, self.rot_state = self.trans_state.take(idx), self.rot_state.take(idx)

    def predict(self, steps: int = 1) -> None:
        """Constant-velocity prediction (3.12) of every filter (A.12–A.21, Alg. 4, Alg. 6), ``steps``
        times Δt ahead (the frames since the last one, :func:`.upf.prediction_steps`)."""
        for _ in range(steps):
            self.trans_state = self.translation.predict(self.trans_state)
            self.rot_state = self.rotation.predict(self.rot_state)

    def update(self, z_pos: np.ndarray, z_quat: np.ndarray) -> None:
        """Update every filter with the one measurement z_t (§5.2.3)."""
        m = len(self)
        self.trans_state = self.translation.update(self.trans_state, np.broadcast_to(z_pos, (m, 3)))
        self.rot_state = self.rotation.update(self.rot_state, np.broadcast_to(z_quat, (m, 4)))

    def estimates(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, orientation and angular velocity of every filter."""
        pos, vel = self.translation.estimate(self.trans_state)
        quat, omega = self.rotation.estimate(self.rot_state)
        return pos, vel, quat, omega

    def recentre(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """Move every filter onto the given poses (see the module docstring)."""
        x = self.trans_state.x.copy()
        x[:, :3] = pos
        self.trans_state = replace(self.trans_state, x=x, sigmas=None)
        self.rot_state = recentre(self.kind, self.rot_state, quat)
