"""``pose_boosting`` in-process over DDS: rendered frame + detection → hypotheses; matching by
stamp in either order; bad input dropped. Also the rendered scene ``test_node_tracker`` uses. With the
pose database and generator stood in for by scripted ones and the callbacks called directly: the
ROI given to the boosting core, the PoseHypotheses made of its hypotheses, and the pairs held
until a calibration the database matches."""

import dataclasses
import functools
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image, RegionOfInterest
from test_node_common import camera_info_msg, image_msg, ros  # noqa: F401 (fixture)

from uav_landing_msgs.msg import Detection, DetectionArray, PoseHypotheses
from uav_landing_vision.boosting import DatabaseConfig, DatabaseError, HypothesisConfig, PoseHypothesisGenerator, build_database
from uav_landing_vision.boosting.database import NOMINAL_QUAT
from uav_landing_vision.camera import CameraModel
from uav_landing_vision.config import ConfigError, from_mapping, load_node_parameters
from uav_landing_vision.geometry import euler_zyx_to_quat, quat_multiply
from uav_landing_vision.model import fixed_wing_mesh
from uav_landing_vision.nodes import pose_boosting as pose_boosting_module
from uav_landing_vision.nodes.pose_boosting import PoseBoostingNode
from uav_landing_vision.nodes.qos import IMAGE_QOS, RELIABLE_QOS
from uav_landing_vision.render import Renderer
from uav_landing_vision.render.boxes import projected_roi
from uav_landing_vision.stamps import stamp_ns

PARAMS = Path(__file__).parents[2] / "config" / "pose_boosting.yaml"
CAMERA = CameraModel(320, 240, [[280.0, 0, 160.0], [0, 280.0, 120.0], [0, 0, 1]])
TRUE_QUAT = quat_multiply(euler_zyx_to_quat(np.radians([20.0, -15.0, 10.0])), NOMINAL_QUAT)
SKY = np.broadcast_to(np.array([90, 140, 210], np.uint8), (240, 320, 3)).copy()
M, M0 = 40, 30


def true_position(k: int) -> np.ndarray:
    """The UAV's position at frame k: 5 m ahead, drifting right and closer."""
    return np.array([0.1 + 0.03 * k, -0.05, 5.0 - 0.05 * k])


@functools.lru_cache(maxsize=None)
def _renderer() -> Renderer:
    return Renderer(CAMERA, fixed_wing_mesh("high"))


def scene_frame(k: int) -> np.ndarray:
    """Frame k: the shaded UAV at its true pose over a plain sky (rectified, rgb)."""
    return _renderer().shaded(TRUE_QUAT, true_position(k), SKY)[0]


def true_roi(k: int) -> tuple[int, int, int, int]:
    return projected_roi(CAMERA, fixed_wing_mesh("high").vertices, TRUE_QUAT, true_position(k))


@pytest.fixture(scope="session")
def small_database(tmp_path_factory) -> Path:
    """A pose database for CAMERA (2000 renders within ±45° of the nominal attitude)."""
    db = build_database(CAMERA, fixed_wing_mesh("high"), DatabaseConfig(count=2000, half_range_deg=(45.0, 45.0, 45.0)), progress=False)
    return db.save(tmp_path_factory.mktemp("database") / "small.npz")


def stamp(k: int) -> tuple[int, int]:
    return divmod(1_000_000_000 + k * 33_000_000, 1_000_000_000)


def detections_msg(k: int, boxes) -> DetectionArray:
    msg = DetectionArray(detections=[
        Detection(roi=RegionOfInterest(x_offset=x, y_offset=y, width=w, height=h), score=s) for x, y, w, h, s in boxes
    ])
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp(k)
    msg.header.frame_id = "camera_optical_frame"
    return msg


