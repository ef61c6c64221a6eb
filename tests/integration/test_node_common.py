"""Shared node pieces (image and pose conversion, QoS, stamp matching, calibration updates, parameters → config,
/diagnostics), and the in-process rclpy harness and bag/image helpers the other ``test_node_*`` modules import."""

import math
import os
import signal
import subprocess
import sys
import threading
import time
import types
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import Pose, PoseStamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import CompressionFormat, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import CameraInfo, Image

from uav_landing_vision.camera import CameraInfoError, CameraModel, camera_info_fields
from uav_landing_vision.config import ConfigError, load_node_parameters
from uav_landing_vision.nodes import base
from uav_landing_vision.nodes.base import LandingNode, format_links, parse_links, run_node
from uav_landing_vision.nodes.calibration import Calibration
from uav_landing_vision.nodes.image import ImageError, image_to_numpy, image_to_rgb, numpy_to_image
from uav_landing_vision.nodes.poses import numpy_to_pose, pose_to_numpy
from uav_landing_vision.nodes.qos import IMAGE_QOS, KEEP_ALL_QOS, RELIABLE_QOS, SENSOR_QOS, qos_for_type
from uav_landing_vision.nodes.sync import RepeatedStampError, StampCache

SPIN_TIMEOUT_S = 30.0  # generous: discovery takes seconds and other jobs share the 2 cores
SMALL_CAMERA = CameraModel(40, 30, np.array([[36.0, 0.0, 19.6], [0.0, 36.0, 14.8], [0.0, 0.0, 1.0]]), np.array([-0.25, 0.08, 0.001, -0.002, 0.0]))


class RosHarness:
    """A private rclpy context (own DDS domain), a probe node and one executor for nodes under test."""

    def __init__(self, domain_id: int):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.probe = Node("test_probe", context=self.context)
        self.executor.add_node(self.probe)
        self._nodes = [self.probe]

    def add(self, node):
        self.executor.add_node(node)
        self._nodes.append(node)
        return node

    def spin_until(self, predicate, timeout: float = SPIN_TIMEOUT_S) -> bool:
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def collect(self, msg_type, topic: str, qos) -> list:
        """A subscription of the probe that appends every message to the returned list."""
        received = []
        self.probe.create_subscription(msg_type, topic, received.append, qos)
        return received

    def close(self):
        for node in reversed(self._nodes):
            node.destroy_node()
        self.executor.shutdown()
        self.context.try_shutdown()


@pytest.fixture
def ros(ros_domain_id):
    harness = RosHarness(ros_domain_id)
    yield harness
    harness.close()


def participant_of(node, topic: str) -> bytes:
    """The DDS participant (GUID prefix: the first 12 bytes of the endpoint's GID) of the only
    publisher of ``topic`` that ``node`` sees."""
    (info,) = node.get_publishers_info_by_topic(topic)
    return bytes(info.endpoint_gid[:12])


def rgb_frame(camera: CameraModel, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(camera.height, camera.width, 3), dtype=np.uint8)


def image_msg(pixels: np.ndarray, encoding: str, sec: int = 1, nanosec: int = 0, frame_id: str = "camera_optical_frame", pad: int = 0) -> Image:
    """An Image of ``pixels``, optionally with ``pad`` bytes of row padding."""
    height, width = pixels.shape[:2]
    rows = pixels.reshape(height, -1)
    padded = np.concatenate([rows, np.full((height, pad), 0xEE, np.uint8)], axis=1) if pad else rows
    msg = Image(height=height, width=width, encoding=encoding, step=padded.shape[1], data=padded.tobytes())
    msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = sec, nanosec, frame_id
    return msg


def camera_info_msg(camera: CameraModel, sec: int = 1, nanosec: int = 0) -> CameraInfo:
    msg = CameraInfo(**camera_info_fields(camera))
    msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = sec, nanosec, camera.frame_id
    return msg


