"""``tracker`` in-process over DDS on rendered frames with hypotheses from the boosting core:
the pose converges, nothing is published without an estimate, bad input is dropped; and its
time-line handling with callbacks called directly (no DDS traffic, no camera)."""

import dataclasses
from pathlib import Path

import moderngl
import numpy as np
import pytest
from geometry_msgs.msg import Pose, PoseArray, PoseWithCovarianceStamped
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, Image
from test_node_common import camera_info_msg, image_msg, participant_of, ros  # noqa: F401 (fixture)
from test_node_pose_boosting import (  # noqa: F401 (fixture)
    CAMERA, M, M0, SKY, TRUE_QUAT, scene_frame, small_database, stamp, true_position, true_roi,
)

from uav_landing_msgs.msg import PoseHypotheses, TrackerStatus
from uav_landing_vision.boosting import HypothesisConfig, PoseDatabase, PoseHypothesisGenerator
from uav_landing_vision.config import ConfigError
from uav_landing_vision.geometry import geodesic_angle
from uav_landing_vision.nodes.image import image_to_numpy
from uav_landing_vision.nodes.poses import numpy_to_pose, pose_to_numpy
from uav_landing_vision.nodes import sync
from uav_landing_vision.nodes import tracker as tracker_node
from uav_landing_vision.nodes.qos import IMAGE_QOS, RELIABLE_QOS
from uav_landing_vision.nodes.tracker import BoostedPoses, TrackerNode
from uav_landing_vision.stamps import stamp_ns
from uav_landing_vision.tracking.upf import STAGES, Tracker, load_tracker_config

PARAMS = Path(__file__).parents[2] / "config" / "tracker.yaml"
TIMEOUT_S = 0.3
NS = 1_000_000_000


@pytest.fixture(scope="module")
def generator(small_database):
    return PoseHypothesisGenerator(PoseDatabase.load(small_database), CAMERA, HypothesisConfig(particles=M, kept=M0))


def hypotheses_msg(k: int, poses=()) -> PoseHypotheses:
    msg = PoseHypotheses(poses=[numpy_to_pose(Pose(), p, q) for p, q in poses])
    msg.header.stamp.sec, msg.header.stamp.nanosec = stamp(k)
    msg.header.frame_id = "camera_optical_frame"
    return msg


def boosted_msg(generator, k: int) -> PoseHypotheses:
    """What pose_boosting publishes for frame k with the true ROI: M poses, best first."""
    hyps = generator.generate(scene_frame(k), true_roi(k), count=M)
    return hypotheses_msg(k, zip(hyps.positions, hyps.quats / np.linalg.norm(hyps.quats, axis=1, keepdims=True)))


class Rig:
    def __init__(self, ros, *overrides):
        self.ros = ros
        self.node = ros.add(TrackerNode(
            context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
            parameter_overrides=[Parameter("particles", value=M), Parameter("boosted", value=M - M0),
                                 Parameter("node.hypotheses_timeout_s", value=TIMEOUT_S), *overrides],
        ))
        self.info_pub = ros.probe.create_publisher(CameraInfo, "camera/camera_info_rect", IMAGE_QOS)
        self.image_pub = ros.probe.create_publisher(Image, "camera/image_rect", IMAGE_QOS)
        self.hyp_pub = ros.probe.create_publisher(PoseHypotheses, "uav/pose_hypotheses", RELIABLE_QOS)
        self.poses = ros.collect(PoseWithCovarianceStamped, "uav/pose", RELIABLE_QOS)
        self.particles = ros.collect(PoseArray, "uav/particles", RELIABLE_QOS)
        self.status = ros.collect(TrackerStatus, "uav/tracker_status", RELIABLE_QOS)
        self.overlay = ros.collect(Image, "uav/overlay", IMAGE_QOS)
        # Matched by the node's own publishers: the overlay's is in a participant of its own, which
        # sees the probe later than the node does.
        outputs = [self.node._pose_pub, self.node._particles_pub, self.node._status_pub, self.node._overlay_pub]
        assert ros.spin_until(lambda: all(p.get_subscription_count() for p in (self.info_pub, self.image_pub, self.hyp_pub))
                              and all(p.get_subscription_count() for p in outputs if p is not None)), "discovery"

    def send_info(self):
        self.info_pub.publish(camera_info_msg(CAMERA))
        assert self.ros.spin_until(lambda: self.node._tracker is not None)

    def status_of(self, k: int):
        return next((s for s in self.status if stamp_ns(s.header.stamp) == stamp_ns(hypotheses_msg(k).header.stamp)), None)

    def send(self, k: int, *msgs):
        """Publish the messages of frame k in order; the frame's status once tracked, or None if dropped."""
        dropped = self.node.counters["dropped"]
        for msg in msgs:
            (self.image_pub if isinstance(msg, Image) else self.hyp_pub).publish(msg)
        assert self.ros.spin_until(lambda: self.status_of(k) is not None or self.node.counters["dropped"] > dropped)
        return self.status_of(k)

    def track_a_first_run(self, generator, frames: int = 3):
        """Track frames 0 .. frames - 1 stamped 5 s later than frame_msg's: a replay's first run."""
        for k in range(frames):
            image, hyps = frame_msg(k), boosted_msg(generator, k)
            image.header.stamp.sec += 5
            hyps.header.stamp.sec += 5
            self.image_pub.publish(image)
            self.hyp_pub.publish(hyps)
            assert self.ros.spin_until(lambda: self.node.counters["tracked"] == k + 1)

    def pose_of(self, k: int):
        return next((p for p in self.poses if stamp_ns(p.header.stamp) == stamp_ns(hypotheses_msg(k).header.stamp)), None)


