"""``bag_player``: plays a rosbag2 bag (mcap or sqlite3) onto its recorded topics; exits when it ends.

Stands in for ``ros2 bag play`` where rosbag2 is not installed; reads with ``rosbags``. Every
message is checked by deserialising it with the installed message type, then its recorded
bytes are published unchanged. Images and camera_info go out with the graph's image QoS
(reliable, keep last 5), other topics reliable, keep last 10 (``qos.qos_for_type``); images
from a DDS participant of their own (``LandingNode.create_image_publisher``: sharing one with
them, ground truths were lost). Messages
go out in bag time order (the recorder's receive times; ``clock`` follows it), except that a
frame (``pace_topic`` message) goes after the messages recorded with it: those of its bag time
and, before the next frame and up to ``FRAME_LAG_NS`` later, those of its header stamp (a
driver's camera_info, received after its image). So a frame's camera_info precedes it.

Modes (parameter ``mode``):

- ``timed``: at the recorded rate times ``rate`` (``rate: 1000.0`` ≈ as fast as possible).
- ``paced``: each ``pace_topic`` message (the camera image) is published only once the
  previous one is acknowledged: a message on ``ack_topic`` (type ``ack_type``, any message
  with a header) carries its ``header.stamp``. The messages recorded after a frame (the next
  frame's camera_info and ground truth) wait for its acknowledgement too: a node that takes the
  latest camera_info never rectifies a frame with the next frame's calibration. The downstream
  then never has more than one frame in flight and drops none. After ``ack_timeout_s`` without
  it the frame counts as an ack timeout (logged, on ``/diagnostics``) and playback goes on.
  The default acknowledgement is ``camera/image_rect`` (undistort); ``ack_topic: uav/tracker_status`` with
  ``ack_type: uav_landing_msgs/msg/TrackerStatus`` paces on the whole pipeline (the tracker
  publishes one status per tracked frame, with its stamp, estimate or not).

Before playing, the player waits (up to ``ready_timeout_s``) until every topic of
``ready_topics`` has a subscriber and a publisher and, in paced mode, until ``pace_topic``
has a subscriber and ``ack_topic`` a publisher; then, for each node of ``ready_nodes``, until
its ``/diagnostics`` say that each of its links on a ready topic is up (DDS has matched it with
every peer the node sees: ``LandingNode.links``): the player sees only its own links, and a
message sent before DDS matched the two ends of another is lost to that peer, so a replay's
result would hang on discovery times. A paced player not ready by then exits with code 1.
``clock: true`` publishes the bag time on ``/clock`` before each message
(the latest so far: it never goes back) and again at least every ``SPIN_S`` while a paced frame
waits for its acknowledgement: nodes take ``/clock`` best effort (rclpy's time source), and one
lost message left a node's clock behind the frames it was given.
A missing or unreadable bag fails start-up (exit code 2).
"""

import importlib
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.duration import Duration
from rclpy.qos import ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.validate_node_name import validate_node_name
from rosbags.rosbag2 import Reader
from rosgraph_msgs.msg import Clock

from ..config import ConfigError
from ..sim.bag import BagError, bag_messages, open_bag
from ..stamps import header_stamp_ns, stamp_fields, stamp_ns
from .base import LINKS_KEY, LandingNode, parse_links, run_node
from .participant import IMAGE_TYPES
from .qos import RELIABLE_QOS, qos_for_type

SPIN_S = 0.1  # while a paced frame waits: how long each spin may wait, and how often /clock is published again
ACKED_FLUSH_TIMEOUT_S = 5.0  # at the end, how long reliable topics may take to be acknowledged
FRAME_LAG_NS = 500_000_000  # how much later than its frame a frame's camera_info or truth may be recorded


@dataclass(frozen=True)
class BagPlayerConfig:
    bag: str = ""  # rosbag2 directory, or a single .mcap / .db3 file
    mode: Literal["timed", "paced"] = "timed"
    rate: float = 1.0  # timed mode: speed factor on the recorded rate
    pace_topic: str = "/camera/image_raw"  # the frames' topic as published (remapping applies); paced: they wait for an ack
    ack_topic: str = "camera/image_rect"  # paced mode: the topic that acknowledges a frame by its stamp
    ack_type: str = "sensor_msgs/msg/Image"
    ack_timeout_s: float = 10.0
    ready_topics: tuple[str, ...] = ()
    ready_nodes: tuple[str, ...] = ()  # nodes whose links on ready_topics must be up (their /diagnostics)
    ready_timeout_s: float = 30.0
    ready_settle_s: float = 0.0  # then wait this long for the other processes to match each other
    clock: bool = False
    progress_every: int = 50  # log a line every this many pace-topic messages (0: never)

    def __post_init__(self):
        if not self.bag:
            raise ValueError("bag: no bag given (set the parameter 'bag', e.g. -p bag:=/path/to/bag)")
        if not self.rate > 0.0:
            raise ValueError(f"rate must be > 0, got {self.rate}")
        if not (self.ack_timeout_s > 0.0 and self.ready_timeout_s > 0.0):
            raise ValueError("ack_timeout_s and ready_timeout_s must be > 0")
        if self.ready_settle_s < 0.0:
            raise ValueError(f"ready_settle_s must be >= 0, got {self.ready_settle_s}")
        if self.progress_every < 0:
            raise ValueError(f"progress_every must be >= 0, got {self.progress_every}")


