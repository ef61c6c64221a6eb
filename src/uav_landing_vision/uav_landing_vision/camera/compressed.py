"""Frames a camera driver sent compressed (``sensor_msgs/CompressedImage``: JPEG or PNG bytes),
and frames written as image files.

``image_transport``'s compressed plugin writes 8-bit colour frames as BGR JPEG or PNG (its
``format`` field, e.g. ``"rgb8; jpeg compressed bgr8"``, names the original encoding and what
was compressed), grey frames as grey ones. Its ``compressedDepth`` frames (16-bit depth) are
not camera frames and are refused.
"""

import io
import warnings

import cv2
import numpy as np
from PIL import Image

from .model import MAX_IMAGE_SIDE


def decode_compressed(data, fmt: str = "", size: tuple[int, int] | None = None) -> tuple[np.ndarray, str]:
    """``(pixels, encoding)`` of compressed image bytes: ``uint8 (H, W, 3)`` ``bgr8`` for a colour
    image (an alpha channel is dropped), ``(H, W)`` ``mono8`` for a grey one. ValueError, naming the
    format, for data OpenCV cannot decode, for depth or 16-bit images, and, before decoding, for a
    header of another ``size`` ``(width, height)`` than the one given or of a side over
    ``MAX_IMAGE_SIDE``: a few hundred bytes can claim 20000×20000 pixels, gigabytes to decode."""
    if "compresseddepth" in fmt.lower().replace(" ", ""):
        raise ValueError(f"compressed image format '{fmt}' is a depth image, not a camera frame")
    buffer = np.frombuffer(bytes(data), np.uint8)
    width, height = _header_size(buffer, fmt)
    if not (width <= MAX_IMAGE_SIDE and height <= MAX_IMAGE_SIDE):
        raise ValueError(f"compressed image (format '{fmt}') claims {width}x{height} pixels, over {MAX_IMAGE_SIDE} a side")
    if size is not None and (width, height) != tuple(size):
        raise ValueError(f"compressed image is {width}x{height}, expected {size[0]}x{size[1]}")
    try:  # OpenCV raises (not None) for a header claiming more pixels than it will decode
        pixels = cv2.imdecode(buffer, cv2.IMREAD_UNCHANGED) if buffer.size else None
    except cv2.error as exc:
        raise ValueError(f"cannot decode the compressed image ({len(buffer)} bytes, format '{fmt}'): "
                         f"OpenCV refused it ({getattr(exc, 'err', exc)})") from exc
    if pixels is None or pixels.size == 0:
        raise ValueError(f"cannot decode the compressed image ({len(buffer)} bytes, format '{fmt}')")
    if pixels.dtype != np.uint8:
        raise ValueError(f"compressed image (format '{fmt}') has {pixels.dtype} pixels, expected 8-bit")
    if pixels.ndim == 2:
        return pixels, "mono8"
    if pixels.shape[2] == 4:
        return cv2.cvtColor(pixels, cv2.COLOR_BGRA2BGR), "bgr8"
    if pixels.shape[2] == 3:
        return pixels, "bgr8"
    raise ValueError(f"compressed image (format '{fmt}') has {pixels.shape[2]} channels")


def _header_size(buffer: np.ndarray, fmt: str) -> tuple[int, int]:
    """``(width, height)`` read from the image's header alone (Pillow opens lazily)."""
    try:
        with warnings.catch_warnings():  # Pillow warns of large sizes; ours are checked by the caller
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(buffer.tobytes())) as image:
                return image.size
    except Image.DecompressionBombError as exc:
        raise ValueError(f"compressed image (format '{fmt}') claims too many pixels: {exc}") from exc
    except (OSError, ValueError, SyntaxError) as exc:  # Pillow's errors for unreadable headers
        raise ValueError(f"cannot decode the compressed image ({len(buffer)} bytes, format '{fmt}'): "
                         f"no image header found ({exc})") from exc


def write_image(path, rgb: np.ndarray, params=()) -> None:
    """Write the RGB ``uint8 (H, W, 3)`` image to ``path`` (format by its suffix, OpenCV ``params``);
    OSError if it cannot: OpenCV returns False there (a full disk, a missing folder), not raises."""
    if not cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), list(params)):
        raise OSError(f"cannot write the image {path} (disk full or not writable?)")
