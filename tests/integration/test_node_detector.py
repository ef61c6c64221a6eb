"""``detector``: refuses to start without a model; with a freshly initialised network exported to
ONNX it runs in-process over DDS and publishes well-formed DetectionArray messages. With the network
stood in for by a scripted detector and its callbacks called directly: which region each frame is
searched in (the search window from the last pose, or the full frame) and the track box."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from geometry_msgs.msg import PoseWithCovarianceStamped
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image
from test_node_common import camera_info_msg, image_msg, rgb_frame, ros  # noqa: F401 (fixture)

from uav_landing_msgs.msg import DetectionArray
from uav_landing_vision.camera import CameraModel
from uav_landing_vision.config import ConfigError
from uav_landing_vision.detection.detector import Detections, search_window
from uav_landing_vision.detection.track_box import grow_roi
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.nodes import detector as detector_module
from uav_landing_vision.nodes.detector import DetectorNode, DetectorNodeConfig
from uav_landing_vision.nodes.qos import IMAGE_QOS, RELIABLE_QOS
from uav_landing_vision.render.boxes import projected_roi

PARAMS = Path(__file__).parents[2] / "config" / "detector.yaml"
CAMERA = CameraModel(96, 64, [[80.0, 0, 48.0], [0, 80.0, 32.0], [0, 0, 1]])
MAX_DETECTIONS = 5


@pytest.fixture(scope="module")
def model(tmp_path_factory) -> Path:
    """A freshly initialised (untrained) detector network exported as the runtime expects it."""
    import torch  # development extras (requirements-dev)

    from uav_landing_vision.detection.export import export_onnx
    from uav_landing_vision.detection.network import UavDetectorNet

    torch.manual_seed(0)
    return export_onnx(UavDetectorNet(width=8, blocks=(1, 1, 1)), tmp_path_factory.mktemp("model") / "fresh.onnx", (96, 64))


class Rig:
    def __init__(self, ros, model: Path, *overrides):
        self.ros = ros
        # An untrained network scores every cell near its 0.01 prior: a low threshold keeps some.
        self.node = ros.add(DetectorNode(
            context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
            parameter_overrides=[Parameter("model", value=str(model)), Parameter("score_threshold", value=0.005),
                                 Parameter("max_detections", value=MAX_DETECTIONS), *overrides],
        ))
        self.image_pub = ros.probe.create_publisher(Image, "camera/image_rect", IMAGE_QOS)
        self.out = ros.collect(DetectionArray, "uav/detections", RELIABLE_QOS)
        assert ros.spin_until(lambda: self.image_pub.get_subscription_count() and self.node.count_subscribers("uav/detections")), "discovery"

    def send(self, msg):
        """Publish one image; its DetectionArray, or None when the node dropped it."""
        before = (self.node.counters["published"], self.node.counters["dropped"])
        self.image_pub.publish(msg)
        assert self.ros.spin_until(lambda: (self.node.counters["published"], self.node.counters["dropped"]) != before)
        if self.node.counters["published"] == before[0]:
            return None
        assert self.ros.spin_until(lambda: len(self.out) == self.node.counters["published"])
        return self.out[-1]


def _check(out, image):
    assert out.header == image.header
    assert 1 <= len(out.detections) <= MAX_DETECTIONS
    scores = [d.score for d in out.detections]
    assert scores == sorted(scores, reverse=True) and all(0.005 <= s <= 1.0 for s in scores)
    for d in out.detections:
        r = d.roi
        assert r.width > 0 and r.height > 0
        assert 0 <= r.x_offset and r.x_offset + r.width <= image.width
        assert 0 <= r.y_offset and r.y_offset + r.height <= image.height


def test_start_up_fails_clearly_without_a_model(ros, tmp_path):
    missing = tmp_path / "detector.onnx"
    with pytest.raises(ConfigError, match=r"model: the detector model '.*detector.onnx' is missing .*uav-landing train-detector"):
        DetectorNode(context=ros.context, parameter_overrides=[Parameter("model", value=str(missing))])
    not_onnx = tmp_path / "bogus.onnx"
    not_onnx.write_bytes(b"not a model")
    with pytest.raises(ConfigError, match="model: the detector model '.*bogus.onnx' cannot be loaded"):
        DetectorNode(context=ros.context, parameter_overrides=[Parameter("model", value=str(not_onnx))])


def test_start_up_fails_clearly_without_the_verifier_it_names(ros, model, tmp_path):
    with pytest.raises(ConfigError, match=r"model: .* or the verifier '.*none.onnx' is missing"):
        DetectorNode(context=ros.context, parameter_overrides=[Parameter("model", value=str(model)),
                                                               Parameter("verifier", value=str(tmp_path / "none.onnx"))])


@pytest.mark.parametrize("threshold, kept", [(0.0, MAX_DETECTIONS), (0.999, 0)])
def test_the_shipped_verifier_drops_the_boxes_it_rejects(ros, model, threshold, kept):
    """An untrained network's boxes on a noise frame, none of them the UAV: a threshold of
    0.999 drops them all, 0 keeps them all."""
    rig = Rig(ros, model, Parameter("verifier", value="verifier.onnx"), Parameter("verifier_threshold", value=threshold))
    image = image_msg(rgb_frame(CAMERA, 0), "rgb8", sec=4)
    out = rig.send(image)
    assert out is not None and out.header == image.header and len(out.detections) == kept


def test_main_exits_with_code_2_naming_the_missing_model(tmp_path, capsys, ros_domain_id, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros_domain_id))
    code = detector_module.main(["--ros-args", "-p", f"model:={tmp_path / 'none.onnx'}"])
    assert code == 2 and "none.onnx' is missing" in capsys.readouterr().err


def test_runs_the_network_and_publishes_well_formed_detections(ros, model):
    rig = Rig(ros, model)
    for i, encoding in enumerate(["rgb8", "bgr8"]):
        image = image_msg(rgb_frame(CAMERA, i), encoding, sec=3, nanosec=i)
        _check(rig.send(image), image)
    assert rig.node.counters["detections"] >= 2


def test_malformed_images_are_dropped_and_the_node_keeps_working(ros, model):
    rig = Rig(ros, model)
    mono = image_msg(rgb_frame(CAMERA)[..., 0].copy(), "mono8")
    assert rig.send(mono) is None and "has no colour" in rig.node.last_error
    short = image_msg(rgb_frame(CAMERA), "rgb8")
    short.data = bytes(7)
    assert rig.send(short) is None and "image data has 7 bytes" in rig.node.last_error
    assert rig.send(Image(encoding="rgb8")) is None and "empty image" in rig.node.last_error
    image = image_msg(rgb_frame(CAMERA, 5), "rgb8", sec=9)
    _check(rig.send(image), image)
    assert rig.node.counters["dropped"] == 3


def test_search_window_from_the_last_pose(ros, model):
    rig = Rig(ros, model, Parameter("node.search_window", value=True), Parameter("window_min_px", value=32),
              Parameter("window_grow", value=1.0))
    windows = []  # the window each detection was run in
    detect = rig.node._detector.detect
    rig.node._detector.detect = lambda frame, window=None: windows.append(window) or detect(frame, window)
    info_pub = ros.probe.create_publisher(CameraInfo, "camera/camera_info_rect", IMAGE_QOS)
    pose_pub = ros.probe.create_publisher(PoseWithCovarianceStamped, "uav/pose", RELIABLE_QOS)
    assert ros.spin_until(lambda: info_pub.get_subscription_count() and pose_pub.get_subscription_count())
    image = image_msg(rgb_frame(CAMERA, 1), "rgb8", sec=5)
    _check(rig.send(image), image)  # no pose yet: full frame
    assert rig.node.counters["windowed"] == 0 and windows == [None]
    info_pub.publish(camera_info_msg(CAMERA, sec=5))
    pose = PoseWithCovarianceStamped(header=image.header)
    pose.pose.pose.position.z, pose.pose.pose.orientation.w = 8.0, 1.0
    pose_pub.publish(pose)
    assert ros.spin_until(lambda: rig.node._calibration.camera is not None and rig.node._pose is not None)
    later = image_msg(rgb_frame(CAMERA, 2), "rgb8", sec=5, nanosec=33_000_000)
    out = rig.send(later)
    _check(out, later)
    assert rig.node.counters["windowed"] == 1
    # The window is centred on the model projected at the pose (OpenCV; pixel centres at integers,
    # so the extent's edges are half a pixel out), window_min_px a side: the model is 12 x 18 px.
    uv = cv2.projectPoints(fixed_wing_mesh("high").vertices, np.zeros(3), np.array([0.0, 0.0, 8.0]), CAMERA.K,
                           None)[0].reshape(-1, 2)
    centre = (uv.min(axis=0) + uv.max(axis=0)) / 2 + 0.5
    assert len(windows) == 2 and windows[1] is not None, windows  # one search, in a window
    x, y, w, h = windows[1]
    assert (w, h) == (32, 32) and np.all(np.abs(np.array([x + w / 2, y + h / 2]) - centre) <= 1.0), (windows[1], centre)
    for d in out.detections:  # what was found in the window: the full frame is searched only when it holds nothing
        r = d.roi
        assert x <= r.x_offset and r.x_offset + r.width <= x + w and y <= r.y_offset and r.y_offset + r.height <= y + h
    stale = image_msg(rgb_frame(CAMERA, 3), "rgb8", sec=7)  # 2 s after the pose: full frame
    _check(rig.send(stale), stale)
    assert rig.node.counters["windowed"] == 1 and windows[2:] == [None]
    bad = PoseWithCovarianceStamped(header=image.header)
    bad.pose.pose.orientation.w = float("nan")
    dropped = rig.node.counters["dropped"]
    pose_pub.publish(bad)
    assert ros.spin_until(lambda: rig.node.counters["dropped"] > dropped)
    assert "uav/pose rejected: pose quaternion is not a finite unit" in rig.node.last_error


def test_track_box_where_the_network_finds_nothing(ros, model):
    """An untrained network scores every cell near 0.01, so at 0.99 it finds nothing: with a
    recent pose the node publishes that pose's grown box with score 0, at most max_frames times
    in a row."""
    rig = Rig(ros, model, Parameter("score_threshold", value=0.99), Parameter("track_box.max_frames", value=2))
    info_pub = ros.probe.create_publisher(CameraInfo, "camera/camera_info_rect", IMAGE_QOS)
    pose_pub = ros.probe.create_publisher(PoseWithCovarianceStamped, "uav/pose", RELIABLE_QOS)
    assert ros.spin_until(lambda: info_pub.get_subscription_count() and pose_pub.get_subscription_count())
    first = image_msg(rgb_frame(CAMERA, 1), "rgb8", sec=5)
    assert rig.send(first).detections == []  # no pose yet
    info_pub.publish(camera_info_msg(CAMERA, sec=5))
    pose = PoseWithCovarianceStamped(header=first.header)
    pose.pose.pose.position.z, pose.pose.pose.orientation.w = 8.0, 1.0
    pose_pub.publish(pose)
    assert ros.spin_until(lambda: rig.node._calibration.camera is not None and rig.node._pose is not None)
    expected = grow_roi(projected_roi(CAMERA, fixed_wing_mesh("high").vertices, [0, 0, 0, 1], [0, 0, 8.0]),
                        rig.node._track_box.config.grow, CAMERA.width, CAMERA.height)
    for i in range(3):
        out = rig.send(image_msg(rgb_frame(CAMERA, 2 + i), "rgb8", sec=5, nanosec=(i + 1) * 33_000_000))
        if i < 2:
            assert [(d.roi.x_offset, d.roi.y_offset, d.roi.width, d.roi.height, d.score) for d in out.detections] == [
                (*expected, 0.0)]
        else:
            assert out.detections == []  # max_frames reached
    assert rig.node.counters["track_boxes"] == 2 and rig.node.counters["detections"] == 0


@pytest.mark.parametrize(
    "override, message",
    [
        (Parameter("score_threshold", value=1.5), "score_threshold must be in"),
        (Parameter("node.window_max_age_s", value=-1.0), "window_max_age_s must be finite and > 0"),
        (Parameter("node.search_window", value="on"), "node.search_window: expected bool"),
        (Parameter("stride", value=8), r"unknown key\(s\) \['stride'\]"),
        (Parameter("track_box.max_frames", value=0), "max_frames must be at least 1"),
    ],
)
def test_bad_parameters_fail_start_up(ros, override, message):
    with pytest.raises(ConfigError, match=message):
        DetectorNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)], parameter_overrides=[override])


@pytest.mark.parametrize("age", [0.0, -1.0, float("inf"), float("nan")])
def test_node_config_built_in_code_refuses_an_age_limit_that_is_not_finite_and_positive(age):
    with pytest.raises(ValueError, match="window_max_age_s must be finite and > 0"):
        DetectorNodeConfig(window_max_age_s=age)


# --- search window and track box, with a scripted network and the callbacks called directly ------

BOX = np.array([[40.0, 28.0, 52.0, 36.0]], np.float32)  # what the scripted network finds


class ScriptedDetector:
    """Records the window of every search; finds BOX, except in the searches ``empty`` says."""

    input_size, strides = (96, 64), (8,)

    def __init__(self):
        self.windows, self.box = [], BOX
        self.empty = lambda window: False

    def detect(self, frame, window=None):
        self.windows.append(window)
        if self.empty(window):
            return Detections(np.zeros((0, 4), np.float32), np.zeros(0, np.float32))
        return Detections(self.box.copy(), np.array([0.9], np.float32))


@pytest.fixture
def make_node(ros, monkeypatch):
    """A DetectorNode on a scripted network whose publications are kept in ``node.published``."""

    def make(*overrides):
        scripted = ScriptedDetector()
        monkeypatch.setattr(detector_module, "_load_detector", lambda config: scripted)
        node = ros.add(DetectorNode(
            context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
            parameter_overrides=[Parameter("window_min_px", value=32), Parameter("window_grow", value=1.0), *overrides]))
        node.published = []
        node._pub.publish = node.published.append
        return node, scripted

    return make


def pose_msg(sec: int, nanosec: int = 0, z: float = 8.0) -> PoseWithCovarianceStamped:
    """The UAV z m ahead of the camera, level."""
    msg = PoseWithCovarianceStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    msg.pose.pose.position.z, msg.pose.pose.orientation.w = z, 1.0
    return msg


def calibrate(node):
    node._on_camera_info(camera_info_msg(CAMERA))
    assert node._calibration.camera is not None


def expected_window():
    roi = projected_roi(CAMERA, fixed_wing_mesh("high").vertices, [0, 0, 0, 1], [0, 0, 8.0])
    return search_window(roi, CAMERA.width, CAMERA.height, 1.0, 32)


def test_a_pose_older_than_the_image_within_the_max_age_sets_the_search_window(make_node):
    node, net = make_node(Parameter("node.search_window", value=True))
    calibrate(node)
    node._on_pose(pose_msg(5))
    node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5, nanosec=400_000_000))
    assert net.windows == [expected_window()] and node.counters["windowed"] == 1


def test_a_pose_exactly_the_max_age_old_sets_the_search_window_and_one_a_nanosecond_older_does_not(make_node):
    """Compared in integer ns: 0.3 s as ``ns * 1e-9`` is 0.30000000000000004, past a limit of 0.3."""
    node, net = make_node(Parameter("node.search_window", value=True), Parameter("node.window_max_age_s", value=0.3))
    calibrate(node)
    node._on_pose(pose_msg(5))
    node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5, nanosec=300_000_000))
    node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5, nanosec=300_000_001))
    assert net.windows == [expected_window(), None]


def test_a_pose_newer_than_the_image_is_not_used_for_the_search_window(make_node):
    node, net = make_node(Parameter("node.search_window", value=True))
    calibrate(node)
    node._on_pose(pose_msg(5, 10_000_000))
    node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5))
    assert net.windows == [None] and node.counters["windowed"] == 0


def test_an_image_of_another_size_than_the_calibration_is_searched_whole(make_node):
    node, net = make_node(Parameter("node.search_window", value=True))
    calibrate(node)
    node._on_pose(pose_msg(5))
    other = CameraModel(128, 64, [[80.0, 0, 64.0], [0, 80.0, 32.0], [0, 0, 1]])
    node._on_image(image_msg(rgb_frame(other), "rgb8", sec=5, nanosec=33_000_000))
    assert net.windows == [None]


def test_without_a_calibration_or_with_the_pose_behind_the_camera_the_full_frame_is_searched(make_node):
    node, net = make_node(Parameter("node.search_window", value=True))
    node._on_pose(pose_msg(5))
    node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5, nanosec=33_000_000))  # no camera_info_rect yet
    calibrate(node)
    node._on_pose(pose_msg(5, 66_000_000, z=-8.0))  # behind the camera: no projected box
    node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5, nanosec=99_000_000))
    assert net.windows == [None, None] and len(node.published) == 2


def test_a_window_that_holds_nothing_is_followed_by_a_full_frame_search(make_node):
    node, net = make_node(Parameter("node.search_window", value=True))
    calibrate(node)
    node._on_pose(pose_msg(5))
    net.empty = lambda window: window is not None
    node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5, nanosec=33_000_000))
    assert net.windows == [expected_window(), None]
    (out,) = node.published
    assert [(d.roi.x_offset, d.roi.y_offset, d.roi.width, d.roi.height, d.score) for d in out.detections] == [
        (40, 28, 12, 8, pytest.approx(0.9))]
    assert node.counters["detections"] == 1 and node.counters["track_boxes"] == 0


def test_without_the_search_window_every_frame_is_searched_whole_even_with_a_pose(make_node):
    node, net = make_node(Parameter("node.search_window", value=False))
    calibrate(node)
    node._on_pose(pose_msg(5))
    node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5, nanosec=33_000_000))
    assert net.windows == [None] and node.counters["windowed"] == 0


def test_a_detection_restarts_the_track_box_count(make_node):
    """track_box.max_frames = 2 frames in a row without a detection get the box; a detection in
    between starts the count again."""
    node, net = make_node(Parameter("track_box.max_frames", value=2))
    calibrate(node)
    node._on_pose(pose_msg(5))
    found = iter([False, False, True, False, False, False])
    boxes = []
    for k in range(6):
        hit = next(found)
        net.empty = lambda window, hit=hit: not hit
        node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5, nanosec=(k + 1) * 20_000_000))
        out = node.published[-1]
        boxes.append([d.score for d in out.detections])
    assert boxes == [[0.0], [0.0], [pytest.approx(0.9)], [0.0], [0.0], []]


def test_a_window_near_the_right_edge_is_kept_inside_the_image(make_node):
    """96 x 64: a pose projected at u = 85 px gets a 32 px window whose right side is the image's."""
    node, net = make_node(Parameter("node.search_window", value=True))
    calibrate(node)
    msg = pose_msg(5)
    msg.pose.pose.position.x = 3.7  # u = 48 + 80 * 3.7 / 8 = 85
    node._on_pose(msg)
    node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5, nanosec=33_000_000))
    roi = projected_roi(CAMERA, fixed_wing_mesh("high").vertices, [0, 0, 0, 1], [3.7, 0, 8.0])
    x, y, w, h = net.windows[0]
    assert (x + w, w, h) == (96, 32, 32) and net.windows == [search_window(roi, 96, 64, 1.0, 32)]
    assert y == int(np.clip(round(roi[1] + roi[3] / 2 - 16), 0, 32))


def test_a_detection_over_the_image_corner_is_clipped_to_the_image(make_node):
    node, net = make_node()
    net.box = np.array([[80.0, 56.0, 100.0, 70.0]], np.float32)
    node._on_image(image_msg(rgb_frame(CAMERA), "rgb8", sec=5))
    (out,) = node.published
    assert [(d.roi.x_offset, d.roi.y_offset, d.roi.width, d.roi.height) for d in out.detections] == [(80, 56, 16, 8)]
