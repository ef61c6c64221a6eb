"""Configuration loading: ROS 2 parameter files (scalars as rcl reads them) into validated dataclasses."""

import math
import re
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import pytest

from uav_landing_vision.config import ConfigError, check_seed, from_mapping, load_node_parameters


@dataclass(frozen=True)
class Inner:
    sigma: float = 1.0
    names: tuple[str, ...] = ()


@dataclass(frozen=True)
class Outer:
    count: int = 3
    mode: Literal["a", "b"] = "a"
    enabled: bool = True
    inner: Inner = field(default_factory=Inner)
    size: tuple[int, int] = (64, 64)
    label: str | None = None
    gains: list[float] = field(default_factory=list)

    def __post_init__(self):
        if self.count < 1:
            raise ValueError(f"count must be >= 1, got {self.count}")


@dataclass(frozen=True)
class Required:
    rate_hz: float


def test_nested_values_and_coercion():
    cfg = from_mapping(Outer, {"count": 5, "mode": "b", "inner": {"sigma": 2, "names": ["x", "y"]}, "size": [32, 16]})
    assert cfg == Outer(count=5, mode="b", inner=Inner(sigma=2.0, names=("x", "y")), size=(32, 16))
    assert isinstance(cfg.inner.sigma, float)
    assert from_mapping(Outer, {"label": None}).label is None


@pytest.mark.parametrize(
    "values, message",
    [
        ({"cuont": 5}, r"unknown key\(s\) \['cuont'\]"),
        ({"count": "5"}, "count: expected an integer"),
        ({"count": True}, "count: expected an integer"),
        ({"mode": "c"}, "mode: 'c' is not one of"),
        ({"inner": {"sigma": "big"}}, "inner.sigma: expected a number"),
        ({"inner": {"sigma": float("nan")}}, "inner.sigma: expected a finite number"),
        ({"inner": {"sigma": float("-inf")}}, "inner.sigma: expected a finite number"),
        ({"inner": {"sigma": 10**400}}, "inner.sigma: expected a finite number"),
        ({"inner": {"bogus": 1}}, "inner: unknown key"),
        ({"size": [1, 2, 3]}, "size: expected 2 values"),
        ({"enabled": "yes"}, "enabled: expected bool"),
        ({"count": 0}, "count must be >= 1"),
        ({1: 2, "foo": 3}, r"unknown key\(s\) \['1', 'foo'\]"),  # keys of mixed types are listed, not sorted as is
        ({"inner": 5}, "inner: expected a mapping for Inner, got int"),
        ({"inner": [1, 2]}, "inner: expected a mapping for Inner, got list"),
        ({"inner": {"sigma": True}}, "inner.sigma: expected a number, got True"),
        ({"label": 5}, "label: expected str, got 5"),
        ({"label": ["a"]}, "label: expected str"),
        ({"inner": {"names": [1, "b"]}}, "inner.names: expected str, got 1"),
        ({"inner": {"names": "xy"}}, "inner.names: expected a list, got 'xy'"),
        ({"gains": [1.0, "2"]}, "gains: expected a number, got '2'"),
        ({"gains": 3.0}, "gains: expected a list"),
    ],
)
def test_bad_values_are_named(values, message):
    with pytest.raises(ConfigError, match=message):
        from_mapping(Outer, values)


