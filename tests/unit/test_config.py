"""Configuration loading: ROS 2 parameter files into validated dataclasses."""

from dataclasses import dataclass, field
from typing import Literal

import pytest

from uav_landing_vision.config import ConfigError, from_mapping, load_node_parameters


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

    def __post_init__(self):
        if self.count < 1:
            raise ValueError(f"count must be >= 1, got {self.count}")


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
