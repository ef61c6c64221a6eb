"""Configuration of the GCS bridge: the ``gcs_bridge`` section of ``config/gcs_bridge.yaml``.

Fields mirror the YAML keys, so angles are in degrees (``*_deg``); the radian properties are
what the code uses. Loading goes through the shared :mod:`uav_landing_vision.config` loader:
unknown, missing or invalid keys raise ``ConfigError`` (a ``ValueError``).
"""

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from ..config import ConfigError, from_mapping, load_node_parameters

MessageName = Literal["ODOMETRY", "ATT_POS_MOCAP", "VISION_POSITION_ESTIMATE", "LANDING_TARGET"]
GO_AROUND_DEADLINE_S = 0.5

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class CameraMountConfig:
    frame_id: str  # the camera's optical frame, as its images (hence the tracker's poses) name it
    position_m: Vec3  # optical centre in the ship frame (x bow, y starboard, z down)
    rpy_deg: Vec3  # Z-Y-X roll, pitch, yaw of the camera mount in the ship frame

    def __post_init__(self):
        if not self.frame_id.strip():
            raise ValueError("camera.frame_id must not be empty")

    @property
    def rpy(self) -> Vec3:
        return tuple(math.radians(a) for a in self.rpy_deg)


@dataclass(frozen=True)
class ConeConfig:
    """Landing cone of Fig. 1.5 and the no-return range of Fig. 1.4."""

    alpha1_deg: float  # maximum apparent descent angle
    alpha2_deg: float  # minimum apparent descent angle
    glide_slope_deg: float  # nominal apparent descent angle
    beta2_deg: float  # full horizontal opening: inside when |lateral angle| <= beta2 / 2
    distance_m: float  # d: the cone is flown within this range of the landing point
    no_return_distance_m: float  # NO_RETURN below this range
    no_return_confirm_poses: int  # NO_RETURN needs this many successive in-cone poses, the last within range
    max_range_rate_mps: float  # a range change faster than this between successive poses breaks that run
    approach_course_deg: float  # course of the landing UAV in the ship frame (0 = toward the bow)

    def __post_init__(self):
        if not 0.0 < self.alpha2_deg < self.glide_slope_deg < self.alpha1_deg < 90.0:
            raise ValueError("cone: need 0 < alpha2_deg < glide_slope_deg < alpha1_deg < 90")
        if not 0.0 < self.beta2_deg < 180.0:
            raise ValueError("cone.beta2_deg must be in (0, 180)")
        if not 0.0 < self.no_return_distance_m < self.distance_m:
            raise ValueError("cone: need 0 < no_return_distance_m < distance_m")
        if self.no_return_confirm_poses < 2:
            raise ValueError("cone.no_return_confirm_poses must be an integer >= 2")
        if not 0.0 < self.max_range_rate_mps < math.inf:
            raise ValueError("cone.max_range_rate_mps must be > 0 and finite")
        if not math.isfinite(self.approach_course_deg):
            raise ValueError("cone.approach_course_deg must be finite")

    alpha1 = property(lambda self: math.radians(self.alpha1_deg))
    alpha2 = property(lambda self: math.radians(self.alpha2_deg))
    glide_slope = property(lambda self: math.radians(self.glide_slope_deg))
    beta2 = property(lambda self: math.radians(self.beta2_deg))
    approach_course = property(lambda self: math.radians(self.approach_course_deg))


@dataclass(frozen=True)
class MavlinkConfig:
    connection: str  # udpout:HOST:PORT, udpin:HOST:PORT, tcp:HOST:PORT or a serial device (gcs.link)
    system_id: int
    component_id: int
    messages: tuple[MessageName, ...]
    odometry_frame: Literal["LOCAL_FRD", "LOCAL_NED", "MOCAP_NED"]
    rate_hz: float  # position messages per second at most
    signing_key_file: str  # "" = no signing
    signing_link_id: int
    signing_timestamp_file: str  # where the signing timestamp survives restarts; "" = the key file's path + ".timestamp"

    def __post_init__(self):
        if not self.connection.strip():
            raise ValueError("mavlink.connection must not be empty")
        if not (1 <= self.system_id <= 255 and 1 <= self.component_id <= 255):
            raise ValueError("mavlink.system_id and mavlink.component_id must be in 1..255")
        if not 0 <= self.signing_link_id <= 255:
            raise ValueError("mavlink.signing_link_id must be in 0..255")
        if not self.messages or len(set(self.messages)) != len(self.messages):
            raise ValueError(f"mavlink.messages must be a non-empty list of distinct names, got {self.messages}")
        if not 0.0 < self.rate_hz <= 100.0:
            raise ValueError("mavlink.rate_hz must be in (0, 100]")
        if self.signing_timestamp_file and not self.signing_key_file:
            raise ValueError("mavlink.signing_timestamp_file is set, but signing is off (no mavlink.signing_key_file)")

    @property
    def signing_timestamp_path(self) -> str:
        """The signing timestamp's state file ("" without signing)."""
        if not self.signing_key_file:
            return ""
        return self.signing_timestamp_file or self.signing_key_file + ".timestamp"


MAX_SHIP_OFFSET_M = 1e3  # camera and net lie on the ship (beyond float32, every pose was refused)


@dataclass(frozen=True)
class GcsBridgeConfig:
    camera: CameraMountConfig
    net_position_m: Vec3  # landing point (centre of the net) in the ship frame
    cone: ConeConfig
    mavlink: MavlinkConfig
    stale_timeout_s: float  # a pose older than this is stale
    go_around_hold_s: float  # GO_AROUND lasts this long before LOITER

    def __post_init__(self):
        if not all(math.isfinite(v) for v in (*self.camera.position_m, *self.camera.rpy_deg, *self.net_position_m)):
            raise ValueError("camera and net positions and angles must be finite")
        if max(map(abs, (*self.camera.position_m, *self.net_position_m))) > MAX_SHIP_OFFSET_M:
            raise ValueError(f"camera and net positions must lie within {MAX_SHIP_OFFSET_M:g} m of the ship frame's "
                             f"origin, got {self.camera.position_m} and {self.net_position_m}")
        worst_delay = self.stale_timeout_s + 1.0 / self.mavlink.rate_hz  # staleness + one tick
        if not (self.stale_timeout_s > 0.0 and worst_delay <= GO_AROUND_DEADLINE_S):
            raise ValueError(
                f"need stale_timeout_s > 0 and stale_timeout_s + 1/mavlink.rate_hz <= {GO_AROUND_DEADLINE_S} s "
                "(the go-around advisory deadline)"
            )
        if not 0.0 <= self.go_around_hold_s < math.inf:
            raise ValueError("go_around_hold_s must be >= 0 and finite")


def load_config(path: str | Path, node: str = "gcs_bridge") -> GcsBridgeConfig:
    """The bridge configuration from a ROS 2 parameter file."""
    return config_from_parameters(load_node_parameters(path, node), where=f"{path}:{node}")


def config_from_parameters(params: Mapping, where: str = "gcs_bridge") -> GcsBridgeConfig:
    """From nested parameters or ROS-style dotted names (``cone.alpha1_deg``), as a node holds them."""
    return from_mapping(GcsBridgeConfig, _nest(params), where)


def _nest(params: Mapping) -> dict:
    out: dict = {}
    for key, value in params.items():
        *groups, leaf = str(key).split(".")
        node = out
        for group in groups:
            node = node.setdefault(group, {})
            if not isinstance(node, dict):
                raise ConfigError(f"parameter '{key}' clashes with the value of '{group}'")
        node[leaf] = _nest(value) if isinstance(value, Mapping) else value
    return out