class Rig:
    def __init__(self, ros, database: Path, *overrides):
        self.ros = ros
        self.node = ros.add(PoseBoostingNode(
            context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
            parameter_overrides=[Parameter("database", value=str(database)), Parameter("particles", value=M),
                                 Parameter("kept", value=M0), *overrides],
        ))
        self.info_pub = ros.probe.create_publisher(CameraInfo, "camera/camera_info_rect", IMAGE_QOS)
        self.image_pub = ros.probe.create_publisher(Image, "camera/image_rect", IMAGE_QOS)
        self.det_pub = ros.probe.create_publisher(DetectionArray, "uav/detections", RELIABLE_QOS)
        self.out = ros.collect(PoseHypotheses, "uav/pose_hypotheses", RELIABLE_QOS)
        assert ros.spin_until(lambda: all(p.get_subscription_count() for p in (self.info_pub, self.image_pub, self.det_pub))
                              and self.node.count_subscribers("uav/pose_hypotheses") >= 1), "discovery"

    def send_info(self, camera=CAMERA):
        self.info_pub.publish(camera_info_msg(camera))
        assert self.ros.spin_until(
            lambda: self.node._calibration.camera is not None and np.array_equal(self.node._calibration.camera.K, camera.K)
        )

    def send(self, *msgs):
        """Publish image and/or detection messages in order; wait until the node published or dropped."""
        before = (self.node.counters["published"], self.node.counters["dropped"])
        for msg in msgs:
            (self.image_pub if isinstance(msg, Image) else self.det_pub).publish(msg)
        assert self.ros.spin_until(lambda: (self.node.counters["published"], self.node.counters["dropped"]) != before)
        if self.node.counters["published"] == before[0]:
            return None
        assert self.ros.spin_until(lambda: len(self.out) == self.node.counters["published"])
        return self.out[-1]


def frame_msg(k: int, encoding: str = "rgb8") -> Image:
    pixels = scene_frame(k)
    if encoding == "bgr8":
        pixels = pixels[..., ::-1].copy()
    return image_msg(pixels, encoding, *stamp(k))


def library_generator(database: Path) -> PoseHypothesisGenerator:
    """The boosting core with the node's parameter file and the rig's M, M0 and database."""
    params = {k: v for k, v in load_node_parameters(PARAMS, "pose_boosting").items() if k != "node"}
    config = from_mapping(HypothesisConfig, {**params, "particles": M, "kept": M0, "database": str(database)})
    return PoseHypothesisGenerator.from_config(config, CAMERA)


