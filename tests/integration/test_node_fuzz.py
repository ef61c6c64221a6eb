"""A node logs and drops a bad message, it never dies on one: each node's subscription callbacks,
called directly with hostile messages (hypothesis, fixed seed: NaN/inf/huge numbers, sizes and
data lengths that disagree, zero or non-unit quaternions, stamps at 0, negative or at the end of
int32, unknown states, odd frame ids), then a good message, which must be processed normally."""

import math
import signal
import time

import cv2
import numpy as np
import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, Pose, PoseStamped, PoseWithCovarianceStamped, Quaternion
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image, RegionOfInterest
from std_msgs.msg import Header
from test_node_common import SMALL_CAMERA, camera_info_msg, image_msg, rgb_frame, ros  # noqa: F401 (fixture)
from test_node_detector import CAMERA as DETECTOR_CAMERA
from test_node_detector import PARAMS as DETECTOR_PARAMS
from test_node_detector import model  # noqa: F401 (fixture)
from test_node_evaluator import PARAMS as EVALUATOR_PARAMS
from test_node_evaluator import pose_msg, truth_msg
from test_node_gcs_bridge import PARAMS as GCS_PARAMS
from test_node_gcs_bridge import landing_position
from test_node_pose_boosting import CAMERA, M, M0, detections_msg, library_generator, scene_frame, small_database, true_roi  # noqa: F401
from test_node_pose_boosting import PARAMS as BOOSTING_PARAMS
from test_node_tracker import PARAMS as TRACKER_PARAMS
from test_node_tracker import boosted_msg, generator  # noqa: F401 (fixture)

from uav_landing_msgs.msg import Detection, DetectionArray, OrientedBox, PoseHypotheses, TrackerStatus
from uav_landing_vision.nodes.detector import DetectorNode
from uav_landing_vision.nodes.evaluator import EvaluatorNode
from uav_landing_vision.nodes.gcs_bridge import GcsBridgeNode
from uav_landing_vision.nodes.pose_boosting import PoseBoostingNode
from uav_landing_vision.nodes.tracker import TrackerNode
from uav_landing_vision.nodes.undistort import Undistort

# Hostile numbers overflow in numpy on their way to being refused, or into a report: expected.
pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")
FUZZ = settings(max_examples=40, deadline=None, derandomize=True, suppress_health_check=list(HealthCheck))
CALLBACK_LIMIT_S = 20  # a callback still running after this long hangs
GOOD_SEC = 5000  # good message k is stamped GOOD_SEC + k s, GOOD_NS ns
GOOD_NS = 123_456_789
U32 = 2**32 - 1

# --- hostile messages ---------------------------------------------------------------------------

floats = st.one_of(st.sampled_from([0.0, -0.0, 1e-300, 1e300, -1e300, 3.4e38, math.nan, math.inf, -math.inf]),
                   st.floats(allow_nan=True, allow_infinity=True), st.floats(-100, 100))
floats32 = st.one_of(st.sampled_from([0.5, math.nan, math.inf, -math.inf, 3.4e38, -1.0]), st.floats(width=32))
u32 = st.one_of(st.sampled_from([0, 1, 30, 40, 64, 96, 240, 320, 16385, U32]), st.integers(0, U32))
stamps = st.builds(Time, sec=st.one_of(st.sampled_from([0, -1, -(2**31), 2**31 - 1]), st.integers(-(2**31), 2**31 - 1)),
                   nanosec=st.one_of(st.sampled_from([0, 999_999_999, 10**9, U32]), st.integers(0, U32)))
headers = st.builds(Header, stamp=stamps,
                    frame_id=st.one_of(st.sampled_from(["camera_optical_frame", "", "カメラ", "a" * 300]), st.text(max_size=8)))
unit_quats = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 1e-3).map(
    lambda v: Quaternion(**dict(zip("xyzw", (np.array(v) / np.linalg.norm(v)).tolist()))))
quats = st.one_of(unit_quats, st.builds(Quaternion, x=floats, y=floats, z=floats, w=floats),
                  st.sampled_from([Quaternion(w=0.0), Quaternion(w=1.00011), Quaternion(w=-1.0)]))
poses = st.builds(Pose, position=st.builds(Point, x=floats, y=floats, z=floats), orientation=quats)
covariances = st.one_of(st.lists(floats, min_size=36, max_size=36),
                        st.sampled_from([[0.0] * 36, [math.nan] * 36, list(np.diag([0.01] * 6).ravel()), list(np.diag([-1.0] * 6).ravel())]))


