"""Configuration of the GCS bridge, read from the ``gcs_bridge`` section of ``config/gcs_bridge.yaml``.

The YAML holds degrees (``*_deg``); the dataclasses hold radians. Unknown, missing or
invalid keys raise ``ValueError`` naming the key.
"""

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import yaml

MESSAGE_NAMES = ("ODOMETRY", "ATT_POS_MOCAP", "VISION_POSITION_ESTIMATE", "LANDING_TARGET")
ODOMETRY_FRAMES = ("LOCAL_FRD", "LOCAL_NED", "MOCAP_NED")
GO_AROUND_DEADLINE_S = 0.5


@dataclass(frozen=True)
class ConeConfig:
    """Landing cone of Fig. 1.5 and the no-return range of Fig. 1.4; angles in radians."""

    alpha1: float  # maximum apparent descent angle
    alpha2: float  # minimum apparent descent angle
    glide_slope: float  # nominal apparent descent angle, alpha2 < glide_slope < alpha1
    beta2: float  # full horizontal opening; inside when |lateral angle| <= beta2 / 2
    distance: float  # d: the cone starts this far from the landing point (m)
    no_return_distance: float  # range below which the landing cannot be aborted (m)
    approach_course: float  # course flown by the landing UAV in the landing frame (0 = toward the bow)


@dataclass(frozen=True)
class MavlinkConfig:
    connection: str  # pymavlink connection string (udpout:, udpin:, tcp:, serial device)
    system_id: int
    component_id: int
    messages: tuple[str, ...]
    odometry_frame: str
    rate_hz: float
    signing_key_file: str  # "" = no signing
    signing_link_id: int


@dataclass(frozen=True)
class GcsBridgeConfig:
    camera_position: tuple[float, float, float]  # camera optical centre in the ship frame (m)
    camera_rpy: tuple[float, float, float]  # Z-Y-X roll, pitch, yaw of the camera in the ship frame (rad)
    net_position: tuple[float, float, float]  # landing point in the ship frame (m)
    cone: ConeConfig
    mavlink: MavlinkConfig
    stale_timeout_s: float
    go_around_hold_s: float


_SCHEMA = {
    "camera": {"position_m": "vec3", "rpy_deg": "vec3"},
    "landing": {"net_position_m": "vec3", "approach_course_deg": "float"},
    "cone": {
        "alpha1_deg": "float",
        "alpha2_deg": "float",
        "glide_slope_deg": "float",
        "beta2_deg": "float",
        "distance_m": "float",
        "no_return_distance_m": "float",
    },
    "mavlink": {
        "connection": "str",
        "system_id": "int",
        "component_id": "int",
        "messages": "strlist",
        "odometry_frame": "str",
        "rate_hz": "float",
        "signing_key_file": "str",
        "signing_link_id": "int",
    },
    "stale_timeout_s": "float",
    "go_around_hold_s": "float",
}


def load_config(path: str | Path, node_name: str = "gcs_bridge") -> GcsBridgeConfig:
    """Read ``<node_name>: ros__parameters:`` from a ROS 2 parameter YAML file."""
    with open(path, encoding="utf-8") as f:
        doc = yaml.safe_load(f)
    try:
        params = doc[node_name]["ros__parameters"]
    except (KeyError, TypeError) as exc:
        raise ValueError(f"{path}: no '{node_name}: ros__parameters:' section") from exc
    return config_from_parameters(params)


def config_from_parameters(params: Mapping) -> GcsBridgeConfig:
    """Build the config from nested parameters or ROS-style dotted names (``cone.alpha1_deg``)."""
    p = _check(_nest(params), _SCHEMA, "")
    cam, land, cone, mav = p["camera"], p["landing"], p["cone"], p["mavlink"]
    rad = math.radians
    cone_cfg = ConeConfig(
        alpha1=rad(cone["alpha1_deg"]),
        alpha2=rad(cone["alpha2_deg"]),
        glide_slope=rad(cone["glide_slope_deg"]),
        beta2=rad(cone["beta2_deg"]),
        distance=cone["distance_m"],
        no_return_distance=cone["no_return_distance_m"],
        approach_course=rad(land["approach_course_deg"]),
    )
    mav_cfg = MavlinkConfig(
        connection=mav["connection"],
        system_id=mav["system_id"],
        component_id=mav["component_id"],
        messages=tuple(mav["messages"]),
        odometry_frame=mav["odometry_frame"],
        rate_hz=mav["rate_hz"],
        signing_key_file=mav["signing_key_file"],
        signing_link_id=mav["signing_link_id"],
    )
    cfg = GcsBridgeConfig(
        camera_position=cam["position_m"],
        camera_rpy=tuple(rad(a) for a in cam["rpy_deg"]),
        net_position=land["net_position_m"],
        cone=cone_cfg,
        mavlink=mav_cfg,
        stale_timeout_s=p["stale_timeout_s"],
        go_around_hold_s=p["go_around_hold_s"],
    )
    _validate(cfg)
    return cfg


