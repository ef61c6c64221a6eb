"""``sensor_msgs/Image`` ↔ numpy for the 8-bit encodings the pipeline uses (cv_bridge is not available),
and ``sensor_msgs/CompressedImage`` → numpy (``camera.decode_compressed``).

Arrays are ``uint8`` of shape ``(height, width, 3)`` for ``rgb8``/``bgr8`` and ``(height, width)``
for ``mono8``. Row padding (``step`` > ``width × channels``) is honoured on input and never
written. ``is_bigendian`` is read as the standard says, but it cannot change 8-bit data: every
supported channel is one byte, so both byte orders give the same array.
"""

import cv2
import numpy as np
from sensor_msgs.msg import CompressedImage, Image

from ..camera import decode_compressed

CHANNELS = {"rgb8": 3, "bgr8": 3, "mono8": 1}


class ImageError(ValueError):
    """An image message this pipeline cannot use (encoding, size, step or data length)."""


def image_to_numpy(msg: Image) -> np.ndarray:
    """The pixels of ``msg`` as a read-only array view; :class:`ImageError` if the message is unusable."""
    channels = CHANNELS.get(msg.encoding)
    if channels is None:
        raise ImageError(f"unsupported image encoding '{msg.encoding}' (supported: {', '.join(CHANNELS)})")
    height, width, step = msg.height, msg.width, msg.step
    if height == 0 or width == 0:
        raise ImageError(f"empty image ({width}x{height})")
    row_bytes = width * channels
    if step < row_bytes:
        raise ImageError(f"step {step} is shorter than one row of {width} {msg.encoding} pixels ({row_bytes} bytes)")
    if len(msg.data) != step * height:
        raise ImageError(f"image data has {len(msg.data)} bytes, expected step x height = {step} x {height}")
    rows = np.frombuffer(msg.data, dtype=np.uint8).reshape(height, step)[:, :row_bytes]
    rows.flags.writeable = False
    return rows.reshape(height, width, channels) if channels > 1 else rows


def compressed_to_numpy(msg: CompressedImage, size: tuple[int, int] | None = None) -> tuple[np.ndarray, str]:
    """``(pixels, encoding)`` of a compressed frame: ``bgr8`` colour or ``mono8`` grey, as
    :func:`image_to_numpy` gives them; :class:`ImageError` if it cannot be decoded or its header
    is not of ``size`` ``(width, height)``, when given (checked before decoding)."""
    try:
        return decode_compressed(msg.data, msg.format, size)
    except ValueError as exc:
        raise ImageError(str(exc)) from exc


def numpy_to_image(pixels: np.ndarray, encoding: str, header) -> Image:
    """An ``Image`` with ``header`` holding ``pixels`` (uint8, shape as the module docstring says)."""
    channels = CHANNELS.get(encoding)
    if channels is None:
        raise ImageError(f"unsupported image encoding '{encoding}' (supported: {', '.join(CHANNELS)})")
    pixels = np.asarray(pixels)
    expected_ndim = 3 if channels > 1 else 2
    if pixels.dtype != np.uint8 or pixels.ndim != expected_ndim or (channels > 1 and pixels.shape[2] != channels):
        raise ImageError(f"{encoding} needs a uint8 array of {expected_ndim} dimensions, got {pixels.dtype} {pixels.shape}")
    height, width = pixels.shape[:2]
    return Image(
        header=header,
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * channels,
        data=np.ascontiguousarray(pixels).tobytes(),
    )


def image_to_rgb(msg: Image) -> np.ndarray:
    """The pixels of an ``rgb8`` (as is) or ``bgr8`` (converted) image as RGB ``(H, W, 3)``;
    :class:`ImageError` for other encodings (the detector and the colour metric need colour)."""
    if msg.encoding not in ("rgb8", "bgr8"):
        raise ImageError(f"image encoding '{msg.encoding}' has no colour (expected rgb8 or bgr8)")
    pixels = image_to_numpy(msg)
    return pixels if msg.encoding == "rgb8" else cv2.cvtColor(pixels, cv2.COLOR_BGR2RGB)