def near(k_sec: int):
    """Stamps from ``k_sec`` − 1 s to ``k_sec`` + 1 s: among the good messages of that time."""
    return st.builds(lambda d, ns: Time(sec=k_sec + d, nanosec=ns), st.sampled_from([-1, 0]), st.integers(0, 999_999_999))


def plausible_poses(k_sec: int):
    """Usable poses (finite, unit quaternion, camera frame) stamped near ``k_sec``, at hostile depths."""
    def build(stamp, x, y, z, q, cov):
        msg = PoseWithCovarianceStamped()
        msg.header.stamp, msg.header.frame_id = stamp, "camera_optical_frame"
        msg.pose.pose = Pose(position=Point(x=x, y=y, z=z), orientation=q)
        msg.pose.covariance = cov
        return msg
    depth = st.one_of(st.floats(0.01, 100), st.sampled_from([0.0, 1e-12, -1.0, 1e6, 1e300]))
    return st.builds(build, near(k_sec), st.floats(-3, 3), st.floats(-3, 3), depth, unit_quats, covariances)


def hostile_poses(k_sec: int):
    """Any pose: malformed in any field, or usable at a hostile depth near ``k_sec``."""
    def build(header, pose, cov):
        msg = PoseWithCovarianceStamped(header=header)
        msg.pose.pose, msg.pose.covariance = pose, cov
        return msg
    return st.one_of(st.builds(build, headers, poses, covariances), plausible_poses(k_sec))


@st.composite
def images(draw, width: int, height: int, k_sec: int):
    """Unsupported encodings, empty or huge sizes, steps and data lengths that disagree."""
    encoding = draw(st.sampled_from(["rgb8", "bgr8", "mono8", "rgba8", "16UC1", "", "🎥"]))
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1}.get(encoding, 3)
    w, h = draw(st.one_of(st.just((width, height)), st.tuples(u32, u32), st.tuples(st.integers(0, 50), st.integers(0, 50))))
    row = min(w * channels, U32)
    step = draw(st.one_of(st.just(row), st.sampled_from([0, row + 1, U32]), st.integers(0, U32)))
    full = step * h
    length = draw(st.one_of(st.just(full if full <= 400_000 else 0), st.just(max(min(full, 400_000) - 1, 0)), st.integers(0, 5000)))
    data = np.random.default_rng(draw(st.integers(0, 1000))).integers(0, 256, length, dtype=np.uint8).tobytes()
    header = draw(st.one_of(headers, st.builds(Header, stamp=near(k_sec))))
    return Image(header=header, width=w, height=h, encoding=encoding, step=step, is_bigendian=draw(st.integers(0, 255)), data=data)


@st.composite
def camera_infos(draw, width: int, height: int):
    w, h = draw(st.one_of(st.just((width, height)), st.tuples(st.sampled_from([0, 1, 40, 16385, U32]), st.sampled_from([0, 1, 30, U32]))))
    good_k = [0.9 * max(w, 1), 0.0, w / 2, 0.0, 0.9 * max(w, 1), h / 2, 0.0, 0.0, 1.0]
    k = draw(st.one_of(st.just(good_k), st.lists(floats, min_size=9, max_size=9), st.sampled_from([[0.0] * 9, [math.nan] * 9])))
    d = draw(st.one_of(st.just([]), st.just([0.0] * 5), st.lists(floats, max_size=14), st.lists(st.floats(-1, 1), min_size=5, max_size=5)))
    roi = draw(st.one_of(st.just(RegionOfInterest()), st.builds(RegionOfInterest, x_offset=u32, y_offset=u32, width=u32, height=u32)))
    return CameraInfo(header=draw(headers), width=w, height=h, distortion_model=draw(st.sampled_from(["plumb_bob", "", "equidistant", "ü"])),
                      d=d, k=k, r=draw(st.one_of(st.just(list(np.eye(3).ravel())), st.lists(floats, min_size=9, max_size=9))),
                      binning_x=draw(st.sampled_from([0, 1, 2, U32])), binning_y=draw(st.sampled_from([0, 1, U32])), roi=roi)


rois = st.one_of(st.builds(RegionOfInterest, x_offset=u32, y_offset=u32, width=u32, height=u32),
                 st.builds(RegionOfInterest, x_offset=st.integers(0, 330), y_offset=st.integers(0, 250),
                           width=st.integers(0, 330), height=st.integers(0, 250)))
detection_lists = st.lists(st.builds(Detection, roi=rois, score=floats32), max_size=8)
statuses = st.builds(TrackerStatus, header=headers, state=st.integers(0, 255), best_likelihood=floats32,
                     effective_particles=floats32, stage_names=st.lists(st.text(max_size=4), max_size=4),
                     stage_ms=st.lists(floats32, max_size=4))
