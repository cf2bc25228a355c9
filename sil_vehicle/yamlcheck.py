"""Deprecated: what tools/ still imports until it moves to `trq_params.loader`.

Nothing in sil_vehicle or trq_offboard imports this module (tests/meta checks it). `ConfigError`
and `load_yaml` are the loader's own (one error class, one YAML dialect); `Section` is the old
key-by-key reader that tools/campaign.py and tools/run_scenario.py still use for their own
files. Delete this module once tools/ calls `trq_params.loader.load(path, Model)` or
`validate(Model, data, file)` instead.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from trq_params.loader import ConfigError, merge
from trq_params.loader import read_yaml as load_yaml

__all__ = ["ConfigError", "Section", "load_yaml", "merge"]


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