def frame_msg(k: int, pixels=None) -> Image:
    return image_msg(scene_frame(k) if pixels is None else pixels, "rgb8", *stamp(k))


def test_pose_converges_on_rendered_frames_with_boosted_hypotheses(ros, generator):
    rig = Rig(ros, Parameter("node.overlay", value=True))
    rig.send_info()
    frames = 6
    sent = []
    for k in range(frames):
        image, hyps = frame_msg(k), boosted_msg(generator, k)
        status = rig.send(k, *((image, hyps) if k % 2 else (hyps, image)))  # both orders of arrival
        assert status is not None and status.header == image.header
        sent.append(hyps)
    assert rig.node.counters["without_hypotheses"] == 0 and rig.node.counters["dropped"] == 0
    assert ros.spin_until(lambda: len(rig.poses) == frames and len(rig.particles) == frames and len(rig.overlay) == frames)
    last = rig.poses[-1]
    assert last.header == frame_msg(frames - 1).header
    position, quat = pose_to_numpy(last.pose.pose)
    assert np.linalg.norm(position - true_position(frames - 1)) < 0.5
    assert np.degrees(geodesic_angle(quat, TRUE_QUAT)) < 20.0
    cov = np.array(last.pose.covariance).reshape(6, 6)
    assert np.all(np.isfinite(cov)) and np.all(np.diag(cov) > 0)
    assert len(rig.particles[-1].poses) == M and rig.particles[-1].header == last.header
    status = rig.status[-1]
    assert status.state in (TrackerStatus.ACQUIRING, TrackerStatus.TRACKING) and 0 < status.best_likelihood <= 1
    assert list(status.stage_names) == list(STAGES) and len(status.stage_ms) == len(STAGES)
    assert 1.0 <= status.effective_particles <= M
    overlay = image_to_numpy(rig.overlay[-1])
    assert overlay.shape == (240, 320, 3) and (overlay == (0, 255, 0)).all(axis=2).sum() > 20  # outline drawn
    # The overlay's images leave from a DDS participant of their own: sent from one participant,
    # images and small messages lost some of the small ones (participant.py).
    assert participant_of(ros.probe, "/uav/overlay") != participant_of(ros.probe, "/uav/pose")
    # What reaches uav/pose is the core's result on the same frames and hypotheses, field by field.
    core = Tracker(dataclasses.replace(load_tracker_config(PARAMS), particles=M, boosted=M - M0), CAMERA)
    for k, hyps in enumerate(sent):
        poses = [pose_to_numpy(p) for p in hyps.poses]
        result = core.step(scene_frame(k), stamp_ns(hyps.header.stamp),
                           BoostedPoses(np.array([q for _, q in poses]), np.array([p for p, _ in poses])))
        published, status = rig.pose_of(k), rig.status_of(k)
        assert (status.state, status.best_likelihood, status.effective_particles) == (  # float32 on the wire
            result.state, np.float32(result.best_likelihood), np.float32(result.effective_particles))
        np.testing.assert_array_equal(np.hstack(pose_to_numpy(published.pose.pose)),
                                      np.hstack([result.position, result.quat]))
        np.testing.assert_array_equal(np.array(published.pose.covariance).reshape(6, 6), result.covariance)
        np.testing.assert_array_equal([np.hstack(pose_to_numpy(p)) for p in rig.particles[k].poses],
                                      np.hstack([result.particles.pos, result.particles.quat]))


