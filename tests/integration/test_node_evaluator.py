"""``evaluator``: poses matched to ground truth by stamp → the thesis-format report, when done
(frame count) in-process and on SIGINT as a process; lost frames and bad poses; estimates written in stamp order."""

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, PoseWithCovarianceStamped
from rclpy.duration import Duration
from rclpy.parameter import Parameter
from test_node_common import ros  # noqa: F401 (fixture)

from uav_landing_vision.config import ConfigError
from uav_landing_vision.nodes import evaluator as evaluator_node
from uav_landing_vision.nodes.evaluator import EvaluatorNode, run_until_done
from uav_landing_vision.nodes.poses import numpy_to_pose
from uav_landing_vision.nodes.qos import KEEP_ALL_QOS, RELIABLE_QOS
from uav_landing_vision.stamps import stamp_ns
from uav_landing_vision.sim import read_pose_csv

REPO = Path(__file__).parents[2]
PARAMS = REPO / "config" / "evaluator.yaml"
QUAT = np.array([0.0, 0.0, 0.0, 1.0])
REPORT_FILES = {"tables.txt", "translation_error.csv", "rotation_error.csv", "translation_error.png",
                "rotation_error.png", "summary.json", "estimates.csv"}


def truth_msg(k: int) -> PoseStamped:
    msg = PoseStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(1_000_000_000 + k * 33_000_000, 1_000_000_000)
    numpy_to_pose(msg.pose, [0.0, 0.0, 10.0 - k], QUAT)
    return msg


def pose_msg(k: int, error_m: float = 0.1, quat=QUAT, sigma=(0.0, 0.0)) -> PoseWithCovarianceStamped:
    """A pose ``error_m`` off the truth in x; covariance diag(σ_m², σ_rad²), zeros ("unknown") by default."""
    msg = PoseWithCovarianceStamped(header=truth_msg(k).header)
    numpy_to_pose(msg.pose.pose, [error_m, 0.0, 10.0 - k], quat)
    msg.pose.covariance = np.diag(np.repeat(np.square(sigma), 3)).ravel().tolist()
    return msg


class Rig:
    def __init__(self, ros, tmp_path, *overrides):
        self.ros = ros
        self.node = ros.add(EvaluatorNode(
            context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)],
            parameter_overrides=[Parameter("out_dir", value=str(tmp_path / "report")), Parameter("sequence", value="seq"),
                                 Parameter("variant", value="C4N2"), *overrides],
        ))
        self.truth_pub = ros.probe.create_publisher(PoseStamped, "uav/ground_truth", RELIABLE_QOS)
        self.pose_pub = ros.probe.create_publisher(PoseWithCovarianceStamped, "uav/pose", RELIABLE_QOS)
        assert ros.spin_until(lambda: self.truth_pub.get_subscription_count() and self.pose_pub.get_subscription_count())