def test_hypotheses_from_the_best_detection_in_either_order(ros, small_database):
    rig = Rig(ros, small_database)
    rig.send_info()
    library = library_generator(small_database)
    decoy = (0, 0, 30, 20, 0.3)  # lower score: not used
    for k, order in [(0, "image first"), (1, "detections first")]:
        x, y, w, h = true_roi(k)
        image, dets = frame_msg(k, "rgb8" if k == 0 else "bgr8"), detections_msg(k, [decoy, (x, y, w, h, 0.9)])
        out = rig.send(*((image, dets) if order == "image first" else (dets, image)))
        assert out is not None and out.header == image.header, order
        assert len(out.poses) == len(out.distances) == M  # always M: the tracker takes what it needs
        assert list(out.distances) == sorted(out.distances)
        positions = np.array([[p.position.x, p.position.y, p.position.z] for p in out.poses])
        quats = np.array([[p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w] for p in out.poses])
        np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-9)
        assert np.linalg.norm(positions[0] - true_position(k)) < 1.0  # weak perspective from one box
        # Pose by pose (best first), what the boosting core makes of the frame in RGB and the best ROI.
        expected = library.generate(scene_frame(k), (x, y, w, h), count=M)
        np.testing.assert_allclose(positions, expected.positions, rtol=0, atol=1e-12)
        np.testing.assert_allclose(quats, expected.quats / np.linalg.norm(expected.quats, axis=1, keepdims=True),
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(out.distances, expected.distances, rtol=1e-6)
        obb = out.obb
        assert (obb.center_x, obb.center_y, obb.width, obb.height) == pytest.approx(
            (expected.obb.x, expected.obb.y, expected.obb.w, expected.obb.h), rel=1e-6)
        assert x <= obb.center_x <= x + w and y <= obb.center_y <= y + h
        assert obb.width >= obb.height > 0 and -math.pi / 2 <= obb.angle < math.pi / 2
        turn = (obb.angle - math.radians(expected.obb.theta)) % math.pi  # the same line: equal up to a half turn
        assert min(turn, math.pi - turn) < 1e-6
    assert rig.node.counters["dropped"] == 0


def test_no_detection_gives_an_empty_hypotheses_message(ros, small_database):
    rig = Rig(ros, small_database)
    rig.send_info()
    out = rig.send(frame_msg(2), detections_msg(2, []))
    assert out is not None and stamp_ns(out.header.stamp) == stamp_ns(detections_msg(2, []).header.stamp)
    assert len(out.poses) == 0 and len(out.distances) == 0 and out.obb.width == 0.0
    assert rig.node.counters["without_hypotheses"] == 1 and rig.node.counters["dropped"] == 0


def test_malformed_detections_and_images_are_dropped(ros, small_database):
    rig = Rig(ros, small_database)
    rig.send_info()
    x, y, w, h = true_roi(3)
    bad = [(10, 10, 0, 5, 0.99), (400, 300, 10, 10, 0.99), (x, y, w, h, float("nan"))]
    out = rig.send(frame_msg(3), detections_msg(3, [*bad, (x, y, w, h, 0.6)]))
    assert out is not None and len(out.poses) == M  # the usable detection is used
    assert rig.node.counters["dropped"] == 3
    assert "score nan" in rig.node.last_error
    mono = image_msg(scene_frame(4)[..., 0].copy(), "mono8", *stamp(4))
    assert rig.send(mono) is None and "has no colour" in rig.node.last_error
    short = frame_msg(5)
    short.data = bytes(10)
    assert rig.send(short) is None and "image data has 10 bytes" in rig.node.last_error


def test_many_unusable_detections_are_dropped_in_one_log_line(ros, small_database):
    """Boxes outside the frame: each was logged on its own (~0.3 ms a call in rclpy's logger, even
    throttled), so 20 000 of them held the node ~5 s on one 0.5 MB message. They are each counted,
    and logged in one drop."""
    rig = Rig(ros, small_database)
    rig.send_info()
    drops = []
    real_drop = rig.node.drop
    rig.node.drop = lambda reason, count=1: drops.append(count) or real_drop(reason, count)
    x, y, w, h = true_roi(6)
    bad = [(400 + k % 7, 300, 10, 10, 0.99) for k in range(2_000)]
    out = rig.send(frame_msg(6), detections_msg(6, [*bad, (x, y, w, h, 0.6)]))
    assert out is not None and len(out.poses) == M  # the usable detection is used
    assert drops == [2_000] and rig.node.counters["dropped"] == 2_000
    assert rig.node.last_error.startswith(f"2000 unusable detections of stamp {stamp_ns(out.header.stamp)} ns: detection 0: ")
    assert rig.node.last_error.endswith("; and 1997 more")


def test_unmatched_entries_older_than_the_cache_are_dropped(ros, small_database):
    rig = Rig(ros, small_database, Parameter("node.cache_size", value=2))
    rig.send_info()
    for k in range(2):
        rig.image_pub.publish(frame_msg(10 + k))
    assert ros.spin_until(lambda: rig.node.counters["received"] == 2)
    assert rig.send(detections_msg(20, [])) is None  # a third stamp evicts the oldest image
    assert rig.node.last_error.startswith(f"no detections with stamp {stamp_ns(frame_msg(10).header.stamp)} ns")
    out = rig.send(detections_msg(11, []))  # the image of stamp 11 is still there
    assert out is not None and stamp_ns(out.header.stamp) == stamp_ns(frame_msg(11).header.stamp)


def test_frames_the_detector_skipped_are_counted_not_dropped(ros, small_database):
    """A detector slower than the camera skips frames, so their images wait here for detections
    that never come; and an image can leave the queue unread. A complete pair ends every older
    entry (both inputs arrive in stamp order): counted as skipped. Before, they waited for the
    cache to overflow and were logged as dropped errors."""
    rig = Rig(ros, small_database)
    rig.send_info()
    rig.image_pub.publish(frame_msg(1))  # the detector skipped frame 1
    rig.det_pub.publish(detections_msg(2, []))  # frame 2's image was not read
    assert ros.spin_until(lambda: rig.node.counters["received"] == rig.node.counters["detections_received"] == 1)
    out = rig.send(frame_msg(3), detections_msg(3, []))
    assert out is not None and stamp_ns(out.header.stamp) == stamp_ns(frame_msg(3).header.stamp)
    assert rig.node.counters["skipped"] == 2 and rig.node.counters["dropped"] == 0
    assert len(rig.node._cache) == 0


def test_calibration_the_database_was_not_made_for_is_refused(ros, small_database):
    rig = Rig(ros, small_database)
    other = CameraModel(320, 240, [[300.0, 0, 160.0], [0, 300.0, 120.0], [0, 0, 1]])
    rig.info_pub.publish(camera_info_msg(other))
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == 1)
    assert "pose database was built for a camera" in rig.node.last_error
    rig.image_pub.publish(frame_msg(0))
    rig.det_pub.publish(detections_msg(0, [(*true_roi(0), 0.9)]))
    assert ros.spin_until(lambda: rig.node.counters["received"] == rig.node.counters["detections_received"] == 1)
    assert rig.node.counters["published"] == 0  # held until a calibration the database matches
    rig.send_info()
    assert ros.spin_until(lambda: len(rig.out) == 1) and len(rig.out[0].poses) == M
    assert rig.out[0].header == frame_msg(0).header
    assert rig.send(frame_msg(1), detections_msg(1, [(*true_roi(1), 0.9)])) is not None