def test_nothing_is_published_on_pose_without_an_estimate(ros, generator):
    rig = Rig(ros)
    rig.send_info()
    # No hypotheses ever: each frame waits TIMEOUT_S, is tracked by prediction, and there is nothing.
    status = rig.send(0, frame_msg(0))
    assert status.state == TrackerStatus.LOST and rig.node.counters["without_hypotheses"] == 1
    assert rig.send(1, frame_msg(1), hypotheses_msg(1)).state == TrackerStatus.LOST  # empty hypotheses
    status = rig.send(2, frame_msg(2), boosted_msg(generator, 2))
    assert status.state == TrackerStatus.ACQUIRING and ros.spin_until(lambda: rig.pose_of(2) is not None)
    # The UAV leaves the frame: the particles score nothing, so there is no estimate to publish.
    assert rig.send(3, frame_msg(3, SKY), hypotheses_msg(3)).state != TrackerStatus.LOST
    assert rig.send(4, frame_msg(4, SKY)) is not None
    assert rig.node.counters["tracked"] == 5 and rig.node.counters["published"] == 1  # one pose: frame 2's
    assert [stamp_ns(p.header.stamp) for p in rig.poses] == [stamp_ns(frame_msg(2).header.stamp)]


def test_malformed_input_is_dropped_and_tracking_goes_on(ros, generator):
    rig = Rig(ros)
    rig.image_pub.publish(frame_msg(0))
    rig.hyp_pub.publish(boosted_msg(generator, 0))
    assert ros.spin_until(lambda: rig.node.counters["received"] == rig.node.counters["hypotheses_received"] == 1)
    assert rig.status_of(0) is None  # held until the first calibration ...
    rig.send_info()
    assert ros.spin_until(lambda: rig.status_of(0) is not None)  # ... then tracked
    bad = boosted_msg(generator, 1)
    bad.poses[3].orientation.w = 3.0
    rig.send(1, frame_msg(1), bad)
    assert "pose quaternion is not a finite unit" in rig.node.last_error
    assert ros.spin_until(lambda: rig.status_of(1) is not None)  # tracked at once, by prediction
    nan = boosted_msg(generator, 2)
    nan.poses[0].position.x = float("nan")
    rig.send(2, nan, frame_msg(2))
    assert "pose position is not finite" in rig.node.last_error
    mono = image_msg(scene_frame(3)[..., 0].copy(), "mono8", *stamp(3))
    assert rig.send(3, mono) is None and "has no colour" in rig.node.last_error
    small = image_msg(np.zeros((30, 40, 3), np.uint8), "rgb8", *stamp(4))
    assert rig.send(4, small, hypotheses_msg(4)) is None and "image is 40x30" in rig.node.last_error
    assert ros.spin_until(lambda: rig.node.last_error == f"hypotheses stamped {stamp_ns(hypotheses_msg(4).header.stamp)} "
                          "ns have no image")  # the small image was dropped on arrival: its hypotheses wait alone
    dropped = rig.node.counters["dropped"]
    rig.hyp_pub.publish(boosted_msg(generator, 5))  # hypotheses whose image never comes
    assert ros.spin_until(lambda: rig.node.counters["dropped"] > dropped)
    assert rig.node.last_error.endswith("have no image")
    rig.hyp_pub.publish(boosted_msg(generator, 2))  # late: frame 2 was tracked
    assert ros.spin_until(lambda: rig.node.counters["dropped"] > dropped + 1)
    assert "arrived after their frame was tracked" in rig.node.last_error
    assert rig.send(6, frame_msg(6), boosted_msg(generator, 6)).state != TrackerStatus.LOST
    assert ros.spin_until(lambda: rig.pose_of(6) is not None)


