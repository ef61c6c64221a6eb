"""``camera.decode_compressed``: the frames image_transport's compressed plugin sends, and what it must refuse."""

import struct
import zlib

import cv2
import numpy as np
import pytest

from uav_landing_vision.camera import decode_compressed, write_image
from uav_landing_vision.camera.model import MAX_IMAGE_SIDE


def _frame(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), (5, 5), 0)


def _encode(ext: str, pixels: np.ndarray, *params) -> bytes:
    ok, buf = cv2.imencode(ext, pixels, list(params))
    assert ok
    return buf.tobytes()


def test_png_colour_is_exact_bgr8():
    bgr = _frame()
    pixels, encoding = decode_compressed(_encode(".png", bgr), "bgr8; png compressed bgr8")
    assert encoding == "bgr8" and pixels.dtype == np.uint8
    np.testing.assert_array_equal(pixels, bgr)


def test_jpeg_colour_is_close_and_keeps_the_channel_order():
    bgr = _frame()
    bgr[:16] = (255, 0, 0)  # a blue band: BGR order survives
    pixels, encoding = decode_compressed(_encode(".jpg", bgr, cv2.IMWRITE_JPEG_QUALITY, 95), "rgb8; jpeg compressed bgr8")
    assert encoding == "bgr8" and pixels.shape == bgr.shape
    assert np.abs(pixels.astype(int) - bgr).mean() < 8.0  # lossy, chroma subsampled
    assert pixels[4:12, 4:60, 0].mean() > 240 and pixels[4:12, 4:60, 2].mean() < 15


def test_grey_is_mono8_and_alpha_is_dropped():
    grey = _frame()[..., 1].copy()
    pixels, encoding = decode_compressed(_encode(".png", grey), "mono8; png compressed mono8")
    assert encoding == "mono8" and pixels.shape == grey.shape
    np.testing.assert_array_equal(pixels, grey)
    bgra = np.dstack([_frame(), np.full((48, 64), 7, np.uint8)])
    pixels, encoding = decode_compressed(_encode(".png", bgra), "bgra8; png compressed bgra8")
    assert encoding == "bgr8"
    np.testing.assert_array_equal(pixels, bgra[..., :3])


def _png_header(width: int, height: int) -> bytes:
    """A PNG whose header claims ``width`` × ``height`` RGB pixels, with almost no pixel data."""
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))


def _jpeg_header(width: int, height: int) -> bytes:
    """A small JPEG whose frame header (SOF0) is rewritten to claim ``width`` × ``height``."""
    data = bytearray(_encode(".jpg", np.zeros((8, 8, 3), np.uint8)))
    sof = data.index(b"\xff\xc0")
    data[sof + 5:sof + 9] = struct.pack(">HH", height, width)
    return bytes(data)


@pytest.mark.parametrize("data, fmt, message", [
    # OpenCV raised cv2.error here, not a ValueError: one such frame stopped the undistort node.
    (_png_header(40000, 40000), "png", "compressed image (format 'png') claims too many pixels"),
    (_jpeg_header(65000, 65000), "jpeg", "compressed image (format 'jpeg') claims too many pixels"),
    (_png_header(16385, 10), "png", "compressed image (format 'png') claims 16385x10 pixels, over 16384 a side"),
    (b"", "jpeg", "cannot decode the compressed image (0 bytes, format 'jpeg')"),
    (b"\xff\xd8\xff not really a jpeg", "jpeg", "cannot decode the compressed image (21 bytes"),
    (None, "16UC1; png compressed", "has uint16 pixels, expected 8-bit"),
    (b"\x00" * 16, "16UC1; compressedDepth png", "is a depth image, not a camera frame"),
    (b"\x00" * 16, "16UC1; compressed Depth png", "is a depth image, not a camera frame"),
])
def test_what_cannot_be_a_camera_frame_is_refused_by_name(data, fmt, message):
    if data is None:
        data = _encode(".png", np.full((8, 8), 1000, np.uint16))
    with pytest.raises(ValueError) as err:
        decode_compressed(data, fmt)
    assert message in str(err.value)


def test_a_header_of_another_size_than_expected_is_refused_before_decoding(monkeypatch):
    """A 629-byte JPEG whose header says 12000 x 12000 decoded to 432 MB in seconds; with the
    calibration's size given, the header alone refuses it."""
    decoded = []
    monkeypatch.setattr(cv2, "imdecode", lambda *args: decoded.append(args))
    with pytest.raises(ValueError, match="compressed image is 12000x12000, expected 64x48"):
        decode_compressed(_jpeg_header(12000, 12000), "jpeg", size=(64, 48))
    assert decoded == []
    monkeypatch.undo()
    pixels, _ = decode_compressed(_encode(".png", _frame()), "png", size=(64, 48))
    assert pixels.shape == (48, 64, 3)


@pytest.mark.parametrize("shape", [(MAX_IMAGE_SIDE + 1, 1), (1, MAX_IMAGE_SIDE + 1)])
def test_a_png_over_the_side_limit_in_either_dimension_is_refused(shape):
    """A real (small) PNG, one pixel wide or high: refused by its header, whichever side is too long."""
    data = _encode(".png", np.zeros(shape, np.uint8))
    height, width = shape
    with pytest.raises(ValueError, match=f"claims {width}x{height} pixels, over {MAX_IMAGE_SIDE} a side"):
        decode_compressed(data, "png")


@pytest.mark.parametrize("shape", [(MAX_IMAGE_SIDE, 1), (1, MAX_IMAGE_SIDE)])
def test_a_png_of_the_side_limit_is_decoded(shape):
    pixels, encoding = decode_compressed(_encode(".png", np.zeros(shape, np.uint8)), "png")
    assert pixels.shape == shape and encoding == "mono8"


def test_write_image_round_trips_rgb_through_cv2_imread(tmp_path):
    """An RGB array written as PNG reads back, by cv2.imread (BGR), as the same pixels."""
    rgb = _frame(5)
    write_image(tmp_path / "frame.png", rgb)
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "frame.png"))[..., ::-1], rgb)


def test_write_image_into_a_missing_folder_is_an_os_error(tmp_path):
    with pytest.raises(OSError, match="cannot write the image"):
        write_image(tmp_path / "missing" / "frame.png", _frame())


def test_compressed_to_numpy_checks_the_size_and_names_the_message_format():
    """The node-side conversion passes the expected size and the message's format on, and
    raises ImageError."""
    from sensor_msgs.msg import CompressedImage

    from uav_landing_vision.nodes.image import ImageError, compressed_to_numpy

    msg = CompressedImage(format="bgr8; png compressed bgr8", data=_encode(".png", _frame()))
    pixels, encoding = compressed_to_numpy(msg, size=(64, 48))
    assert encoding == "bgr8"
    np.testing.assert_array_equal(pixels, _frame())
    with pytest.raises(ImageError, match="compressed image is 64x48, expected 32x24"):
        compressed_to_numpy(msg, size=(32, 24))
    with pytest.raises(ImageError, match="format 'rgb8; jpeg compressed bgr8'"):
        compressed_to_numpy(CompressedImage(format="rgb8; jpeg compressed bgr8", data=b"\xff\xd8\xff garbage"))