def _nest(params: Mapping) -> dict:
    out: dict = {}
    for key, value in params.items():
        *parents, leaf = str(key).split(".")
        node = out
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"parameter '{key}' clashes with a non-group value")
        node[leaf] = _nest(value) if isinstance(value, Mapping) else value
    return out


def _check(values, schema, prefix: str):
    if isinstance(schema, dict):
        if not isinstance(values, dict):
            raise ValueError(f"'{prefix.rstrip('.')}' must be a group of parameters")
        unknown = sorted(set(values) - set(schema))
        missing = sorted(set(schema) - set(values))
        if unknown:
            raise ValueError(f"unknown gcs_bridge parameter(s): {', '.join(prefix + k for k in unknown)}")
        if missing:
            raise ValueError(f"missing gcs_bridge parameter(s): {', '.join(prefix + k for k in missing)}")
        return {k: _check(values[k], s, f"{prefix}{k}.") for k, s in schema.items()}
    return _convert(values, schema, prefix.rstrip("."))


def _convert(value, kind: str, name: str):
    def number(v):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise ValueError(f"'{name}' must be a finite number, got {v!r}")
        return float(v)

    if kind == "float":
        return number(value)
    if kind == "vec3":
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            raise ValueError(f"'{name}' must be a list of 3 numbers, got {value!r}")
        return tuple(number(v) for v in value)
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"'{name}' must be an integer, got {value!r}")
        return value
    if kind == "str":
        if not isinstance(value, str):
            raise ValueError(f"'{name}' must be a string, got {value!r}")
        return value
    if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
        raise ValueError(f"'{name}' must be a list of strings, got {value!r}")
    return list(value)


def _validate(cfg: GcsBridgeConfig) -> None:
    c, m = cfg.cone, cfg.mavlink
    if not 0.0 < c.alpha2 < c.glide_slope < c.alpha1 < math.pi / 2:
        raise ValueError("cone: need 0 < alpha2_deg < glide_slope_deg < alpha1_deg < 90")
    if not 0.0 < c.beta2 < math.pi:
        raise ValueError("cone.beta2_deg must be in (0, 180)")
    if not 0.0 < c.no_return_distance < c.distance:
        raise ValueError("cone: need 0 < no_return_distance_m < distance_m")
    if not m.connection.strip():
        raise ValueError("mavlink.connection must not be empty")
    if not 1 <= m.system_id <= 255 or not 1 <= m.component_id <= 255:
        raise ValueError("mavlink.system_id and mavlink.component_id must be in 1..255")
    if not 0 <= m.signing_link_id <= 255:
        raise ValueError("mavlink.signing_link_id must be in 0..255")
    bad = [n for n in m.messages if n not in MESSAGE_NAMES]
    if bad or not m.messages or len(set(m.messages)) != len(m.messages):
        raise ValueError(f"mavlink.messages: a non-empty list of distinct names from {MESSAGE_NAMES}, got {m.messages}")
    if m.odometry_frame not in ODOMETRY_FRAMES:
        raise ValueError(f"mavlink.odometry_frame must be one of {ODOMETRY_FRAMES}, got {m.odometry_frame!r}")
    if not 0.0 < m.rate_hz <= 100.0:
        raise ValueError("mavlink.rate_hz must be in (0, 100]")
    if cfg.stale_timeout_s <= 0.0 or cfg.stale_timeout_s + 1.0 / m.rate_hz > GO_AROUND_DEADLINE_S:
        raise ValueError(
            f"need stale_timeout_s > 0 and stale_timeout_s + 1/rate_hz <= {GO_AROUND_DEADLINE_S} s "
            "(the go-around advisory deadline)"
        )
    if cfg.go_around_hold_s < 0.0:
        raise ValueError("go_around_hold_s must be >= 0")