def write_bag(path, entries, storage=StoragePlugin.MCAP, compression=None):
    """A rosbag2 bag of ``entries`` = [(topic, type name, bag time ns, message or raw bytes)], in order;
    ``compression``: a zstd :class:`CompressionMode` (file, message; storage: mcap chunks)."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    writer = Writer(path, version=9, storage_plugin=storage)
    if compression is not None:
        writer.set_compression(compression, CompressionFormat.ZSTD)
    with writer:
        connections = {}
        for topic, type_name, t_ns, msg in entries:
            key = (topic, type_name)
            if key not in connections:
                connections[key] = writer.add_connection(topic, type_name, typestore=typestore)
            writer.write(connections[key], t_ns, msg if isinstance(msg, bytes) else serialize_message(msg))
    return path


def frame_entries(camera: CameraModel, count: int, period_ns: int = 33_000_000, image_first: bool = True):
    """Bag entries of ``count`` frames: image and camera_info sharing each stamp (image first by default)."""
    entries = []
    for i in range(count):
        t = 1_000_000_000 + i * period_ns
        sec, nanosec = divmod(t, 1_000_000_000)
        image = ("/camera/image_raw", "sensor_msgs/msg/Image", t, image_msg(rgb_frame(camera, i), "rgb8", sec, nanosec))
        info = ("/camera/camera_info", "sensor_msgs/msg/CameraInfo", t, camera_info_msg(camera, sec, nanosec))
        entries += [image, info] if image_first else [info, image]
    return entries


# --- image conversion -------------------------------------------------------------------------

@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "mono8"])
@pytest.mark.parametrize("pad", [0, 3])
@pytest.mark.parametrize("bigendian", [0, 1])
def test_image_round_trip_honours_step_padding(encoding, pad, bigendian):
    rng = np.random.default_rng(1)
    shape = (5, 7) if encoding == "mono8" else (5, 7, 3)
    pixels = rng.integers(0, 256, size=shape, dtype=np.uint8)
    msg = image_msg(pixels, encoding, pad=pad)
    msg.is_bigendian = bigendian  # one-byte channels: no byte order to apply
    np.testing.assert_array_equal(image_to_numpy(msg), pixels)
    back = numpy_to_image(image_to_numpy(msg), encoding, msg.header)
    assert (back.step, back.width, back.height, back.encoding, back.header) == (pixels[0].size, 7, 5, encoding, msg.header)
    np.testing.assert_array_equal(image_to_numpy(back), pixels)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"encoding": "rgba8"}, "unsupported image encoding 'rgba8'"),
        ({"encoding": "16UC1"}, "unsupported image encoding '16UC1'"),
        ({"step": 20}, "step 20 is shorter than one row"),
        ({"height": 6}, "expected step x height"),
        ({"data": bytes(10)}, "image data has 10 bytes"),
        ({"width": 0, "height": 0, "step": 0, "data": b""}, "empty image"),
    ],
)
def test_unusable_images_raise_a_clear_error(change, message):
    msg = image_msg(np.zeros((5, 7, 3), np.uint8), "rgb8")
    for key, value in change.items():
        setattr(msg, key, value)
    with pytest.raises(ImageError, match=message):
        image_to_numpy(msg)


def test_numpy_to_image_rejects_arrays_that_do_not_fit_the_encoding():
    with pytest.raises(ImageError, match="rgb8 needs a uint8 array of 3 dimensions"):
        numpy_to_image(np.zeros((4, 4), np.uint8), "rgb8", image_msg(np.zeros((1, 1), np.uint8), "mono8").header)
    with pytest.raises(ImageError, match="mono8 needs a uint8 array"):
        numpy_to_image(np.zeros((4, 4), np.float32), "mono8", Image().header)
    with pytest.raises(ImageError, match="unsupported image encoding 'yuv422'"):
        numpy_to_image(np.zeros((4, 4, 2), np.uint8), "yuv422", Image().header)


def test_a_fisheye_camera_info_is_refused_on_the_rectified_topic_even_without_coefficients():
    """An equidistant lens with D = 0 still projects θ, not tan θ: its image is not rectified."""
    fisheye = CameraModel(320, 240, [[300.0, 0, 160.0], [0, 300.0, 120.0], [0, 0, 1]], [], distortion_model="equidistant")
    calibration = Calibration(rectified=True)
    with pytest.raises(CameraInfoError, match=r"equidistant distortion \[0.0, 0.0, 0.0, 0.0\] in the camera_info of a rectified"):
        calibration.update(camera_info_msg(fisheye))
    assert calibration.camera is None
    assert Calibration(rectified=False).update(camera_info_msg(fisheye))


def test_qos_reliable_in_the_graph_best_effort_only_for_camera_drivers():
    assert SENSOR_QOS.reliability == ReliabilityPolicy.BEST_EFFORT
    assert IMAGE_QOS.reliability == ReliabilityPolicy.RELIABLE
    assert qos_for_type("sensor_msgs/msg/Image") is IMAGE_QOS
    assert qos_for_type("sensor_msgs/msg/CameraInfo") is IMAGE_QOS
    for name in ("uav_landing_msgs/msg/PoseHypotheses", "geometry_msgs/msg/PoseWithCovarianceStamped", "geometry_msgs/msg/PoseStamped"):
        profile = qos_for_type(name)
        assert profile is RELIABLE_QOS and profile.reliability == ReliabilityPolicy.RELIABLE and profile.depth >= 10
    assert KEEP_ALL_QOS.reliability == ReliabilityPolicy.RELIABLE and KEEP_ALL_QOS.history == HistoryPolicy.KEEP_ALL


# --- stamp matching ------------------------------------------------------------------------


def test_stamp_cache_pairs_by_stamp_in_either_order_and_evicts_the_oldest():
    cache = StampCache(("image", "boxes"), size=2)
    assert cache.add("image", 10, "i10") == (None, [])
    assert cache.add("boxes", 20, "b20") == (None, [])
    entry, evicted = cache.add("boxes", 10, "b10")
    assert entry.items == {"image": "i10", "boxes": "b10"} and evicted == [] and len(cache) == 1
    cache.add("image", 30, "i30")
    entry, evicted = cache.add("image", 40, "i40")  # three waiting stamps: the oldest goes
    assert entry is None and [e.stamp_ns for e in evicted] == [20] and len(cache) == 2
    assert [e.stamp_ns for e in cache.pop_older(40)] == [30] and len(cache) == 1
    with pytest.raises(KeyError):
        cache.add("pose", 50, "p")


def test_stamp_cache_refuses_a_repeated_stamp_and_keeps_the_first_message():
    cache = StampCache(("image", "boxes"), size=4)
    cache.add("image", 10, "first")
    with pytest.raises(RepeatedStampError, match="second image stamped 10 ns"):
        cache.add("image", 10, "second")
    entry, _ = cache.add("boxes", 10, "b10")
    assert entry.items["image"] == "first"
    assert cache.add("image", 10, "again") == (None, [])  # a completed stamp is no longer waiting


def test_stamp_cache_hands_back_the_entries_of_an_old_time_line():
    cache = StampCache(("image", "boxes"), size=3, restart_behind_ns=100)
    cache.add("image", 1000, "i1000")
    cache.add("image", 1010, "i1010")
    assert cache.add("boxes", 950, "b950") == (None, [])  # 60 ns behind: late, kept waiting
    entry, evicted = cache.add("image", 10, "i10")  # a replay from the start: the old entries go
    assert entry is None and [e.stamp_ns for e in evicted] == [950, 1000, 1010] and len(cache) == 1
    entry, _ = cache.add("boxes", 10, "b10")
    assert entry.items == {"image": "i10", "boxes": "b10"}


# --- parameters → config, diagnostics -------------------------------------------------------

@dataclass(frozen=True)
class _Inner:
    gain: float = 1.5
    names: tuple[str, ...] = ("a", "b")


@dataclass(frozen=True)
class _Config:
    mode: Literal["fast", "slow"] = "fast"
    count: int = 3
    inner: _Inner = _Inner()


class _Probe(LandingNode):
    def __init__(self, **kwargs):
        super().__init__("config_probe", **kwargs)
        self.config = self.load_config(_Config)


SCALARS = ["1e-3", "1.0e3", "1E3", "+.5e+2", "6.8523015e+5", ".5", "5.", "-.inf", ".NaN", "09", "1_000", "1:30",
           "0b11", "0o10", "0x10", "0X1F", "-0X10", "010", "+5", "-0", "12e", "yes", "Off", "2.5", "fast",
           "nan", "inf", "-Infinity", "y", "Y", "n", "N", "NO", "On", "oN", "yES", "tRue", "FALSE", "null", "Null",
           "~", "2026-11-27", "2001-12-14t21:59:43.10-05:00"]


def test_the_cli_reads_a_parameter_files_scalars_as_rcl_does(ros, tmp_path):
    """rcl's parser is the oracle: PyYAML's YAML 1.1 read 1e-3 as a string (so a tracker.yaml the
    node took failed `uav-landing evaluate`) and 1_000 or 1:30 as integers, which rcl reads as strings;
    y and n as strings, which rcl reads as booleans; null, ~ and dates as None and dates, which rcl
    reads as strings. (Left apart: numbers beyond a double.)"""
    params = tmp_path / "scalars.yaml"
    params.write_text("scalars:\n  ros__parameters:\n" + "".join(f"    p{i}: {v}\n" for i, v in enumerate(SCALARS)))
    node = ros.add(Node("scalars", context=ros.context, automatically_declare_parameters_from_overrides=True,
                        cli_args=["--ros-args", "--params-file", str(params)]))
    ours = load_node_parameters(params, "scalars")
    for i, text in enumerate(SCALARS):
        theirs = node.get_parameter(f"p{i}").value
        assert type(ours[f"p{i}"]) is type(theirs), text
        assert ours[f"p{i}"] == theirs or (math.isnan(theirs) and math.isnan(ours[f"p{i}"])), text


def test_config_from_params_file_nested_groups_and_defaults(ros, tmp_path):
    params = tmp_path / "probe.yaml"
    params.write_text("config_probe:\n  ros__parameters:\n    count: 7\n    inner:\n      gain: 2\n")
    node = ros.add(_Probe(context=ros.context, cli_args=["--ros-args", "--params-file", str(params)]))
    assert node.config == _Config(count=7, inner=_Inner(gain=2.0))
    # Every effective value is a declared parameter, defaults included.
    assert node.get_parameter("mode").value == "fast"
    assert list(node.get_parameter("inner.names").value) == ["a", "b"]


def test_a_parameter_set_at_run_time_is_refused_not_reported_as_applied(ros):
    """The node runs on the configuration it validated at start-up: a ``ros2 param set`` (here
    through the parameter services, as ros2cli does) is refused, whether the value is good or not."""
    from rclpy.parameter_client import AsyncParameterClient

    node = ros.add(_Probe(context=ros.context))
    client = AsyncParameterClient(ros.probe, "config_probe")
    assert ros.spin_until(lambda: client.services_are_ready())
    for param in (Parameter("count", value=9), Parameter("inner.gain", value=float("nan"))):
        future = client.set_parameters([param])
        assert ros.spin_until(future.done)
        result = future.result().results[0]
        assert not result.successful and "read-only" in result.reason
    assert node.get_parameter("count").value == 3 and node.get_parameter("inner.gain").value == 1.5
    assert node.config == _Config()


@pytest.mark.parametrize(
    "override, message",
    [
        (Parameter("mode", value="medium"), "mode: 'medium' is not one of"),
        (Parameter("count", value="three"), "count: expected an integer"),
        (Parameter("inner.gain", value=True), "inner.gain: expected a number"),
        (Parameter("colour", value=1), r"unknown key\(s\) \['colour'\]"),
        (Parameter("inner.gain", value=float("nan")), "inner.gain: expected a finite number"),
    ],
)
def test_bad_parameter_fails_start_up_naming_the_key(ros, override, message):
    with pytest.raises(ConfigError, match=message):
        _Probe(context=ros.context, parameter_overrides=[override])


@pytest.mark.parametrize("leaf_first", [True, False])
def test_a_name_given_both_as_a_value_and_as_a_group_fails_start_up(ros, leaf_first):
    overrides = [Parameter("inner", value="x"), Parameter("inner.gain", value=2.0)]
    with pytest.raises(ConfigError, match="parameter inner"):
        _Probe(context=ros.context, parameter_overrides=overrides if leaf_first else overrides[::-1])


def test_drops_are_logged_once_a_second_for_each_kind_and_all_counted(ros, monkeypatch):
    """A drop that repeats all the time (a MAVLink link down, every tick) must not hide the
    others from the log: one node-wide throttle let the link's errors hide a rejected pose's."""
    node = ros.add(_Probe(context=ros.context))
    logged = []
    monkeypatch.setattr(node, "get_logger", lambda: types.SimpleNamespace(error=logged.append))
    clock = [1000.0]
    monkeypatch.setattr(base.time, "monotonic", lambda: clock[0])
    for _ in range(3):
        node.drop("link down", count=2, kind="mavlink")
        node.drop("pose in frame 'x'")
    assert logged == ["dropped: link down", "dropped: pose in frame 'x'"]
    assert node.counters["dropped"] == 9 and node.last_error == "pose in frame 'x'"
    clock[0] += 1.0  # a second on: each kind is logged again
    node.drop("link down", kind="mavlink")
    node.drop("pose in frame 'y'")
    assert logged[2:] == ["dropped: link down", "dropped: pose in frame 'y'"]


def test_an_empty_list_parameter_is_an_empty_tuple(ros, tmp_path):
    """rcl hands ``[]`` (YAML or ``-p``) over untyped; rclpy refused to declare it and the node died."""
    params = tmp_path / "probe.yaml"
    params.write_text("config_probe:\n  ros__parameters:\n    inner:\n      names: []\n")
    node = ros.add(_Probe(context=ros.context, cli_args=["--ros-args", "--params-file", str(params)]))
    assert node.config == _Config(inner=_Inner(names=()))
    with pytest.raises(ConfigError, match=r"count: expected an integer, got \[\]"):
        _Probe(context=ros.context, cli_args=["--ros-args", "-p", "count:=[]"])


@pytest.mark.parametrize(
    "ros_args, message",
    [
        (["--params-file", "/nonexistent/probe.yaml"], "Couldn't parse params file: '--params-file /nonexistent/probe.yaml'"),
        (["-p", "inner.gain:=[1, 2.5]"], "Couldn't parse parameter override rule"),
        (["--bogus"], "--bogus"),
    ],
)
def test_run_node_exits_2_on_unusable_ros_arguments(capsys, ros_args, message):
    """A missing or malformed parameter file is a start-up failure like a bad value: one line, code 2."""
    assert run_node(_Probe, ["--ros-args", *ros_args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("[FATAL] cannot start: ") and message in err and "Traceback" not in err


def test_run_node_exits_2_naming_an_empty_list_given_for_a_value(capsys, ros_domain_id, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros_domain_id))
    assert run_node(_Probe, ["--ros-args", "-p", "count:=[]"]) == 2
    assert "count: expected an integer, got []" in capsys.readouterr().err


class _PublishesAfterShutdown(_Probe):
    """A callback at work when Ctrl-C / SIGTERM shuts the context down (as rclpy's signal handler
    does), publishing once it is done."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.create_timer(0.01, self._work)

    def _work(self):
        self.context.shutdown()
        self.publish_diagnostics()


