"""ROS camera_info YAML files and ``sensor_msgs/CameraInfo`` fields ↔ :class:`CameraModel`.

The YAML layout is the one written by ROS's camera calibrator (camera_calibration_parsers):
``image_width``, ``image_height``, ``camera_name``, ``camera_matrix``, ``distortion_model``,
``distortion_coefficients``, ``rectification_matrix``, ``projection_matrix``.
"""

from pathlib import Path

import numpy as np
import yaml

from ..config import UniqueKeyLoader
from .model import DEFAULT_FRAME_ID, DISTORTION_MODELS, CameraModel

_YAML_KEYS = {
    "image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
    "distortion_coefficients", "rectification_matrix", "projection_matrix",
}


class CameraInfoError(ValueError):
    """A camera calibration (file or message) that cannot describe this camera."""


def _distortion_model(model, d: np.ndarray) -> str:
    """The model to read ``d`` with: one of :data:`DISTORTION_MODELS`, or ``""`` (none given)
    with all-zero coefficients, read as ``plumb_bob``. Non-zero coefficients with no model are
    refused: four could be plumb_bob's or an equidistant (fisheye) lens's."""
    supported = ", ".join(DISTORTION_MODELS)
    if model == "" and np.any(d != 0):
        raise CameraInfoError(f"{np.count_nonzero(d)} non-zero distortion coefficients but no distortion_model "
                              f"to say how to read them; set it ({supported})")
    if model not in (*DISTORTION_MODELS, ""):
        raise CameraInfoError(f"distortion model '{model}' is not supported ({supported})")
    return model or "plumb_bob"


def _matrix(doc: dict, key: str, rows: int, cols: int, source: str) -> np.ndarray:
    entry = doc.get(key)
    if not isinstance(entry, dict) or "data" not in entry:
        raise CameraInfoError(f"{source}: '{key}' must be a mapping with rows, cols and data")
    if (entry.get("rows", rows), entry.get("cols", cols)) != (rows, cols):
        raise CameraInfoError(f"{source}: '{key}' must be {rows}x{cols}")
    data = _numbers(entry["data"], key, source)
    if data.size != rows * cols:
        raise CameraInfoError(f"{source}: '{key}' needs {rows * cols} values, has {data.size}")
    return data.reshape(rows, cols)


def _numbers(values, key: str, source: str) -> np.ndarray:
    if not isinstance(values, list) or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in values):
        raise CameraInfoError(f"{source}: '{key}' must be a list of numbers, got {values!r}")
    try:
        return np.array(values, dtype=float)
    except OverflowError as exc:  # an integer beyond the float range
        raise CameraInfoError(f"{source}: '{key}' must be a list of numbers ({exc})") from exc


def _pixels(doc: dict, key: str, source: str) -> int:
    if key not in doc:
        raise CameraInfoError(f"{source}: missing {key}")
    value = doc[key]
    if isinstance(value, bool) or not isinstance(value, int):
        raise CameraInfoError(f"{source}: '{key}' must be an integer number of pixels, got {value!r}")
    return value


def load_camera_info_yaml(path, frame_id: str = DEFAULT_FRAME_ID) -> CameraModel:
    """Read a ROS camera_info YAML file; raise :class:`CameraInfoError` on anything malformed."""
    path = Path(path)
    try:
        doc = yaml.load(path.read_bytes(), UniqueKeyLoader)  # bytes: an undecodable file is a YAMLError
    except (OSError, yaml.YAMLError) as exc:
        raise CameraInfoError(f"cannot read camera calibration {path}: {exc}") from exc
    if not isinstance(doc, dict):
        raise CameraInfoError(f"{path}: not a camera_info YAML mapping")
    unknown = set(doc) - _YAML_KEYS
    if unknown:
        raise CameraInfoError(f"{path}: unknown keys {sorted(unknown)}")
    K = _matrix(doc, "camera_matrix", 3, 3, str(path))
    dist_entry = doc.get("distortion_coefficients", {"data": []})  # none given: no distortion
    if not isinstance(dist_entry, dict) or "data" not in dist_entry:
        raise CameraInfoError(f"{path}: 'distortion_coefficients' must be a mapping with rows, cols and data")
    dist = _numbers(dist_entry["data"], "distortion_coefficients", str(path))
    shape = (dist_entry.get("rows", 1), dist_entry.get("cols", dist.size))
    if shape != (1, dist.size):  # ROS's own parser reads rows x cols values
        raise CameraInfoError(f"{path}: 'distortion_coefficients' must be 1x{dist.size} for its {dist.size} values, "
                              f"got {shape[0]}x{shape[1]}")
    try:
        model = _distortion_model(doc.get("distortion_model", "plumb_bob"), dist)
    except CameraInfoError as exc:
        raise CameraInfoError(f"{path}: {exc}") from exc
    if "rectification_matrix" in doc:
        R = _matrix(doc, "rectification_matrix", 3, 3, str(path))
        if np.any(R) and not np.allclose(R, np.eye(3)):  # all zeros: none, as in a message
            raise CameraInfoError(f"{path}: a rectification rotation (stereo) is not supported; it must be identity")
    if "projection_matrix" in doc:
        _matrix(doc, "projection_matrix", 3, 4, str(path))  # unused (rectification keeps K), but well-formed
    width, height = _pixels(doc, "image_width", str(path)), _pixels(doc, "image_height", str(path))
    try:
        return CameraModel(width, height, K, dist, frame_id, model)
    except ValueError as exc:
        raise CameraInfoError(f"{path}: {exc}") from exc