def test_report_when_the_frame_count_is_reached_lost_frames_counted(ros, tmp_path):
    rig = Rig(ros, tmp_path, Parameter("frames", value=5), Parameter("settle_s", value=0.2))
    for k in range(5):
        rig.truth_pub.publish(truth_msg(k))
        if k != 2:  # frame 2: no pose, i.e. lost
            rig.pose_pub.publish(pose_msg(k, error_m=0.1 * (k + 1), sigma=(0.1, 0.01)))
    rig.pose_pub.publish(pose_msg(2, quat=[0.0, 0.0, 0.0, 2.0]))  # non-unit: dropped, stays lost
    rig.pose_pub.publish(pose_msg(4, error_m=9.0))  # a second pose for frame 4: dropped
    rig.pose_pub.publish(pose_msg(7))  # no ground truth for it: not scored
    assert run_until_done(rig.node, ros.executor) == 0
    node = rig.node
    assert (node.counters["received"], node.counters["truth_received"], node.counters["dropped"]) == (7, 5, 2)
    out = tmp_path / "report"
    assert {p.name for p in out.iterdir()} == REPORT_FILES
    summary = json.loads((out / "summary.json").read_text())
    assert summary["sequence"] == "seq" and summary["frames"] == 5
    c4 = summary["variants"]["C4N2"]
    assert c4["lost_frames_pct"] == pytest.approx(20.0) and c4["ms_per_frame"] is None
    assert c4["translation_m"]["mae"] == pytest.approx(np.mean([0.1, 0.2, 0.4, 0.5]))
    assert c4["rotation_deg"]["mae"] == pytest.approx(0.0, abs=1e-3)
    tables = (out / "tables.txt").read_text()
    assert "seq: translation error (m)" in tables
    by_depth = tables.split("median error by true depth")[1].split("\n\n")[0].splitlines()
    assert by_depth[-1].split()[0] == "all" and by_depth[-1].endswith("0.30 | 0.00 (4)")
    # 95 % region of 3 dof: NEES <= 7.81; position errors 0.1, 0.2 (inside) and 0.4, 0.5 m (outside) at σ 0.1 m
    coverage = {line.split()[0]: line.split()[-3:] for line in tables.split("95 % region")[1].split("\n\n")[0].splitlines()[2:]}
    assert coverage["0-8"] == ["0/2", "|", "2/2"] and coverage["8-15"] == ["2/2", "|", "2/2"]
    assert coverage["all"] == ["2/4", "|", "4/4"]
    assert len(read_pose_csv(out / "estimates.csv").stamps_ns) == 5  # frames 0, 1, 3, 4, 7
    assert "INCOMPLETE" not in tables
    # A replay's truth precedes its pose: a pose without one means a truth was lost, so the report names it.
    assert tables.rstrip().endswith(f"UNSCORED: 1 poses without ground truth, stamped (ns) {stamp_ns(truth_msg(7).header.stamp)}")


def test_a_report_of_fewer_frames_than_expected_says_so(ros, tmp_path):
    rig = Rig(ros, tmp_path, Parameter("frames", value=20))
    for k in range(3):
        rig.truth_pub.publish(truth_msg(k))
        rig.pose_pub.publish(pose_msg(k))
    assert ros.spin_until(lambda: rig.node.counters["truth_received"] == 3 and rig.node.counters["received"] == 3)
    out = rig.node.write()  # as on a shutdown before the sequence ended
    tables = (out / "tables.txt").read_text()
    assert tables.rstrip().endswith("INCOMPLETE: 3 of the 20 ground-truth frames expected were received")


def test_without_ground_truth_no_report(ros, tmp_path):
    rig = Rig(ros, tmp_path, Parameter("idle_timeout_s", value=0.1))
    assert not rig.node.done()  # the idle timeout counts from the first ground truth
    assert rig.node.write() is None and not (tmp_path / "report").exists()


def test_idle_timeout_ends_the_sequence(ros, tmp_path):
    rig = Rig(ros, tmp_path, Parameter("idle_timeout_s", value=0.2))
    rig.truth_pub.publish(truth_msg(0))
    assert ros.spin_until(lambda: rig.node.counters["truth_received"] == 1)
    assert run_until_done(rig.node, ros.executor) == 0
    summary = json.loads((tmp_path / "report" / "summary.json").read_text())
    assert summary["frames"] == 1 and summary["variants"]["C4N2"]["lost_frames_pct"] == 100.0


def test_a_publish_racing_the_shutdown_still_writes_the_report(ros, tmp_path):
    """Ctrl-C while a callback publishes (here /diagnostics): rclpy's RCLError left run_until_done
    and the report of the whole replay was lost."""
    rig = Rig(ros, tmp_path)
    rig.truth_pub.publish(truth_msg(0))
    assert ros.spin_until(lambda: rig.node.counters["truth_received"] == 1)

    def shut_down_then_publish():
        ros.context.shutdown()
        rig.node.publish_diagnostics()

    rig.node.create_timer(0.01, shut_down_then_publish)
    assert run_until_done(rig.node, ros.executor) == 0
    assert json.loads((tmp_path / "report" / "summary.json").read_text())["frames"] == 1


