"""YAML -> typed, validated run configuration.

A run config is one YAML file. Its top level holds the run's own keys (``images``, ``workspace``,
``executor``, ``seed``, ``stages``) and one section per stage, validated against that stage's
``Config`` dataclass (fields declared with :func:`recon.options.opt`). Validation is strict: an
unknown key is an error naming its full path and the closest valid key; a wrong type names the key
and the expected type; numbers are checked against the field's bounds. Every field has a default,
so an empty file is a valid config.

Integers must also fit a C ``int``: options end up in COLMAP and OpenCV, whose bindings refuse
anything wider with a stack of C++ signatures. A config whose aliases expand beyond
:data:`MAX_EXPANDED` (a "billion laughs" file, or one that refers to itself) is refused before
anything walks it.
"""

from __future__ import annotations

import dataclasses
import difflib
import re
import types
import typing
from pathlib import Path
from typing import Any, Literal

import yaml

from recon.options import doc_of, opt


class ConfigError(ValueError):
    """A config problem, worded for the user: it names the key or file and what to do."""


#: the range of a C ``int``, which every integer option must fit
INT_MIN, INT_MAX = -(2**31), 2**31 - 1
#: the most a config may hold once its YAML aliases are expanded (characters of its scalars, plus
#: one per value): far above any real config, far below what would exhaust memory
MAX_EXPANDED = 1_000_000
#: a number as YAML 1.2 writes it; YAML 1.1 (PyYAML) reads ``5e-3`` (no dot) as a string
_FLOAT = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?")


@dataclasses.dataclass(frozen=True)
class RunOptions:
    """The run's own keys (everything but the per-stage sections)."""

    images: str | None = opt(None, "folder of input photos (JPEG/PNG/TIFF); relative to the config file")
    video: str | None = opt(None, "a video file to take keyframes from instead of `images` (see "
                                  "ingest.keyframes); relative to the config file")
    workspace: str | None = opt(None, "output folder; relative to the config file")
    executor: str = opt("local", "where per-image/per-pair work runs: local | processes:N | "
                                 "dask://host:port | dask-local:N")
    seed: int = opt(0, "random seed for every stage that samples", ge=0)
    stages: list[str] = opt([], "stages to run, in order; empty = every stage up to `until`")
    until: str = opt("export", "last stage to run when `stages` is empty")

    def __post_init__(self):
        if self.images and self.video:
            raise ConfigError("video: the input is either a photo folder (`images`) or a video (`video`), not both")


# ---------------------------------------------------------------------------------------------
# Loading


def read_yaml(path: Path) -> dict:
    """Read a YAML mapping; syntax errors name the file, line and column."""
    try:
        text = Path(path).read_text()
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read config file ({exc.strerror})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f":{mark.line + 1}:{mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(f"{path}{where}: invalid YAML: {problem}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping of keys to values")
    _check_expansion(data, str(path))
    return data


def _check_expansion(data: Any, where: str) -> None:
    if _too_big(data):
        raise ConfigError(f"{where}: expands to more than {MAX_EXPANDED // 1_000_000} MB through YAML aliases "
                          "(or an alias refers to itself); write it out without them")


def _too_big(data: Any, budget: int = MAX_EXPANDED) -> bool:
    """Whether ``data`` holds more than ``budget`` (scalar characters plus one per value), counting
    a value each time an alias repeats it. Stops as soon as the budget is spent, so a structure
    that is exponential (or cyclic) once expanded costs no more than ``budget`` steps."""
    stack = [data]
    while stack:
        value = stack.pop()
        budget -= 1
        if isinstance(value, dict):
            stack.extend(value.keys())
            stack.extend(value.values())
        elif isinstance(value, list):
            stack.extend(value)
        elif isinstance(value, (str, bytes)):
            budget -= len(value)
        if budget < 0:
            return True
    return False


def apply_overrides(data: dict, overrides: list[str] | dict[str, Any]) -> dict:
    """Apply ``key.sub=value`` overrides (values parsed as YAML) onto a nested dict copy."""
    data = _deep_copy(data)
    items = overrides.items() if isinstance(overrides, dict) else [_split_override(o) for o in overrides]
    for dotted, value in items:
        parts = dotted.split(".")
        node = data
        for part in parts[:-1]:
            child = node.get(part)
            if child is None:
                child = node[part] = {}
            if not isinstance(child, dict):
                raise ConfigError(f"override {dotted}: '{part}' is not a section")
            node = child
        node[parts[-1]] = value
    return data


def _split_override(text: str) -> tuple[str, Any]:
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"override '{text}': expected key=value, e.g. features.max_image_size=1600")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError:
        value = raw
    _check_expansion(value, f"override {key.strip()}")
    return key.strip(), value


def _deep_copy(data):
    if isinstance(data, dict):
        return {k: _deep_copy(v) for k, v in data.items()}
    if isinstance(data, list):
        return [_deep_copy(v) for v in data]
    return data


# ---------------------------------------------------------------------------------------------
# Validation against dataclasses