def test_hypotheses_the_core_cannot_go_on_with_restart_the_track_on_the_next_frame(ros, generator):
    """Finite, unit hypotheses 1e200 m away start a track whose next step overflows: that frame
    restarts the track from its own hypotheses instead of being dropped (as every later one was),
    and a frame without hypotheses does not crash the node on the half-stepped filters."""
    rig = Rig(ros)
    rig.send_info()
    assert rig.send(0, frame_msg(0), hypotheses_msg(0, [(np.array([1e200, 0.0, 1e200]), TRUE_QUAT)] * M)) is not None
    for k in (1, 2):
        status = rig.send(k, frame_msg(k), boosted_msg(generator, k))
        assert status is not None and status.state != TrackerStatus.LOST
    assert rig.send(3, frame_msg(3)) is not None  # tracked by prediction after the timeout
    assert rig.node.counters["dropped"] == 0


def test_a_refinement_batch_beyond_512_poses_is_rendered(ros):
    """The renderer is sized for the largest batch the tracker renders: with refine.candidates
    >= 512 the first camera_info raised ValueError out of the callback and the node died."""
    rig = Rig(ros, Parameter("refine.candidates", value=600))
    rig.send_info()
    assert rig.node._renderer.max_batch >= 601


def test_frames_a_newer_frame_supersedes_are_skipped_not_tracked(ros, generator):
    """A camera faster than the tracker: frames 1 and 2 still wait for hypotheses when frame 3
    comes complete; tracking them by prediction would only make frame 3 (and every later one)
    older, so they are skipped and counted."""
    rig = Rig(ros, Parameter("node.hypotheses_timeout_s", value=10.0))
    rig.send_info()
    assert rig.send(0, frame_msg(0), boosted_msg(generator, 0)) is not None
    for k in (1, 2):
        rig.image_pub.publish(frame_msg(k))
    assert rig.send(3, frame_msg(3), boosted_msg(generator, 3)) is not None
    assert rig.node.counters["skipped"] == 2 and rig.node.counters["without_hypotheses"] == 0
    assert rig.status_of(1) is None and rig.status_of(2) is None


def test_hypotheses_whose_image_was_lost_are_skipped_not_dropped(ros, generator):
    """A tracker slower than its camera: the image queue keeps the newest frames, so the
    hypotheses of a frame whose image it never read come alone. Once a newer frame is complete
    they are counted as skipped; they were logged as dropped errors, 8 a landing replayed live."""
    rig = Rig(ros, Parameter("node.hypotheses_timeout_s", value=10.0))
    rig.send_info()
    assert rig.send(0, frame_msg(0), boosted_msg(generator, 0)) is not None
    rig.hyp_pub.publish(boosted_msg(generator, 1))
    assert ros.spin_until(lambda: rig.node.counters["hypotheses_received"] == 2)
    assert rig.send(2, frame_msg(2), boosted_msg(generator, 2)) is not None
    assert rig.node.counters["skipped"] == 1 and rig.node.counters["dropped"] == 0


def test_a_replay_started_again_restarts_the_track(ros, generator):
    rig = Rig(ros)
    rig.send_info()
    rig.track_a_first_run(generator)
    late = frame_msg(3)
    late.header.stamp.sec += 4  # 1 s behind the last: out of order, dropped
    assert rig.send(3, late) is None and "is not after the last tracked frame" in rig.node.last_error
    for k in range(3, 6):  # 5 s behind: a new time-line, tracked from its first frame
        status = rig.send(k, frame_msg(k), boosted_msg(generator, k))
        assert status is not None and status.state != TrackerStatus.LOST
    assert rig.node.counters["tracked"] == 6 and ros.spin_until(lambda: rig.pose_of(5) is not None)
    assert rig.status_of(3).state == TrackerStatus.ACQUIRING  # the track restarted


def test_a_new_time_lines_hypotheses_that_come_before_its_image_are_kept(ros, generator):
    """They were dropped as having come after their frame (stamped behind the old time-line's
    last frame), and the restart emptied the cache: the first frame of a replay started again
    waited for them, then was tracked without them."""
    rig = Rig(ros)
    rig.send_info()
    rig.track_a_first_run(generator)
    dropped = rig.node.counters["dropped"]
    rig.hyp_pub.publish(boosted_msg(generator, 0))  # the new time-line: hypotheses first
    assert ros.spin_until(lambda: len(rig.node._cache) == 1)
    status = rig.send(0, frame_msg(0))
    assert status is not None and status.state == TrackerStatus.ACQUIRING  # a fresh track, from its hypotheses
    assert rig.node.counters["dropped"] == dropped and rig.node.counters["hypotheses_received"] == 4