def test_run_node_exits_0_when_a_callback_publishes_after_the_shutdown(capsys, ros_domain_id, monkeypatch):
    """rclpy raised RCLError ("publisher's context is invalid") out of the executor: exit code 1, a traceback."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros_domain_id))
    assert run_node(_PublishesAfterShutdown, ["--ros-args"]) == 0
    assert not rclpy.ok()


class _InterruptedInAConversion(_Probe):
    """Ctrl-C's KeyboardInterrupt raised while rclpy converts a message comes out of pybind11 as a
    RuntimeError; rclpy's signal thread shuts the context down a moment later."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.create_timer(0.01, self._take)

    def _take(self):
        threading.Timer(0.1, self.context.shutdown).start()
        raise RuntimeError("Unable to convert call argument '0' to Python object")


class _FailsInACallback(_Probe):
    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.create_timer(0.01, self._fail)

    def _fail(self):
        raise RuntimeError("a bug")


def test_run_node_exits_0_when_ctrl_c_interrupts_a_message_conversion(ros_domain_id, monkeypatch):
    """Seen stopping undistort while frames came (3 of 50 stops): exit code 1 and a traceback."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros_domain_id))
    assert run_node(_InterruptedInAConversion, ["--ros-args"]) == 0


class _InterruptedByCtrlC(_Probe):
    """Ctrl-C as rclpy delivers it: KeyboardInterrupt in the main thread at once, the context shut
    down by rclpy's signal thread a moment later, once it has triggered every executor's guard."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.create_timer(0.01, self._interrupt)

    def _interrupt(self):
        threading.Timer(0.2, self.context.shutdown).start()
        raise KeyboardInterrupt