obbs = st.builds(OrientedBox, center_x=floats, center_y=floats, width=floats, height=floats, angle=floats)


# --- driving a node ----------------------------------------------------------------------------

def _hang(signum, frame):
    raise TimeoutError(f"a callback ran past {CALLBACK_LIMIT_S} s")


def call(callback, msg) -> None:
    """Run one callback; an exception it lets out fails the test, and so does a hang."""
    previous = signal.signal(signal.SIGALRM, _hang)
    signal.alarm(CALLBACK_LIMIT_S)
    try:
        callback(msg)
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def wire(node) -> tuple[dict, dict]:
    """The node's subscription callbacks and, for each of its topics, the list its publisher now fills."""
    callbacks = {s.topic_name.lstrip("/"): s.callback for s in node.subscriptions}
    published = {}
    for pub in node.publishers:
        pub.publish = published.setdefault(pub.topic_name.lstrip("/"), []).append
    return callbacks, published


def feed(callbacks, messages) -> None:
    for topic, msg in messages:
        call(callbacks[topic], msg)


def on_topics(strategies: dict):
    """Lists of one (topic, message) drawn from ``{topic: strategy}``."""
    return st.one_of(*(s.map(lambda m, t=topic: [(t, m)]) for topic, s in strategies.items()))


def flat(groups) -> list:
    return [m for group in groups for m in group]


# --- the nodes ----------------------------------------------------------------------------------

def test_undistort(ros):
    node = ros.add(Undistort(context=ros.context))
    callbacks, published = wire(node)
    rectified = published["camera/image_rect"]
    maps = SMALL_CAMERA.undistortion_maps()

    @FUZZ
    @given(st.data())
    def run(data):
        k = node.counters["received"]
        hostile = on_topics({"camera/camera_info": camera_infos(40, 30), "camera/image_raw": images(40, 30, GOOD_SEC + k)})
        feed(callbacks, flat(data.draw(st.lists(hostile, min_size=1, max_size=4))))
        call(callbacks["camera/camera_info"], camera_info_msg(SMALL_CAMERA))
        pixels = rgb_frame(SMALL_CAMERA, k)
        call(callbacks["camera/image_raw"], image_msg(pixels, "rgb8", GOOD_SEC + k, GOOD_NS))
        assert rectified and rectified[-1].header.stamp == Time(sec=GOOD_SEC + k, nanosec=GOOD_NS), node.last_error
        assert bytes(rectified[-1].data) == cv2.remap(pixels, *maps, cv2.INTER_LINEAR).tobytes()

    run()


def test_detector(ros, model):
    """Threshold 0.999: the untrained network finds nothing, so track boxes and search windows come
    from the hostile poses."""
    node = ros.add(DetectorNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(DETECTOR_PARAMS)],
                                parameter_overrides=[Parameter("model", value=str(model)), Parameter("score_threshold", value=0.999),
                                                     Parameter("node.search_window", value=True)]))
    callbacks, published = wire(node)

    @FUZZ
    @given(st.data())
    def run(data):
        k = node.counters["received"]
        call(callbacks["camera/camera_info_rect"], camera_info_msg(DETECTOR_CAMERA))
        hostile = on_topics({"camera/camera_info_rect": camera_infos(96, 64), "camera/image_rect": images(96, 64, GOOD_SEC + k),
                             "uav/pose": hostile_poses(GOOD_SEC + k)})
        feed(callbacks, flat(data.draw(st.lists(hostile, min_size=1, max_size=4))))
        image = image_msg(rgb_frame(DETECTOR_CAMERA, k), "rgb8", GOOD_SEC + k, GOOD_NS)
        call(callbacks["camera/image_rect"], image)
        out = published["uav/detections"][-1]
        assert out.header == image.header, node.last_error
        for det in out.detections:
            r = det.roi
            assert 0 < r.width and 0 < r.height and r.x_offset + r.width <= 96 and r.y_offset + r.height <= 64
            assert 0.0 <= det.score <= 1.0

    run()