def test_an_unusable_frame_never_restarts_the_track_and_a_restart_counts_what_it_drops(ros, generator):
    """A frame stamped far behind the last tracked one starts a new time-line. It used to do so
    before it was checked: a malformed image or one of the wrong size stamped 0 (a driver's
    glitch) restarted the track and emptied the cache, and the frame waiting there for its
    hypotheses was lost without being counted. Now such an image is dropped and nothing else
    changes; a real restart counts the stamps it abandons."""
    rig = Rig(ros)
    rig.send_info()

    def later(msg):  # the first run is stamped 5 s after the second
        msg.header.stamp.sec += 5
        return msg

    for k in range(3):
        rig.image_pub.publish(later(frame_msg(k)))
        rig.hyp_pub.publish(later(boosted_msg(generator, k)))
        assert ros.spin_until(lambda: rig.node.counters["tracked"] == k + 1)
    rig.image_pub.publish(later(frame_msg(3)))  # waits for its hypotheses
    assert ros.spin_until(lambda: len(rig.node._cache) == 1)
    bad_step = frame_msg(0)
    bad_step.step = 3
    wrong_size = image_msg(np.zeros((120, 160, 3), np.uint8), "rgb8", *stamp(0))
    for bad, why in ((bad_step, "step 3 is shorter than one row"), (wrong_size, "image is 160x120 but the calibration is 320x240")):
        dropped = rig.node.counters["dropped"]
        rig.image_pub.publish(bad)
        assert ros.spin_until(lambda: rig.node.counters["dropped"] == dropped + 1) and why in rig.node.last_error
    assert len(rig.node._cache) == 1 and rig.node._tracker.particles is not None
    rig.hyp_pub.publish(later(boosted_msg(generator, 3)))
    assert ros.spin_until(lambda: rig.node.counters["tracked"] == 4)
    assert rig.status[-1].state == TrackerStatus.TRACKING  # the same track
    rig.image_pub.publish(later(frame_msg(4)))  # waits for its hypotheses, then the replay starts again
    assert ros.spin_until(lambda: len(rig.node._cache) == 1)
    dropped = rig.node.counters["dropped"]
    rig.image_pub.publish(frame_msg(0))
    rig.hyp_pub.publish(boosted_msg(generator, 0))
    assert ros.spin_until(lambda: rig.status_of(0) is not None) and rig.status_of(0).state == TrackerStatus.ACQUIRING
    assert rig.node.counters["dropped"] == dropped + 1 and "1 stamp(s) of the old time-line" in rig.node.last_error


def test_a_malformed_stamp_is_dropped_before_it_can_shift_the_time_line(ros, generator):
    """A stamp with nanosec >= 1e9 is malformed. Read as a time, (s, 1.5e9 ns) is 1.4 s after
    the frames around it: tracked, it made the tracker drop every valid frame of the next 1.4 s as
    out of order. Every node drops such a message before its callback (``LandingNode``)."""
    rig = Rig(ros)
    rig.send_info()
    for k in range(3):
        assert rig.send(k, frame_msg(k), boosted_msg(generator, k)) is not None
    image, hyps = frame_msg(3), boosted_msg(generator, 3)
    for msg in (image, hyps):
        msg.header.stamp.nanosec += 1_500_000_000
    dropped = rig.node.counters["dropped"]
    rig.image_pub.publish(image)
    rig.hyp_pub.publish(hyps)
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == dropped + 2)
    assert "header stamp" in rig.node.last_error and "is malformed (nanosec must be below 1000000000)" in rig.node.last_error
    assert rig.node.counters["tracked"] == 3 and rig.node.counters["received"] == 3
    for k in range(4, 6):
        status = rig.send(k, frame_msg(k), boosted_msg(generator, k))
        assert status is not None and status.state == TrackerStatus.TRACKING