def test_run_node_tears_down_after_a_ctrl_c_only_once_rclpys_signal_thread_is_done(ros_domain_id, monkeypatch):
    """The executor's teardown frees the guard condition list the signal thread walks: begun at
    the KeyboardInterrupt, it crashed the GCS bridge's stop (SIGSEGV on the signal thread)."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros_domain_id))
    context_up_at_teardown = []
    shutdown = SingleThreadedExecutor.shutdown

    def recording_shutdown(executor, *args, **kwargs):
        context_up_at_teardown.append(executor.context.ok())
        return shutdown(executor, *args, **kwargs)

    monkeypatch.setattr(SingleThreadedExecutor, "shutdown", recording_shutdown)
    assert run_node(_InterruptedByCtrlC, ["--ros-args"]) == 0
    assert context_up_at_teardown == [False]


def test_run_node_raises_a_callback_error_while_the_context_stays_up(ros_domain_id, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(ros_domain_id))
    with pytest.raises(RuntimeError, match="a bug"):
        run_node(_FailsInACallback, ["--ros-args"])
    assert not rclpy.ok()


CRASHES_IN_C = """
import ctypes, sys
from uav_landing_vision.nodes import base

class CrashesInC(base.LandingNode):
    def __init__(self, **kwargs):
        super().__init__("crash_probe", **kwargs)
        self.create_timer(0.01, self.read_null)

    def read_null(self):
        ctypes.string_at(0)