def test_a_raw_camera_info_on_the_rectified_topic_is_refused(ros, small_database):
    """The nodes on rectified images use K alone: a camera_info with distortion there (a raw
    camera's, wired past undistort) was taken, its distortion silently ignored."""
    rig = Rig(ros, small_database)
    rig.info_pub.publish(camera_info_msg(dataclasses.replace(CAMERA, dist=np.array([-0.2, 0.05, 0.0, 0.0, 0.0]))))
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == 1)
    assert "distortion [-0.2, 0.05, 0.0, 0.0, 0.0] in the camera_info of a rectified image" in rig.node.last_error
    assert rig.node._calibration.camera is None
    rig.send_info()
    assert rig.send(frame_msg(0), detections_msg(0, [(*true_roi(0), 0.9)])) is not None


def test_a_frame_dropped_for_want_of_calibration_says_why_the_camera_info_was_refused(ros, small_database):
    rig = Rig(ros, small_database, Parameter("node.cache_size", value=1))
    rig.info_pub.publish(camera_info_msg(dataclasses.replace(CAMERA, dist=np.array([-0.2, 0.05, 0.0, 0.0, 0.0]))))
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == 1)
    for k in range(2):
        rig.image_pub.publish(frame_msg(k))
        rig.det_pub.publish(detections_msg(k, [(*true_roi(k), 0.9)]))
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == 2)
    assert "(the latest camera_info was refused: plumb_bob distortion [-0.2, 0.05, 0.0, 0.0, 0.0] in the camera_info" in rig.node.last_error


@pytest.mark.parametrize(
    "override, message",
    [
        (Parameter("database", value="/nonexistent/db.npz"), "database: pose database /nonexistent/db.npz not found"),
        (Parameter("kept", value=40), "need particles M >= 1 and 0 <= kept M0 < M"),
        (Parameter("node.cache_size", value=0), "cache_size must be at least 1"),
        (Parameter("fast.radius", value=3), r"unknown key\(s\) \['radius'\]"),
    ],
)
def test_bad_parameters_fail_start_up(ros, override, message):
    with pytest.raises(ConfigError, match=message):
        overrides = {p.name: p for p in (Parameter("particles", value=M), Parameter("kept", value=M0), override)}
        PoseBoostingNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
                         parameter_overrides=list(overrides.values()))


# --- scripted database and generator, the callbacks called directly ----------------------------

OTHER = CameraModel(320, 240, [[300.0, 0, 160.0], [0, 300.0, 120.0], [0, 0, 1]])


class ScriptedGenerator:
    """Made for CAMERA only (DatabaseError otherwise); records each ROI; returns ``hyps``."""

    made = []

    def __init__(self, database, camera, config):
        if not np.array_equal(camera.K, CAMERA.K):
            raise DatabaseError("pose database was built for another camera")
        self.rois, self.hyps = [], None
        ScriptedGenerator.made.append(self)

    def generate(self, frame, roi, count):
        self.rois.append(tuple(int(v) for v in roi))
        rng = np.random.default_rng(3)
        quats = rng.normal(size=(count, 4)) * 3.0  # not unit: the node normalises them
        return self.hyps or SimpleNamespace(obb=SimpleNamespace(x=100.0, y=80.0, w=30.0, h=12.0, theta=30.0),
                                            quats=quats, positions=rng.normal(size=(count, 3)),
                                            distances=np.sort(rng.random(count)))


def make_node(ros, monkeypatch, *overrides) -> PoseBoostingNode:
    """A PoseBoostingNode on ScriptedGenerator whose publications are kept in ``node.published``."""
    ScriptedGenerator.made = []
    monkeypatch.setattr(pose_boosting_module, "_load_database",
                        lambda config: SimpleNamespace(quats=np.zeros((1, 4)), distance=10.0))
    monkeypatch.setattr(pose_boosting_module, "PoseHypothesisGenerator", ScriptedGenerator)
    n = ros.add(PoseBoostingNode(
        context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
        parameter_overrides=[Parameter("particles", value=M), Parameter("kept", value=M0), *overrides]))
    n.published = []
    n._pub.publish = n.published.append
    return n


