"""``undistort`` in-process over DDS: rectified frames, and every bad input dropped without a crash; and,
callbacks called directly, the ``interpolation`` parameter is the filter the frames are rectified with."""

import types

import cv2
import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from test_node_common import SMALL_CAMERA, camera_info_msg, image_msg, rgb_frame, ros  # noqa: F401 (fixture)

from uav_landing_vision.camera import save_camera_info_yaml
from uav_landing_vision.config import ConfigError
from uav_landing_vision.nodes.image import image_to_numpy
from uav_landing_vision.nodes.qos import IMAGE_QOS, SENSOR_QOS
from uav_landing_vision.nodes.undistort import HELD_IMAGES, Undistort


class Rig:
    """The node under test wired to the probe's publishers and collecting subscriptions."""

    def __init__(self, ros, input_qos=IMAGE_QOS, compressed=False, **node_kwargs):
        self.ros = ros
        self.node = ros.add(Undistort(context=ros.context, **node_kwargs))
        self.image_pub = (ros.probe.create_publisher(CompressedImage, "camera/image_raw/compressed", input_qos) if compressed
                          else ros.probe.create_publisher(Image, "camera/image_raw", input_qos))
        self.info_pub = ros.probe.create_publisher(CameraInfo, "camera/camera_info", input_qos)
        self.rect = ros.collect(Image, "camera/image_rect", IMAGE_QOS)
        self.rect_info = ros.collect(CameraInfo, "camera/camera_info_rect", IMAGE_QOS)
        info_from_topic = not self.node.config.camera_info_file
        assert ros.spin_until(
            lambda: self.image_pub.get_subscription_count() >= 1
            and (self.info_pub.get_subscription_count() >= 1 or not info_from_topic)
            and self.node.count_subscribers("camera/image_rect") >= 1
            and self.node.count_subscribers("camera/camera_info_rect") >= 1
        ), "discovery"

    def send_info(self, camera, sec=1):
        before = self.node.counters["camera_info_received"]
        self.info_pub.publish(camera_info_msg(camera, sec))
        assert self.ros.spin_until(lambda: self.node.counters["camera_info_received"] > before)

    def send_image(self, msg):
        """Publish one image; return the rectified image, or None when the node dropped it."""
        before = (self.node.counters["published"], self.node.counters["dropped"])
        self.image_pub.publish(msg)
        assert self.ros.spin_until(lambda: (self.node.counters["published"], self.node.counters["dropped"]) != before)
        if self.node.counters["dropped"] != before[1]:
            return None
        assert self.ros.spin_until(lambda: len(self.rect) > before[0] and len(self.rect_info) > before[0])
        return self.rect[-1]


def _expected(camera, pixels):
    return cv2.remap(pixels, *camera.undistortion_maps(), cv2.INTER_LINEAR)


@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "mono8"])
def test_rectifies_each_encoding_with_same_header_and_rectified_camera_info(ros, encoding):
    rig = Rig(ros)
    rig.send_info(SMALL_CAMERA)
    pixels = rgb_frame(SMALL_CAMERA, 3)
    if encoding == "mono8":
        pixels = pixels[..., 0].copy()
    raw = image_msg(pixels, encoding, sec=5, nanosec=123, pad=4)
    rect = rig.send_image(raw)
    assert rect is not None
    assert (rect.header, rect.encoding, rect.width, rect.height) == (raw.header, encoding, 40, 30)
    np.testing.assert_array_equal(image_to_numpy(rect), _expected(SMALL_CAMERA, pixels))
    assert not np.array_equal(image_to_numpy(rect), pixels)  # the lens model really changed the frame
    info = rig.rect_info[-1]
    assert info.header == raw.header
    np.testing.assert_array_equal(info.k, SMALL_CAMERA.K.ravel())
    assert list(info.d) == [0.0] * 5 and (info.width, info.height) == (40, 30)


def send_uncalibrated(rig, msg):
    """Publish an image the node cannot rectify yet (it holds it, or drops the oldest it held)."""
    before = rig.node.counters["received"]
    rig.image_pub.publish(msg)
    assert rig.ros.spin_until(lambda: rig.node.counters["received"] > before)