def test_pose_boosting(ros, small_database):
    node = ros.add(PoseBoostingNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(BOOSTING_PARAMS)],
                                    parameter_overrides=[Parameter("database", value=str(small_database)),
                                                         Parameter("particles", value=M), Parameter("kept", value=M0)]))
    callbacks, published = wire(node)
    library = library_generator(small_database)

    def pairs(k_sec):  # a frame and hostile detections with one stamp: boosted
        def build(stamp, j, detections):
            image = image_msg(scene_frame(j), "rgb8", stamp.sec, stamp.nanosec)
            return [("camera/image_rect", image), ("uav/detections", DetectionArray(header=image.header, detections=detections))]
        return st.builds(build, near(k_sec).filter(lambda t: t.nanosec != GOOD_NS), st.integers(0, 19), detection_lists)

    @FUZZ
    @given(st.data())
    def run(data):
        k = node.counters["received"]
        hostile = on_topics({"camera/camera_info_rect": camera_infos(320, 240), "camera/image_rect": images(320, 240, GOOD_SEC + k),
                             "uav/detections": st.builds(DetectionArray, header=headers, detections=detection_lists)})
        feed(callbacks, flat(data.draw(st.lists(st.one_of(hostile, pairs(GOOD_SEC + k)), min_size=1, max_size=4))))
        call(callbacks["camera/camera_info_rect"], camera_info_msg(CAMERA))
        j = k % 20
        image = image_msg(scene_frame(j), "rgb8", GOOD_SEC + k, GOOD_NS)
        detections = detections_msg(j, [(*true_roi(j), 0.9)])
        detections.header = image.header
        feed(callbacks, [("uav/detections", detections), ("camera/image_rect", image)])
        out = published["uav/pose_hypotheses"][-1]
        assert out.header == image.header, node.last_error
        positions = [[p.position.x, p.position.y, p.position.z] for p in out.poses]
        np.testing.assert_array_equal(positions, library.generate(scene_frame(j), true_roi(j), count=M).positions)

    run()


def test_tracker(ros, generator):
    """Hostile hypotheses paired with frames reach the core; the good frame after them is tracked
    (unless a hostile frame tracked within 2 s before is newer: then it is out of order)."""
    node = ros.add(TrackerNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(TRACKER_PARAMS)],
                               parameter_overrides=[Parameter("particles", value=M), Parameter("boosted", value=M - M0),
                                                    Parameter("node.hypotheses_timeout_s", value=1e-3)]))
    callbacks, published = wire(node)
    boosted = [boosted_msg(generator, j) for j in range(20)]
    good_poses = st.sampled_from([p for b in boosted for p in b.poses[:5]])
    far = st.sampled_from([np.array([1e200, 0.0, 1e200]), np.array([0.0, 0.0, 1e-9]), np.array([0.0, 0.0, -5.0])]).map(
        lambda p: Pose(position=Point(x=p[0], y=p[1], z=p[2]), orientation=Quaternion(w=1.0)))

    def hypotheses(k_sec):
        pose_lists = st.lists(st.one_of(poses, good_poses, far, plausible_poses(k_sec).map(lambda m: m.pose.pose)), max_size=45)
        return st.builds(PoseHypotheses, header=st.one_of(headers, st.builds(Header, stamp=near(k_sec))), obb=obbs,
                         poses=pose_lists, distances=st.lists(floats32, max_size=45))

    def pairs(k_sec):
        def build(stamp, j, hyps):
            image = image_msg(scene_frame(j), "rgb8", stamp.sec, stamp.nanosec)
            hyps.header = image.header
            return [("camera/image_rect", image), ("uav/pose_hypotheses", hyps)]
        return st.builds(build, near(k_sec), st.integers(0, 19), hypotheses(k_sec))

    @FUZZ
    @given(st.data())
    def run(data):
        k_sec = GOOD_SEC + node.counters["received"]
        hostile = on_topics({"camera/camera_info_rect": camera_infos(320, 240), "camera/image_rect": images(320, 240, k_sec),
                             "uav/pose_hypotheses": hypotheses(k_sec)})
        for group in data.draw(st.lists(st.one_of(hostile, pairs(k_sec)), min_size=1, max_size=4)):
            feed(callbacks, group)
            time.sleep(2e-3)
            node._on_deadline()  # what waited past the timeout: tracked by prediction
        call(callbacks["camera/camera_info_rect"], camera_info_msg(CAMERA))
        j = k_sec % 20
        image = image_msg(scene_frame(j), "rgb8", k_sec, GOOD_NS)
        hyps = boosted[j]
        hyps.header = image.header
        good = k_sec * 1_000_000_000 + GOOD_NS
        out_of_order = 0 <= node._last_stamp - good <= 2_000_000_000
        feed(callbacks, [("camera/image_rect", image), ("uav/pose_hypotheses", hyps)])
        status = [s for s in published["uav/tracker_status"] if s.header == image.header]
        assert len(status) == (0 if out_of_order else 1), node.last_error
        for s in status:
            assert s.state in (0, 1, 2) and math.isfinite(s.best_likelihood) and math.isfinite(s.effective_particles)
        for pose in (p.pose for p in published["uav/pose"] if p.header == image.header):
            q = pose.pose.orientation
            assert np.all(np.isfinite([pose.pose.position.x, pose.pose.position.y, pose.pose.position.z]))
            assert math.isclose(math.hypot(q.x, q.y, q.z, q.w), 1.0, rel_tol=1e-6) and np.all(np.isfinite(pose.covariance))

    run()