class BagPlayer(LandingNode):
    def __init__(self, **kwargs):
        super().__init__("bag_player", **kwargs)
        self.config = cfg = self.load_config(BagPlayerConfig)
        self._ready_topics = [_resolved(self, "ready_topics", topic) for topic in cfg.ready_topics]
        self._node_links = {}  # ready node -> its links from its latest /diagnostics
        self._diagnostics_sub = None
        if cfg.ready_nodes:
            for name in cfg.ready_nodes:
                _check_node_name(name)
            self._diagnostics_sub = self.create_subscription(DiagnosticArray, "/diagnostics", self._on_diagnostics, RELIABLE_QOS)
        self._reader = _open_bag(cfg.bag)
        self._players = {}
        self._played = set()  # ids of the connections whose messages are played
        self._clock_ns = 0  # the bag time last published on /clock
        self._pending = None  # stamp (ns) of the paced frame awaiting its acknowledgement
        self._acked = set()
        try:
            self._set_up(cfg)
        except ConfigError:
            self.destroy_node()  # the bag, the images' participant, the node
            raise
        topics = {c.topic: c.msgcount for c in self._reader.connections if c.topic in self._players}
        self.get_logger().info(f"bag {cfg.bag}: {self._reader.message_count} messages, topics {topics}, mode {cfg.mode}")

    def _set_up(self, cfg: BagPlayerConfig) -> None:
        """The publishers, the clock and (paced) the acknowledgement; :class:`ConfigError` if the
        bag cannot be paced as configured."""
        for conn in self._reader.connections:
            self._add_publisher(conn)
        self._pace = self._bag_topic(_resolved(self, "pace_topic", cfg.pace_topic))  # None: the bag has no frames
        self._clock_pub = self.create_publisher(Clock, "/clock", RELIABLE_QOS) if cfg.clock else None
        if cfg.mode == "paced":
            pace = self._players.get(self._pace)
            if pace is None:
                playable = sorted(f"{c.topic} [{c.msgtype}]" for c in self._reader.connections if c.id in self._played)
                raise ConfigError(f"pace_topic: '{cfg.pace_topic}' is not a playable topic of the bag (topics: {playable}); "
                                  f"to play a recording of other topic names remap them (-r /recorded/name:={cfg.pace_topic})")
            if "header" not in pace.msg_type.get_fields_and_field_types():
                raise ConfigError(f"pace_topic: '{cfg.pace_topic}' has no header to acknowledge")
            ack_cls = _message_class(cfg.ack_type)
            if ack_cls is None or "header" not in ack_cls.get_fields_and_field_types():
                raise ConfigError(f"ack_type: '{cfg.ack_type}' is not an installed message type with a header")
            ack_topic = _resolved(self, "ack_topic", cfg.ack_topic)
            self._ack_sub = self.create_subscription(ack_cls, ack_topic, self._on_ack, qos_for_type(cfg.ack_type))

    def _bag_topic(self, name: str) -> str | None:
        """The bag topic published as ``name`` (a resolved topic name: remapping applies), if any."""
        return next((topic for topic, publisher in self._players.items() if publisher.topic_name == name), None)

    def _add_publisher(self, conn) -> None:
        topic, type_name = conn.topic, conn.msgtype
        cls = _message_class(type_name)
        if cls is None:
            self.get_logger().warn(f"{topic}: message type {type_name} is not installed; topic not played")
            return
        if topic in self._players and self._players[topic].msg_type is not cls:
            self.get_logger().warn(f"{topic}: recorded with several types; {type_name} not played")
            return
        if topic not in self._players:
            create = self.create_image_publisher if type_name in IMAGE_TYPES else self.create_publisher
            self._players[topic] = create(cls, topic, qos_for_type(type_name))
        self._played.add(conn.id)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            if status.hardware_id not in self.config.ready_nodes:
                continue
            text = next((v.value for v in status.values if v.key == LINKS_KEY), None)
            try:
                self._node_links[status.hardware_id] = None if text is None else parse_links(text)
            except ValueError as exc:
                self.drop(f"/diagnostics of {status.hardware_id}: {exc}")

    def _on_ack(self, msg) -> None:
        self._acked.add(stamp_ns(msg.header.stamp))

    def play(self, executor) -> int:
        """Play the whole bag; 0 when it has been played, 1 when it could not be read or (paced) nobody listens."""
        if not self._wait_until_ready(executor):
            return 1
        paced = self.config.mode == "paced"
        first_ns = start = None
        pending_t_ns = None  # bag time of the pending frame: later messages wait for its acknowledgement
        frames = 0
        total = sum(c.msgcount for c in self._reader.connections if c.topic == self._pace)
        try:
            for conn, t_ns, raw, msg in self._messages():
                is_frame = paced and conn.topic == self._pace
                if is_frame or (self._pending is not None and t_ns > pending_t_ns):
                    self._wait_for_ack(executor)
                elif not paced:
                    if first_ns is None:
                        first_ns, start = t_ns, time.monotonic()
                    _spin_until(executor, start + (t_ns - first_ns) * 1e-9 / self.config.rate)
                self._publish_clock(t_ns)
                self._players[conn.topic].publish(raw)
                self.counters["published"] += 1
                if is_frame:
                    self._pending, pending_t_ns = stamp_ns(msg.header.stamp), t_ns
                if conn.topic == self._pace:
                    frames += 1
                    every = self.config.progress_every
                    if every and (frames % every == 0 or frames == total):
                        self.get_logger().info(f"played {frames}/{total} frames")
                executor.spin_once(timeout_sec=0.0)
        except BagError as exc:
            self.get_logger().error(f"bag {self.config.bag} cannot be read further: {exc}")
            return 1
        self._wait_for_ack(executor)
        for publisher in self._players.values():
            if publisher.qos_profile.reliability == ReliabilityPolicy.RELIABLE:
                publisher.wait_for_all_acked(Duration(seconds=ACKED_FLUSH_TIMEOUT_S))
        c = self.counters
        self.get_logger().info(
            f"bag finished: published {c['published']}, acknowledged {c['acknowledged']}, "
            f"ack timeouts {c['ack_timeouts']}, dropped {c['dropped']}"
        )
        return 0

    def _messages(self):
        """The played messages ``(connection, bag time, raw, message)`` in bag time order, except
        that a frame (``pace_topic`` message) comes after those recorded with it: at its bag time
        or, before the next frame and at most ``FRAME_LAG_NS`` later, with its header stamp (its
        camera_info and ground truth, which a recorder may receive after it)."""
        frame, held = None, []
        for item in self._decoded():
            if frame is not None and (item[0].topic == self._pace or item[1] > frame[1] + FRAME_LAG_NS):
                yield from _after_its_own(frame, held)
                frame, held = None, []
            if item[0].topic == self._pace:
                frame = item
            elif frame is None:
                yield item
            else:
                held.append(item)
        if frame is not None:
            yield from _after_its_own(frame, held)

    def _decoded(self):
        """``(connection, bag time, raw, message)`` of the played topics in bag time order; a
        message that does not deserialise is dropped (logged, counted)."""
        for conn, t_ns, raw in bag_messages(self._reader):
            if conn.id not in self._played:
                continue
            self.counters["received"] += 1
            try:
                msg = deserialize_message(raw, self._players[conn.topic].msg_type)
            except RuntimeError as exc:
                self.drop(f"{conn.topic}: message at {t_ns} ns does not deserialise as {conn.msgtype}: {exc}")
                continue
            try:
                header_stamp_ns(msg)
            except ValueError as exc:
                self.drop(f"{conn.topic}: message at {t_ns} ns: {exc}")
                continue
            yield conn, t_ns, raw, msg

    def _missing(self) -> list[str]:
        missing = []
        for name in self._ready_topics:
            own = self._players.get(self._bag_topic(name))
            if own is not None and own.get_subscription_count() == 0:
                missing.append(f"subscriber of {name}")
            elif own is None and (self.count_publishers(name) == 0 or self.count_subscribers(name) == 0):
                missing.append(f"publisher and subscriber of {name}")
        if self.config.mode == "paced":
            pace = self._players[self._pace]
            if pace.get_subscription_count() == 0:
                missing.append(f"subscriber of {pace.topic_name}")
            if self._ack_sub.get_publisher_count() == 0:
                missing.append(f"publisher of {self._ack_sub.topic_name}")
        return missing + self._links_down()

    def _links_down(self) -> list[str]:
        """What :meth:`_missing` lists for ``ready_nodes``: their reports, or their links on a ready topic not up."""
        missing, ready = [], set(self._ready_topics)
        for name in self.config.ready_nodes:
            if name not in self._node_links:
                missing.append(f"/diagnostics from {name}")
            elif self._node_links[name] is None:
                missing.append(f"links in the /diagnostics of {name} (not a node of this graph?)")
            else:
                missing += [f"match of {name}'s {'publisher' if kind == 'pub' else 'subscription'} {topic} "
                            f"with every peer ({matched} of {seen})"
                            for kind, topic, matched, seen in self._node_links[name]
                            if topic in ready and not 0 < seen == matched]
        return missing

    def _wait_until_ready(self, executor) -> bool:
        start = time.monotonic()
        deadline = start + self.config.ready_timeout_s
        while (missing := self._missing()) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        if self._diagnostics_sub is not None:  # needed no more
            self.destroy_subscription(self._diagnostics_sub)
            self._diagnostics_sub = None
        if not missing:
            if self._ready_topics or self.config.ready_nodes:
                self.get_logger().info(f"links up after {time.monotonic() - start:.1f} s "
                                       f"({len(self._ready_topics)} topics, {len(self.config.ready_nodes)} nodes)")
            _spin_until(executor, time.monotonic() + self.config.ready_settle_s)
            return True
        text = f"not ready after {self.config.ready_timeout_s:g} s: no {', no '.join(missing)}"
        if self.config.mode == "paced":
            self.get_logger().error(text)
            return False
        self.get_logger().warn(text + "; playing anyway")
        return True

    def _publish_clock(self, t_ns: int = 0) -> None:
        """With ``clock``, publish the latest bag time so far, ``t_ns`` or earlier (never back: a
        frame may follow its later-recorded camera_info)."""
        if self._clock_pub is None:
            return
        self._clock_ns = max(self._clock_ns, t_ns)
        sec, nanosec = stamp_fields(self._clock_ns)
        self._clock_pub.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))

    def _wait_for_ack(self, executor) -> None:
        """Wait for the acknowledgement of the pending frame (if any), at most ``ack_timeout_s``."""
        if self._pending is None:
            return
        deadline = time.monotonic() + self.config.ack_timeout_s
        while self._pending not in self._acked and time.monotonic() < deadline:
            self._publish_clock()
            executor.spin_once(timeout_sec=SPIN_S)
        if self._pending in self._acked:
            self.counters["acknowledged"] += 1
        else:
            self.counters["ack_timeouts"] += 1
            self.last_error = f"no acknowledgement of the frame stamped {self._pending} ns within {self.config.ack_timeout_s:g} s"
            self.get_logger().warn(self.last_error)
        self._pending = None
        self._acked.clear()

    def destroy_node(self):
        if self._reader.is_open:
            self._reader.close()
        super().destroy_node()


