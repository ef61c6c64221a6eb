"""``bag_player`` in-process over DDS: timed and paced playback, /clock, and bad bags or parameters;
also its replay order, pacing by header stamp, timed rate, readiness and settle time, played in the test's thread."""

import threading

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PointStamped, PoseStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import CompressionMode, StoragePlugin, Writer
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image
from test_node_common import SMALL_CAMERA, frame_entries, participant_of, ros, write_bag  # noqa: F401 (fixture)

from uav_landing_vision.config import ConfigError
from uav_landing_vision.nodes import bag_player as bag_player_module
from uav_landing_vision.nodes.base import LINKS_KEY, LandingNode
from uav_landing_vision.nodes.bag_player import FRAME_LAG_NS, BagPlayer, BagPlayerConfig
from uav_landing_vision.nodes.qos import RELIABLE_QOS, IMAGE_QOS
from uav_landing_vision.stamps import stamp_ns

FRAMES = 5


def _truth(t_ns: int, z: float = 0.0):
    """A bag entry of /uav/ground_truth stamped and recorded at ``t_ns``."""
    truth = PoseStamped()
    truth.header.stamp.sec, truth.header.stamp.nanosec = divmod(t_ns, 1_000_000_000)
    truth.pose.position.z = z
    return ("/uav/ground_truth", "geometry_msgs/msg/PoseStamped", t_ns, truth)


def _bag(tmp_path, storage=StoragePlugin.MCAP, frames=FRAMES, extra=(), compression=None):
    entries = frame_entries(SMALL_CAMERA, frames)
    entries += [_truth(t, 50.0 - i) for i, (_, _, t, _) in enumerate(entries[::2])]
    entries = sorted(entries + list(extra), key=lambda e: e[2])  # stable: image before camera_info
    return write_bag(tmp_path / "bag", entries, storage, compression)


class Playback:
    """A BagPlayer playing in a thread with its own executor, as its main() would."""

    def __init__(self, ros, bag, cli_args=None, **params):
        overrides = [Parameter("bag", value=str(bag))] + [Parameter(k, value=v) for k, v in params.items()]
        self.node = BagPlayer(context=ros.context, cli_args=cli_args, parameter_overrides=overrides)
        self.executor = SingleThreadedExecutor(context=ros.context)
        self.executor.add_node(self.node)
        self.result = None
        self._thread = threading.Thread(target=self._play)

    def _play(self):
        self.result = self.node.play(self.executor)

    def start(self):
        self._thread.start()
        return self

    def done(self) -> bool:
        return not self._thread.is_alive()

    def close(self):
        self._thread.join(timeout=60)
        self.executor.shutdown()
        self.node.destroy_node()


def acknowledge_every_frame(ros, playback, frames, ack_pub) -> list:
    """Acknowledge each frame as it comes until the playback ends; the frames acknowledged."""
    acked = []

    def step():
        for frame in frames[len(acked):]:
            ack_pub.publish(PoseStamped(header=frame.header))
            acked.append(frame)
        return playback.done()

    assert ros.spin_until(step)
    return acked


@pytest.fixture
def playbacks():
    started = []
    yield started
    for playback in started:
        playback.close()