def test_gcs_bridge(ros):
    """Hostile poses and statuses, some stamped fresh on the node's clock and vouched for by a
    TRACKING status so that the ticks send them (every MAVLink message type); then a good pose is
    guided on."""
    messages = ["ODOMETRY", "ATT_POS_MOCAP", "VISION_POSITION_ESTIMATE", "LANDING_TARGET"]
    node = ros.add(GcsBridgeNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(GCS_PARAMS)],
                                 parameter_overrides=[Parameter("mavlink.connection", value="udpout:127.0.0.1:9"),
                                                      Parameter("mavlink.messages", value=messages)]))
    callbacks, published = wire(node)
    good_position = [0.5, -2.0, 30.0]

    def good_pose():
        msg = PoseWithCovarianceStamped()
        msg.header.stamp, msg.header.frame_id = node.get_clock().now().to_msg(), "camera_optical_frame"
        msg.pose.pose.position = Point(x=good_position[0], y=good_position[1], z=good_position[2])
        msg.pose.pose.orientation.w = 1.0
        msg.pose.covariance = list(np.diag([0.01] * 6).ravel())
        return msg

    def restamped(msg, lag_ns):  # stamped on the node's clock when fed, not when drawn
        if lag_ns is not None:
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(node.get_clock().now().nanoseconds - lag_ns, 10**9)
        return msg

    lags = st.one_of(st.none(), st.integers(-60_000_000, 400_000_000))
    hostile = st.one_of(st.tuples(st.just("uav/pose"), hostile_poses(0), lags), st.tuples(st.just("uav/tracker_status"), statuses, lags))

    @FUZZ
    @given(st.lists(st.tuples(hostile, st.booleans()), min_size=1, max_size=4))
    def run(seq):
        for (topic, msg, lag), vouched in seq:
            call(callbacks[topic], restamped(msg, lag))
            if vouched:
                call(callbacks["uav/tracker_status"], TrackerStatus(header=msg.header, state=TrackerStatus.TRACKING))
                time.sleep(0.08)  # the tick sends a pose at most every 0.75 / rate_hz
                node._tick()
        time.sleep(0.07)  # after every hostile stamp, within the clock-lead tolerance
        for _ in range(2):  # the first tick may count a hostile LOST or ACQUIRING status
            pose = good_pose()
            feed(callbacks, [("uav/pose", pose), ("uav/tracker_status", TrackerStatus(header=pose.header, state=TrackerStatus.TRACKING))])
            node._tick()
        guidance = published["uav/landing_guidance"][-1]
        assert guidance.header.stamp == pose.header.stamp, node.last_error
        assert guidance.range == pytest.approx(np.linalg.norm(landing_position(good_position)), abs=1e-9)

    run()


def test_evaluator(ros, tmp_path):
    node = ros.add(EvaluatorNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(EVALUATOR_PARAMS)],
                                 parameter_overrides=[Parameter("out_dir", value=str(tmp_path / "report"))]))
    callbacks, _ = wire(node)
    as_truth = lambda m: PoseStamped(header=m.header, pose=m.pose.pose)  # noqa: E731

    def pairs(truth, pose):
        pose.header = truth.header
        return [("uav/ground_truth", as_truth(truth)), ("uav/pose", pose)]

    hostile = st.one_of(on_topics({"uav/pose": hostile_poses(1), "uav/ground_truth": hostile_poses(1).map(as_truth)}),
                        st.builds(pairs, plausible_poses(1), plausible_poses(1)))

    @FUZZ
    @given(st.lists(hostile, min_size=1, max_size=5))
    def run(seq):
        k = node.counters["truth_received"]
        feed(callbacks, flat(seq))
        truth, pose = truth_msg(1), pose_msg(1)
        truth.header.stamp.sec = pose.header.stamp.sec = GOOD_SEC + k
        feed(callbacks, [("uav/ground_truth", truth), ("uav/pose", pose)])
        stamp = (GOOD_SEC + k) * 1_000_000_000 + truth.header.stamp.nanosec
        assert stamp in node.truth and stamp in node.estimates, node.last_error

    run()
    assert node.write() is not None and (tmp_path / "report" / "summary.json").exists()
