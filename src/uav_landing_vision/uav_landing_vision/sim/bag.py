"""Simulated sequences on disk: rosbag2 (mcap) through ``rosbags``, and plain PNG + CSV folders.

Topics: ``/camera/image_raw`` (sensor_msgs/Image, rgb8), ``/camera/camera_info`` and
``/uav/ground_truth`` (geometry_msgs/PoseStamped in the camera optical frame), one message
each per frame with the same header stamp (also the bag's record time).
"""

import csv
from contextlib import closing, contextmanager
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from .. import stamps
from ..camera import (
    DEFAULT_FRAME_ID, CameraModel, camera_from_info_msg, camera_info_fields, decode_compressed, save_camera_info_yaml,
    write_image,
)

IMAGE_TOPIC = "/camera/image_raw"
COMPRESSED_IMAGE_TOPIC = IMAGE_TOPIC + "/compressed"  # image_transport's compressed frames, read where IMAGE_TOPIC is absent
INFO_TOPIC = "/camera/camera_info"
TRUTH_TOPIC = "/uav/ground_truth"
POSE_TYPES = ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped")
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)
CSV_HEADER = ["stamp_ns", "x", "y", "z", "qx", "qy", "qz", "qw"]

_TS = get_typestore(Stores.ROS2_JAZZY)


@dataclass(frozen=True)
class Poses:
    """Stamped poses: ``stamps_ns (N,)`` int64, ``trans (N,3)``, ``quat (N,4)`` [x,y,z,w]."""

    stamps_ns: np.ndarray
    trans: np.ndarray
    quat: np.ndarray