@pytest.mark.parametrize("storage, compression", [
    (StoragePlugin.MCAP, None), (StoragePlugin.SQLITE3, None), (StoragePlugin.MCAP, CompressionMode.FILE),
    (StoragePlugin.SQLITE3, CompressionMode.MESSAGE), (StoragePlugin.MCAP, CompressionMode.STORAGE),
], ids=["mcap", "sqlite3", "mcap-zstd-file", "sqlite3-zstd-message", "mcap-zstd-chunks"])
def test_timed_playback_publishes_every_topic_with_its_type_and_the_clock(ros, playbacks, tmp_path, storage, compression):
    images = ros.collect(Image, "/camera/image_raw", IMAGE_QOS)
    infos = ros.collect(CameraInfo, "/camera/camera_info", IMAGE_QOS)
    truths = ros.collect(PoseStamped, "/uav/ground_truth", RELIABLE_QOS)
    clocks = ros.collect(Clock, "/clock", RELIABLE_QOS)
    playback = Playback(
        ros, _bag(tmp_path, storage, compression=compression), mode="timed", rate=2.0, clock=True,
        ready_topics=["/camera/image_raw", "/camera/camera_info", "/uav/ground_truth", "/clock"],
    )
    playbacks.append(playback.start())
    assert ros.spin_until(lambda: playback.done() and len(truths) == FRAMES and len(images) == FRAMES)
    assert playback.result == 0
    stamps = [1_000_000_000 + i * 33_000_000 for i in range(FRAMES)]
    assert [stamp_ns(m.header.stamp) for m in truths] == stamps
    assert [m.pose.position.z for m in truths] == [50.0 - i for i in range(FRAMES)]
    assert [stamp_ns(m.header.stamp) for m in images] == stamps
    assert ros.spin_until(lambda: len(infos) == FRAMES)
    assert ros.spin_until(lambda: len(clocks) == 3 * FRAMES)  # one per message
    assert stamp_ns(clocks[-1].clock) == stamps[-1]
    assert playback.node.counters["published"] == 3 * FRAMES
    # The frames leave from a DDS participant of their own: sharing one with them, ground truths
    # were lost in paced replays of the graph (participant.py).
    frames_from = participant_of(ros.probe, "/camera/image_raw")
    assert frames_from not in {participant_of(ros.probe, topic) for topic in ("/camera/camera_info", "/uav/ground_truth", "/clock")}


def test_within_one_timestamp_the_frame_comes_after_its_camera_info(ros, tmp_path):
    bag = write_bag(tmp_path / "bag", frame_entries(SMALL_CAMERA, 3, image_first=True))
    node = ros.add(BagPlayer(context=ros.context, parameter_overrides=[Parameter("bag", value=str(bag))]))
    topics = [item[0].topic for item in node._messages()]
    assert topics == ["/camera/camera_info", "/camera/image_raw"] * 3


def test_a_frames_camera_info_and_truth_recorded_after_it_are_played_before_it(ros, playbacks, tmp_path):
    """``ros2 bag record`` stamps each message with its receive time: a camera driver's
    camera_info, published after its image, is recorded a little later. It is played before
    its image (undistort dropped the first frame: "image before any camera_info"), with
    the frame's ground truth; a message stamped otherwise stays after it, and /clock never goes back."""
    entries = []
    for i, (image, info) in enumerate(zip(*[iter(frame_entries(SMALL_CAMERA, 3))] * 2)):
        truth = PoseStamped(header=image[3].header)
        other = PointStamped()
        other.header.stamp.sec = 7
        t = image[2]
        entries += [image, ("/other", "geometry_msgs/msg/PointStamped", t + 1_000, other),
                    (info[0], info[1], t + 2_000, info[3]), ("/uav/ground_truth", "geometry_msgs/msg/PoseStamped", t + 3_000, truth)]
    bag = write_bag(tmp_path / "bag", entries)
    node = ros.add(BagPlayer(context=ros.context, parameter_overrides=[Parameter("bag", value=str(bag))]))
    topics = [item[0].topic for item in node._messages()]
    assert topics == ["/camera/camera_info", "/uav/ground_truth", "/camera/image_raw", "/other"] * 3
    clocks = ros.collect(Clock, "/clock", RELIABLE_QOS)
    playback = Playback(ros, bag, mode="timed", rate=1000.0, clock=True, ready_topics=["/clock"])
    playbacks.append(playback.start())
    assert ros.spin_until(lambda: playback.done() and len(clocks) == len(entries))
    stamps = [stamp_ns(c.clock) for c in clocks]
    assert stamps == sorted(stamps) and stamps[-1] == entries[-1][2]