def test_an_image_that_comes_before_its_camera_info_is_rectified_once_the_camera_info_comes(ros):
    """A bag replay or a driver may deliver a frame's image before its camera_info (two topics: DDS
    does not order them); the first frame of a paced replay used to be dropped, and the replay
    then waited for its acknowledgement in vain."""
    rig = Rig(ros)
    pixels = rgb_frame(SMALL_CAMERA)
    raw = image_msg(pixels, "rgb8", sec=7)
    send_uncalibrated(rig, raw)
    assert not rig.rect and rig.node.counters["dropped"] == 0
    rig.info_pub.publish(camera_info_msg(SMALL_CAMERA, sec=7))
    assert ros.spin_until(lambda: len(rig.rect) == 1 and len(rig.rect_info) == 1)
    assert rig.rect[0].header == raw.header == rig.rect_info[0].header
    np.testing.assert_array_equal(image_to_numpy(rig.rect[0]), _expected(SMALL_CAMERA, pixels))
    assert rig.send_image(image_msg(pixels, "rgb8", sec=8)) is not None
    assert rig.node.counters["dropped"] == 0


def test_images_held_for_want_of_calibration_are_bounded_and_the_drop_says_why(ros):
    """Only the newest HELD_IMAGES wait; a driver publishing each image before its camera_info
    (image_transport's CameraPublisher does) with a refused calibration has the drop name the refusal
    (K all zeros: an uncalibrated camera), the one line a second that is logged."""
    rig = Rig(ros)
    uncalibrated = camera_info_msg(SMALL_CAMERA)
    uncalibrated.k = [0.0] * 9
    rig.info_pub.publish(uncalibrated)
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == 1)
    for sec in range(1, HELD_IMAGES + 3):
        send_uncalibrated(rig, image_msg(rgb_frame(SMALL_CAMERA, sec), "rgb8", sec=sec))
    assert rig.node.counters["dropped"] == 1 + 2 and not rig.rect
    assert rig.node.last_error == ("image stamped 2000000000 ns: no usable camera_info (the latest camera_info was "
                                   "refused: camera_info K is missing (all zeros means an uncalibrated camera)) "
                                   f"within {HELD_IMAGES} frames")
    rig.send_info(SMALL_CAMERA)
    assert ros.spin_until(lambda: len(rig.rect) == HELD_IMAGES)
    assert [m.header.stamp.sec for m in rig.rect] == list(range(3, HELD_IMAGES + 3))


def test_malformed_images_are_dropped_and_the_node_keeps_working(ros):
    rig = Rig(ros)
    rig.send_info(SMALL_CAMERA)
    pixels = rgb_frame(SMALL_CAMERA)
    wrong_encoding = image_msg(pixels, "rgb8")
    wrong_encoding.encoding = "rgba8"
    short_data = image_msg(pixels, "rgb8")
    short_data.data = bytes(100)
    wrong_size = image_msg(np.zeros((20, 40, 3), np.uint8), "rgb8")
    empty = Image(encoding="rgb8")
    for msg, reason in [
        (wrong_encoding, "unsupported image encoding 'rgba8'"),
        (short_data, "image data has 100 bytes"),
        (wrong_size, "image is 40x20 but the calibration is 40x30"),
        (empty, "empty image (0x0)"),
    ]:
        assert rig.send_image(msg) is None
        assert reason in rig.node.last_error
    assert rig.node.counters["dropped"] == 4
    assert rig.send_image(image_msg(pixels, "rgb8")) is not None


def test_unusable_camera_info_is_dropped_and_the_previous_calibration_kept(ros):
    rig = Rig(ros)
    rig.send_info(SMALL_CAMERA)
    bad = camera_info_msg(SMALL_CAMERA)
    bad.k = [0.0] * 9
    bad.header.stamp.sec = 2
    rig.info_pub.publish(bad)
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == 1)
    assert "K is missing" in rig.node.last_error
    nan = camera_info_msg(SMALL_CAMERA)
    nan.d = [float("nan")] * 5
    rig.info_pub.publish(nan)
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == 2)
    pixels = rgb_frame(SMALL_CAMERA, 9)
    rect = rig.send_image(image_msg(pixels, "rgb8"))
    np.testing.assert_array_equal(image_to_numpy(rect), _expected(SMALL_CAMERA, pixels))


def test_a_new_calibration_replaces_the_old_one(ros):
    rig = Rig(ros)
    rig.send_info(SMALL_CAMERA)
    other = type(SMALL_CAMERA)(20, 10, np.array([[18.0, 0, 9.5], [0, 18.0, 4.5], [0, 0, 1]]), np.array([0.1, 0, 0, 0, 0]))
    rig.send_info(other)
    assert rig.send_image(image_msg(rgb_frame(SMALL_CAMERA), "rgb8")) is None  # old size no longer matches
    pixels = rgb_frame(other, 4)
    rect = rig.send_image(image_msg(pixels, "rgb8"))
    np.testing.assert_array_equal(image_to_numpy(rect), _expected(other, pixels))