def test_parameter_file_sections(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("tracker:\n  ros__parameters:\n    count: 7\n")
    assert load_node_parameters(path, "tracker") == {"count": 7}
    with pytest.raises(ConfigError, match="no section 'detector'"):
        load_node_parameters(path, "detector")
    path.write_text("tracker:\n  count: 7\n")
    with pytest.raises(ConfigError, match="ros__parameters"):
        load_node_parameters(path, "tracker")
    path.write_text("tracker: [\n")
    with pytest.raises(ConfigError, match="cannot read"):
        load_node_parameters(path, "tracker")
    path.write_bytes("# Kamera f\u00fcr das Deck\ntracker:\n  ros__parameters: {count: 7}\n".encode("latin-1"))
    with pytest.raises(ConfigError, match=f"cannot read parameter file {path}: unacceptable character"):
        load_node_parameters(path, "tracker")  # a UnicodeDecodeError naming no file before
    path.write_bytes("# Kamera f\u00fcr das Deck\ntracker:\n  ros__parameters: {count: 7}\n".encode("utf-16"))
    assert load_node_parameters(path, "tracker") == {"count": 7}  # YAML may be UTF-16 with a byte order mark


def test_parameter_file_with_a_repeated_key_is_refused(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("tracker:\n  ros__parameters:\n    count: 7\n    mode: a\n    count: 8\n")
    with pytest.raises(ConfigError, match="duplicate key 'count' on line 5"):
        load_node_parameters(path, "tracker")
    path.write_text("base: &b {count: 7, mode: a}\ntracker:\n  ros__parameters:\n    <<: *b\n    count: 8\n")
    assert load_node_parameters(path, "tracker") == {"count": 8, "mode": "a"}  # a merge key may be overridden


def test_parameter_without_a_value_is_refused_as_rcl_refuses_it(tmp_path):
    """rcl stops at ``key:`` with nothing after it ("No value"); PyYAML read None."""
    path = tmp_path / "p.yaml"
    path.write_text("tracker:\n  ros__parameters:\n    count: 7\n    mode:\n")
    with pytest.raises(ConfigError, match="no value on line 4"):
        load_node_parameters(path, "tracker")


def _scalar(tmp_path, text: str):
    path = tmp_path / "p.yaml"
    path.write_text(f"node:\n  ros__parameters:\n    value: {text}\n")
    return load_node_parameters(path, "node")["value"]


@pytest.mark.parametrize(
    "text, expected",
    [
        ("010", 8),  # strtol base 0: a leading 0 is octal
        ("-010", -8),
        ("0", 0),
        ("0x10", 16),
        ("0X1F", 31),
        ("-0x10", -16),
        ("+17", 17),
        ("1e-3", 0.001),  # strtod: an exponent without a dot
        ("1E3", 1000.0),
        ("2e+2", 200.0),
        (".5", 0.5),
        ("5.", 5.0),
        ("-.5e1", -5.0),
    ],
)
def test_parameter_file_numbers_read_as_strtol_and_strtod_read_them(tmp_path, text, expected):
    value = _scalar(tmp_path, text)
    assert value == expected and type(value) is type(expected)


@pytest.mark.parametrize("text", ["1_000", "0b11", "1:30", "0o10"])
def test_parameter_file_numbers_that_rcl_does_not_read_are_strings(tmp_path, text):
    assert _scalar(tmp_path, text) == text


@pytest.mark.parametrize("text, sign", [(".inf", 1), ("-.inf", -1), ("+.Inf", 1)])
def test_parameter_file_infinities_are_floats(tmp_path, text, sign):
    value = _scalar(tmp_path, text)
    assert isinstance(value, float) and math.isinf(value) and math.copysign(1.0, value) == sign


def test_parameter_file_with_an_unhashable_key_is_a_config_error(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("node:\n  ros__parameters:\n    ? [a, b]\n    : 1\n")
    with pytest.raises(ConfigError, match="cannot read parameter file"):
        load_node_parameters(path, "node")


@pytest.mark.parametrize("text", ["", "# nothing\n", "- node\n- other\n", "just text\n"])
def test_parameter_file_without_a_mapping_has_no_section(tmp_path, text):
    path = tmp_path / "p.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="no section 'node'"):
        load_node_parameters(path, "node")


@pytest.mark.parametrize("params", ["5", "[1, 2]", "null", "text"])
def test_ros_parameters_that_are_not_a_mapping_are_refused(tmp_path, params):
    path = tmp_path / "p.yaml"
    path.write_text(f"node:\n  ros__parameters: {params}\n")
    with pytest.raises(ConfigError, match="must hold a 'ros__parameters' mapping"):
        load_node_parameters(path, "node")


def test_typed_sequences_and_optionals_are_converted():
    cfg = from_mapping(Outer, {"label": "deck", "gains": [1, 2.5], "inner": {"names": ["a"]}})
    assert cfg.label == "deck" and cfg.gains == [1.0, 2.5] and isinstance(cfg.gains, list)
    assert all(isinstance(g, float) for g in cfg.gains) and cfg.inner.names == ("a",)


def test_a_missing_required_value_is_a_config_error():
    with pytest.raises(ConfigError, match="rate_hz"):
        from_mapping(Required, {})
    assert from_mapping(Required, {"rate_hz": 30}).rate_hz == 30.0


@pytest.mark.parametrize("seed", [0, 7, np.int64(3), 2**63])
def test_a_non_negative_integer_is_a_seed(seed):
    assert check_seed(seed) == int(seed) and type(check_seed(seed)) is int


@pytest.mark.parametrize("seed", [-1, np.int32(-2), True, False, 1.0, "3", None])
def test_a_negative_bool_float_or_text_seed_is_refused(seed):
    """True is an int to Python, and 1.0 would pass a >= 0 test: neither is a seed."""
    with pytest.raises(ValueError, match=f"seed must be a non-negative integer, got {re.escape(repr(seed))}"):
        check_seed(seed)


def _seeded_configs():
    from uav_landing_vision.boosting import DatabaseConfig
    from uav_landing_vision.boosting.evaluation import BoostingEvalConfig
    from uav_landing_vision.detection.dataset import DatasetConfig
    from uav_landing_vision.detection.train import TrainConfig
    from uav_landing_vision.detection.verifier_train import VerifierTrainConfig
    from uav_landing_vision.tracking.optimiser_evaluation import OptimiserEvalConfig
    from uav_landing_vision.tracking.upf import TrackerConfig

    return [DatabaseConfig, BoostingEvalConfig, DatasetConfig, TrainConfig, VerifierTrainConfig, OptimiserEvalConfig,
            TrackerConfig]


@pytest.mark.parametrize("index", range(7))
@pytest.mark.parametrize("seed", [-1, True, 2.0])
def test_every_seeded_config_refuses_what_is_not_a_seed(index, seed):
    config = _seeded_configs()[index]
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        config(seed=seed)
    assert config(seed=5).seed == 5