class SequenceWriter:
    """Write frames to a new rosbag2 directory (mcap) and, optionally, a PNG + CSV folder."""

    def __init__(self, bag_dir, camera: CameraModel, png_dir=None, compress: bool = False):
        self.camera = camera
        self.png_dir = Path(png_dir) if png_dir else None
        self._csv = None
        if self.png_dir:  # first, so that a PNG folder that exists leaves no bag behind
            self.png_dir.mkdir(parents=True, exist_ok=False)
            save_camera_info_yaml(camera, self.png_dir / "camera_info.yaml")
            self._csv_file = (self.png_dir / "ground_truth.csv").open("w", newline="")
            self._csv = csv.writer(self._csv_file)
            self._csv.writerow(CSV_HEADER)
        self.writer = Writer(Path(bag_dir), version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP)
        if compress:
            self.writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self.writer.open()
        self.conn = {
            IMAGE_TOPIC: self.writer.add_connection(IMAGE_TOPIC, "sensor_msgs/msg/Image", typestore=_TS),
            INFO_TOPIC: self.writer.add_connection(INFO_TOPIC, "sensor_msgs/msg/CameraInfo", typestore=_TS),
            TRUTH_TOPIC: self.writer.add_connection(TRUTH_TOPIC, "geometry_msgs/msg/PoseStamped", typestore=_TS),
        }
        info = camera_info_fields(camera)
        self._info = dict(height=info["height"], width=info["width"], distortion_model=info["distortion_model"],
                          d=np.array(info["d"]), k=np.array(info["k"]), r=np.array(info["r"]), p=np.array(info["p"]))

    def write(self, stamp_ns: int, image_rgb: np.ndarray, trans: np.ndarray, quat: np.ndarray) -> None:
        m = _TS.types
        sec, nanosec = stamps.stamp_fields(stamp_ns)
        header = m["std_msgs/msg/Header"](stamp=m["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec),
                                          frame_id=self.camera.frame_id)
        h, w = image_rgb.shape[:2]
        image = m["sensor_msgs/msg/Image"](header=header, height=h, width=w, encoding="rgb8", is_bigendian=0,
                                           step=3 * w, data=np.ascontiguousarray(image_rgb).reshape(-1))
        roi = m["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        info = m["sensor_msgs/msg/CameraInfo"](header=header, binning_x=0, binning_y=0, roi=roi, **self._info)
        pose = m["geometry_msgs/msg/Pose"](
            position=m["geometry_msgs/msg/Point"](x=float(trans[0]), y=float(trans[1]), z=float(trans[2])),
            orientation=m["geometry_msgs/msg/Quaternion"](x=float(quat[0]), y=float(quat[1]),
                                                          z=float(quat[2]), w=float(quat[3])))
        truth = m["geometry_msgs/msg/PoseStamped"](header=header, pose=pose)
        for topic, msg in ((IMAGE_TOPIC, image), (INFO_TOPIC, info), (TRUTH_TOPIC, truth)):
            self.writer.write(self.conn[topic], stamp_ns, _TS.serialize_cdr(msg, self.conn[topic].msgtype))
        if self._csv:
            write_image(self.png_dir / f"{stamp_ns}.png", image_rgb)
            self._csv.writerow([stamp_ns, *map(repr, map(float, trans)), *map(repr, map(float, quat))])

    def close(self) -> None:
        self.writer.close()
        if self._csv:
            self._csv_file.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class BagError(ValueError):
    """A rosbag2 bag that cannot be opened, or read to its end."""


@contextmanager
def _as_bag_error():
    """Turn whatever reading a bag raises into :class:`BagError`: rosbags passes a damaged
    file's zstd, EOF and sqlite errors on as they are."""
    try:
        yield
    except Exception as exc:
        raise BagError(str(exc) or type(exc).__name__) from exc


def open_bag(path) -> Reader:
    """The open reader of a bag (a rosbag2 folder, or one .mcap / .db3 file); :class:`BagError`
    (the reason) if it cannot be opened."""
    with _as_bag_error():
        reader = Reader(Path(path))
        reader.open()
    return reader


def bag_messages(reader: Reader, connections=()):
    """``reader.messages(connections)`` (all of them without any); :class:`BagError` where the
    file turns out to be damaged."""
    messages = reader.messages(connections=connections)
    while True:
        with _as_bag_error():
            item = next(messages, None)
        if item is None:
            return
        yield item


def _stamp(header) -> int:
    """A header's stamp in integer ns; :class:`BagError` for a malformed one."""
    try:
        return stamps.stamp_ns(header.stamp)
    except ValueError as exc:
        raise BagError(str(exc)) from exc


def _decode_image(msg) -> np.ndarray:
    """RGB uint8 (H, W, 3) of a sensor_msgs/Image (rgb8, bgr8, mono8) or CompressedImage."""
    if hasattr(msg, "format"):
        pixels, encoding = decode_compressed(msg.data, msg.format)
        return cv2.cvtColor(pixels, cv2.COLOR_BGR2RGB if encoding == "bgr8" else cv2.COLOR_GRAY2RGB)
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1}.get(msg.encoding)
    if channels is None:
        raise ValueError(f"unsupported image encoding {msg.encoding!r} (rgb8, bgr8, mono8)")
    rows = np.asarray(msg.data, np.uint8).reshape(msg.height, msg.step)
    img = rows[:, : msg.width * channels].reshape(msg.height, msg.width, channels)
    if msg.encoding == "bgr8":
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    if msg.encoding == "mono8":
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    return img.copy()


def _topic_messages(path, topic: str, types: tuple[str, ...]):
    """Deserialised messages of ``topic`` (or of the first topic with one of ``types`` if empty).
    A missing or unreadable bag or topic, or a topic of another type, is a ValueError naming both."""
    try:
        with closing(open_bag(path)) as reader:
            conns = [c for c in reader.connections if (c.topic == topic if topic else c.msgtype in types)]
            if not conns and topic == IMAGE_TOPIC:
                conns = [c for c in reader.connections if c.topic == COMPRESSED_IMAGE_TOPIC]
            if not conns:
                found = sorted(f"{c.topic} [{c.msgtype}]" for c in reader.connections)
                raise ValueError(f"{path}: no topic {topic or 'of type ' + ' or '.join(types)}; has {found}")
            conns = [c for c in conns if c.topic == conns[0].topic]
            wrong = sorted({c.msgtype for c in conns} - set(types))
            if wrong:
                raise ValueError(f"{path}: topic {conns[0].topic} is {', '.join(wrong)}, not {' or '.join(types)}")
            for conn, _, raw in bag_messages(reader, conns):
                yield _TS.deserialize_cdr(raw, conn.msgtype)
    except (BagError, SerdeError) as exc:
        what = topic or f"the {' or '.join(types)} topic"
        raise ValueError(f"cannot read {what} of bag {path}: {exc}") from exc


def recorded_topics(remaps=None) -> tuple[str, str, str]:
    """The bag topics of the frames, their camera_info and the ground truth: :data:`IMAGE_TOPIC`,
    :data:`INFO_TOPIC` and :data:`TRUTH_TOPIC`, or what the topic ``remaps`` ``{recorded: name}``
    (``uav-landing graph --remap FROM:=TO``) play under those names."""
    recorded = {name: source for source, name in (remaps or {}).items()}
    return tuple(recorded.get(name, name) for name in (IMAGE_TOPIC, INFO_TOPIC, TRUTH_TOPIC))


def iter_images(path, topic: str = IMAGE_TOPIC):
    """RGB frames of an image topic of a bag (empty topic: the first Image/CompressedImage topic;
    :data:`IMAGE_TOPIC`: :data:`COMPRESSED_IMAGE_TOPIC` in a bag that has only that)."""
    for msg in _topic_messages(path, topic, IMAGE_TYPES):
        yield _decode_image(msg)


def iter_frames(path, topic: str = IMAGE_TOPIC):
    """``(stamp_ns, rgb image)`` pairs of a bag's image topic, in order."""
    for msg in _topic_messages(path, topic, IMAGE_TYPES):
        yield _stamp(msg.header), _decode_image(msg)


def increasing_frames(path, topic: str = IMAGE_TOPIC):
    """:func:`iter_frames`, each frame checked to be stamped after the one before: a frame recorded
    twice or out of order raises ValueError naming both (an evaluation would score it twice, or
    against the wrong motion)."""
    last = None
    for k, (stamp, image) in enumerate(iter_frames(path, topic)):
        if last is not None and stamp <= last:
            raise ValueError(f"{path}: frame {k} is stamped {stamp} ns, not after frame {k - 1} ({last} ns): "
                             "a recording's frames must have increasing header stamps")
        last = stamp
        yield stamp, image


def read_camera(path, topic: str = INFO_TOPIC) -> CameraModel:
    """The camera of the first camera_info message of a bag."""
    for msg in _topic_messages(path, topic, INFO_TYPES):
        return camera_from_info_msg(msg, frame_id=msg.header.frame_id or DEFAULT_FRAME_ID)
    raise ValueError(f"{path}: no message on {topic or 'a camera_info topic'}")


def read_poses(path, topic: str = "") -> Poses:
    """Stamped poses from a bag topic (PoseStamped or PoseWithCovarianceStamped), a CSV file, or
    a simulator PNG folder (its ``ground_truth.csv``). For a bag, an empty topic means
    ``/uav/ground_truth``.
    """
    path = Path(path)
    if path.is_dir() and (path / "ground_truth.csv").exists():
        path = path / "ground_truth.csv"
    if path.suffix == ".csv":
        return read_pose_csv(path)
    stamps, trans, quat = [], [], []
    for msg in _topic_messages(path, topic or TRUTH_TOPIC, POSE_TYPES):
        pose = msg.pose.pose if hasattr(msg.pose, "covariance") else msg.pose
        stamps.append(_stamp(msg.header))
        trans.append([pose.position.x, pose.position.y, pose.position.z])
        quat.append([pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w])
    return Poses(np.array(stamps, np.int64), np.array(trans, float).reshape(-1, 3), np.array(quat, float).reshape(-1, 4))


def read_pose_csv(path) -> Poses:
    """Poses from a CSV with the columns ``stamp_ns,x,y,z,qx,qy,qz,qw`` (extra columns ignored);
    none for a header alone (the estimates of a run that posed no frame)."""
    with Path(path).open(newline="") as f:
        reader = csv.DictReader(f)
        missing = [c for c in CSV_HEADER if c not in (reader.fieldnames or [])]
        if missing:
            raise ValueError(f"{path}: needs a header with {CSV_HEADER} (missing {missing})")
        rows = []
        for row in reader:
            if any(row[c] is None for c in CSV_HEADER):
                raise ValueError(f"{path}: line {reader.line_num} has fewer than the {len(CSV_HEADER)} columns")
            try:
                stamp = int(row["stamp_ns"])
                if not -(2**63) <= stamp < 2**63:
                    raise ValueError(f"stamp_ns {stamp} does not fit 64 bits")
                rows.append((stamp, *(float(row[c]) for c in CSV_HEADER[1:])))
            except ValueError as exc:
                raise ValueError(f"{path}: line {reader.line_num}: {exc}") from None
    values = np.array([r[1:] for r in rows], float).reshape(-1, 7)
    return Poses(np.array([r[0] for r in rows], np.int64), values[:, :3], values[:, 3:])


def write_pose_csv(path, poses: Poses) -> None:
    """Write poses in the CSV format of :func:`read_pose_csv`."""
    with Path(path).open("w", newline="") as f:
        out = csv.writer(f)
        out.writerow(CSV_HEADER)
        for s, t, q in zip(poses.stamps_ns, poses.trans, poses.quat):
            out.writerow([int(s), *map(repr, map(float, t)), *map(repr, map(float, q))])