def test_sigint_writes_the_report_and_exits_cleanly(ros, ros_domain_id, tmp_path):
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain_id), PYTHONUNBUFFERED="1")
    log = tmp_path / "evaluator.log"
    proc = subprocess.Popen(
        [sys.executable, "-m", "uav_landing_vision.nodes.evaluator", "--ros-args", "--params-file", str(PARAMS),
         "-p", f"out_dir:={tmp_path / 'report'}"],
        env=env, stdout=log.open("w"), stderr=subprocess.STDOUT,
    )
    reports = ros.collect(DiagnosticArray, "/diagnostics", RELIABLE_QOS)

    def took_all(array: DiagnosticArray) -> bool:
        counters = {kv.key: kv.value for status in array.status if status.hardware_id == "evaluator" for kv in status.values}
        return counters.get("truth_received") == "3" and counters.get("received") == "3"

    try:
        truth_pub = ros.probe.create_publisher(PoseStamped, "uav/ground_truth", RELIABLE_QOS)
        pose_pub = ros.probe.create_publisher(PoseWithCovarianceStamped, "uav/pose", RELIABLE_QOS)
        assert ros.spin_until(lambda: (truth_pub.get_subscription_count() and pose_pub.get_subscription_count()) or proc.poll() is not None)
        for k in range(3):
            truth_pub.publish(truth_msg(k))
            pose_pub.publish(pose_msg(k))
        # Acknowledged is not yet taken: a SIGINT before the node's executor took a message loses
        # it (CI saw "3 ground-truth frames, 2 with a pose"). Its diagnostics say what it took.
        assert ros.spin_until(lambda: any(took_all(report) for report in reports) or proc.poll() is not None)
        proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    output = log.read_text()
    assert code == 0, output
    summary = json.loads((tmp_path / "report" / "summary.json").read_text())
    assert summary["frames"] == 3 and summary["variants"]["tracker"]["lost_frames_pct"] == 0.0, output
    assert "3 ground-truth frames, 3 with a pose" in output


def test_messages_that_come_while_the_node_is_busy_are_all_scored(ros, tmp_path):
    """DDS queues what arrives while the node does not spin (busy writing, or starved of CPU on a
    loaded machine; a timed replay at full speed sends a burst). The subscriptions kept the last
    10, so a longer stall lost ground truths and poses, i.e. frames scored as lost or not at all."""
    frames = 40
    rig = Rig(ros, tmp_path, Parameter("frames", value=frames), Parameter("settle_s", value=0.2),
              Parameter("idle_timeout_s", value=5.0))  # ends the run should ground truths be missing
    truth_pub = ros.probe.create_publisher(PoseStamped, "uav/ground_truth", KEEP_ALL_QOS)
    pose_pub = ros.probe.create_publisher(PoseWithCovarianceStamped, "uav/pose", KEEP_ALL_QOS)
    assert ros.spin_until(lambda: truth_pub.get_subscription_count() and pose_pub.get_subscription_count())
    for k in range(frames):  # nobody spins: all of it waits in the node's subscriptions
        truth_pub.publish(truth_msg(k))
        pose_pub.publish(pose_msg(k))
    for publisher in (truth_pub, pose_pub):
        assert publisher.wait_for_all_acked(Duration(seconds=10))
    assert run_until_done(rig.node, ros.executor) == 0
    assert (rig.node.counters["truth_received"], rig.node.counters["received"]) == (frames, frames)
    summary = json.loads((tmp_path / "report" / "summary.json").read_text())
    assert summary["frames"] == frames and summary["variants"]["C4N2"]["lost_frames_pct"] == 0.0