@pytest.mark.parametrize("rules", [
    ["/deck_cam/image_raw:=/camera/image_raw", "/deck_cam/camera_info:=/camera/camera_info"],  # the bag onto the graph
    ["/camera/image_raw:=/deck_cam/image_raw", "/camera/camera_info:=/deck_cam/camera_info"],  # the graph onto the bag
], ids=["bag-onto-graph", "graph-onto-bag"])
def test_a_bag_of_other_topic_names_plays_paced_under_remapping(ros, playbacks, tmp_path, rules):
    """The default pace_topic and ready_topics (the graph's names) are resolved through the
    node's remapping rules, as its publishers are."""
    entries = [(topic.replace("/camera/", "/deck_cam/"), *rest) for topic, *rest in frame_entries(SMALL_CAMERA, FRAMES)]
    published = rules[0].split(":=")[1]
    frames = ros.collect(Image, published, IMAGE_QOS)
    infos = ros.collect(CameraInfo, published.replace("image_raw", "camera_info"), IMAGE_QOS)
    ack_pub = ros.probe.create_publisher(PoseStamped, "test/ack", RELIABLE_QOS)
    playback = Playback(ros, write_bag(tmp_path / "bag", entries), cli_args=["--ros-args", *[a for r in rules for a in ("-r", r)]],
                        mode="paced", ack_topic="test/ack", ack_type="geometry_msgs/msg/PoseStamped",
                        ready_topics=["/camera/image_raw", "/camera/camera_info"])
    playbacks.append(playback.start())
    acked = acknowledge_every_frame(ros, playback, frames, ack_pub)
    assert playback.result == 0 and len(acked) == FRAMES and playback.node.counters["ack_timeouts"] == 0
    assert ros.spin_until(lambda: len(infos) == FRAMES)


def test_paced_playback_publishes_a_frame_only_after_the_previous_one_is_acknowledged(ros, playbacks, tmp_path):
    """The probe holds back the acknowledgement of frame 2 until the player has reported on
    /diagnostics once more (the player spins ~1 s meanwhile): frame 3 must not come before it."""
    frames = ros.collect(Image, "/camera/image_raw", IMAGE_QOS)
    reports = ros.collect(DiagnosticArray, "/diagnostics", RELIABLE_QOS)
    ack_pub = ros.probe.create_publisher(PoseStamped, "test/ack", RELIABLE_QOS)
    playback = Playback(ros, _bag(tmp_path), mode="paced", ack_topic="test/ack", ack_type="geometry_msgs/msg/PoseStamped", ack_timeout_s=60.0)
    playbacks.append(playback.start())
    acked = []
    held = {}

    def step():
        assert len(frames) <= len(acked) + 1, "a frame was published before the previous one was acknowledged"
        if len(frames) > len(acked):
            frame = frames[len(acked)]
            if len(acked) == 2 and held.setdefault("reports", len(reports)) == len(reports):
                return playback.done()  # hold the ack until the next diagnostics report
            ack = PoseStamped(header=frame.header)
            ack_pub.publish(ack)
            acked.append(stamp_ns(frame.header.stamp))
        return playback.done()

    assert ros.spin_until(step)
    assert playback.result == 0
    assert acked == [1_000_000_000 + i * 33_000_000 for i in range(FRAMES)]
    assert (playback.node.counters["acknowledged"], playback.node.counters["ack_timeouts"]) == (FRAMES, 0)