def test_frames_resuming_after_a_gap_longer_than_the_prediction_restart_the_track(ros, generator):
    """The camera stalls for 5 s: the core predicts at most MAX_PREDICTION_STEPS Δt (~2 s) ahead,
    so the carried particles are not of the resumed frame's time. Its status must not say
    TRACKING on them (the GCS bridge would guide on that pose): the track restarts."""
    rig = Rig(ros)
    rig.send_info()
    states = [rig.send(k, frame_msg(k), boosted_msg(generator, k)).state for k in range(5)]
    assert states[-1] == TrackerStatus.TRACKING, states

    def restamped(msg, k):  # frame k's pixels at a later frame's stamp
        msg.header.stamp.sec, msg.header.stamp.nanosec = stamp(k)
        return msg

    status = rig.send(160, restamped(frame_msg(5), 160))  # 5.1 s on; no hypotheses: tracked by prediction
    assert status is not None and status.state == TrackerStatus.LOST and rig.pose_of(160) is None
    status = rig.send(161, restamped(frame_msg(6), 161), restamped(boosted_msg(generator, 6), 161))
    assert status.state == TrackerStatus.ACQUIRING and ros.spin_until(lambda: rig.pose_of(161) is not None)


def test_a_frame_dropped_for_want_of_calibration_says_why_the_camera_info_was_refused(ros):
    rig = Rig(ros, Parameter("node.cache_size", value=1))
    rig.info_pub.publish(camera_info_msg(dataclasses.replace(CAMERA, dist=np.array([-0.2, 0.05, 0.0, 0.0, 0.0]))))
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == 1)
    for k in range(2):
        rig.image_pub.publish(frame_msg(k))
        rig.hyp_pub.publish(hypotheses_msg(k))
    assert ros.spin_until(lambda: rig.node.counters["dropped"] == 2)
    assert "no camera/camera_info_rect (the latest camera_info was refused: plumb_bob distortion [-0.2" in rig.node.last_error


def test_a_calibration_it_cannot_use_is_dropped_and_the_last_one_kept(ros, generator, monkeypatch):
    rig = Rig(ros)
    rig.send_info()
    first = rig.node._renderer
    first_vbo = first._vbo

    def send(camera):
        dropped = rig.node.counters["dropped"]
        rig.info_pub.publish(camera_info_msg(camera))
        assert ros.spin_until(lambda: rig.node.counters["dropped"] > dropped or rig.node._renderer is not first)

    other = dataclasses.replace(CAMERA, K=CAMERA.K + np.diag([1.0, 1.0, 0.0]))
    real_renderer = tracker_node.Renderer

    def no_framebuffer(*args, **kwargs):
        raise moderngl.Error("the framebuffer is not complete")

    monkeypatch.setattr(tracker_node, "Renderer", no_framebuffer)
    send(other)
    assert "cannot render at" in rig.node.last_error and rig.node._renderer is first
    wide = camera_info_msg(CAMERA)
    wide.width = 20000
    dropped = rig.node.counters["dropped"]
    rig.info_pub.publish(wide)
    assert ros.spin_until(lambda: rig.node.counters["dropped"] > dropped)
    assert "1..16384 px" in rig.node.last_error
    assert rig.send(0, frame_msg(0), boosted_msg(generator, 0)).state != TrackerStatus.LOST  # still tracking
    monkeypatch.setattr(tracker_node, "Renderer", real_renderer)
    send(other)  # the same calibration, tried again, now taken; the old renderer's GL objects are freed
    assert rig.node._renderer is not first and type(first_vbo.mglo).__name__ == "InvalidObject"


@pytest.mark.parametrize(
    "override, message",
    [
        (Parameter("variant", value="C9"), "variant must be one of"),
        (Parameter("node.hypotheses_timeout_s", value=0.0), "need hypotheses_timeout_s > 0"),
        (Parameter("node.overlay", value="yes"), "node.overlay: expected bool"),
        (Parameter("node.colour", value=1), r"unknown key\(s\) \['colour'\]"),
        # Each passed start-up before: the renderer refused every calibration later (the tracker
        # up, never tracking), or the first squared noise overflowed in a callback.
        (Parameter("tile", value=2048), "tile must be 16 to 1024 px"),
        # 65536 px wide: beyond any GL's limit (NVIDIA's is 32768)
        (Parameter("refine.candidates", value=10**6),
         r"silhouette atlas .* exceeds .*; lower particles \(100\), refine.candidates \(1000000\) or tile"),
        (Parameter("motion.position_process_std", value=1e200), "position_process_std must be positive and at most"),
        (Parameter("covariance_floor_m", value=1e200), "covariance_floor_m must be within 0 to 1000"),
        (Parameter("pfo.noise_trans_sigma_m", value=[1e20, 0.1, 0.2]), "noise_trans_sigma_m must be positive and at most"),
        (Parameter("refine.sigma_deg", value=[1e155]), r"sigma_deg must be non-empty and within \(0, 180\]"),
        (Parameter("motion.dt", value=1e155), "dt must be positive and at most 10 s"),
        (Parameter("motion.ukf_beta", value=1e60), "beta and kappa must be within 0 to 100"),
    ],
)
def test_bad_parameters_fail_start_up(ros, override, message):
    with pytest.raises(ConfigError, match=message):
        TrackerNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)], parameter_overrides=[override])