def test_nearest_interpolation_keeps_every_pixel_of_a_lens_without_distortion(ros):
    """cv2.remap's nearest neighbour on fixed-point maps (what undistortion_maps gives) took the
    next pixel for fractions below one half: a lens without distortion came out shifted by one
    pixel right and down (OpenCV issue 24106)."""
    rig = Rig(ros, parameter_overrides=[Parameter("interpolation", value="nearest")])
    lens = type(SMALL_CAMERA)(SMALL_CAMERA.width, SMALL_CAMERA.height, SMALL_CAMERA.K, np.zeros(5))
    rig.send_info(lens)
    pixels = rgb_frame(lens, 5)
    np.testing.assert_array_equal(image_to_numpy(rig.send_image(image_msg(pixels, "rgb8"))), pixels)


@pytest.mark.parametrize("model, d", [("equidistant", [-0.05, 0.01, -0.002, 0.0005]),
                                      ("rational_polynomial", [0.12, -0.05, 0.001, -0.002, 0.01, 0.35, -0.02, 0.004])])
def test_a_fisheye_or_rational_lens_is_rectified_by_its_own_model(ros, model, d):
    """camera_info's other distortion models (a wide-angle deck camera is often calibrated as a
    fisheye): rectified with the model the driver names, as cv2.fisheye / cv2 do."""
    rig = Rig(ros)
    lens = type(SMALL_CAMERA)(SMALL_CAMERA.width, SMALL_CAMERA.height, SMALL_CAMERA.K, d, distortion_model=model)
    rig.send_info(lens)
    pixels = rgb_frame(lens, 8)
    rect = rig.send_image(image_msg(pixels, "rgb8"))
    np.testing.assert_array_equal(image_to_numpy(rect), cv2.remap(pixels, *lens.undistortion_maps(), cv2.INTER_LINEAR))
    info = rig.rect_info[-1]
    assert info.distortion_model == "plumb_bob" and list(info.d) == [0.0] * 5  # the rectified image has none
    assert rig.node.counters["dropped"] == 0


def test_best_effort_camera_driver_with_camera_qos_sensor_data(ros):
    rig = Rig(ros, input_qos=SENSOR_QOS, parameter_overrides=[Parameter("camera_qos", value="sensor_data")])
    rig.send_info(SMALL_CAMERA)
    pixels = rgb_frame(SMALL_CAMERA, 6)
    rect = rig.send_image(image_msg(pixels, "rgb8"))
    np.testing.assert_array_equal(image_to_numpy(rect), _expected(SMALL_CAMERA, pixels))


def compressed_msg(pixels: np.ndarray, ext: str, fmt: str, sec: int = 1) -> CompressedImage:
    """What image_transport's compressed plugin sends for a bgr8 (or mono8) frame."""
    ok, buf = cv2.imencode(ext, pixels)
    assert ok
    msg = CompressedImage(format=fmt, data=buf.tobytes())
    msg.header.stamp.sec, msg.header.frame_id = sec, "camera_optical_frame"
    return msg


def test_a_compressed_camera_with_image_transport_compressed(ros):
    """Recorded bags and camera drivers often carry image_transport's compressed frames (JPEG or PNG
    on camera/image_raw/compressed): decoded, rectified, published as bgr8 (mono8 for a grey camera).
    Undecodable data is dropped by name and the node goes on."""
    rig = Rig(ros, compressed=True, parameter_overrides=[Parameter("image_transport", value="compressed")])
    assert rig.node.count_publishers("camera/image_raw") == 0 and not rig.node.get_subscriptions_info_by_topic(
        "/camera/image_raw")
    rig.send_info(SMALL_CAMERA)
    bgr = rgb_frame(SMALL_CAMERA, 7)[..., ::-1].copy()
    raw = compressed_msg(bgr, ".png", "bgr8; png compressed bgr8", sec=9)
    rect = rig.send_image(raw)
    assert (rect.header, rect.encoding, rect.width, rect.height) == (raw.header, "bgr8", 40, 30)
    np.testing.assert_array_equal(image_to_numpy(rect), _expected(SMALL_CAMERA, bgr))  # PNG: lossless
    assert rig.rect_info[-1].header == raw.header
    jpeg = compressed_msg(bgr, ".jpg", "rgb8; jpeg compressed bgr8")
    rect = rig.send_image(jpeg)
    decoded = cv2.imdecode(np.frombuffer(bytes(jpeg.data), np.uint8), cv2.IMREAD_COLOR)
    assert rect.encoding == "bgr8"
    np.testing.assert_array_equal(image_to_numpy(rect), _expected(SMALL_CAMERA, decoded))
    grey = rig.send_image(compressed_msg(bgr[..., 1].copy(), ".png", "mono8; png compressed mono8"))
    assert grey.encoding == "mono8"
    broken = compressed_msg(bgr, ".jpg", "jpeg")
    broken.data = broken.data[:40]
    assert rig.send_image(broken) is None and "cannot decode the compressed image (40 bytes" in rig.node.last_error
    huge = compressed_msg(bgr, ".jpg", "jpeg")  # its frame header (SOF0) says 65000 x 65000: OpenCV raised, the node died
    sof = bytes(huge.data).index(b"\xff\xc0")
    huge.data = bytes(huge.data[:sof + 5]) + (65000).to_bytes(2, "big") * 2 + bytes(huge.data[sof + 9:])
    assert rig.send_image(huge) is None and "claims too many pixels" in rig.node.last_error
    # A header of 12000 x 12000 on a few hundred bytes: OpenCV decoded it (gigabytes, seconds) before the size check.
    large = compressed_msg(bgr, ".jpg", "jpeg")
    large.data = bytes(large.data[:sof + 5]) + (12000).to_bytes(2, "big") * 2 + bytes(large.data[sof + 9:])
    assert rig.send_image(large) is None and "compressed image is 12000x12000, expected 40x30" in rig.node.last_error
    small = compressed_msg(np.zeros((20, 40, 3), np.uint8), ".png", "png")
    assert rig.send_image(small) is None and "compressed image is 40x20, expected 40x30" in rig.node.last_error
    assert rig.send_image(raw) is not None