sys.exit(base.run_node(CrashesInC, ["--ros-args"]))
"""


def _run_script(script: str, ros_domain_id: int) -> subprocess.CompletedProcess:
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain_id),
               PYTHONPATH=os.pathsep.join([str(Path(__file__).parents[2] / "src" / "uav_landing_vision"), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=50)


def test_a_node_that_crashes_in_c_prints_where(ros_domain_id):
    """A node that died of SIGSEGV (undistort, once, stopping in CI) had said nothing."""
    done = _run_script(CRASHES_IN_C, ros_domain_id)
    assert done.returncode == -signal.SIGSEGV
    assert "Segmentation fault" in done.stderr and "in read_null" in done.stderr, done.stderr


HANGS_IN_TEARDOWN = """
import sys, time
from uav_landing_vision.nodes import base
base.TEARDOWN_LIMIT_S = 1.0

class HangsInTeardown(base.LandingNode):
    def __init__(self, **kwargs):
        super().__init__("teardown_probe", **kwargs)
        self.create_timer(0.01, self.context.shutdown)  # as Ctrl-C does

    def destroy_node(self):  # as Fast DDS's participant teardown once did, where no signal reaches it
        def stuck_in_teardown():
            time.sleep(60)
        stuck_in_teardown()

sys.exit(base.run_node(HangsInTeardown, ["--ros-args"]))
"""


def test_a_teardown_that_hangs_ends_the_process_printing_where(ros_domain_id):
    """Seen in loaded e2e runs: the GCS bridge stuck in rclpy's destroy_node (the middleware's C++),
    deaf to SIGINT and SIGTERM, until the graph killed it."""
    done = _run_script(HANGS_IN_TEARDOWN, ros_domain_id)
    assert done.returncode == 1
    assert "Timeout" in done.stderr and "in stuck_in_teardown" in done.stderr, done.stderr


def test_diagnostics_report_counters_and_the_last_error(ros):
    diagnostics = []
    ros.probe.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, RELIABLE_QOS)
    node = ros.add(_Probe(context=ros.context))
    node.counters["received"] += 2
    node.drop("bad thing")

    def report():
        for array in diagnostics:
            for status in array.status:
                if status.hardware_id == "config_probe":
                    return status
        return None

    assert ros.spin_until(lambda: report() is not None)
    status = report()
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.WARN and "bad thing" in status.message
    assert (values["received"], values["dropped"], values["published"], values["last_error"]) == ("2", "1", "0", "bad thing")


def test_a_nodes_links_show_what_dds_matched_against_what_the_node_sees_and_reach_its_diagnostics(ros):
    """A publisher before and after a subscriber of it appears; the image participant's publishers
    count as the node's; rclpy's own /rosout and /parameter_events are left out."""
    node = ros.add(_Probe(context=ros.context))
    pose_pub = node.create_publisher(PoseStamped, "/uav/pose", RELIABLE_QOS)
    node.create_image_publisher(Image, "camera/image_rect", IMAGE_QOS)
    node.create_subscription(PoseStamped, "/uav/ground_truth", lambda msg: None, RELIABLE_QOS)
    links = {(kind, topic): (matched, seen) for kind, topic, matched, seen in node.links()}
    assert links[("pub", "/uav/pose")] == (0, 0) and links[("sub", "/uav/ground_truth")] == (0, 0)
    assert ("pub", "/camera/image_rect") in links and ("pub", "/diagnostics") in links
    assert not {topic for _, topic in links} & {"/rosout", "/parameter_events"}
    ros.collect(PoseStamped, "/uav/pose", RELIABLE_QOS)
    ros.collect(Image, "/camera/image_rect", IMAGE_QOS)
    ros.probe.create_publisher(PoseStamped, "/uav/ground_truth", RELIABLE_QOS)
    up = lambda: all(0 < seen == matched for kind, topic, matched, seen in node.links() if topic != "/diagnostics")  # noqa: E731
    assert ros.spin_until(up)
    assert pose_pub.get_subscription_count() == 1
    diagnostics = ros.collect(DiagnosticArray, "/diagnostics", RELIABLE_QOS)
    assert ros.spin_until(lambda: any(s.hardware_id == "config_probe" for a in diagnostics for s in a.status))
    status = next(s for a in diagnostics for s in a.status if s.hardware_id == "config_probe")
    text = next(kv.value for kv in status.values if kv.key == base.LINKS_KEY)
    reported = {(kind, topic): (matched, seen) for kind, topic, matched, seen in parse_links(text)}
    assert reported[("pub", "/uav/pose")] == (1, 1) and reported[("sub", "/uav/ground_truth")] == (1, 1)
    assert reported[("pub", "/camera/image_rect")] == (1, 1)


def test_links_read_back_as_written_and_anything_else_is_refused():
    links = [("pub", "/uav/pose", 2, 3), ("sub", "/camera/image_rect", 1, 1)]
    assert format_links(links) == "pub /uav/pose 2/3; sub /camera/image_rect 1/1"
    assert parse_links(format_links(links)) == links and parse_links("") == []
    for bad in ("pub /uav/pose 2", "get /uav/pose 1/1", "pub uav/pose 1/1", "sub /a 1/x", "sub /a -1/1", "pub /a b 1/1"):
        with pytest.raises(ValueError, match="not a link"):
            parse_links(bad)


def test_stamp_cache_size_must_be_positive():
    """Size 0 would evict every incomplete stamp at once: nothing could ever pair."""
    with pytest.raises(ValueError, match="at least 1"):
        StampCache(("image", "boxes"), size=0)


def test_a_completing_message_still_hands_back_the_old_time_line():
    """The entries evicted by a time-line restart come back even when the same message
    completes its own stamp."""
    cache = StampCache(("image", "boxes"), size=3, restart_behind_ns=100)
    cache.add("image", 10, "i10")
    cache.add("image", 1000, "i1000")
    entry, evicted = cache.add("boxes", 10, "b10")
    assert entry.items == {"image": "i10", "boxes": "b10"}
    assert [e.stamp_ns for e in evicted] == [1000] and len(cache) == 0


def test_pop_older_and_pop_newer_return_oldest_first_and_exclude_the_stamp():
    cache = StampCache(("image", "boxes"), size=8)
    for stamp in (30, 20, 50, 40):
        cache.add("image", stamp, stamp)
    assert [e.stamp_ns for e in cache.pop_older(40)] == [20, 30]
    cache.add("image", 10, 10)
    assert [e.stamp_ns for e in cache.pop_newer(10)] == [40, 50]
    assert len(cache) == 1


def test_pop_expired_takes_the_expired_and_every_older_entry(monkeypatch):
    """Ages by the monotonic clock; the newest expired stamp and all older ones
    go, oldest first; younger entries with newer stamps stay."""
    from uav_landing_vision.nodes import sync

    cache = StampCache(("image", "boxes"), size=8)
    for stamp, since in ((10, 100.0), (20, 101.0), (30, 100.5), (40, 105.0), (50, 105.5)):
        cache.add("image", stamp, stamp)
        cache._entries[stamp].since = since
    cache.add("boxes", 25, "b25")  # stamp 25 arrived just now: not expired, but older than 30
    monkeypatch.setattr(sync.time, "monotonic", lambda: 106.0)
    assert [e.stamp_ns for e in cache.pop_expired(2.0)] == [10, 20, 25, 30]
    assert sorted(cache._entries) == [40, 50]
    assert cache.pop_expired(2.0) == []


def test_has_newer_looks_for_that_input_only_and_strictly_after():
    """A newer entry holding only the other input does not supersede a frame."""
    cache = StampCache(("image", "boxes"), size=8)
    cache.add("boxes", 30, "b30")
    cache.add("image", 20, "i20")
    assert not cache.has_newer("image", 20)
    cache.add("image", 40, "i40")
    assert cache.has_newer("image", 20) and cache.has_newer("image", 39) and not cache.has_newer("image", 40)


def test_a_message_exactly_restart_behind_ns_before_a_waiting_entry_is_late_not_a_new_time_line():
    cache = StampCache(("image", "boxes"), size=4, restart_behind_ns=100)
    cache.add("image", 1000, "i1000")
    assert cache.add("boxes", 900, "b900") == (None, [])  # exactly 100 ns behind: still the same time-line
    assert len(cache) == 2
    entry, evicted = cache.add("boxes", 899, "b899")  # 101 ns behind: the old time-line goes
    assert entry is None and [e.stamp_ns for e in evicted] == [1000]
    assert sorted(cache._entries) == [899, 900]


# Poses: what pose_to_numpy accepts, what it refuses, and the axis and quaternion order it keeps.


def _pose(position, quat) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in position)
    pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w = (float(v) for v in quat)
    return pose


def test_pose_to_numpy_reads_x_y_z_and_a_quaternion_in_x_y_z_w_order():
    rng = np.random.default_rng(7)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    position, quat = pose_to_numpy(_pose([1.0, -2.0, 30.0], q))
    np.testing.assert_array_equal(position, [1.0, -2.0, 30.0])
    np.testing.assert_array_equal(quat, q)
    back = numpy_to_pose(Pose(), position, quat)
    assert (back.orientation.x, back.orientation.y, back.orientation.z, back.orientation.w) == tuple(q)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
@pytest.mark.parametrize("index", range(4))
def test_pose_to_numpy_refuses_a_quaternion_with_a_non_finite_component(bad, index):
    """NaN makes ‖q‖ NaN, and a NaN never compares above the tolerance: only the finiteness check refuses it."""
    q = [0.0, 0.0, 0.0, 1.0]
    q[index] = bad
    with pytest.raises(ValueError, match="quaternion is not a finite unit"):
        pose_to_numpy(_pose([0.0, 0.0, 10.0], q))


@pytest.mark.parametrize("scale", [0.5, 0.99, 0.999, 1.001, 1.01, 2.0])
def test_pose_to_numpy_refuses_a_quaternion_too_short_or_too_long(scale):
    q = np.array([0.1, -0.2, 0.3, 0.9])
    q = scale * q / np.linalg.norm(q)
    with pytest.raises(ValueError, match="quaternion is not a finite unit"):
        pose_to_numpy(_pose([0.0, 0.0, 10.0], q))


@pytest.mark.parametrize("scale", [1.0 - 5e-5, 1.0, 1.0 + 5e-5])
def test_pose_to_numpy_accepts_a_quaternion_within_float32_rounding_of_unit(scale):
    q = np.array([0.1, -0.2, 0.3, 0.9])
    q = scale * q / np.linalg.norm(q)
    _, quat = pose_to_numpy(_pose([0.0, 0.0, 10.0], q))
    np.testing.assert_array_equal(quat, q)  # as sent: the node does not renormalise


# Images: what image_to_numpy refuses, and the axis and channel order the conversions keep.


@pytest.mark.parametrize("width, height", [(0, 5), (7, 0)])
def test_an_image_with_one_side_zero_is_refused_as_empty(width, height):
    msg = Image(height=height, width=width, encoding="rgb8", step=width * 3, data=b"")
    with pytest.raises(ImageError, match="empty image"):
        image_to_numpy(msg)


@pytest.mark.parametrize("extra", [1, 7, 21])
def test_image_data_longer_than_step_times_height_is_an_image_error(extra):
    """Too much data is as unusable as too little, and must be an ImageError (what the nodes catch),
    not numpy's reshape error."""
    msg = image_msg(np.zeros((5, 7, 3), np.uint8), "rgb8")
    msg.data = bytes(5 * 21 + extra)
    with pytest.raises(ImageError, match="expected step x height"):
        image_to_numpy(msg)