def save_camera_info_yaml(camera: CameraModel, path, camera_name: str = "deck_camera") -> None:
    """Write ``camera`` as a ROS camera_info YAML file."""
    fields = camera_info_fields(camera)

    def block(rows, cols, data):
        return {"rows": rows, "cols": cols, "data": [float(v) for v in data]}

    doc = {
        "image_width": camera.width,
        "image_height": camera.height,
        "camera_name": camera_name,
        "camera_matrix": block(3, 3, fields["k"]),
        "distortion_model": fields["distortion_model"],
        "distortion_coefficients": block(1, len(fields["d"]), fields["d"]),
        "rectification_matrix": block(3, 3, fields["r"]),
        "projection_matrix": block(3, 4, fields["p"]),
    }
    Path(path).write_text(yaml.safe_dump(doc, sort_keys=False))


def camera_info_fields(camera: CameraModel) -> dict:
    """The fields of a ``sensor_msgs/CameraInfo`` message (lower-case names as in rclpy)."""
    P = np.hstack([camera.K, np.zeros((3, 1))])
    return {
        "width": camera.width,
        "height": camera.height,
        "distortion_model": camera.distortion_model,
        "d": camera.dist.tolist(),
        "k": camera.K.ravel().tolist(),
        "r": np.eye(3).ravel().tolist(),
        "p": P.ravel().tolist(),
    }


def camera_from_info_msg(msg, frame_id: str = DEFAULT_FRAME_ID) -> CameraModel:
    """The camera of a ``sensor_msgs/CameraInfo``; :class:`CameraInfoError` if unusable.

    Binning and a region of interest are refused: K and D describe the full sensor, so the
    images of such a driver would not match them."""
    if msg.binning_x > 1 or msg.binning_y > 1:
        raise CameraInfoError(f"camera_info binning {msg.binning_x}x{msg.binning_y} is not supported "
                              "(calibrate and stream at full resolution)")
    roi = msg.roi
    if (roi.x_offset or roi.y_offset or (roi.width, roi.height) not in ((0, 0), (msg.width, msg.height))):
        raise CameraInfoError(f"camera_info region of interest {roi.width}x{roi.height}+{roi.x_offset}+"
                              f"{roi.y_offset} is not supported (the full {msg.width}x{msg.height} image only)")
    return camera_from_info_fields(msg.width, msg.height, msg.distortion_model, msg.d, msg.k, msg.r, frame_id)


def camera_from_info_fields(
    width, height, distortion_model, d, k, r=None, frame_id: str = DEFAULT_FRAME_ID
) -> CameraModel:
    """Validate ``sensor_msgs/CameraInfo`` fields and build the camera; :class:`CameraInfoError` if unusable."""
    model = _distortion_model(distortion_model, np.asarray(d, dtype=float))
    k = np.asarray(k, dtype=float)
    if k.size != 9 or not np.any(k):
        raise CameraInfoError("camera_info K is missing (all zeros means an uncalibrated camera)")
    if r is not None and np.any(r) and not np.allclose(np.asarray(r, dtype=float).reshape(3, 3), np.eye(3)):
        raise CameraInfoError("camera_info R must be identity (monocular camera)")
    try:
        return CameraModel(int(width), int(height), k.reshape(3, 3), np.asarray(d, dtype=float), frame_id, model)
    except ValueError as exc:
        raise CameraInfoError(str(exc)) from exc
