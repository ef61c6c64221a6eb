"""Component configuration: one dataclass per component, read from a node's YAML section.

The files in ``config/`` are ROS 2 parameter files (``<node>: ros__parameters: {...}``), so the
nodes (``--ros-args --params-file``) and the CLI read the same values. Unknown keys, missing
sections, values of the wrong type and numbers that are not finite (``.nan``, ``.inf``) are
errors that name the file and the key.
"""

import dataclasses
import math
import re
import types
import typing
from collections.abc import Hashable
from pathlib import Path

import numpy as np
import yaml


class ConfigError(ValueError):
    """A configuration file or value that cannot be used."""


def check_seed(seed) -> int:
    """A random seed as an int; ValueError unless a non-negative integer (bool and float refused).

    numpy's own error names no option and comes only when the first generator is made, after
    work may have started.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative integer, got {seed!r}")
    return int(seed)


class UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader with ROS 2's numbers (below), and a mapping that gives the same key
    twice is an error."""

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":  # "<<: *anchor" keys may be overridden
                continue
            key = self.construct_object(key_node, deep=True)
            if not isinstance(key, Hashable):  # the base class reports it
                continue
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    problem=f"duplicate key {key!r} on line {key_node.start_mark.line + 1}")
            seen.add(key)
        return super().construct_mapping(node, deep)


# Numbers as rcl's parameter parser reads them (strtol with base 0, then strtod), so that the CLI
# and the nodes read a file alike: PyYAML's YAML 1.1 reads 1e-3 as a string, and 1_000, 1:30 and
# 0b11 as integers, which rcl reads as strings.
_INT = "tag:yaml.org,2002:int"
_FLOAT = "tag:yaml.org,2002:float"
UniqueKeyLoader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag not in (_INT, _FLOAT)]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
UniqueKeyLoader.add_implicit_resolver(
    _INT, re.compile(r"^[-+]?(?:0|[1-9][0-9]*|0[0-7]+|0[xX][0-9a-fA-F]+)$"), list("-+0123456789"))
UniqueKeyLoader.add_implicit_resolver(
    _FLOAT, re.compile(r"^(?:[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?"
                       r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN)|[-+]?(?i:nan|inf|infinity))$"),
    list("-+0123456789.nNiI"))


def _rcl_int(loader, node) -> int:
    """An integer as strtol with base 0 reads it: 0x / 0X hexadecimal, a leading 0 octal."""
    text = loader.construct_scalar(node)
    digits = text.lstrip("+-")
    return int(text, 16 if digits[:2] in ("0x", "0X") else 8 if len(digits) > 1 and digits[0] == "0" else 10)


UniqueKeyLoader.add_constructor(_INT, _rcl_int)


class ParameterFileLoader(UniqueKeyLoader):
    """The loader of ROS 2 parameter files: every plain scalar as rcl reads it. Besides the
    numbers, y and n are booleans too (each word lower case, capitalised or upper case), null,
    ~ and dates are strings, and an empty value is an error. (Scenario and calibration files
    keep YAML's empty values: an empty section there takes the defaults.)"""


_BOOL = "tag:yaml.org,2002:bool"
_NULL = "tag:yaml.org,2002:null"
_RCL_WORDS = {"y": True, "yes": True, "true": True, "on": True, "n": False, "no": False, "false": False, "off": False}
ParameterFileLoader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag not in (_BOOL, _NULL, "tag:yaml.org,2002:timestamp")]
    for first, resolvers in UniqueKeyLoader.yaml_implicit_resolvers.items()
}
ParameterFileLoader.add_implicit_resolver(
    _BOOL, re.compile("^(?:" + "|".join(f"{w}|{w.capitalize()}|{w.upper()}" for w in _RCL_WORDS) + ")$"),
    list("yYnNtTfFoO"))
ParameterFileLoader.add_implicit_resolver(_NULL, re.compile(r"^$"), [""])


def _rcl_bool(loader, node) -> bool:
    return _RCL_WORDS[loader.construct_scalar(node).lower()]


def _no_value(loader, node):
    raise yaml.constructor.ConstructorError(problem=f"no value on line {node.start_mark.line + 1}")


ParameterFileLoader.add_constructor(_BOOL, _rcl_bool)
ParameterFileLoader.add_constructor(_NULL, _no_value)


def load_node_parameters(path, node: str) -> dict:
    """The ``ros__parameters`` mapping of ``node`` in a ROS 2 parameter file."""
    path = Path(path)
    try:
        doc = yaml.load(path.read_bytes(), ParameterFileLoader)  # bytes: an undecodable file is a YAMLError
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(f"cannot read parameter file {path}: {exc}") from exc
    if not isinstance(doc, dict) or node not in doc:
        raise ConfigError(f"{path}: no section '{node}'")
    section = doc[node]
    if not isinstance(section, dict) or not isinstance(section.get("ros__parameters"), dict):
        raise ConfigError(f"{path}: section '{node}' must hold a 'ros__parameters' mapping")
    return section["ros__parameters"]


def from_mapping(cls, values: dict, where: str = ""):
    """Build dataclass ``cls`` from ``values``; unknown keys and wrong types raise :class:`ConfigError`.

    Nested dataclass fields take nested mappings; tuple and list fields take YAML lists.
    Ints are accepted where floats are expected. The dataclass's ``__post_init__`` does the
    range checks.
    """
    prefix = f"{where}: " if where else ""
    if not isinstance(values, dict):
        raise ConfigError(f"{prefix}expected a mapping for {cls.__name__}, got {type(values).__name__}")
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(map(str, set(values) - set(fields)))
    if unknown:
        raise ConfigError(f"{prefix}unknown key(s) {unknown} for {cls.__name__}; known: {sorted(fields)}")
    hints = typing.get_type_hints(cls)
    kwargs = {}
    for name, value in values.items():
        key = f"{where}.{name}" if where else name
        kwargs[name] = _convert(hints[name], value, key)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{prefix}{exc}") from exc


def _convert(hint, value, key: str):
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        return from_mapping(hint, value, key)
    if origin in (typing.Union, types.UnionType):
        options = [a for a in typing.get_args(hint) if a is not type(None)]
        if value is None and len(options) < len(typing.get_args(hint)):
            return None
        return _convert(options[0], value, key)
    if origin is typing.Literal:
        if value not in typing.get_args(hint):
            raise ConfigError(f"{key}: {value!r} is not one of {list(typing.get_args(hint))}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{key}: expected a list, got {value!r}")
        args = typing.get_args(hint)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise ConfigError(f"{key}: expected {len(args)} values, got {len(value)}")
            return tuple(_convert(a, v, key) for a, v in zip(args, value))
        item = args[0] if args else typing.Any
        return origin(_convert(item, v, key) for v in value)
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        try:
            number = float(value)
        except OverflowError:  # an integer beyond the float range
            number = math.inf
        if not math.isfinite(number):
            raise ConfigError(f"{key}: expected a finite number, got {value!r}")
        return number
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if hint in (str, bool) and not isinstance(value, hint):
        raise ConfigError(f"{key}: expected {hint.__name__}, got {value!r}")
    return value