@pytest.mark.parametrize("encoding, shape", [("rgb8", (4, 6, 3)), ("bgr8", (4, 6, 3)), ("mono8", (4, 6))])
@pytest.mark.parametrize("pad", [0, 2])
def test_image_to_numpy_gives_a_read_only_view(encoding, shape, pad):
    pixels = np.random.default_rng(3).integers(0, 256, size=shape, dtype=np.uint8)
    view = image_to_numpy(image_msg(pixels, encoding, pad=pad))
    np.testing.assert_array_equal(view, pixels)
    assert not view.flags.writeable
    with pytest.raises(ValueError):
        view[0, 0] = 1


def test_image_to_rgb_swaps_bgr_channels_and_keeps_rgb():
    rgb = np.random.default_rng(5).integers(0, 256, size=(3, 4, 3), dtype=np.uint8)
    np.testing.assert_array_equal(image_to_rgb(image_msg(rgb, "rgb8")), rgb)
    np.testing.assert_array_equal(image_to_rgb(image_msg(np.ascontiguousarray(rgb[..., ::-1]), "bgr8", pad=5)), rgb)
    with pytest.raises(ImageError, match="has no colour"):
        image_to_rgb(image_msg(rgb[..., 0].copy(), "mono8"))


def test_numpy_to_image_of_a_non_square_frame_has_height_rows_of_width_pixels():
    pixels = np.random.default_rng(9).integers(0, 256, size=(3, 5, 3), dtype=np.uint8)
    msg = numpy_to_image(pixels, "bgr8", Image().header)
    assert (msg.height, msg.width, msg.step, msg.is_bigendian, len(msg.data)) == (3, 5, 15, 0, 45)
    np.testing.assert_array_equal(np.frombuffer(bytes(msg.data), np.uint8).reshape(3, 5, 3), pixels)


