"""The configuration's schema machinery and loader.

A schema is a frozen dataclass whose fields are declared with :func:`spec` (the meaning
and units, the inclusive range, the allowed values, a sequence's length, and for an
optional ``X | None`` field the value given when a file omits it). :func:`load` reads a
TOML file and builds the dataclass, rejecting unknown keys, missing keys, wrong types
and out-of-range values with a :class:`ConfigError` that names the file, the dotted key
and what was expected (and, for a key missing from an older file, what the shipped file
has). :class:`Loaded` keeps a configuration with its exact text (its id).

The schemas themselves are in :mod:`svss_daq.config` (hardware, acquisition, devices)
and :mod:`svss_daq.config_processing` (processing); ``from svss_daq.config import ...``
gives every name of the three.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")

CONFIG_ENV = "SVSS_CONFIG_DIR"


class ConfigError(ValueError):
    """A configuration file is missing, unreadable or invalid."""


def spec(doc: str, lo: float | None = None, hi: float | None = None,
         choices: tuple | None = None, length: int | None = None,
         min_length: int | None = None, default: Any = None) -> Any:
    """Declare a schema field: ``doc`` with units, inclusive range, allowed values,
    exact or minimum sequence length, and for an optional (``X | None``) field the value
    :func:`load` gives it when the file omits it."""
    return field(metadata={"doc": doc, "lo": lo, "hi": hi, "choices": choices,
                           "length": length, "min_length": min_length,
                           "default": default})


def omitted_default(cls: type, name: str) -> Any:
    """The value :func:`load` gives field ``name`` of schema ``cls`` when a file omits
    it (its :func:`spec` ``default``; None where it has none)."""
    return {f.name: f for f in dataclasses.fields(cls)}[name].metadata.get("default")


# ----------------------------------------------------------------------- the loader


def _expected(f: dataclasses.Field, tp: Any) -> str:
    m = f.metadata
    what = _type_name(tp)
    if m.get("choices"):
        what += f" one of {list(m['choices'])}"
    if m.get("lo") is not None or m.get("hi") is not None:
        what += f" in [{m.get('lo')}, {m.get('hi')}]"
    if m.get("length") is not None:
        what += f" of length {m['length']}"
    if m.get("min_length"):
        what += f" of at least {m['min_length']} entries"
    return f"{what} ({m.get('doc', '')})"


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (types.UnionType, typing.Union):
        return " or ".join(_type_name(a) for a in typing.get_args(tp) if a is not type(None))
    if origin is tuple:
        args = typing.get_args(tp)
        return f"array of {_type_name(args[0])}"
    if dataclasses.is_dataclass(tp):
        return "table"
    return {float: "number", int: "integer", str: "string", bool: "boolean"}.get(tp, str(tp))


def _convert(value: Any, tp: Any, f: dataclasses.Field, key: str, file: str) -> Any:
    def fail(msg: str) -> ConfigError:
        return ConfigError(f"{file}: key '{key}': {msg}; expected {_expected(f, tp)}")

    origin = typing.get_origin(tp)
    if origin in (types.UnionType, typing.Union):
        inner = [a for a in typing.get_args(tp) if a is not type(None)][0]
        return None if value is None else _convert(value, inner, f, key, file)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise fail(f"got {type(value).__name__}")
        return _build(tp, value, key, file)
    if origin is tuple:
        if not isinstance(value, list):
            raise fail(f"got {type(value).__name__}")
        m = f.metadata
        if m.get("length") is not None and len(value) != m["length"]:
            raise fail(f"got {len(value)} entries")
        if m.get("min_length") and len(value) < m["min_length"]:
            raise fail(f"got {len(value)} entries")
        inner = typing.get_args(tp)[0]
        inner_field = f
        if typing.get_origin(inner) is tuple:  # nested arrays: check inner length by type
            n_inner = len(typing.get_args(inner)) if typing.get_args(inner)[-1] is not Ellipsis else None
            inner_field = dataclasses.field(metadata={**m, "length": n_inner, "min_length": None})
        return tuple(_convert(v, inner, inner_field, f"{key}[{i}]", file)
                     for i, v in enumerate(value))
    if tp is bool:
        if not isinstance(value, bool):
            raise fail(f"got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise fail(f"got {value!r}")
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise fail(f"got {value!r}")
        value = float(value)
        if value != value:
            raise fail("got NaN")
    elif tp is str:
        if not isinstance(value, str):
            raise fail(f"got {value!r}")
    m = f.metadata
    if m.get("choices") and value not in m["choices"]:
        raise fail(f"got {value!r}")
    if m.get("lo") is not None and value < m["lo"]:
        raise fail(f"got {value!r}, below the minimum")
    if m.get("hi") is not None and value > m["hi"]:
        raise fail(f"got {value!r}, above the maximum")
    return value


def _build(cls: type[T], data: dict, prefix: str, file: str) -> T:
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        where = f"table '{prefix}'" if prefix else "top level"
        raise ConfigError(f"{file}: unknown key '{_join(prefix, unknown[0])}' in {where}; "
                          f"expected one of {sorted(fields)}")
    kwargs = {}
    for name, f in fields.items():
        key = _join(prefix, name)
        tp = hints[name]
        if name not in data:
            optional = typing.get_origin(tp) in (types.UnionType, typing.Union)
            if optional:
                kwargs[name] = f.metadata.get("default")
                continue
            if typing.get_origin(tp) is tuple and f.metadata.get("min_length") == 0:
                kwargs[name] = ()
                continue
            raise ConfigError(f"{file}: missing key '{key}'; expected {_expected(f, tp)}")
        kwargs[name] = _convert(data[name], tp, f, key, file)
    obj = cls(**kwargs)
    check = getattr(obj, "config_problem", None)
    if check is not None:
        problem = check()
        if problem is not None:
            raise ConfigError(f"{file}: key '{_join(prefix, problem[0])}': {problem[1]}")
    return obj


def _join(prefix: str, name: str) -> str:
    return f"{prefix}.{name}" if prefix else name


#: the shipped file of each top-level schema (config/), whose values a "missing key"
#: error quotes: a file written before a key existed is told what to add
SHIPPED_FILES = {"ProcessingConfig": "processing.toml", "HardwareConfig": "hardware.toml",
                 "DaqConfig": "daq.toml", "DevicesConfig": "devices.toml",
                 "AcquireConfig": "acquire.toml"}


def _toml_text(v: Any) -> str:
    """``v`` written as TOML."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_text(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_toml_text(x)}" for k, x in v.items()) + "}"
    return repr(v)


