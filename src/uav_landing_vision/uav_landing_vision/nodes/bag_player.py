"""``bag_player``: plays a rosbag2 bag (mcap or sqlite3) onto its recorded topics; exits when it ends.

Stands in for ``ros2 bag play`` where rosbag2 is not installed; reads with ``rosbags``. Every
message is checked by deserialising it with the installed message type, then its recorded
bytes are published unchanged. Images and camera_info go out with the graph's image QoS
(reliable, keep last 5), other topics reliable, keep last 10 (``qos.qos_for_type``). Messages
sharing a bag timestamp are published with the ``pace_topic`` message last, so a frame's
camera_info precedes its image.

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
has a subscriber and ``ack_topic`` a publisher; a paced player that is not ready by then
exits with code 1. ``clock: true`` publishes the bag time on ``/clock`` before each message.
A missing or unreadable bag fails start-up (exit code 2).
"""

import importlib
import itertools
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from builtin_interfaces.msg import Time
from rclpy.duration import Duration
from rclpy.qos import ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader, ReaderError
from rosgraph_msgs.msg import Clock

from ..config import ConfigError
from .base import LandingNode, run_node, stamp_ns
from .qos import RELIABLE_QOS, qos_for_type

ACKED_FLUSH_TIMEOUT_S = 5.0  # at the end, how long reliable topics may take to be acknowledged


@dataclass(frozen=True)
class BagPlayerConfig:
    bag: str = ""  # rosbag2 directory, or a single .mcap / .db3 file
    mode: Literal["timed", "paced"] = "timed"
    rate: float = 1.0  # timed mode: speed factor on the recorded rate
    pace_topic: str = "/camera/image_raw"  # paced mode: the bag topic whose messages wait for an ack
    ack_topic: str = "camera/image_rect"  # paced mode: the topic that acknowledges a frame by its stamp
    ack_type: str = "sensor_msgs/msg/Image"
    ack_timeout_s: float = 10.0
    ready_topics: tuple[str, ...] = ()
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
        self._reader = _open_bag(cfg.bag)
        self._players = {}
        self._played = set()  # ids of the connections whose messages are played
        for conn in self._reader.connections:
            self._add_publisher(conn)
        self._clock_pub = self.create_publisher(Clock, "/clock", RELIABLE_QOS) if cfg.clock else None
        self._pending = None  # stamp (ns) of the paced frame awaiting its acknowledgement
        self._acked = set()
        if cfg.mode == "paced":
            pace = self._players.get(cfg.pace_topic)
            if pace is None:
                raise ConfigError(f"pace_topic: '{cfg.pace_topic}' is not a playable topic of the bag (topics: {sorted(self._players)})")
            if "header" not in pace.msg_type.get_fields_and_field_types():
                raise ConfigError(f"pace_topic: '{cfg.pace_topic}' has no header to acknowledge")
            ack_cls = _message_class(cfg.ack_type)
            if ack_cls is None or "header" not in ack_cls.get_fields_and_field_types():
                raise ConfigError(f"ack_type: '{cfg.ack_type}' is not an installed message type with a header")
            ack_topic = _resolved(self, "ack_topic", cfg.ack_topic)
            self._ack_sub = self.create_subscription(ack_cls, ack_topic, self._on_ack, qos_for_type(cfg.ack_type))
        topics = {c.topic: c.msgcount for c in self._reader.connections if c.topic in self._players}
        self.get_logger().info(f"bag {cfg.bag}: {self._reader.message_count} messages, topics {topics}, mode {cfg.mode}")

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
            self._players[topic] = self.create_publisher(cls, topic, qos_for_type(type_name))
        self._played.add(conn.id)

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
        total = sum(c.msgcount for c in self._reader.connections if c.topic == self.config.pace_topic)
        try:
            for conn, t_ns, raw in self._messages():
                if conn.id not in self._played:
                    continue
                publisher = self._players[conn.topic]
                self.counters["received"] += 1
                try:
                    msg = deserialize_message(raw, publisher.msg_type)
                except RuntimeError as exc:
                    self.drop(f"{conn.topic}: message at {t_ns} ns does not deserialise as {conn.msgtype}: {exc}")
                    continue
                is_frame = paced and conn.topic == self.config.pace_topic
                if is_frame or (self._pending is not None and t_ns > pending_t_ns):
                    self._wait_for_ack(executor)
                elif not paced:
                    if first_ns is None:
                        first_ns, start = t_ns, time.monotonic()
                    _spin_until(executor, start + (t_ns - first_ns) * 1e-9 / self.config.rate)
                if self._clock_pub is not None:
                    self._clock_pub.publish(Clock(clock=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)))
                publisher.publish(raw)
                self.counters["published"] += 1
                if is_frame:
                    self._pending, pending_t_ns = stamp_ns(msg.header.stamp), t_ns
                if conn.topic == self.config.pace_topic:
                    frames += 1
                    every = self.config.progress_every
                    if every and (frames % every == 0 or frames == total):
                        self.get_logger().info(f"played {frames}/{total} frames")
                executor.spin_once(timeout_sec=0.0)
        except (ReaderError, OSError) as exc:
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
        """The bag's messages in time order; within one timestamp the pace topic comes last."""
        stream = self._reader.messages()
        for _, group in itertools.groupby(stream, key=lambda item: item[1]):
            yield from sorted(group, key=lambda item: item[0].topic == self.config.pace_topic)

    def _missing(self) -> list[str]:
        missing = []
        for name in self._ready_topics:
            own = self._players.get(name)
            if own is not None and own.get_subscription_count() == 0:
                missing.append(f"subscriber of {name}")
            elif own is None and (self.count_publishers(name) == 0 or self.count_subscribers(name) == 0):
                missing.append(f"publisher and subscriber of {name}")
        if self.config.mode == "paced":
            if self._players[self.config.pace_topic].get_subscription_count() == 0:
                missing.append(f"subscriber of {self.config.pace_topic}")
            if self._ack_sub.get_publisher_count() == 0:
                missing.append(f"publisher of {self._ack_sub.topic_name}")
        return missing

    def _wait_until_ready(self, executor) -> bool:
        deadline = time.monotonic() + self.config.ready_timeout_s
        while (missing := self._missing()) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        if not missing:
            _spin_until(executor, time.monotonic() + self.config.ready_settle_s)
            return True
        text = f"not ready after {self.config.ready_timeout_s:g} s: no {', no '.join(missing)}"
        if self.config.mode == "paced":
            self.get_logger().error(text)
            return False
        self.get_logger().warn(text + "; playing anyway")
        return True

    def _wait_for_ack(self, executor) -> None:
        """Wait for the acknowledgement of the pending frame (if any), at most ``ack_timeout_s``."""
        if self._pending is None:
            return
        deadline = time.monotonic() + self.config.ack_timeout_s
        while self._pending not in self._acked and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
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


def _open_bag(path: str) -> Reader:
    if not Path(path).exists():
        raise ConfigError(f"bag: '{path}' does not exist")
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, OSError) as exc:
        raise ConfigError(f"bag: '{path}' is not a readable rosbag2 bag: {exc}") from exc
    return reader


def _resolved(node, key: str, topic: str) -> str:
    """``topic`` as ``node`` resolves it; :class:`ConfigError` naming parameter ``key`` if it is no topic name."""
    try:
        return node.resolve_topic_name(topic)
    except RuntimeError as exc:  # rclpy's RCLError
        raise ConfigError(f"{key}: '{topic}' is not a valid topic name: {exc}") from exc


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
