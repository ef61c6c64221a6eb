"""What every node of the graph shares: configuration from ROS parameters, ``/diagnostics``, ``main()``.

Parameters come from ``--ros-args --params-file config/<node>.yaml`` (or ``-p key:=value``);
nested YAML groups arrive as dotted names (``cone.alpha1_deg``) and are nested again before
validation, so the node reads the same file, with the same checks, as the CLI. They are
read-only once declared: a change needs a restart, which validates it.
"""

import array
import dataclasses
import faulthandler
import signal
import sys
import threading
import time
from collections import Counter

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node

from ..camera import CameraInfoError
from ..config import ConfigError, from_mapping
from ..stamps import header_stamp_ns, stamp_ns
from .image import ImageError, image_to_rgb
from .participant import ImageParticipant
from .qos import RELIABLE_QOS

DIAGNOSTICS_PERIOD_S = 1.0
SHUTDOWN_GRACE_S = 1.0  # an error out of the executor is a stop when the context goes down this soon
SIGNAL_THREAD_LIMIT_S = 5.0  # how long a Ctrl-C waits for rclpy's signal thread before the teardown
TEARDOWN_LIMIT_S = 5.0  # a node's teardown taking longer has hung: the process ends (run_node)
DROP_LOG_PERIOD_S = 1.0  # a kind of drop is logged at most this often
# Parameters every rclpy node declares itself; they are not part of a node's configuration.
ROS_PARAMETERS = frozenset({"use_sim_time", "start_type_description_service"})
# What an executor can raise when Ctrl-C / SIGTERM end a node (see stopped_by_shutdown).
SHUTDOWN_ERRORS = (KeyboardInterrupt, ExternalShutdownException, RuntimeError)
LINKS_KEY = "links"  # the /diagnostics value listing the node's links (format_links)
_UNREPORTED_TOPICS = frozenset({"/rosout", "/parameter_events"})  # rclpy's own, on every node


def _descriptor(**fields) -> ParameterDescriptor:
    """Read-only: a node validates its parameters once, at start-up, and runs on that
    configuration; a later ``ros2 param set`` is refused rather than reported as applied."""
    return ParameterDescriptor(read_only=True, description="read at start-up; restart the node to change it",
                               **fields)