def test_calibration_from_a_file_parameter(ros, tmp_path):
    path = tmp_path / "cam.yaml"
    save_camera_info_yaml(SMALL_CAMERA, path)
    rig = Rig(ros, parameter_overrides=[Parameter("camera_info_file", value=str(path))])
    assert rig.node.count_subscribers("camera/camera_info") == 0  # the file replaces the topic
    pixels = rgb_frame(SMALL_CAMERA, 5)
    rect = rig.send_image(image_msg(pixels, "bgr8"))
    np.testing.assert_array_equal(image_to_numpy(rect), _expected(SMALL_CAMERA, pixels))


@pytest.mark.parametrize(
    "override, message",
    [
        (Parameter("interpolation", value="bicubic"), "interpolation: 'bicubic' is not one of"),
        (Parameter("camera_info_file", value="/nonexistent/cam.yaml"), "camera_info_file: cannot read camera calibration"),
        (Parameter("rate", value=2.0), r"unknown key\(s\) \['rate'\]"),
        (Parameter("image_transport", value="theora"), "image_transport: 'theora' is not one of"),
    ],
)
def test_bad_parameters_fail_start_up(ros, override, message):
    with pytest.raises(ConfigError, match=message):
        Undistort(context=ros.context, parameter_overrides=[override])


@pytest.fixture
def make_node(ros):
    """Undistort nodes of a given ``interpolation``, their outputs collected in ``rect`` and ``rect_info``."""

    def make(interpolation: str):
        node = ros.add(Undistort(context=ros.context, parameter_overrides=[Parameter("interpolation", value=interpolation)]))
        node.rect, node.rect_info = [], []
        node._image_pub = types.SimpleNamespace(publish=node.rect.append)
        node._info_pub = types.SimpleNamespace(publish=node.rect_info.append)
        return node

    return make


def _rectify(node, pixels: np.ndarray) -> np.ndarray:
    node._on_camera_info(camera_info_msg(SMALL_CAMERA))
    msg = image_msg(pixels, "rgb8", sec=3)
    node._on_image(msg)
    assert node.counters["dropped"] == 0, node.last_error
    (rect,) = node.rect
    assert rect.header == msg.header and node.rect_info[0].header == msg.header
    return image_to_numpy(rect)


def test_each_interpolation_rectifies_with_its_own_opencv_filter(make_node):
    pixels = rgb_frame(SMALL_CAMERA, 21)
    maps = SMALL_CAMERA.undistortion_maps()
    linear = cv2.remap(pixels, *maps, cv2.INTER_LINEAR)
    cubic = cv2.remap(pixels, *maps, cv2.INTER_CUBIC)
    assert not np.array_equal(linear, cubic)  # the noise frame tells the filters apart
    np.testing.assert_array_equal(_rectify(make_node("linear"), pixels), linear)
    np.testing.assert_array_equal(_rectify(make_node("cubic"), pixels), cubic)
    nearest = _rectify(make_node("nearest"), pixels)
    # Nearest copies pixels: every output pixel is one of the frame's (or the black border).
    sources = {tuple(p) for p in pixels.reshape(-1, 3)} | {(0, 0, 0)}
    assert all(tuple(p) in sources for p in nearest.reshape(-1, 3))
    assert not np.array_equal(nearest, linear)