def test_paced_playback_holds_the_next_frames_camera_info_and_truth_until_the_ack(ros, playbacks, tmp_path):
    """While frame 0 waits for its acknowledgement (held over one more /diagnostics report), the
    camera_info and ground truth recorded with frame 1 stay back: a node that takes the latest
    camera_info would otherwise rectify frame 0 with frame 1's calibration."""
    frames = ros.collect(Image, "/camera/image_raw", IMAGE_QOS)
    infos = ros.collect(CameraInfo, "/camera/camera_info", IMAGE_QOS)
    truths = ros.collect(PoseStamped, "/uav/ground_truth", RELIABLE_QOS)
    reports = ros.collect(DiagnosticArray, "/diagnostics", RELIABLE_QOS)
    ack_pub = ros.probe.create_publisher(PoseStamped, "test/ack", RELIABLE_QOS)
    playback = Playback(ros, _bag(tmp_path), mode="paced", ack_topic="test/ack", ack_type="geometry_msgs/msg/PoseStamped",
                        ack_timeout_s=60.0, ready_topics=["/camera/camera_info", "/uav/ground_truth"])
    playbacks.append(playback.start())
    assert ros.spin_until(lambda: len(frames) == 1)
    held = len(reports)
    assert ros.spin_until(lambda: len(reports) > held)  # the player has spun a second or so meanwhile
    assert (len(infos), len(truths)) == (1, 1)
    acked = acknowledge_every_frame(ros, playback, frames, ack_pub)
    assert playback.result == 0 and len(acked) == FRAMES
    assert ros.spin_until(lambda: len(infos) == FRAMES and len(truths) == FRAMES)


def test_paced_playback_publishes_the_clock_again_while_a_frame_waits(ros, playbacks, tmp_path):
    """Nodes take /clock best effort (rclpy's time source): with one /clock per message, a lost one
    left the GCS bridge's clock two frames behind the poses of a replay, which it then dropped as
    ahead of its clock. While frame 0 waits (held over one more /diagnostics report, about 1 s),
    its bag time goes out again and again; /clock never goes past it."""
    frames = ros.collect(Image, "/camera/image_raw", IMAGE_QOS)
    clocks = ros.collect(Clock, "/clock", RELIABLE_QOS)
    reports = ros.collect(DiagnosticArray, "/diagnostics", RELIABLE_QOS)
    ack_pub = ros.probe.create_publisher(PoseStamped, "test/ack", RELIABLE_QOS)
    playback = Playback(ros, _bag(tmp_path), mode="paced", clock=True, ack_topic="test/ack",
                        ack_type="geometry_msgs/msg/PoseStamped", ack_timeout_s=60.0, ready_topics=["/clock"])
    playbacks.append(playback.start())
    assert ros.spin_until(lambda: len(frames) == 1)
    held = len(reports)
    assert ros.spin_until(lambda: len(reports) > held)
    first = stamp_ns(frames[0].header.stamp)
    assert len(clocks) >= 5 and {stamp_ns(c.clock) for c in clocks} == {first}
    acknowledge_every_frame(ros, playback, frames, ack_pub)
    stamps = [stamp_ns(c.clock) for c in clocks]
    assert stamps == sorted(stamps) and stamps[-1] == stamp_ns(frames[-1].header.stamp)


def test_paced_playback_goes_on_after_an_ack_timeout(ros, playbacks, tmp_path):
    frames = ros.collect(Image, "/camera/image_raw", IMAGE_QOS)
    ack_pub = ros.probe.create_publisher(PoseStamped, "test/ack", RELIABLE_QOS)
    playback = Playback(ros, _bag(tmp_path), mode="paced", ack_topic="test/ack", ack_type="geometry_msgs/msg/PoseStamped", ack_timeout_s=0.5)
    playbacks.append(playback.start())
    acked = set()

    def step():
        for i, frame in enumerate(frames):
            if i != 1 and i not in acked:  # frame 1 is never acknowledged
                ack_pub.publish(PoseStamped(header=frame.header))
                acked.add(i)
        return playback.done()

    assert ros.spin_until(step)
    assert playback.result == 0 and len(frames) == FRAMES
    assert (playback.node.counters["acknowledged"], playback.node.counters["ack_timeouts"]) == (FRAMES - 1, 1)
    assert "no acknowledgement of the frame stamped 1033000000 ns" in playback.node.last_error


def test_paced_playback_without_a_downstream_gives_up_with_exit_code_1(ros, tmp_path):
    node = ros.add(BagPlayer(context=ros.context, parameter_overrides=[
        Parameter("bag", value=str(_bag(tmp_path))), Parameter("mode", value="paced"), Parameter("ready_timeout_s", value=0.5),
    ]))
    assert node.play(ros.executor) == 1
    assert node.counters["published"] == 0