@pytest.mark.parametrize("encoding, shape", [("rgb8", (4, 6, 4)), ("bgr8", (4, 6, 1)), ("rgb8", (4, 6, 2))])
def test_numpy_to_image_refuses_a_colour_array_of_another_channel_count(encoding, shape):
    """A 4-channel array written as rgb8 would give data longer than step x height."""
    with pytest.raises(ImageError, match=f"{encoding} needs a uint8 array of 3 dimensions"):
        numpy_to_image(np.zeros(shape, np.uint8), encoding, Image().header)


def test_compressed_images_travel_with_the_image_qos_as_raw_images_and_camera_info_do():
    for name in ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo"):
        assert qos_for_type(name) is IMAGE_QOS, name


# Calibration: a camera_info that differs from the one in use in any field the camera is built
# from is a new calibration (taken, or refused), never a repeat.

QVGA_CAMERA = CameraModel(320, 240, np.array([[300.0, 0.0, 160.0], [0.0, 300.0, 120.0], [0.0, 0.0, 1.0]]),
                          np.array([-0.2, 0.05, 0.001, -0.001, 0.0]))


def _info(**changes) -> CameraInfo:
    """QVGA_CAMERA's camera_info with the fields named changed (``roi_*``: those of its region of interest)."""
    msg = camera_info_msg(QVGA_CAMERA)
    for name, value in changes.items():
        if name.startswith("roi_"):
            setattr(msg.roi, name[4:], value)
        else:
            setattr(msg, name, value)
    return msg