class LandingNode(Node):
    """A node configured from its parameters that reports its counters on ``/diagnostics`` at 1 Hz.

    Subclasses count messages with ``self.counters[...] += 1`` and reject a bad message with
    :meth:`drop`, which logs the reason, counts it and never raises. A message whose header stamp
    is malformed (``nanosec`` not below 1e9) is dropped before its subscription's callback: read as
    a time, (s, 1.5e9 ns) would be half a second after (s + 1, 0) and alias a valid stamp.
    """

    def __init__(self, name: str, **kwargs):
        super().__init__(name, **kwargs)
        self._declare_overrides()
        self.counters = Counter(received=0, dropped=0, published=0)
        self.last_error = ""
        self._dropped_at_last_report = 0
        self._drop_logged: dict[str, float] = {}  # kind of drop -> monotonic time it was last logged
        self._diagnostics = self.create_publisher(DiagnosticArray, "/diagnostics", RELIABLE_QOS)
        self._image_participant = None  # made with the first image publisher
        # Steady time: diagnostics keep flowing when use_sim_time is set and /clock is paused.
        self.create_timer(DIAGNOSTICS_PERIOD_S, self.publish_diagnostics, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def create_subscription(self, msg_type, topic, callback, qos_profile, **kwargs):
        """rclpy's, with messages of a malformed header stamp dropped before ``callback``."""

        def checked(msg):
            try:
                header_stamp_ns(msg)
            except ValueError as exc:
                self.drop(f"{topic}: {exc}")
                return
            callback(msg)

        return super().create_subscription(msg_type, topic, checked, qos_profile, **kwargs)

    def create_image_publisher(self, msg_type, topic: str, qos):
        """A publisher of images from the node's second DDS participant (``participant.py``: sent
        from one participant, images and small messages lost some of the small ones)."""
        if self._image_participant is None:
            self._image_participant = ImageParticipant(self)
        return self._image_participant.create_publisher(msg_type, topic, qos)

    def links(self) -> list[tuple[str, str, int, int]]:
        """Each publisher and subscription of the node (its image participant's too) as
        ``(kind, topic, matched, seen)``: kind ``pub`` or ``sub``, the peers DDS has matched with
        it and those the node sees in the graph. A link is up when ``0 < seen == matched``; until
        then messages sent on it can be lost to a peer (DDS matches each pair of processes apart)."""
        publishers = list(self.publishers)
        if self._image_participant is not None:
            publishers += self._image_participant.node.publishers
        out = [("pub", p.topic_name, p.get_subscription_count(), self.count_subscribers(p.topic_name))
               for p in publishers if p.topic_name not in _UNREPORTED_TOPICS]
        return out + [("sub", s.topic_name, s.get_publisher_count(), self.count_publishers(s.topic_name))
                      for s in self.subscriptions if s.topic_name not in _UNREPORTED_TOPICS]

    def destroy_node(self):
        if self._image_participant is not None:
            self._image_participant.destroy()
            self._image_participant = None
        super().destroy_node()

    def _declare_overrides(self) -> None:
        """Declare every parameter given (file or ``-p``). rcl hands an empty list (``[]``) over
        untyped, which rclpy cannot declare statically typed: it is declared dynamically typed."""
        for name, param in self._parameter_overrides.items():
            if not self.has_parameter(name):
                self.declare_parameter(name, param.value, _descriptor(dynamic_typing=param.value is None))

    def parameter_mapping(self) -> dict:
        """The node's own parameters as a nested mapping (dotted names → groups, arrays → lists)."""
        nested: dict = {}
        for name, param in self.get_parameters_by_prefix("").items():
            if name in ROS_PARAMETERS:
                continue
            value = param.value
            if value is None:  # an empty list, declared untyped (see _declare_overrides)
                value = []
            elif isinstance(value, array.array):
                value = list(value)
            *groups, leaf = name.split(".")
            level = nested
            for depth, group in enumerate(groups):
                level = level.setdefault(group, {})
                if not isinstance(level, dict):
                    raise ConfigError(f"parameter {name}: {'.'.join(groups[:depth + 1])} is a value, not a group")
            if isinstance(level.get(leaf), dict):
                raise ConfigError(f"parameter {name} is a group of parameters, not a value")
            level[leaf] = value
        return nested

    def load_config(self, cls, group: str = "", exclude: tuple[str, ...] = ()):
        """Validate the parameters into dataclass ``cls`` (defaults fill what is not given), then
        declare the defaults that were not given so that every effective value is a parameter.

        ``group`` validates only the parameters of that group (``node.*``); ``exclude`` leaves
        groups out (a node whose core configuration and own settings share one parameter file).
        Raises :class:`ConfigError` naming the key of an unknown or invalid parameter.
        """
        mapping = self.parameter_mapping()
        where = f"{self.get_name()} parameters"
        if group:
            mapping, where = mapping.get(group, {}), f"{where}.{group}"
        for name in exclude:
            mapping.pop(name, None)
        config = from_mapping(cls, mapping, where=where)
        prefix = f"{group}." if group else ""
        for name, value in _flatten(dataclasses.asdict(config), prefix):
            if not self.has_parameter(name) and _is_parameter_value(value):
                self.declare_parameter(name, list(value) if isinstance(value, tuple) else value, _descriptor())
        return config

    def take_camera_info(self, calibration, msg, use=None) -> bool:
        """Update ``calibration`` (a :class:`~.calibration.Calibration`) from a camera_info
        message, switching the node with ``use(camera)`` first when given: True when it carries
        a new calibration; an unusable one is dropped."""
        try:
            return calibration.update(msg, use)
        except CameraInfoError as exc:
            self.drop(f"camera_info rejected: {exc}")
            return False

    def receive_frame(self, msg):
        """Count an Image received and convert it (:func:`.image.image_to_rgb`); None when it
        cannot be used, dropped with the reason."""
        self.counters["received"] += 1
        try:
            return image_to_rgb(msg)
        except ImageError as exc:
            self.drop(str(exc))
            return None

    def hold(self, held, frame: tuple, limit: int, waiting_for: str) -> None:
        """Keep ``frame`` (its first item the Image) in the deque ``held`` until the node can use it
        (e.g. the calibration comes a moment after the first image); beyond ``limit`` frames the
        oldest is dropped, saying what it waited for."""
        if len(held) == limit:
            old = held.popleft()[0]
            self.drop(f"image stamped {stamp_ns(old.header.stamp)} ns: {waiting_for} within {limit} frames")
        held.append(frame)

    def drop(self, reason: str, count: int = 1, kind: str = "message") -> None:
        """Count a dropped message (or ``count`` items of one) and log why, at most once a second
        for each ``kind``: a drop that repeats all the time (a MAVLink link down) must not hide
        the others (a rejected pose) from the log."""
        self.counters["dropped"] += count
        self.last_error = reason
        now = time.monotonic()
        if now - self._drop_logged.get(kind, float("-inf")) >= DROP_LOG_PERIOD_S:
            self._drop_logged[kind] = now
            self.get_logger().error(f"dropped: {reason}")

    def publish_diagnostics(self) -> None:
        """One ``DiagnosticStatus``: WARN when messages were dropped since the last report, else OK."""
        dropped_now = self.counters["dropped"] - self._dropped_at_last_report
        self._dropped_at_last_report = self.counters["dropped"]
        status = DiagnosticStatus(
            level=DiagnosticStatus.WARN if dropped_now else DiagnosticStatus.OK,
            name=self.get_fully_qualified_name(),
            message=f"dropped {dropped_now} in the last {DIAGNOSTICS_PERIOD_S:g} s: {self.last_error}" if dropped_now else "ok",
            hardware_id=self.get_name(),
            values=[KeyValue(key=k, value=str(v)) for k, v in sorted(self.counters.items())]
            + [KeyValue(key="last_error", value=self.last_error), KeyValue(key=LINKS_KEY, value=format_links(self.links()))],
        )
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diagnostics.publish(msg)


def format_links(links) -> str:
    """:meth:`LandingNode.links` as one diagnostics value: ``pub /uav/pose 2/3; sub /camera/image_rect 1/1``."""
    return "; ".join(f"{kind} {topic} {matched}/{seen}" for kind, topic, matched, seen in links)


def parse_links(text: str) -> list[tuple[str, str, int, int]]:
    """The links of a :func:`format_links` value; ValueError if it is not one."""
    links = []
    for item in filter(None, text.split("; ")):
        parts = item.split(" ")
        kind, topic, counts = parts if len(parts) == 3 else ("", "", "")
        matched, _, seen = counts.partition("/")
        if kind not in ("pub", "sub") or not topic.startswith("/") or not (matched.isdigit() and seen.isdigit()):
            raise ValueError(f"not a link: {item!r}")
        links.append((kind, topic, int(matched), int(seen)))
    return links


def run_node(factory, args=None, run=None) -> int:
    """Initialise rclpy, build the node, run it until shutdown; the body of every node's ``main()``.

    ``run(node, executor) -> int`` replaces the default spin (the bag player plays and returns).
    ROS arguments rcl cannot parse (a missing or malformed parameter file, an unknown argument) and
    a :class:`ConfigError` while building the node are start-up failures: logged, exit code 2.
    Ctrl-C / SIGTERM end the node cleanly with exit code 0. SIGUSR1 prints the stack of every
    thread to stderr (``uav-landing graph`` sends it to a node that ignored SIGINT and SIGTERM,
    before SIGKILL), so a node that hangs says where. A teardown (executor, node, rclpy) that has
    not ended after :data:`TEARDOWN_LIMIT_S` prints every stack and ends the process, exit code 1:
    it hung in the middleware's C++ (Fast DDS's participant teardown, seen in loaded e2e runs),
    where neither SIGINT nor SIGTERM reaches it.
    """
    faulthandler.enable(file=sys.__stderr__, all_threads=True)  # a crash in C (SIGSEGV, SIGABRT) prints every stack
    faulthandler.register(signal.SIGUSR1, file=sys.__stderr__, all_threads=True)
    try:
        rclpy.init(args=args)
    except RuntimeError as exc:  # rclpy's RCLError and UnknownROSArgsError
        return _cannot_start(exc)
    executor = SingleThreadedExecutor()
    node = None
    try:
        node = factory()
        executor.add_node(node)
        if run is not None:
            return run(node, executor)
        executor.spin()
        return 0
    except ConfigError as exc:
        return _cannot_start(exc)
    except SHUTDOWN_ERRORS as exc:
        if not stopped_by_shutdown(exc):
            raise
        return 0
    finally:
        faulthandler.dump_traceback_later(TEARDOWN_LIMIT_S, exit=True, file=sys.__stderr__)  # a C thread: needs no GIL
        executor.shutdown()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        faulthandler.cancel_dump_traceback_later()


def stopped_by_shutdown(exc: BaseException, context=None) -> bool:
    """Whether ``exc`` is how Ctrl-C / SIGTERM end a node.

    rclpy's signal handler shuts the context down, so a callback that publishes afterwards raises
    RCLError (a RuntimeError) out of the executor. It does so from its own thread, racing the
    KeyboardInterrupt that Ctrl-C raises in the main thread: one raised while rclpy converts a
    message comes out of pybind11 as a RuntimeError, with the context still up for a moment. So a
    RuntimeError is a stop when the context goes down within :data:`SHUTDOWN_GRACE_S`.

    A KeyboardInterrupt is a stop; it returns once the context is down too (or after
    :data:`SIGNAL_THREAD_LIMIT_S`), because the teardown must not begin before: rclpy's signal
    thread wakes the executor, then goes on through its list of guard conditions to trigger and
    only then shuts the context down, and the executor's shutdown frees that list and its guard
    condition. Torn down first, a node crashed on Ctrl-C (SIGSEGV in ``rcl_trigger_guard_condition``
    on the signal thread).
    """
    if isinstance(exc, ExternalShutdownException):
        return True
    interrupted = isinstance(exc, KeyboardInterrupt)
    if not (interrupted or isinstance(exc, RuntimeError)):
        return False
    deadline = time.monotonic() + (SIGNAL_THREAD_LIMIT_S if interrupted else SHUTDOWN_GRACE_S)
    # A timed wait on an event that is never set, not time.sleep: under libfaketime with the
    # monotonic clock left real (the bridge's clock-step test), time.sleep fails with EINVAL.
    pause = threading.Event()
    while rclpy.ok(context=context):
        if time.monotonic() > deadline:
            return interrupted
        pause.wait(0.01)
    return True


def _cannot_start(exc: Exception) -> int:
    print(f"[FATAL] cannot start: {exc}", file=sys.stderr, flush=True)
    return 2


def _flatten(mapping: dict, prefix: str = ""):
    for key, value in mapping.items():
        if isinstance(value, dict):
            yield from _flatten(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def _is_parameter_value(value) -> bool:
    """Whether rclpy can declare ``value`` with its type inferred (not None, not an empty list)."""
    if isinstance(value, (list, tuple)):
        return len(value) > 0
    return isinstance(value, (bool, int, float, str))