def test_undeserialisable_messages_and_uninstalled_types_are_skipped(ros, playbacks, tmp_path):
    garbage = ("/camera/image_raw", "sensor_msgs/msg/Image", 1_010_000_000, b"\x00\x01\x00\x00garbage")
    bag = _bag(tmp_path, extra=[garbage])
    with Writer(tmp_path / "custom", version=9) as writer:  # a type this machine does not have
        conn = writer.add_connection("/custom", "foo_msgs/msg/Bar", msgdef="int32 a\n", rihs01="RIHS01_" + "0" * 64)
        writer.write(conn, 1, b"\x00\x01\x00\x00\x07\x00\x00\x00")
    images = ros.collect(Image, "/camera/image_raw", IMAGE_QOS)
    truths = ros.collect(PoseStamped, "/uav/ground_truth", RELIABLE_QOS)
    playback = Playback(ros, bag, mode="timed", rate=2.0, ready_topics=["/camera/image_raw", "/uav/ground_truth"])
    playbacks.append(playback.start())
    assert ros.spin_until(lambda: playback.done() and len(truths) == FRAMES and len(images) == FRAMES)
    assert playback.result == 0 and playback.node.counters["dropped"] == 1
    assert "/camera/image_raw: message at 1010000000 ns does not deserialise" in playback.node.last_error
    custom = ros.add(BagPlayer(context=ros.context, parameter_overrides=[Parameter("bag", value=str(tmp_path / "custom"))]))
    assert custom.play(ros.executor) == 0 and custom.counters["published"] == 0


def test_a_message_of_a_malformed_header_stamp_is_skipped(ros, playbacks, tmp_path):
    """(0 s, 1.5e9 ns) would alias (1 s, 0.5e9 ns); every node drops it, so the player does not send it."""
    malformed = PoseStamped()
    malformed.header.stamp.sec, malformed.header.stamp.nanosec = 0, 1_500_000_000
    bag = _bag(tmp_path, extra=[("/uav/ground_truth", "geometry_msgs/msg/PoseStamped", 1_010_000_000, malformed)])
    truths = ros.collect(PoseStamped, "/uav/ground_truth", RELIABLE_QOS)
    playback = Playback(ros, bag, mode="timed", rate=2.0, ready_topics=["/uav/ground_truth"])
    playbacks.append(playback.start())
    assert ros.spin_until(lambda: playback.done() and len(truths) == FRAMES)
    assert playback.result == 0 and playback.node.counters["dropped"] == 1
    assert "/uav/ground_truth: message at 1010000000 ns: header stamp 0 s + 1500000000 ns is malformed" in playback.node.last_error
    assert all(t.header.stamp.nanosec < 1_000_000_000 for t in truths)


def test_a_second_type_recorded_on_a_topic_is_not_played(ros, playbacks, tmp_path):
    other = PointStamped()
    other.header.stamp.sec, other.point.x = 1, 7.0
    bag = _bag(tmp_path, extra=[("/uav/ground_truth", "geometry_msgs/msg/PointStamped", 1_010_000_000, other)])
    truths = ros.collect(PoseStamped, "/uav/ground_truth", RELIABLE_QOS)
    playback = Playback(ros, bag, mode="timed", rate=2.0, ready_topics=["/uav/ground_truth"])
    playbacks.append(playback.start())
    assert ros.spin_until(lambda: playback.done() and len(truths) >= FRAMES)
    assert playback.result == 0 and len(truths) == FRAMES and playback.node.counters["dropped"] == 0
    assert [t.pose.position.z for t in truths] == [50.0 - i for i in range(FRAMES)]


