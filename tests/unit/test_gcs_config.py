"""The gcs_bridge parameter file and its validation."""

import dataclasses
import math
from pathlib import Path

import pytest
import yaml

from uav_landing_vision.gcs import config_from_parameters, load_config

SHIPPED = Path(__file__).parents[2] / "config" / "gcs_bridge.yaml"


def shipped_params() -> dict:
    return yaml.safe_load(SHIPPED.read_text())["gcs_bridge"]["ros__parameters"]


def test_shipped_file_loads_in_radians():
    cfg = load_config(SHIPPED)
    assert cfg.cone.distance_m == 50.0
    assert cfg.cone.alpha1 == pytest.approx(math.radians(cfg.cone.alpha1_deg))
    assert cfg.camera.rpy[2] == pytest.approx(math.pi)
    assert cfg.mavlink.messages == ("ODOMETRY",) and cfg.mavlink.signing_key_file == ""


def test_dotted_ros_names_equal_nested():
    def flatten(d, prefix=""):
        out = {}
        for k, v in d.items():
            out.update(flatten(v, f"{prefix}{k}.") if isinstance(v, dict) else {prefix + k: v})
        return out

    assert config_from_parameters(flatten(shipped_params())) == load_config(SHIPPED)


def edit(path: str, value):
    params = shipped_params()
    *groups, leaf = path.split(".")
    node = params
    for g in groups:
        node = node[g]
    if value is KeyError:
        del node[leaf]
    else:
        node[leaf] = value
    return params


@pytest.mark.parametrize(
    "path, value, message",
    [
        ("cone.alpha_one_deg", 5.0, r"unknown key.*alpha_one_deg"),
        ("mavlink.rate", 5.0, r"unknown key.*rate"),
        ("stale_timeout_s", KeyError, "stale_timeout_s"),
        ("mavlink.rate_hz", "fast", "mavlink.rate_hz: expected a number"),
        ("mavlink.system_id", 1.5, "mavlink.system_id: expected an integer"),
        ("mavlink.messages", ["ODOMETRY", "GPS_INPUT"], "'GPS_INPUT' is not one of"),
        ("mavlink.messages", ["ODOMETRY", "ODOMETRY"], "distinct"),
        ("mavlink.messages", [], "non-empty"),
        ("mavlink.odometry_frame", "LOCAL_ENU", "'LOCAL_ENU' is not one of"),
        ("mavlink.system_id", 0, "1..255"),
        ("mavlink.rate_hz", 150.0, r"rate_hz must be in \(0, 100\]"),
        ("mavlink.signing_link_id", 256, "signing_link_id must be in 0..255"),
        ("mavlink.signing_timestamp_file", "/var/lib/station/ts", "signing is off"),
        ("mavlink.connection", " ", "connection"),
        ("camera.position_m", [0.0, 1.0], "expected 3 values"),
        ("camera.frame_id", " ", "camera.frame_id must not be empty"),
        ("net_position_m", [0.0, math.nan, 0.0], "finite"),
        ("net_position_m", [1e39, 0.0, 0.0], "within 1000 m"),  # every pose was refused (float32)
        ("camera.position_m", [0.0, -2000.0, 0.0], "within 1000 m"),
        ("cone.alpha2_deg", 7.0, "alpha2_deg < glide_slope_deg"),
        ("cone.beta2_deg", 180.0, "beta2_deg"),
        ("cone.no_return_distance_m", 60.0, "no_return_distance_m < distance_m"),
        ("cone.no_return_confirm_poses", 1, "no_return_confirm_poses"),
        ("cone.no_return_confirm_poses", 3.0, "expected an integer"),
        ("cone.max_range_rate_mps", 0.0, "max_range_rate_mps"),
        ("cone.max_range_rate_mps", math.inf, "max_range_rate_mps"),
        ("stale_timeout_s", 0.45, "go-around advisory deadline"),
        ("go_around_hold_s", -1.0, "go_around_hold_s"),
        # Each bound of the cone on its own (α2 ≤ 0 would be a cone below the net).
        ("cone.glide_slope_deg", 12.0, "glide_slope_deg < alpha1_deg"),
        ("cone.alpha2_deg", 0.0, "0 < alpha2_deg"),
        ("cone.alpha2_deg", -5.0, "0 < alpha2_deg"),
        ("cone.alpha1_deg", 90.0, "alpha1_deg < 90"),
        ("cone.beta2_deg", 0.0, "beta2_deg"),
        ("cone.no_return_distance_m", 0.0, "no_return_distance_m"),
        ("stale_timeout_s", 0.0, "stale_timeout_s > 0"),
        # Each inequality is strict: equal values are refused too.
        ("cone.glide_slope_deg", 10.0, "glide_slope_deg < alpha1_deg"),
        ("cone.alpha2_deg", 6.0, "alpha2_deg < glide_slope_deg"),
        ("cone.no_return_distance_m", 50.0, "no_return_distance_m < distance_m"),
        ("mavlink.system_id", 256, "1..255"),
        ("mavlink.component_id", 0, "1..255"),  # 0 is MAV_COMP_ID_ALL, a broadcast address
        ("mavlink.component_id", 256, "1..255"),
        ("mavlink.rate_hz", 0.0, r"rate_hz must be in \(0, 100\]"),
    ],
)
def test_invalid_parameters_are_named(path, value, message):
    with pytest.raises(ValueError, match=message):
        config_from_parameters(edit(path, value))