def test_a_camera_info_of_another_height_only_is_a_new_calibration_of_that_height():
    calibration = Calibration()
    assert calibration.update(_info())
    assert calibration.update(_info(height=250))
    assert (calibration.camera.width, calibration.camera.height) == (320, 250)
    assert not calibration.update(_info(height=250))  # a repeat


def test_a_camera_info_of_another_width_only_is_a_new_calibration_of_that_width():
    calibration = Calibration()
    assert calibration.update(_info())
    assert calibration.update(_info(width=330))
    assert (calibration.camera.width, calibration.camera.height) == (330, 240)


@pytest.mark.parametrize("changes, message", [
    ({"r": [0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]}, "R must be identity"),
    ({"binning_x": 2}, "binning 2x0"),
    ({"binning_y": 2}, "binning 0x2"),
    ({"roi_x_offset": 8}, "region of interest"),
    ({"roi_y_offset": 8}, "region of interest"),
    ({"roi_width": 160, "roi_height": 120}, "region of interest"),
])
def test_a_camera_info_that_changes_only_an_unsupported_field_is_refused_not_taken_for_a_repeat(changes, message):
    calibration = Calibration()
    assert calibration.update(_info())
    with pytest.raises(CameraInfoError, match=message):
        calibration.update(_info(**changes))
    assert calibration.camera.width == 320 and message in calibration.refused
    assert calibration.update(_info()) is False  # the calibration in use, again: a repeat
    assert calibration.camera.height == 240
    assert calibration.refused == ""  # the latest camera_info is the one in use


def test_the_reason_of_a_refusal_is_kept_until_a_calibration_is_taken():
    calibration = Calibration(rectified=True)
    with pytest.raises(CameraInfoError):
        calibration.update(_info())  # distortion on a rectified topic
    assert "distortion" in calibration.refused
    assert "refused: " in calibration.waiting_for("no camera_info")
    assert calibration.update(_info(d=[0.0] * 5))
    assert calibration.refused == "" and calibration.waiting_for("no camera_info") == "no camera_info"


def test_a_camera_info_that_changes_only_the_distortion_model_is_a_new_calibration():
    """An equidistant lens with the same (zero) coefficients still projects θ, not tan θ."""
    calibration = Calibration()
    assert calibration.update(_info(d=[0.0] * 4, distortion_model="plumb_bob"))
    assert calibration.update(_info(d=[0.0] * 4, distortion_model="equidistant"))
    assert calibration.camera.distortion_model == "equidistant"


# LandingNode: the parameters a nested configuration declares, the throttle of drop logs, and the
# level of /diagnostics report by report. Callbacks are called directly.


@dataclass(frozen=True)
class _Deep:
    gain: float = 1.5


@dataclass(frozen=True)
class _Middle:
    deep: _Deep = _Deep()
    count: int = 2


@dataclass(frozen=True)
class _NestedConfig:
    middle: _Middle = _Middle()
    mode: str = "fast"


class _NestedProbe(LandingNode):
    def __init__(self, **kwargs):
        super().__init__("base_probe", **kwargs)
        self.config = self.load_config(_NestedConfig)


def test_a_nested_group_two_levels_deep_declares_its_defaults_under_the_full_dotted_name(ros):
    node = ros.add(_NestedProbe(context=ros.context))
    assert node.config == _NestedConfig()
    assert node.get_parameter("middle.deep.gain").value == 1.5
    assert node.get_parameter("middle.count").value == 2
    assert not node.has_parameter("deep.gain")


def test_drops_of_one_kind_are_logged_at_most_once_a_second_and_other_kinds_still_are(ros, monkeypatch):
    node = ros.add(_Probe(context=ros.context))
    logged = []
    monkeypatch.setattr(node, "get_logger", lambda: types.SimpleNamespace(error=logged.append))
    clock = [500.0]
    monkeypatch.setattr(base.time, "monotonic", lambda: clock[0])
    node.drop("pose a")  # kind "message" first, then another kind at the same instant
    node.drop("link down", kind="mavlink")
    assert logged == ["dropped: pose a", "dropped: link down"]
    clock[0] += 0.5  # half a second on: neither kind again
    node.drop("pose b")
    node.drop("link down", kind="mavlink")
    assert len(logged) == 2
    clock[0] += 0.5  # a second after the first
    node.drop("pose c")
    assert logged[2:] == ["dropped: pose c"]
    assert node.counters["dropped"] == 5


def test_diagnostics_warn_only_for_drops_since_the_last_report(ros):
    node = ros.add(_Probe(context=ros.context))
    reports = []
    node._diagnostics = types.SimpleNamespace(publish=reports.append)
    node.drop("bad thing", count=3)
    node.publish_diagnostics()
    node.publish_diagnostics()  # nothing dropped since: OK again
    node.drop("worse thing")
    node.publish_diagnostics()
    levels = [r.status[0].level for r in reports]
    assert levels == [DiagnosticStatus.WARN, DiagnosticStatus.OK, DiagnosticStatus.WARN]
    assert reports[0].status[0].message.startswith("dropped 3 in the last")
    assert reports[1].status[0].message == "ok"
    assert reports[2].status[0].message.startswith("dropped 1 in the last")
    values = {kv.key: kv.value for kv in reports[2].status[0].values}
    assert values["dropped"] == "4" and values["last_error"] == "worse thing"