def _shipped_hint(cls: type, key: str, source: str) -> str:
    """What the shipped file of schema ``cls`` has for dotted ``key`` ('' when it has
    none, or is the file being read)."""
    name = SHIPPED_FILES.get(cls.__name__)
    if name is None or "[" in key:
        return ""
    shipped = config_path(name)
    try:
        if Path(source).resolve() == shipped.resolve():
            return ""
        node = read_toml(shipped)
    except (ConfigError, OSError):
        return ""
    *tables, leaf = key.split(".")
    for t in tables:
        node = node.get(t) if isinstance(node, dict) else None
    if not isinstance(node, dict) or leaf not in node:
        return ""
    where = f" under [{'.'.join(tables)}]" if tables else ""
    return (f"; a key newer than this file? the shipped {shipped} has "
            f"{leaf} = {_toml_text(node[leaf])}{where}: add it (docs/config.md)")


def from_dict(cls: type[T], data: dict, source: str = "<dict>") -> T:
    """Build and validate schema ``cls`` from a parsed TOML mapping. A missing key is
    an error naming it and, where the shipped file of the schema has it, what to add."""
    try:
        return _build(cls, data, "", source)
    except ConfigError as exc:
        m = re.search(r": missing key '([^']+)'", str(exc))
        if m is None:
            raise
        hint = _shipped_hint(cls, m.group(1), source)
        if not hint:
            raise
        raise ConfigError(str(exc) + hint) from None


def read_toml(path: str | os.PathLike) -> dict:
    """Parse a TOML file, raising :class:`ConfigError` naming the file on failure."""
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            return tomllib.load(fh)
    except FileNotFoundError:
        raise ConfigError(f"{path}: configuration file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def load(cls: type[T], path: str | os.PathLike) -> T:
    """Read the TOML file ``path`` and validate it against schema ``cls``."""
    return from_dict(cls, read_toml(path), str(path))


def loads(cls: type[T], text: str, source: str = "<string>") -> T:
    """Validate TOML ``text`` against schema ``cls``."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    return from_dict(cls, data, source)


def config_dir() -> Path:
    """The configuration folder: ``$SVSS_CONFIG_DIR`` or the project's ``config/``."""
    env = os.environ.get(CONFIG_ENV)
    path = Path(env) if env else Path(__file__).resolve().parents[1] / "config"
    if not path.is_dir():
        raise ConfigError(f"{path}: configuration folder not found "
                          f"(set {CONFIG_ENV} to the project's config/ folder)")
    return path


def config_path(name: str) -> Path:
    """Path of a file inside the configuration folder, e.g. ``'hardware.toml'``."""
    return config_dir() / name


def digest(text: str) -> str:
    """Short, stable identity of a configuration text (first 16 hex digits of SHA-256)."""
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Loaded(typing.Generic[T]):
    """A validated configuration with the exact text it came from."""
    value: T
    text: str
    source: str

    @property
    def id(self) -> str:
        return digest(self.text)


def load_with_text(cls: type[T], path: str | os.PathLike) -> Loaded[T]:
    """Like :func:`load` but keep the file's text (for provenance and config ids)."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ConfigError(f"{path}: configuration file not found") from None
    return Loaded(loads(cls, text, str(path)), text, str(path))


def loaded_from_text(cls: type[T], text: str, source: str) -> Loaded[T]:
    """Validate a configuration text carried in a file or message."""
    return Loaded(loads(cls, text, source), text, source)


# -------------------------------------------------------------------------- security
