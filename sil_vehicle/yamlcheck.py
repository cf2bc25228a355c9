"""Strict reading of YAML mappings: every key is consumed once, checked and typed.

A `Section` wraps one mapping of a file. Reading a key removes it from the set of keys still to
read; `done()` then fails on whatever is left (an unknown key). Every error is a `ConfigError`
naming the file, the dotted key, the value and what was expected.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import yaml


class ConfigError(ValueError):
    """A parameter file is wrong. The message names the file, the key, the value, the expectation."""


class _Yaml12Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 booleans: only true/false (any case) are booleans, so that
    `off`, `on`, `yes`, `no` stay strings and a key or value like `off: true` fails the normal
    checks instead of silently turning into False."""


_Yaml12Loader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Yaml12Loader.add_implicit_resolver(
    "tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
    list("tTfF"))


def load_yaml(path: Path) -> dict[str, Any]:
    """Read one YAML file that must hold a mapping at the top level."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from exc
    try:
        data = yaml.load(text, Loader=_Yaml12Loader)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    return data


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Deep merge: mappings merge key by key, anything else in `over` replaces `base`."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def load_with_extends(path: Path, path_keys: tuple[str, ...] = ()) -> dict[str, Any]:
    """Load a file; an `extends: OTHER.yaml` key (relative to the file) supplies the defaults.
    Top-level `path_keys` holding a relative path are made absolute against the folder of the
    file that names them, so an inherited path still points where its author meant."""
    path = Path(path)
    data = _absolute(load_yaml(path), path, path_keys)
    seen = [path.resolve()]
    while "extends" in data:
        ref = data.pop("extends")
        if not isinstance(ref, str):
            raise ConfigError(f"{path}: key 'extends': expected a file name, got {ref!r}")
        base_path = (seen[-1].parent / ref).resolve()
        if base_path in seen:
            raise ConfigError(f"{path}: key 'extends': cycle through {base_path}")
        seen.append(base_path)
        data = merge(_absolute(load_yaml(base_path), base_path, path_keys), data)
    return data


def _absolute(data: dict[str, Any], file: Path, keys: tuple[str, ...]) -> dict[str, Any]:
    for key in keys:
        value = data.get(key)
        if isinstance(value, str) and not Path(value).is_absolute():
            data[key] = str((Path(file).resolve().parent / value).resolve())
    return data


class Section:
    """One mapping of a parameter file, read key by key."""

    def __init__(self, data: Any, file: Path | str, prefix: str = "") -> None:
        self.file = str(file)
        self.prefix = prefix
        if not isinstance(data, dict):
            where = prefix.rstrip(".") or "top level"
            raise ConfigError(f"{self.file}: key '{where}': expected a mapping, got {data!r}")
        self._data = dict(data)

    def _name(self, key: str) -> str:
        return f"{self.prefix}{key}"

    def fail(self, key: str, value: Any, expected: str) -> ConfigError:
        return ConfigError(f"{self.file}: key '{self._name(key)}': got {value!r}, expected {expected}")

    def _take(self, key: str, default: Any) -> Any:
        if key in self._data:
            return self._data.pop(key)
        if default is _REQUIRED:
            raise ConfigError(f"{self.file}: missing key '{self._name(key)}'")
        return default

    def has(self, key: str) -> bool:
        return key in self._data

    def float(self, key: str, lo: float = -math.inf, hi: float = math.inf,
              default: Any = None, *, lo_open: bool = False) -> float:
        value = self._take(key, _REQUIRED if default is None else default)
        expected = f"a number in {'(' if lo_open else '['}{lo}, {hi}]"
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, value, expected)
        value = float(value)
        if not math.isfinite(value) or value < lo or value > hi or (lo_open and value == lo):
            raise self.fail(key, value, expected)
        return value

    def int(self, key: str, lo: int, hi: int, default: Any = None) -> int:
        value = self._take(key, _REQUIRED if default is None else default)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise self.fail(key, value, f"an integer in [{lo}, {hi}]")
        return value

    def bool(self, key: str, default: Any = None) -> bool:
        value = self._take(key, _REQUIRED if default is None else default)
        if not isinstance(value, bool):
            raise self.fail(key, value, "true or false")
        return value

    def str(self, key: str, choices: tuple[str, ...] | None = None, default: Any = None) -> str:
        value = self._take(key, _REQUIRED if default is None else default)
        if not isinstance(value, str) or (choices is not None and value not in choices):
            raise self.fail(key, value, "one of " + ", ".join(choices) if choices else "a string")
        return value

    def floats(self, key: str, n: int, lo: float = -math.inf, hi: float = math.inf,
               default: Any = None) -> tuple[float, ...]:
        value = self._take(key, _REQUIRED if default is None else default)
        expected = f"a list of {n} numbers in [{lo}, {hi}]"
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise self.fail(key, value, expected)
        for item in value:
            if isinstance(item, bool) or not isinstance(item, (int, float)) \
                    or not math.isfinite(item) or not lo <= item <= hi:
                raise self.fail(key, value, expected)
        return tuple(float(v) for v in value)

    def section(self, key: str, default: Any = None) -> "Section":
        value = self._take(key, _REQUIRED if default is None else default)
        return Section(value, self.file, f"{self._name(key)}.")

    def sections(self, key: str, n: int) -> list["Section"]:
        value = self._take(key, _REQUIRED)
        if not isinstance(value, list) or len(value) != n:
            raise self.fail(key, value, f"a list of {n} mappings")
        return [Section(item, self.file, f"{self._name(key)}[{i}].") for i, item in enumerate(value)]

    def raw(self, key: str, default: Any = None) -> Any:
        return self._take(key, _REQUIRED if default is None else default)

    def done(self) -> None:
        """Fail on any key that was not read: a typo must never be silently ignored."""
        if self._data:
            key = sorted(self._data, key=str)[0]     # YAML keys need not be strings
            raise ConfigError(f"{self.file}: unknown key '{self._name(key)}' "
                              f"(value {self._data[key]!r})")


_REQUIRED = object()