def _after_its_own(frame, held) -> list:
    """``held`` (the messages recorded after ``frame``) with those of the frame's bag time or
    header stamp moved before it."""
    stamp = header_stamp_ns(frame[3])
    own, rest = [], []
    for m in held:
        (own if m[1] == frame[1] or (stamp is not None and header_stamp_ns(m[3]) == stamp) else rest).append(m)
    return own + [frame] + rest


def _open_bag(path: str) -> Reader:
    if not Path(path).exists():
        raise ConfigError(f"bag: '{path}' does not exist")
    try:
        return open_bag(path)
    except BagError as exc:
        raise ConfigError(f"bag: '{path}' is not a readable rosbag2 bag: {exc}") from exc


def _resolved(node, key: str, topic: str) -> str:
    """``topic`` as ``node`` resolves it; :class:`ConfigError` naming parameter ``key`` if it is no topic name."""
    try:
        return node.resolve_topic_name(topic)
    except RuntimeError as exc:  # rclpy's RCLError
        raise ConfigError(f"{key}: '{topic}' is not a valid topic name: {exc}") from exc


def _check_node_name(name: str) -> None:
    """:class:`ConfigError` naming ``ready_nodes`` if ``name`` is no node name."""
    try:
        validate_node_name(name)
    except Exception as exc:  # rclpy's InvalidNodeNameException, TypeError
        raise ConfigError(f"ready_nodes: {name!r} is not a node name: {exc}") from exc


def _message_class(type_name: str):
    """The installed message class of ``pkg/msg/Name``, or None."""
    package, kind, name = (type_name.split("/") + ["", ""])[:3]
    if kind != "msg" or not package or not name:
        return None
    try:
        return getattr(importlib.import_module(f"{package}.msg"), name, None)
    except ImportError:
        return None


def _spin_until(executor, deadline: float) -> None:
    while (remaining := deadline - time.monotonic()) > 0.0:
        executor.spin_once(timeout_sec=min(remaining, 0.1))


def main(args=None) -> int:
    return run_node(BagPlayer, args, run=lambda node, executor: node.play(executor))


if __name__ == "__main__":
    sys.exit(main())
