"""The calibrated deck camera: projection, distortion (3.16)–(3.17), camera_info I/O, compressed frames."""

from .camera_info import (
    CameraInfoError,
    camera_from_info_fields,
    camera_from_info_msg,
    camera_info_fields,
    load_camera_info_yaml,
    save_camera_info_yaml,
)
from .compressed import decode_compressed, write_image
from .model import DEFAULT_FRAME_ID, CameraModel

__all__ = [
    "DEFAULT_FRAME_ID",
    "CameraInfoError",
    "CameraModel",
    "camera_from_info_fields",
    "camera_from_info_msg",
    "camera_info_fields",
    "decode_compressed",
    "load_camera_info_yaml",
    "save_camera_info_yaml",
    "write_image",
]