def test_missing_and_corrupt_bags_fail_start_up(ros, tmp_path):
    with pytest.raises(ConfigError, match="bag: '.*nothing' does not exist"):
        BagPlayer(context=ros.context, parameter_overrides=[Parameter("bag", value=str(tmp_path / "nothing"))])
    bag = _bag(tmp_path)
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[:200])
    with pytest.raises(ConfigError, match="is not a readable rosbag2 bag"):
        BagPlayer(context=ros.context, parameter_overrides=[Parameter("bag", value=str(bag))])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ConfigError, match="is not a readable rosbag2 bag.*metadata"):
        BagPlayer(context=ros.context, parameter_overrides=[Parameter("bag", value=str(tmp_path / "empty"))])
    cut_off = _bag(tmp_path / "zstd", compression=CompressionMode.FILE)  # rosbags: an EOFError, not its ReaderError
    packed = next(cut_off.glob("*.zstd"))
    packed.write_bytes(packed.read_bytes()[: packed.stat().st_size // 2])
    with pytest.raises(ConfigError, match="bag: '.*zstd/bag' is not a readable rosbag2 bag: .*end-of-stream"):
        BagPlayer(context=ros.context, parameter_overrides=[Parameter("bag", value=str(cut_off))])


@pytest.mark.parametrize(
    "params, message",
    [
        ({}, "bag: no bag given"),
        ({"mode": "fast"}, "mode: 'fast' is not one of"),
        ({"rate": 0.0}, "rate must be > 0"),
        ({"mode": "paced", "pace_topic": "/nope"}, "pace_topic: '/nope' is not a playable topic"),
        ({"mode": "paced", "pace_topic": "/uav/ground_truth", "ack_type": "std_msgs/msg/String"}, "ack_type: 'std_msgs/msg/String' is not an installed message type with a header"),
        ({"mode": "paced", "ack_type": "nope_msgs/msg/Nope"}, "ack_type: 'nope_msgs/msg/Nope'"),
        ({"mode": "paced", "ack_topic": "camera/image~rect"}, "ack_topic: 'camera/image~rect' is not a valid topic name: .*tilde"),
        ({"ready_topics": ["/camera/image_raw", "uav pose"]}, "ready_topics: 'uav pose' is not a valid topic name: .*alphanumerics"),
        ({"ready_nodes": ["tracker", "no/de"]}, "ready_nodes: 'no/de' is not a node name"),
    ],
)
def test_bad_parameters_fail_start_up(ros, tmp_path, params, message):
    if params:
        params = {"bag": str(_bag(tmp_path)), **params}
    with pytest.raises(ConfigError, match=message):
        BagPlayer(context=ros.context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])


# --- replay order, pacing, rate and readiness: played in the test's thread on the harness's executor ---

def _player(ros, bag, **params) -> BagPlayer:
    """A BagPlayer on the harness's executor: ``play(ros.executor)`` plays it in the test's thread."""
    overrides = [Parameter("bag", value=str(bag))] + [Parameter(k, value=v) for k, v in params.items()]
    return ros.add(BagPlayer(context=ros.context, parameter_overrides=overrides))


def order(node):
    return [(item[0].topic, item[1]) for item in node._messages()]


def test_a_message_recorded_at_the_frames_bag_time_goes_before_the_frame_whatever_its_stamp(ros, tmp_path):
    image = frame_entries(SMALL_CAMERA, 1)[0]
    t = image[2]
    other = PointStamped()
    other.header.stamp.sec = 7
    bag = write_bag(tmp_path / "bag", [image, ("/other", "geometry_msgs/msg/PointStamped", t, other)])
    node = _player(ros, bag)
    assert order(node) == [("/other", t), ("/camera/image_raw", t)]


def test_a_camera_info_recorded_up_to_the_frame_lag_after_its_frame_goes_before_it(ros, tmp_path):
    image, (topic, type_name, t, info) = frame_entries(SMALL_CAMERA, 1)
    bag = write_bag(tmp_path / "bag", [image, (topic, type_name, t + FRAME_LAG_NS, info),
                                       (topic, type_name, t + FRAME_LAG_NS + 1, info)])
    node = _player(ros, bag)
    assert order(node) == [("/camera/camera_info", t + FRAME_LAG_NS), ("/camera/image_raw", t),
                           ("/camera/camera_info", t + FRAME_LAG_NS + 1)]


def test_paced_frames_are_acknowledged_by_their_header_stamp_not_their_recording_time(ros, tmp_path):
    """A recorder receives each frame after its camera took it: bag time = header stamp + 20 ms.
    The acknowledgement (the tracker's status) carries the header stamp."""
    frames = 4
    entries = [(topic, type_name, t + 20_000_000, msg)
               for topic, type_name, t, msg in frame_entries(SMALL_CAMERA, frames, image_first=False)]
    node = _player(ros, write_bag(tmp_path / "bag", entries), mode="paced", ack_topic="test/ack",
                   ack_type="geometry_msgs/msg/PoseStamped", ack_timeout_s=0.3)
    node._missing = lambda: []
    frames_pub = node._players["/camera/image_raw"]
    real_publish = frames_pub.publish
    sent = []

    def publish_and_ack(raw):  # the downstream acknowledges at once
        real_publish(raw)
        msg = deserialize_message(raw, Image)
        sent.append(stamp_ns(msg.header.stamp))
        node._on_ack(PoseStamped(header=msg.header))

    frames_pub.publish = publish_and_ack
    assert node.play(ros.executor) == 0
    assert sent == [1_000_000_000 + i * 33_000_000 for i in range(frames)]
    assert (node.counters["acknowledged"], node.counters["ack_timeouts"]) == (frames, 0)


def test_timed_playback_spaces_the_messages_by_their_bag_time_divided_by_the_rate(ros, tmp_path, monkeypatch):
    times = [1_000_000_000, 1_100_000_000, 1_400_000_000, 2_000_000_000]
    bag = write_bag(tmp_path / "bag", [_truth(t) for t in times])
    deadlines = []
    monkeypatch.setattr(bag_player_module, "_spin_until", lambda executor, deadline: deadlines.append(deadline))
    node = _player(ros, bag, mode="timed", rate=4.0)
    assert node.play(ros.executor) == 0
    played = deadlines[-len(times):]  # after the ready settle time
    assert [d - played[0] for d in played] == pytest.approx([(t - times[0]) * 1e-9 / 4.0 for t in times], abs=1e-6)


def test_a_ready_topic_with_a_subscriber_but_no_publisher_is_not_ready(ros, tmp_path):
    bag = write_bag(tmp_path / "bag", [_truth(1_000_000_000)])
    node = _player(ros, bag, ready_topics=["/only_listened", "/uav/ground_truth"])
    ros.collect(PoseStamped, "/only_listened", RELIABLE_QOS)
    ros.collect(PoseStamped, "/uav/ground_truth", RELIABLE_QOS)
    assert ros.spin_until(lambda: node.count_subscribers("/only_listened")
                          and node._players["/uav/ground_truth"].get_subscription_count())  # discovery
    assert node._missing() == ["publisher and subscriber of /only_listened"]


def test_progress_every_zero_is_a_valid_setting_and_a_zero_ack_timeout_is_not():
    assert BagPlayerConfig(bag="b", progress_every=0).progress_every == 0
    with pytest.raises(ValueError, match="ack_timeout_s and ready_timeout_s must be > 0"):
        BagPlayerConfig(bag="b", ack_timeout_s=0.0)
    with pytest.raises(ValueError, match="progress_every must be >= 0"):
        BagPlayerConfig(bag="b", progress_every=-1)


def test_a_paced_player_is_not_ready_until_its_acknowledgement_has_a_publisher(ros, tmp_path):
    bag = write_bag(tmp_path / "bag", frame_entries(SMALL_CAMERA, 1)[:1])  # one image
    node = _player(ros, bag, mode="paced", ack_topic="/test/ack", ack_type="geometry_msgs/msg/PoseStamped")
    ros.collect(Image, "/camera/image_raw", IMAGE_QOS)
    assert ros.spin_until(lambda: node._players["/camera/image_raw"].get_subscription_count())  # discovery
    assert node._missing() == ["publisher of /test/ack"]
    ros.probe.create_publisher(PoseStamped, "/test/ack", RELIABLE_QOS)
    assert ros.spin_until(lambda: node._ack_sub.get_publisher_count())
    assert node._missing() == []


class _Listener(LandingNode):
    """A graph node taking /uav/ground_truth."""

    def __init__(self, **kwargs):
        super().__init__("listener", **kwargs)
        self.create_subscription(PoseStamped, "/uav/ground_truth", lambda msg: None, RELIABLE_QOS)


def _diagnostics(node_name: str, links: str | None) -> DiagnosticArray:
    values = [KeyValue(key="received", value="0")] + ([] if links is None else [KeyValue(key=LINKS_KEY, value=links)])
    return DiagnosticArray(status=[DiagnosticStatus(name=f"/{node_name}", hardware_id=node_name, values=values)])


def test_a_ready_node_holds_the_player_until_its_own_links_on_ready_topics_are_up(ros, tmp_path):
    """The player sees its own links only: another node's is up when that node says DDS matched
    it with every peer it sees. Played over DDS with a real node, then each report by hand."""
    bag = write_bag(tmp_path / "bag", [_truth(1_000_000_000)])
    node = _player(ros, bag, ready_topics=["/uav/ground_truth"], ready_nodes=["listener", "peer"])
    assert node._missing() == ["subscriber of /uav/ground_truth", "/diagnostics from listener", "/diagnostics from peer"]
    ros.add(_Listener(context=ros.context))
    assert ros.spin_until(lambda: node._missing() == ["/diagnostics from peer"])
    assert ("sub", "/uav/ground_truth", 1, 1) in node._node_links["listener"]
    down = "match of peer's subscription /uav/ground_truth with every peer"
    node._on_diagnostics(_diagnostics("peer", "sub /uav/ground_truth 0/1; sub /elsewhere 0/1; pub /diagnostics 0/0"))
    assert node._missing() == [f"{down} (0 of 1)"]  # links off the ready topics do not count
    node._on_diagnostics(_diagnostics("peer", "sub /uav/ground_truth 0/0"))  # before it saw the player
    assert node._missing() == [f"{down} (0 of 0)"]
    node._on_diagnostics(_diagnostics("peer", None))
    assert node._missing() == ["links in the /diagnostics of peer (not a node of this graph?)"]
    node._on_diagnostics(_diagnostics("peer", "sub /uav/ground_truth one/1"))
    assert node.counters["dropped"] == 1 and "/diagnostics of peer: not a link" in node.last_error
    node._on_diagnostics(_diagnostics("peer", "sub /uav/ground_truth 1/1"))
    assert node._missing() == []
    assert node.play(ros.executor) == 0
    assert node.counters["published"] == 1 and node._diagnostics_sub is None  # needed no more


def test_a_bag_that_cannot_be_read_to_its_end_fails_the_playback(ros, tmp_path, monkeypatch):
    bag = write_bag(tmp_path / "bag", [_truth(t) for t in (1_000_000_000, 1_100_000_000)])
    real = bag_player_module.bag_messages

    def cut_off(reader):
        it = real(reader)
        yield next(it)
        raise bag_player_module.BagError("chunk 2: bad CRC")

    monkeypatch.setattr(bag_player_module, "bag_messages", cut_off)
    node = _player(ros, bag, mode="timed", rate=1000.0)
    assert node.play(ros.executor) == 1
    assert node.counters["published"] == 1


def test_once_ready_the_player_waits_its_settle_time_before_the_first_message(ros, tmp_path, monkeypatch):
    bag = write_bag(tmp_path / "bag", [_truth(1_000_000_000)])
    waits = []  # the seconds each spin was asked to wait, when asked
    monkeypatch.setattr(bag_player_module, "_spin_until",
                        lambda executor, deadline: waits.append(deadline - bag_player_module.time.monotonic()))
    node = _player(ros, bag, mode="timed", ready_settle_s=2.5)
    assert node.play(ros.executor) == 0
    assert len(waits) == 2 and waits[0] == pytest.approx(2.5, abs=0.5) and waits[1] == pytest.approx(0.0, abs=0.5)