def test_poses_without_ground_truth_are_bounded(ros, tmp_path):
    """A live graph runs the evaluator too, and no ground truth ever comes: it kept every pose
    (about 1 KB each) for the whole run. Poses with their ground truth are all kept."""
    node = Rig(ros, tmp_path).node
    limit = evaluator_node.POSES_WITHOUT_TRUTH

    def stamped(msg, k: int):
        msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + k // 30, (k % 30) * 33_000_000
        return msg

    for k in range(limit + 50):
        node._on_pose(stamped(pose_msg(0), k))
    assert len(node.estimates) == len(node.covariances) == limit
    assert min(node.estimates) == stamp_ns(stamped(pose_msg(0), 50).header.stamp)  # the newest are kept
    node._on_truth(stamped(truth_msg(0), limit + 49))  # a late ground truth still finds its pose
    for k in range(limit + 50, 2 * limit + 100):
        node._on_truth(stamped(truth_msg(0), k))
        node._on_pose(stamped(pose_msg(0), k))
    assert len(node.estimates) == len(node.covariances) == 2 * limit + 50
    assert node.counters["poses_without_truth_dropped"] == 50
    frames = len(node.truth)
    report = node.write()
    summary = json.loads((report / "summary.json").read_text())
    assert summary["frames"] == frames and summary["variants"]["C4N2"]["lost_frames_pct"] == 0.0
    # The report counts the forgotten ones too (it said "300 poses" for 350).
    first_kept = stamp_ns(stamped(pose_msg(0), 50).header.stamp)
    assert f"UNSCORED: {limit + 49} poses without ground truth (the oldest 50 forgotten), stamped (ns) {first_kept}, " in (
        report / "tables.txt").read_text()


def test_poses_forgotten_before_their_ground_truth_came_are_reported(ros, tmp_path, monkeypatch):
    """Ground truth more than the kept poses behind: the forgotten poses' frames count as lost and
    the report said nothing of them once the poses it held had all met their truth."""
    monkeypatch.setattr(evaluator_node, "POSES_WITHOUT_TRUTH", 3)
    node = Rig(ros, tmp_path).node
    for k in range(5):
        node._on_pose(pose_msg(k))
    for k in range(5):
        node._on_truth(truth_msg(k))
    tables = (node.write() / "tables.txt").read_text()
    assert tables.rstrip().endswith("UNSCORED: 2 poses without ground truth (the oldest 2 forgotten)")


@pytest.mark.parametrize(
    "override, message",
    [
        (Parameter("frames", value=-1), "need frames >= 0"),
        (Parameter("out_dir", value=""), "out_dir, sequence and variant must not be empty"),
        (Parameter("topic", value="x"), r"unknown key\(s\) \['topic'\]"),
        # A folder that cannot be made failed only when the report was written, after the replay.
        (Parameter("out_dir", value=str(PARAMS / "report")), f"{PARAMS} is not a writable folder"),
    ],
)
def test_bad_parameters_fail_start_up(ros, override, message):
    with pytest.raises(ConfigError, match=message):
        EvaluatorNode(context=ros.context, cli_args=["--ros-args", "--params-file", str(PARAMS)], parameter_overrides=[override])


def test_the_estimates_of_messages_received_out_of_stamp_order_are_written_in_stamp_order(ros, tmp_path):
    """Messages that arrive out of stamp order (a replay started again), callbacks called directly."""
    node = Rig(ros, tmp_path).node
    order = [3, 1, 4, 0, 2]
    for k in order:
        node._on_truth(truth_msg(k))
    for k in order[::-1]:
        pose = PoseWithCovarianceStamped(header=truth_msg(k).header)
        numpy_to_pose(pose.pose.pose, [0.1 * k, 0.0, 10.0 + k], QUAT)
        node._on_pose(pose)
    out = node.write()
    estimates = read_pose_csv(out / "estimates.csv")
    expected = [1_000_000_000 + k * 33_000_000 for k in range(5)]
    assert estimates.stamps_ns.tolist() == expected
    np.testing.assert_allclose(estimates.trans[:, 0], [0.1 * k for k in range(5)])
    np.testing.assert_allclose(estimates.trans[:, 2], [10.0 + k for k in range(5)])