def test_a_renderer_that_fails_its_self_test_fails_start_up(ros, shift_rasterisation):
    """An OpenGL that draws the silhouettes a quarter of a tile pixel off (another pixel-centre rule)."""
    shift_rasterisation(0.25)
    with pytest.raises(ConfigError, match="OpenGL: this machine's OpenGL draws the UAV unlike the reference: FAILED"):
        TrackerNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)])


# Callbacks called directly (no DDS traffic, no camera): a replay started again drops the old
# time-line's waiting stamps only, not the new one's.


@pytest.fixture
def node(ros):
    return ros.add(TrackerNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
                               parameter_overrides=[Parameter("particles", value=M), Parameter("boosted", value=M - M0)]))


def _hypotheses(ns: int) -> PoseHypotheses:
    """One pose 20 m ahead, stamped ``ns``."""
    msg = hypotheses_msg(0, [([0.0, 0.0, 20.0], [0.0, 0.0, 0.0, 1.0])])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, NS)
    return msg


def _image(ns: int) -> Image:
    return image_msg(np.zeros((4, 6, 3), np.uint8), "rgb8", *divmod(ns, NS))


def test_a_new_time_line_drops_the_old_ones_waiting_stamps_and_keeps_its_own_that_came_first(node):
    node._last_stamp = 100 * NS  # the old time-line's last tracked frame
    node._on_hypotheses(_hypotheses(100 * NS + 33_000_000))  # the old time-line's next, its image never came
    node._on_hypotheses(_hypotheses(1 * NS + 33_000_000))  # the new time-line's second frame, early
    assert len(node._cache) == 2 and node.counters["dropped"] == 0
    node._on_image(_image(1 * NS))  # the new time-line's first frame: 99 s behind, a restart
    assert node._last_stamp == -1
    assert node.counters["dropped"] == 1 and "1 stamp(s) of the old time-line" in node.last_error
    assert sorted(node._cache._entries) == [1 * NS, 1 * NS + 33_000_000]


def test_an_image_stamped_as_the_last_tracked_frame_is_dropped_at_once(node):
    node._last_stamp = 5 * NS
    node._on_image(_image(5 * NS))
    assert node.counters["dropped"] == 1 and "is not after the last tracked frame" in node.last_error
    assert len(node._cache) == 0


def test_malformed_hypotheses_leave_their_frame_to_be_tracked_by_prediction_at_once(node):
    bad = _hypotheses(2 * NS)
    bad.poses[0].orientation.w = 2.0  # not a unit quaternion
    node._on_hypotheses(bad)
    assert node.counters["dropped"] == 1 and "uav/pose_hypotheses rejected" in node.last_error
    assert node._cache._entries[2 * NS].items == {"hypotheses": None}  # the frame's pair: no hypotheses
    node._on_image(_image(2 * NS))  # completes at once: held for the calibration, not waiting for a timeout
    assert len(node._cache) == 0 and len(node._uncalibrated) == 1
    assert node._uncalibrated[0][2] is None


def test_of_frames_expiring_together_only_the_newest_is_tracked_the_older_are_skipped(node, monkeypatch):
    for k in range(3):
        node._on_image(_image(3 * NS + k * 33_000_000))
    assert len(node._cache) == 3
    now = sync.time.monotonic()
    monkeypatch.setattr(sync.time, "monotonic", lambda: now + 60.0)  # all three waited past the timeout
    node._on_deadline()
    assert node.counters["skipped"] == 2 and node.counters["without_hypotheses"] == 1
    assert [f[0].header.stamp.nanosec for f in node._uncalibrated] == [66_000_000]  # held for the calibration