def build(cls: type, data: Any, path: str = "") -> Any:
    """Validate ``data`` against dataclass ``cls`` and return an instance (defaults filled in)."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path or 'config'}: expected a mapping of options, got {_kind(data)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    for key in data:
        if key not in fields:
            raise ConfigError(_unknown_key_message(_join(path, str(key)), str(key), list(fields)))
    values = {}
    for name, value in data.items():
        field = fields[name]
        values[name] = _check_value(hints[name], value, _join(path, name), field)
    return cls(**values)


def _unknown_key_message(full: str, key: str, valid: list[str]) -> str:
    close = difflib.get_close_matches(key, valid, n=1, cutoff=0.5)
    hint = f"did you mean '{close[0]}'?" if close else f"valid keys: {', '.join(sorted(valid))}"
    return f"{full}: unknown key; {hint}"


def _check_value(tp: Any, value: Any, path: str, field: dataclasses.Field | None = None) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        options = [a for a in args if a is not type(None)]
        errors = []
        for option in options:
            try:
                return _check_value(option, value, path, field)
            except ConfigError as exc:
                errors.append(exc)
        raise errors[0] if len(options) == 1 else ConfigError(
            f"{path}: expected {_type_name(tp)}, got {_kind(value)} {value!r}")
    if origin is Literal:
        if value not in args:
            raise ConfigError(f"{path}: must be one of {', '.join(map(str, args))}; got {value!r}")
        return value
    if origin is list:
        if not isinstance(value, list):
            raise ConfigError(f"{path}: expected a list, got {_kind(value)} {value!r}")
        return [_check_value(args[0], v, f"{path}[{i}]") for i, v in enumerate(value)]
    if dataclasses.is_dataclass(tp):
        return build(tp, value, path)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{path}: expected true or false, got {_kind(value)} {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path}: expected an integer, got {_kind(value)} {value!r}")
        _check_int_range(value, path, field)
        _check_bounds(value, path, field)
        return value
    if tp is float:
        if isinstance(value, str) and _FLOAT.fullmatch(value.strip()):
            value = float(value)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{path}: expected a number, got {_kind(value)} {value!r}")
        _check_bounds(value, path, field)
        return float(value)
    if tp is str:
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise ConfigError(f"{path}: expected a string, got {_kind(value)} {value!r}")
        return str(value)
    if tp is Any:
        return value
    raise TypeError(f"unsupported option type {tp!r} at {path}")


def _check_int_range(value: int, path: str, field: dataclasses.Field | None) -> None:
    """An integer must fit a C ``int`` (and the option's own bounds, named in the same message)."""
    if INT_MIN <= value <= INT_MAX:
        return
    meta = field.metadata if field is not None else {}
    low = max([INT_MIN, *(b + (k == "gt") for k in ("ge", "gt") if (b := meta.get(k)) is not None)])
    high = min([INT_MAX, *(b - (k == "lt") for k in ("le", "lt") if (b := meta.get(k)) is not None)])
    raise ConfigError(f"{path}: must be an integer from {int(low)} to {int(high)}; got {value}")


def _check_bounds(value: float, path: str, field: dataclasses.Field | None) -> None:
    if field is None:
        return
    meta = field.metadata
    checks = [("ge", lambda b: value >= b, ">="), ("gt", lambda b: value > b, ">"),
              ("le", lambda b: value <= b, "<="), ("lt", lambda b: value < b, "<")]
    for key, ok, sign in checks:
        bound = meta.get(key)
        if bound is not None and not ok(bound):
            raise ConfigError(f"{path}: must be {sign} {bound}; got {value}")


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string",
            list: "a list", dict: "a mapping"}.get(type(value), type(value).__name__)


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp) if a is not type(None))
    if origin is Literal:
        return "one of " + ", ".join(map(str, typing.get_args(tp)))
    if origin is list:
        return f"list of {_type_name(typing.get_args(tp)[0])}"
    return {int: "integer", float: "number", str: "string", bool: "boolean"}.get(tp, getattr(tp, "__name__", str(tp)))


# ---------------------------------------------------------------------------------------------
# Serialising


def to_dict(obj: Any) -> Any:
    """A dataclass instance as plain JSON/YAML-ready data."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    return obj


def describe(obj: Any, indent: int = 0) -> list[str]:
    """YAML lines for a dataclass instance, each field followed by its one-line doc as a comment."""
    lines = []
    pad = "  " * indent
    for field in dataclasses.fields(obj):
        value = getattr(obj, field.name)
        doc = doc_of(field)
        if dataclasses.is_dataclass(value):
            lines.append(f"{pad}{field.name}:" + (f"  # {doc}" if doc else ""))
            lines.extend(describe(value, indent + 1))
            continue
        rendered = yaml.safe_dump(to_dict(value), default_flow_style=True, width=10_000).strip()
        rendered = rendered.removesuffix("\n...").removesuffix("...").strip()
        lines.append(f"{pad}{field.name}: {rendered}" + (f"  # {doc}" if doc else ""))
    return lines


def type_name(cls: type, name: str) -> str:
    """Human-readable type of field ``name`` of dataclass ``cls`` (for ``recon stages``)."""
    return _type_name(typing.get_type_hints(cls)[name])
