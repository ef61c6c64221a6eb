"""``geometry_msgs/Pose`` ↔ numpy (position (3,), quaternion (4,) ``[x, y, z, w]``), checked."""

import numpy as np

UNIT_TOLERANCE = 1e-4  # |‖q‖ − 1| accepted from other nodes (float32 sources round-trip well within it)


def pose_to_numpy(pose) -> tuple[np.ndarray, np.ndarray]:
    """Position and quaternion of ``pose``; ValueError unless finite with a unit quaternion."""
    p, q = pose.position, pose.orientation
    position = np.array([p.x, p.y, p.z], float)
    quat = np.array([q.x, q.y, q.z, q.w], float)
    if not np.all(np.isfinite(position)):
        raise ValueError(f"pose position is not finite: {position.tolist()}")
    if not np.all(np.isfinite(quat)) or abs(np.linalg.norm(quat) - 1.0) > UNIT_TOLERANCE:
        raise ValueError(f"pose quaternion is not a finite unit [x, y, z, w]: {quat.tolist()}")
    return position, quat


def numpy_to_pose(pose, position, quat):
    """Write ``position`` and ``quat`` into the message ``pose`` and return it."""
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position)
    q = pose.orientation
    q.x, q.y, q.z, q.w = (float(v) for v in quat)
    return pose
