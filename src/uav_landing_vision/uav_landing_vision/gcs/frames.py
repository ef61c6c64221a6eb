"""Frames from the tracker's camera pose to what MAVLink consumers expect.

Frames (all right-handed; rotations active, ``p_parent = R @ p_child + t``):

- camera optical (C): x right, y down, z forward (REP 103 optical); the tracker's parent frame.
- camera mount (M): x along the optical axis, y right, z down; ``rpy`` in the YAML rotates M
  into the ship frame, so zero angles = camera looking at the bow, image right = starboard.
- ship body (S): x toward the bow, y to starboard, z down (marine FRD), origin fixed on deck.
- landing (L): the ship frame moved to the landing point (the net); "NED-like": x toward
  the bow (not north), y starboard, z down. No ship attitude enters: it is ship-fixed.
- UAV body: FLU (x forward, y left, z up) in the tracker, FRD (x forward, y right, z down)
  for MAVLink.

Covariances are 6×6 in ROS ``PoseWithCovariance`` order ``(x, y, z, rx, ry, rz)``: position,
then a small rotation about the parent frame's axes, ``R_true = exp([δ]×) R``.
"""

from dataclasses import dataclass

import numpy as np

from ..geometry import euler_zyx_to_matrix, matrix_to_euler_zyx, matrix_to_quat, quat_to_matrix

# Columns: the optical axes x (right), y (down), z (forward) written in the mount frame M.
_OPTICAL_IN_MOUNT = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
# FRD axes written in FLU: a rotation of π about x.
FRD_IN_FLU = np.diag([1.0, -1.0, -1.0])
_UNIT_TOL = 1e-6


@dataclass(frozen=True)
class DeckGeometry:
    """Camera extrinsics on the deck and the landing point, in the ship frame."""

    r_ship_cam: np.ndarray  # (3, 3) optical frame → ship frame
    t_ship_cam: np.ndarray  # (3,) optical centre in the ship frame (m)
    net: np.ndarray  # (3,) landing point in the ship frame (m)

    @classmethod
    def from_mount(cls, camera_position, camera_rpy, net_position) -> "DeckGeometry":
        return cls(
            r_ship_cam=camera_mount_rotation(camera_rpy),
            t_ship_cam=np.asarray(camera_position, dtype=float),
            net=np.asarray(net_position, dtype=float),
        )


@dataclass(frozen=True)
class LandingPose:
    """The UAV in the landing frame L: FRD body, covariance about L's axes."""

    position: np.ndarray  # (3,) UAV centre of gravity relative to the landing point (m)
    quat: np.ndarray  # (4,) [x, y, z, w]: FRD body → L
    covariance: np.ndarray  # (6, 6) ROS order, rotation part about L's axes


def camera_mount_rotation(rpy) -> np.ndarray:
    """Rotation optical frame → ship frame from Z-Y-X ``[roll, pitch, yaw]`` of the mount (rad)."""
    return euler_zyx_to_matrix(np.asarray(rpy, dtype=float)) @ _OPTICAL_IN_MOUNT


def validate_pose(position, quat, covariance) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arrays of a finite position, a unit quaternion and a symmetric PSD 6×6; else ValueError."""
    p = np.asarray(position, dtype=float)
    q = np.asarray(quat, dtype=float)
    cov = np.asarray(covariance, dtype=float)
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise ValueError(f"pose position must be 3 finite numbers, got {position!r}")
    if q.shape != (4,) or not np.all(np.isfinite(q)) or abs(np.linalg.norm(q) - 1.0) > _UNIT_TOL:
        raise ValueError(f"pose quaternion must be a finite unit [x, y, z, w], got {quat!r}")
    if cov.shape == (36,):
        cov = cov.reshape(6, 6)
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        raise ValueError("pose covariance must be 36 finite numbers (6×6)")
    scale = max(1.0, float(np.abs(cov).max()))
    if not np.allclose(cov, cov.T, rtol=0.0, atol=1e-9 * scale):
        raise ValueError("pose covariance is not symmetric")
    if np.linalg.eigvalsh(0.5 * (cov + cov.T)).min() < -1e-9 * scale:
        raise ValueError("pose covariance is not positive semi-definite")
    return p, q, cov


def camera_to_landing(position_cam, quat_cam, covariance_cam, deck: DeckGeometry) -> LandingPose:
    """The tracker's FLU-body-in-camera pose as an FRD-body-in-landing-frame pose.

    ``p_L = R_SC p_C + t_SC − net``; ``R_L,FRD = R_SC R_C,FLU FRD_IN_FLU``; the covariance
    rotates by ``blockdiag(R_SC, R_SC)`` (a body-side change of axes leaves a parent-frame
    rotation error unchanged). Rejects bad input with ValueError.
    """
    p, q, cov = validate_pose(position_cam, quat_cam, covariance_cam)
    r = deck.r_ship_cam
    rot = r @ quat_to_matrix(q) @ FRD_IN_FLU
    big = np.zeros((6, 6))
    big[:3, :3] = big[3:, 3:] = r
    return LandingPose(
        position=r @ p + deck.t_ship_cam - deck.net,
        quat=matrix_to_quat(rot),
        covariance=big @ cov @ big.T,
    )


def euler_covariance(pose: LandingPose) -> np.ndarray:
    """Covariance of ``(x, y, z, roll, pitch, yaw)``, the MAVLink pose-covariance states.

    First-order: the Z-Y-X angle increments are ``W⁻¹ δ`` with
    ``W = [Rz(ψ)Ry(θ)e_x, Rz(ψ)e_y, e_z]`` mapping angle rates to parent-frame rotation.
    Undefined at pitch ±90° (ValueError).
    """
    _, pitch, yaw = matrix_to_euler_zyx(quat_to_matrix(pose.quat))
    if abs(np.cos(pitch)) < 1e-6:
        raise ValueError("roll/pitch/yaw covariance is undefined at pitch ±90°")
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    w = np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])
    jac = np.eye(6)
    jac[3:, 3:] = np.linalg.inv(w)
    return jac @ pose.covariance @ jac.T


def target_in_body(pose: LandingPose) -> np.ndarray:
    """The landing point as seen from the UAV, in its FRD body frame (LANDING_TARGET x, y, z)."""
    return quat_to_matrix(pose.quat).T @ -pose.position
