"""Configuration as validated data: every keyword with its type, default, unit and valid range or choices.

A task's keywords are one frozen dataclass (a `Config` subclass) whose fields are declared with `param`:

    @dataclass(frozen=True)
    class WaypointsConfig(DrivingConfig):
        waypoint_spacing: float = param(2.0, "distance between waypoints", "m", gt=0.0, le=20.0)

`WaypointsConfig.from_dict(kwargs)` converts what a user typed (Python values, JSON or YAML scalars) to the
declared types and checks every range and choice; a bad value raises `ConfigError` naming the keyword, the
value and what is allowed, an unknown keyword lists the valid ones and suggests the closest. `describe()`
gives the table printed by `mjdrive list --kwargs DOMAIN/TASK` and written to docs/task_kwargs.md.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import json
import math
import os
import re
import types
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Union

import numpy as np
import yaml


class ConfigError(ValueError):
    """A keyword with an unknown name or a value outside what it allows (a user's mistake, not a bug)."""


@dataclass(frozen=True)
class Spec:
    """What a keyword allows, beyond its type: bounds (each element of a tuple), choices, dict keys."""

    doc: str
    unit: str = ""
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None
    choices: tuple[Any, ...] | None = None
    length: int | None = None  # exact length of a tuple value
    keys: tuple[str, ...] | None = None  # allowed keys of a dict value

    def bounds_text(self) -> str:
        parts = [f"{op} {_number(bound)}" for op, bound in ((">=", self.ge), (">", self.gt), ("<=", self.le),
                                                            ("<", self.lt)) if bound is not None]
        return " and ".join(parts)


def _number(x: float) -> str:
    return str(int(x)) if float(x).is_integer() and abs(x) < 1e16 else f"{x:g}"


def param(default: Any, doc: str, unit: str = "", **allowed: Any) -> Any:
    """A config field: its default, a one-line description, its unit ("" for none) and what it allows
    (`ge`, `gt`, `le`, `lt` bounds; `choices`; `length` of a tuple; `keys` of a dict)."""
    return dataclasses.field(default=default, metadata={"spec": Spec(doc, unit, **allowed)})


def _spec(field: dataclasses.Field) -> Spec:
    return field.metadata.get("spec") or Spec(doc="")


def _type_name(tp: Any) -> str:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (Union, types.UnionType):
        return " | ".join(_type_name(a) for a in args)
    if origin is tuple:
        return f"tuple[{_type_name(args[0])}, ...]" if len(args) == 2 and args[1] is Ellipsis else \
            "tuple[" + ", ".join(_type_name(a) for a in args) + "]"
    if origin is dict:
        return f"dict[{_type_name(args[0])}, {_type_name(args[1])}]"
    if tp is type(None):
        return "None"
    return getattr(tp, "__name__", str(tp))


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class _Invalid(Exception):
    """Internal: why one value does not fit its type or spec (turned into a ConfigError with the keyword)."""


class _Nested(_Invalid):
    """Internal: a nested config's own ConfigError, reported under a dotted path (`map.crossroad.lane_width=6`)."""

    def __init__(self, message: str, source: str = "") -> None:
        super().__init__(message)
        self.source = source  # " (file 'm.yaml')" when the keywords came from a file


def _nested_message(name: str, error: _Nested) -> str:
    """`name.inner=...: why` for a nested keyword's error, `name: why` for one about the nested keywords."""
    inner = str(error)
    dotted = re.match(r"^[A-Za-z_]\w*[.=:]", inner) is not None
    return f"{name}{error.source}{'.' if dotted else ': '}{inner}"


def _check_bounds(value: float, spec: Spec) -> None:
    bad = ((spec.ge is not None and not value >= spec.ge) or (spec.gt is not None and not value > spec.gt)
           or (spec.le is not None and not value <= spec.le) or (spec.lt is not None and not value < spec.lt))
    if bad:
        raise _Invalid(f"must be {spec.bounds_text()}" + (f" [{spec.unit}]" if spec.unit else ""))


def _convert(value: Any, tp: Any, spec: Spec) -> Any:
    """`value` converted to the type `tp` and checked against `spec`; raises _Invalid with the reason."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        reasons = []
        for option in (a for a in args if a is not type(None)):
            try:
                return _convert(value, option, spec)
            except _Nested:
                raise
            except _Invalid as error:
                reasons.append(str(error))
        # the value has a right type but not a right size, or a list/mapping of the right type a bad element
        bounds = [r for r in reasons if "<" in r or ">" in r or not r.startswith("must be ")]
        if bounds:
            raise _Invalid(bounds[0])
        kinds = [r.removeprefix("must be ") for r in reasons] + (["None"] if type(None) in args else [])
        raise _Invalid("must be " + ", ".join(kinds[:-1]) + " or " + kinds[-1])
    if tp is bool:
        if isinstance(value, (bool, np.bool_)):
            return bool(value)
        raise _Invalid("must be true or false")
    if tp is int:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise _Invalid("must be an integer")
        if isinstance(value, (float, np.floating)) and not float(value).is_integer():
            raise _Invalid("must be an integer")
        value = int(value)
        _check_bounds(value, spec)
        return value
    if tp is float:
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise _Invalid("must be a number")
        value = float(value)
        if not math.isfinite(value):
            raise _Invalid("must be a finite number")
        _check_bounds(value, spec)
        return value
    if tp is str:
        if not isinstance(value, str):
            raise _Invalid("must be a string")
        if spec.choices is not None and value not in spec.choices:
            raise _Invalid("must be one of " + ", ".join(repr(c) for c in spec.choices))
        return value
    if origin is tuple:
        if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple, np.ndarray)):
            raise _Invalid(f"must be a list ({_type_name(tp)})")
        items = list(value)
        variadic = len(args) == 2 and args[1] is Ellipsis
        length = spec.length if variadic else len(args)
        if length is not None and len(items) != length:
            raise _Invalid(f"must have {length} elements, got {len(items)}")
        if variadic and not items:
            raise _Invalid("must not be empty")
        element_types = [args[0]] * len(items) if variadic else list(args)
        element_spec = dataclasses.replace(spec, choices=None)
        out = []
        for i, (item, element_type) in enumerate(zip(items, element_types, strict=True)):
            try:
                out.append(_convert(item, element_type, element_spec))
            except _Invalid as error:
                raise _Invalid(f"element {i} ({_show(item)}) {error}") from None
        out = tuple(out)
        if spec.choices is not None:
            bad = [item for item in out if item not in spec.choices]
            if bad:
                raise _Invalid(f"element {_show(bad[0])} is not one of " + ", ".join(repr(c) for c in spec.choices))
        if len(set(out)) != len(out) and variadic:
            raise _Invalid("must not repeat an element")
        return out
    if origin is dict:
        if not isinstance(value, Mapping):
            raise _Invalid(f"must be a mapping ({_type_name(tp)})")
        key_type, value_type = args
        out = {}
        for key, item in value.items():
            key = _convert(key, key_type, Spec(doc=""))
            if spec.keys is not None and key not in spec.keys:
                raise _Invalid(f"unknown key {key!r}; valid keys: {', '.join(spec.keys)}")
            try:
                out[key] = _convert(item, value_type, dataclasses.replace(spec, keys=None))
            except _Invalid as error:
                raise _Invalid(f"[{key!r}]={_show(item)} {error}") from None
        return out
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        if isinstance(value, tp):
            return value
        if isinstance(value, str) and value.upper() in tp.__members__:
            return tp[value.upper()]
        raise _Invalid("must be one of " + ", ".join(repr(name.lower()) for name in tp.__members__))
    if isinstance(tp, type) and issubclass(tp, Config):
        if isinstance(value, tp):
            return value
        source = ""
        if isinstance(value, str | os.PathLike):
            value, source = _read_mapping(value), f" (file {os.fspath(value)!r})"
        if isinstance(value, Mapping):
            try:
                return tp.from_dict(value)
            except ConfigError as error:
                raise _Nested(str(error), source) from None
        raise _Invalid(f"must be a mapping of {tp.__name__} keywords, or the path of a YAML or JSON file of them")
    if isinstance(tp, type):
        if isinstance(value, tp):
            return value
        raise _Invalid(f"must be a {tp.__module__.split('.')[0]}.{tp.__qualname__}")
    raise TypeError(f"config fields of type {tp!r} are not supported")  # a bug in a Config declaration


def _read_mapping(path: str | os.PathLike) -> Mapping:
    """The keywords in a YAML or JSON file (a nested config given by path); an error naming the file if it cannot
    be read or is not a mapping."""
    name = os.fspath(path)
    try:
        with open(name, encoding="utf-8") as file:
            data = parse_yaml(file.read())  # JSON is YAML
    except OSError as error:
        raise _Nested(f"cannot read the file {name!r}: {error.strerror or error}") from None
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        mark = getattr(error, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        raise _Nested(f"the file {name!r} is not YAML or JSON{where}") from None
    if not isinstance(data, Mapping):
        raise _Nested(f"the file {name!r} must hold a mapping of keywords, not {type(data).__name__}")
    return data


@dataclass(frozen=True)
class Config:
    """Base of validated configurations: frozen, every field declared with `param`."""

    def __post_init__(self) -> None:
        hints = typing.get_type_hints(type(self))
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            try:
                converted = _convert(value, hints[field.name], _spec(field))
            except _Nested as error:
                raise ConfigError(_nested_message(field.name, error)) from None
            except _Invalid as error:
                raise ConfigError(f"{field.name}={_show(value)}: {error}") from None
            object.__setattr__(self, field.name, converted)
        self.check()

    def check(self) -> None:
        """Checks that involve several fields (override; raise ConfigError)."""

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None = None, defaults: Mapping[str, Any] | None = None,
                  where: str = ""):
        """The config of `values` over `defaults` (both keyword -> value); unknown keywords raise ConfigError
        listing the valid ones, bad values one naming the keyword, the value and what is allowed."""
        values = dict(values or {})
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = [key for key in values if key not in names]
        if unknown:
            key = unknown[0]
            close = difflib.get_close_matches(str(key), names, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            context = f" for {where}" if where else ""
            raise ConfigError(f"unknown keyword {key!r}{context}{hint}; valid keywords: {', '.join(names)}")
        try:
            return cls(**{**dict(defaults or {}), **values})
        except ConfigError as error:
            if not where:
                raise
            raise ConfigError(f"{where}: {error}") from None

    @classmethod
    def load(cls, value: Mapping[str, Any] | str | os.PathLike, name: str = "config"):
        """The config of a mapping of keywords or of the path of a YAML or JSON file of them (what a nested
        config keyword takes); ConfigError naming `name`, the file and the keyword otherwise."""
        try:
            return _convert(value, cls, Spec(doc=""))
        except _Nested as error:
            raise ConfigError(_nested_message(name, error)) from None
        except _Invalid as error:
            raise ConfigError(f"{name}={_show(value)}: {error}") from None

    def to_dict(self) -> dict[str, Any]:
        """Field -> value, nested configs as dicts, enums by name (JSON-friendly apart from a RandomState seed)."""
        out = {}
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, Config):
                value = value.to_dict()
            elif isinstance(value, enum.Enum):
                value = value.name.lower()  # what the keyword takes, and JSON
            out[field.name] = value
        return out

    @classmethod
    def describe(cls, defaults: Mapping[str, Any] | None = None) -> list[dict[str, str]]:
        """One row per keyword: name, type, default, unit, allowed, doc (for tables and `--help`)."""
        hints = typing.get_type_hints(cls)
        defaults = dict(defaults or {})
        rows = []
        for field in dataclasses.fields(cls):
            spec = _spec(field)
            default = defaults.get(field.name, field.default)
            allowed = []
            if spec.choices is not None:
                allowed.append("one of " + ", ".join(repr(c) for c in spec.choices))
            if spec.bounds_text():
                allowed.append(spec.bounds_text())
            if spec.length is not None:
                allowed.append(f"{spec.length} elements")
            if spec.keys is not None:
                allowed.append("keys " + ", ".join(spec.keys))
            tp = hints[field.name]
            if _nested_config(tp) is not None:
                allowed.append(f"keywords of {_nested_config(tp).__name__}")
            rows.append({"name": field.name, "type": _type_name(tp), "default": _default_text(default),
                         "unit": spec.unit, "allowed": "; ".join(allowed), "doc": spec.doc})
        return rows

    @classmethod
    def markdown(cls, defaults: Mapping[str, Any] | None = None, prefix: str = "") -> str:
        """The `describe()` rows as a markdown table, then one table per nested config keyword (`map.crossroad`:
        the keywords of its config class), depth first."""
        lines = ["| keyword | type | default | unit | allowed | what |", "| --- | --- | --- | --- | --- | --- |"]
        for row in cls.describe(defaults):
            cells = [f"`{row['name']}`", row["type"], f"`{row['default']}`", row["unit"], row["allowed"], row["doc"]]
            lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
        hints = typing.get_type_hints(cls)
        for field in dataclasses.fields(cls):
            nested = _nested_config(hints[field.name])
            if nested is not None:
                name = f"{prefix}{field.name}"
                lines += ["", f"`{name}`: keywords of {nested.__name__} (a mapping, or the path of a YAML or JSON "
                          "file of them)", "", nested.markdown(prefix=name + ".")]
        return "\n".join(lines)


def _nested_config(tp: Any) -> type[Config] | None:
    """The Config class a keyword of type `tp` takes (alone or in a union), or None."""
    options = typing.get_args(tp) if typing.get_origin(tp) in (Union, types.UnionType) else (tp,)
    return next((t for t in options if isinstance(t, type) and issubclass(t, Config)), None)


def _default_text(value: Any) -> str:
    if isinstance(value, enum.Enum):
        return repr(value.name.lower())
    if isinstance(value, Config):
        return type(value).__name__ + "()"
    if isinstance(value, float):
        return f"{value:g}"
    return repr(value)


# --- values typed on the command line ------------------------------------------------------------------------
SCIENTIFIC = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+$")


class _Loader(yaml.SafeLoader):
    """yaml.SafeLoader (safe: plain data only) that also reads 1e-4 as a float (YAML 1.1 reads it as text)."""


_Loader.add_implicit_resolver("tag:yaml.org,2002:float", SCIENTIFIC, list("-+0123456789."))


def parse_yaml(text: str) -> Any:
    """A YAML document as plain data (the learners' config files; `parse_value`'s fallback)."""
    return yaml.load(text, Loader=_Loader)  # a SafeLoader subclass: never constructs objects


def parse_value(text: str) -> Any:
    """A value typed on the command line (the VALUE of KEY=VALUE), one reading for every command and tool:
    JSON where it parses, else YAML (`parse_yaml`: `[a, b]`, `{key: value}`, `~`, 1e-4, ...), else the text
    itself (a string)."""
    try:
        return json.loads(text)
    except ValueError:
        pass
    try:
        return parse_yaml(text)
    except yaml.YAMLError:
        return text


def parse_task_kwargs(pairs: Sequence[str]) -> dict[str, Any]:
    """`--task-kwarg KEY=VALUE` pairs as a dict, each VALUE read by `parse_value`."""
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key:
            raise ValueError(f"--task-kwarg expects KEY=VALUE, got {pair!r}")
        out[key] = parse_value(value)
    return out


INDEX_DTYPE = np.int64  # the dtype of gymnasium's Discrete spaces (an index must cast to it safely)


def action_index(action, n: int, action_set: str) -> int:
    """The index in 0..n-1 that a discrete action set's `action` names, accepting exactly what gymnasium's
    `Discrete(n).contains` accepts: a Python int (bool included, as gymnasium takes it), a numpy integer scalar
    or a 0-d integer array whose dtype casts safely to int64. Anything else (a float, even a whole one, a
    string, a (1,) array, np.bool_) and an index out of range raise ValueError naming `action_set`: a
    policy that emits floats must not drive with a truncated index."""
    if isinstance(action, int):
        index = int(action)  # a bool is 0 or 1, never a numpy mask
    elif (isinstance(action, (np.generic, np.ndarray)) and np.issubdtype(action.dtype, np.integer)
          and action.shape == () and np.can_cast(action.dtype, INDEX_DTYPE)):
        index = int(action)
    else:
        kind = type(action).__name__
        if isinstance(action, np.generic):
            kind = f"numpy {action.dtype}"
        elif isinstance(action, np.ndarray):
            kind = f"array of dtype {action.dtype}, shape {action.shape}"
        raise ValueError(f"action set {action_set!r}: an action is an integer index in 0..{n - 1} (a Python or "
                         f"numpy integer, or a 0-d integer array), got {action!r} ({kind})")
    if not 0 <= index < n:
        raise ValueError(f"action set {action_set!r}: action index must be in 0..{n - 1}, got {index}")
    return index