@pytest.fixture
def node(ros, monkeypatch):
    return make_node(ros, monkeypatch)


def calibrate(node, camera=CAMERA):
    node._on_camera_info(camera_info_msg(camera))


def send(node, k, boxes):
    """Frame k's image, then its detections (from the detector's frame_id, not the image's)."""
    node._on_image(frame_msg(k))
    detections = detections_msg(k, boxes)
    detections.header.frame_id = "detector_frame"
    node._on_detections(detections)


def test_a_detection_scored_above_one_is_not_used(node):
    calibrate(node)
    send(node, 0, [(10, 10, 40, 20, 1.5), (100, 60, 30, 12, 0.4)])
    assert ScriptedGenerator.made[-1].rois == [(100, 60, 30, 12)]
    assert node.counters["dropped"] == 1 and "score 1.5 is not in [0, 1]" in node.last_error
    assert not node.last_error.endswith("more")  # every unusable one named: no "and 0 more"


def test_a_box_in_the_frame_but_outside_its_height_as_a_width_is_used(node):
    """A 320 x 240 frame: x up to 320, y up to 240."""
    calibrate(node)
    send(node, 0, [(250, 10, 60, 20, 0.9)])
    assert ScriptedGenerator.made[-1].rois == [(250, 10, 60, 20)] and node.counters["dropped"] == 0


def test_hypotheses_carry_the_images_header_unit_quaternions_and_the_obb_in_radians(node):
    calibrate(node)
    send(node, 0, [(100, 60, 30, 12, 0.9)])
    (out,) = node.published
    assert out.header == frame_msg(0).header  # the image's frame_id, not the detector's
    quats = np.array([[p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w] for p in out.poses])
    assert len(out.poses) == M and np.allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-12)
    expected = ScriptedGenerator(None, CAMERA, None).generate(None, (0, 0, 1, 1), M).quats
    np.testing.assert_allclose(quats, expected / np.linalg.norm(expected, axis=1, keepdims=True), atol=1e-12)
    assert (out.obb.center_x, out.obb.center_y, out.obb.width, out.obb.height) == (100.0, 80.0, 30.0, 12.0)
    assert out.obb.angle == pytest.approx(math.radians(30.0))


@pytest.mark.parametrize("theta_deg, angle", [(90.0, -math.pi / 2), (120.0, math.radians(-60.0)), (89.0, math.radians(89.0))])
def test_the_obb_angle_is_given_in_minus_half_pi_to_half_pi(node, theta_deg, angle):
    """OpenCV's minAreaRect angle is in (0, 90]: 90 degrees is the line at -pi/2."""
    calibrate(node)
    generator = ScriptedGenerator.made[-1]
    generator.hyps = SimpleNamespace(obb=SimpleNamespace(x=1.0, y=2.0, w=3.0, h=1.0, theta=theta_deg),
                                     quats=np.tile([0.0, 0.0, 0.0, 1.0], (M, 1)), positions=np.zeros((M, 3)),
                                     distances=np.arange(M, dtype=float))
    send(node, 0, [(100, 60, 30, 12, 0.9)])
    assert node.published[-1].obb.angle == pytest.approx(angle, abs=1e-12)


def test_after_a_refused_calibration_frames_wait_for_a_matching_one(node):
    """Frames are never boosted with the database matched to a calibration the camera no longer has."""
    calibrate(node)
    send(node, 0, [(100, 60, 30, 12, 0.9)])
    assert len(node.published) == 1
    calibrate(node, OTHER)
    assert node.counters["dropped"] == 1 and "pose database was built for another camera" in node.last_error
    send(node, 1, [(100, 60, 30, 12, 0.9)])
    assert len(node.published) == 1  # held
    calibrate(node)
    assert len(node.published) == 2 and node.published[-1].header == frame_msg(1).header


def test_pairs_before_the_first_calibration_are_held_as_many_as_the_cache_size(ros, monkeypatch):
    node = make_node(ros, monkeypatch, Parameter("node.cache_size", value=2))
    for k in range(3):
        send(node, k, [(100, 60, 30, 12, 0.9)])
    assert node.published == [] and node.counters["dropped"] == 1
    assert node.last_error.startswith(f"image stamped {1_000_000_000} ns: no calibration")
    calibrate(node)
    assert [o.header for o in node.published] == [frame_msg(1).header, frame_msg(2).header]