@pytest.mark.parametrize("rate", [math.inf, math.nan, -1.0])
def test_a_cone_built_in_code_refuses_a_range_rate_bound_that_checks_nothing(rate):
    """The cone's own check, not the parameter loader's (which refuses a non-finite number before it)."""
    with pytest.raises(ValueError, match="max_range_rate_mps"):
        dataclasses.replace(load_config(SHIPPED).cone, max_range_rate_mps=rate)


def test_missing_section(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("tracker:\n  ros__parameters: {}\n")
    with pytest.raises(ValueError, match="no section 'gcs_bridge'"):
        load_config(path)


@pytest.mark.parametrize(
    "path, value",
    [
        ("cone.no_return_confirm_poses", 2),
        ("mavlink.rate_hz", 100.0),
        ("go_around_hold_s", 0.0),
        ("stale_timeout_s", 0.4),  # 0.4 + 1/10 Hz: exactly the 0.5 s go-around deadline
    ],
)
def test_values_on_the_edge_of_their_range_are_accepted(path, value):
    cfg = config_from_parameters(edit(path, value))
    node = cfg
    for part in path.split("."):
        node = getattr(node, part)
    assert node == value


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda cfg: dataclasses.replace(cfg, camera=dataclasses.replace(cfg.camera, rpy_deg=(0.0, math.nan, 180.0))),
         "finite"),
        (lambda cfg: dataclasses.replace(cfg.cone, approach_course_deg=math.nan), "approach_course_deg"),
        (lambda cfg: dataclasses.replace(cfg, go_around_hold_s=math.inf), "go_around_hold_s"),
    ],
)
def test_a_config_built_in_code_refuses_non_finite_angles_and_hold(change, message):
    """The dataclasses' own checks, not the parameter loader's (which refuses a non-finite number before them)."""
    with pytest.raises(ValueError, match=message):
        change(load_config(SHIPPED))


def test_a_dotted_name_under_a_plain_value_is_named():
    params = shipped_params()
    params["stale_timeout_s.extra"] = 1.0  # 'stale_timeout_s' holds a number, not a group
    with pytest.raises(ValueError, match="clashes with the value of 'stale_timeout_s'"):
        config_from_parameters(params)


def test_a_dotted_name_overrides_a_nested_one_without_touching_the_callers_parameters():
    params = shipped_params()
    params["cone.alpha1_deg"] = 11.0
    assert config_from_parameters(params).cone.alpha1_deg == 11.0
    assert params["cone"]["alpha1_deg"] == 10.0
