"""The one YAML loader of the toolkit: one dialect, one `extends:` rule, one error type.

What goes in: a file path and a pydantic model (a schema of `trq_params.schema`, or a caller's
own). What comes out: the validated, frozen model; the daemons' config modules build their
records from it. It never builds records or computes derived quantities.

    load(path, Model)             read, resolve `extends:`, validate -> Model instance
    validate(Model, data, file)   validate a mapping already in hand (file names the source)
    read(path, path_keys=())      the merged mapping of a file and its `extends:` chain
    read_yaml(path)               one file, no `extends:` (a mapping at the top level)
    chain(path)                   the files a file is made of (itself and its `extends:` chain)
    dump(mapping)                 YAML text of a mapping (for overlays a tool writes)

Dialect: YAML 1.2 booleans, so only true/false (any case) are booleans; `no`, `off`, `yes`, `on`
stay strings and fail a boolean key instead of silently turning into one.

`extends: OTHER` names a file that supplies defaults: a path relative to the file that writes
it (or absolute), or `builtin:KIND/NAME` for a shipped file (`trq_params.builtin`). Mappings merge
key by key, anything else in the child replaces the parent's value. Cycles and missing files are
errors.

Path-valued keys: a schema marks a field as a path with the `PathStr` type. `load` asks the model
for the dotted keys of its path fields (`path_keys(Model)`) and `read` makes every relative value
of those keys absolute against the folder of the file that wrote the value, before merging, so
an inherited path points where its author meant whoever extends the file. A `NameOrPath` field
(a built-in file's bare name, or a path: `trq_params.is_name` tells them apart) is a path key
too, but a bare name in it stays as written (`name_keys(Model)`).

Errors: `ConfigError`, a ValueError whose message names the file, the dotted key (`rotors[2].spin`),
the value and what was expected.
"""

from __future__ import annotations

import functools
import math
import re
import types
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Callable, Mapping, TypeVar

import trq_params
import yaml
from pydantic import BaseModel, BeforeValidator, ValidationError
from pydantic_core import PydanticCustomError
from trq_params import ConfigError

__all__ = ["ConfigError", "Invalid", "load", "validate", "read", "read_yaml", "chain",
           "path_keys", "name_keys", "leaf_types", "PathStr", "NameOrPath", "Num", "Int", "Flag",
           "Text", "Choice", "Vec", "NumOrVec",
           "Items", "Range", "range_of", "expect", "merge", "dump", "BUILTIN"]

BUILTIN = "builtin:"



class Invalid(Exception):
    """Raised by a schema's cross-key check: `key` is the full dotted key from the top level.
    Not a ValueError on purpose, so that pydantic lets it through to `validate`, which names the
    file."""

    def __init__(self, key: str, value: Any, expected: str) -> None:
        super().__init__(key, value, expected)
        self.key, self.value, self.expected = key, value, expected


# --------------------------------------------------------------------------------------------
# the dialect and `extends:`
# --------------------------------------------------------------------------------------------

class _Yaml12Loader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
    """SafeLoader with YAML 1.2 booleans (only true/false), and a key given twice in one mapping
    refused (YAML 1.2 requires keys to be unique; PyYAML keeps the last silently, so that an
    edit that adds a key a file already has would change nothing, or the wrong thing, without a
    word). On libyaml's parser where PyYAML has it (its wheels do): the same documents, read
    several times faster, which a campaign loading hundreds of parameter files feels."""

    def construct_mapping(self, node, deep=False):
        seen: dict = {}
        for key_node, _ in node.value:
            try:
                key = self.construct_object(key_node, deep=True)
                twice = key in seen
            except TypeError:               # an unhashable key: the constructor's own error
                break
            if twice:
                raise yaml.constructor.ConstructorError(
                    None, None, f"key {key!r} given twice in one mapping (first on line "
                    f"{seen[key] + 1})", key_node.start_mark)
            seen[key] = key_node.start_mark.line
        return super().construct_mapping(node, deep)


_Yaml12Loader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()}
_Yaml12Loader.add_implicit_resolver(
    "tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
    list("tTfF"))


def read_yaml(path: Path | str) -> dict[str, Any]:
    """Read one YAML file that must hold a mapping at the top level."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror}") from exc
    try:
        data = _parsed(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping at the top level, got {type(data).__name__}")
    return _copied(data)


@functools.lru_cache(maxsize=256)
def _parsed(text: str) -> Any:
    """The document of `text`, parsed once per process for the same text (a campaign or a test
    suite reads the same parameter files hundreds of times); callers get `_copied` of it."""
    return yaml.load(text, Loader=_Yaml12Loader)


def _copied(value: Any) -> Any:
    """A copy of a parsed document that shares nothing mutable with it (mappings and lists
    copied; scalars, dates included, are immutable)."""
    if isinstance(value, dict):
        return {k: _copied(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_copied(v) for v in value]
    return value


def dump(data: Mapping[str, Any]) -> str:
    """YAML text of a mapping, keys in their order (the overlays the tools write and fly)."""
    return yaml.safe_dump(dict(data), sort_keys=False)


def merge(base: Mapping[str, Any], over: Mapping[str, Any]) -> dict[str, Any]:
    """Deep merge: mappings merge key by key, anything else in `over` replaces `base`."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def _parent(ref: Any, file: Path) -> Path:
    if not isinstance(ref, str) or not ref:
        raise ConfigError(f"{file}: key 'extends': got {ref!r}, expected a file name or "
                          f"{BUILTIN}KIND/NAME")
    if ref.startswith(BUILTIN):
        kind, sep, name = ref[len(BUILTIN):].partition("/")
        try:
            return trq_params.builtin(kind, name).resolve()
        except ValueError as exc:     # UnknownName, or an unknown kind
            raise ConfigError(f"{file}: key 'extends': got {ref!r}: {exc}") from exc
    return (file.parent / ref).resolve()


def _absolute(data: dict[str, Any], file: Path, keys: tuple[str, ...],
              names: tuple[str, ...] = ()) -> dict[str, Any]:
    """Relative values of the dotted `keys` made absolute against `file`'s folder (a bare name
    in one of the `names` keys stays as written)."""
    for dotted in keys:
        *outer, last = dotted.split(".")
        node: Any = data
        for part in outer:
            node = node.get(part) if isinstance(node, dict) else None
        if isinstance(node, dict):
            value = node.get(last)
            if isinstance(value, str) and not Path(value).is_absolute() \
                    and not (dotted in names and trq_params.is_name(value)):
                node[last] = str((file.parent / value).resolve())
    return data


def chain(path: Path | str) -> list[Path]:
    """The files `path` is made of: itself, then each file its `extends:` names, in order."""
    files = [Path(path).resolve()]
    data = read_yaml(files[0])
    while "extends" in data:
        parent = _parent(data["extends"], files[-1])
        if parent in files:
            raise ConfigError(f"{files[-1]}: key 'extends': cycle through {parent}")
        files.append(parent)
        data = read_yaml(parent)
    return files


def read(path: Path | str, path_keys: tuple[str, ...] = (),
         name_keys: tuple[str, ...] = ()) -> dict[str, Any]:
    """The mapping of `path` with its `extends:` chain merged (children override parents), each
    layer's relative values of `path_keys` resolved against its own folder (bare names in
    `name_keys` left as they are)."""
    file = Path(path).resolve()
    chain = [file]
    layers = [_absolute(read_yaml(path), file, path_keys, name_keys)]
    while "extends" in layers[-1]:
        parent = _parent(layers[-1].pop("extends"), chain[-1])
        if parent in chain:
            raise ConfigError(f"{chain[-1]}: key 'extends': cycle through {parent}")
        if not parent.is_file():
            raise ConfigError(f"{chain[-1]}: key 'extends': no such file {parent}")
        chain.append(parent)
        layers.append(_absolute(read_yaml(parent), parent, path_keys, name_keys))
    merged: dict[str, Any] = {}
    for layer in reversed(layers):
        merged = merge(merged, layer)
    return merged


# --------------------------------------------------------------------------------------------
# validation
# --------------------------------------------------------------------------------------------

M = TypeVar("M", bound=BaseModel)


def load(path: Path | str, model: type[M], *, context: Any = None) -> M:
    """Read `path` (with `extends:`) and validate it as `model`."""
    return validate(model, read(path, path_keys(model), name_keys(model)), path, context=context)


def validate(model: type[M], data: Any, file: Path | str, *, prefix: str = "",
             context: Any = None) -> M:
    """Validate a mapping as `model`; errors are ConfigErrors naming `file` and the dotted key,
    which starts with `prefix` when the mapping is a part of a file (`events[2]`)."""
    try:
        return model.model_validate(data, context=context)
    except ValidationError as exc:
        raise _translate(exc, model, file, prefix) from None
    except Invalid as exc:
        raise ConfigError(f"{file}: key '{_join(prefix, exc.key)}': got {exc.value!r}, "
                          f"expected {exc.expected}") from None


def _join(prefix: str, key: str) -> str:
    if not prefix or not key:
        return prefix or key
    return prefix + key if key.startswith("[") else f"{prefix}.{key}"


def dotted(loc: tuple[Any, ...]) -> str:
    """('rotors', 2, 'spin') -> 'rotors[2].spin'"""
    out = ""
    for part in loc:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def _translate(exc: ValidationError, model: type[BaseModel], file: Path | str,
               prefix: str = "") -> ConfigError:
    """pydantic's first error (its loc, input and msg) as a ConfigError."""
    err = exc.errors(include_url=False)[0]
    loc = tuple(p for p in err["loc"] if not (isinstance(p, str) and p.startswith("function-")))
    key, kind, value = _join(prefix, dotted(loc)) or "top level", err["type"], err.get("input")
    if kind == "missing":
        return ConfigError(f"{file}: key '{key}' is missing")
    if kind == "extra_forbidden":
        owner = _model_at(model, loc[:-1])
        known = f": expected one of {', '.join(owner.model_fields)}" if owner else ""
        return ConfigError(f"{file}: unknown key '{key}' (value {value!r}){known}")
    if kind == "expected":
        expected = err["ctx"]["expected"]
    elif kind in ("model_type", "model_attributes_type", "dict_type"):
        expected = "a mapping"
    else:
        expected = err["msg"][0].lower() + err["msg"][1:]
    return ConfigError(f"{file}: key '{key}': got {value!r}, expected {expected}")


def _unwrap(tp: Any) -> Any:
    """The model class inside an annotation (Annotated, Optional, tuple[X, ...]), or None."""
    while True:
        origin = typing.get_origin(tp)
        if origin is Annotated:
            tp = typing.get_args(tp)[0]
        elif origin in (typing.Union, types.UnionType, tuple, list):
            inner = [_unwrap(a) for a in typing.get_args(tp) if a is not type(None)]
            inner = [a for a in inner if a is not None]
            return inner[0] if inner else None
        else:
            return tp if isinstance(tp, type) and issubclass(tp, BaseModel) else None


def _model_at(model: type[BaseModel], loc: tuple[Any, ...]) -> type[BaseModel] | None:
    current: Any = model
    for part in loc:
        if isinstance(part, int):
            continue
        field = current.model_fields.get(part) if current else None
        current = _unwrap(field.annotation) if field else None
        if current is None:
            return None
    return current


@dataclass(frozen=True)
class _PathMark:
    """Metadata of a path-valued field (see `PathStr`, `NameOrPath`)."""
    names: bool = False          # a bare name is a built-in file's, left as written


_PATH = _PathMark()
_NAME_OR_PATH = _PathMark(names=True)


def _field_type(field: Any) -> Any:
    """A field's type as written (pydantic keeps a top-level Annotated's metadata apart), with
    Optional[...] removed."""
    tp = Annotated[(field.annotation, *field.metadata)] if field.metadata else field.annotation
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        tp = args[0] if len(args) == 1 else tp
    return tp


def leaf_types(model: type[BaseModel], prefix: str = "") -> dict[str, Any]:
    """The dotted keys of the fields of `model` and of its nested models (not inside lists),
    each with its field type (Optional removed): what a flat mapping of its values may hold."""
    out: dict[str, Any] = {}
    for name, field in model.model_fields.items():
        key = f"{prefix}{field.alias or name}"
        tp = _field_type(field)
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            out.update(leaf_types(tp, key + "."))
        else:
            out[key] = tp
    return out


def path_keys(model: type[BaseModel], prefix: str = "", *,
              only_names: bool = False) -> tuple[str, ...]:
    """The dotted keys of the fields typed `PathStr` or `NameOrPath` in `model` and its nested
    models (not inside lists); `only_names`: of the `NameOrPath` ones alone."""
    out: list[str] = []
    for name, field in model.model_fields.items():
        key = f"{prefix}{field.alias or name}"
        marks = [m for m in field.metadata if isinstance(m, _PathMark)]
        if marks:
            if marks[0].names or not only_names:
                out.append(key)
            continue
        tp = field.annotation
        while typing.get_origin(tp) is Annotated:
            tp = typing.get_args(tp)[0]
        if typing.get_origin(tp) in (typing.Union, types.UnionType):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            tp = args[0] if len(args) == 1 else None
        if isinstance(tp, type) and issubclass(tp, BaseModel):
            out.extend(path_keys(tp, key + ".", only_names=only_names))
    return tuple(out)


def name_keys(model: type[BaseModel]) -> tuple[str, ...]:
    """The dotted keys of the `NameOrPath` fields: a bare name in them is not a path."""
    return path_keys(model, only_names=True)


# --------------------------------------------------------------------------------------------
# field types: each checks its value and says what it expected in the same words everywhere
# --------------------------------------------------------------------------------------------

def expect(expected: str) -> PydanticCustomError:
    """The error a field check raises (the translator puts `expected` into the message)."""
    return PydanticCustomError("expected", "{expected}", {"expected": expected})


def _checked(check: Callable[[Any], Any]) -> BeforeValidator:
    return BeforeValidator(check)


def _is_number(value: Any) -> bool:
    return not isinstance(value, bool) and isinstance(value, (int, float)) \
        and math.isfinite(value)


@dataclass(frozen=True)
class Range:
    """The bounds of a Num, Int or Vec field, kept on its type: what a campaign may draw within
    (`typing.get_args(tp)[1:]` holds it)."""
    lo: float
    hi: float


def range_of(tp: Any) -> Range | None:
    """The Range a field type carries, if any."""
    return next((m for m in typing.get_args(tp)[1:] if isinstance(m, Range)), None) \
        if typing.get_origin(tp) is Annotated else None


def Num(lo: float = -math.inf, hi: float = math.inf, *, open_lo: bool = False) -> Any:
    """A finite number in [lo, hi] (or (lo, hi]); an integer in the file becomes a float."""
    want = f"a number in {'(' if open_lo else '['}{lo:g}, {hi:g}]"

    def check(value: Any) -> float:
        if not _is_number(value) or not lo <= value <= hi or (open_lo and value == lo):
            raise expect(want)
        return float(value)
    return Annotated[float, _checked(check), Range(lo, hi)]


def Int(lo: int, hi: int) -> Any:
    """An integer in [lo, hi] (not a bool, not a float)."""
    def check(value: Any) -> int:
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise expect(f"an integer in [{lo}, {hi}]")
        return value
    return Annotated[int, _checked(check), Range(lo, hi)]


def _flag(value: Any) -> bool:
    if not isinstance(value, bool):
        raise expect("true or false")
    return value


Flag = Annotated[bool, _checked(_flag)]
"""true or false (YAML 1.2: `no`, `off` are strings, so they are rejected)."""


def _text(value: Any) -> str:
    if not isinstance(value, str):
        raise expect("a string")
    return value


Text = Annotated[str, _checked(_text)]
PathStr = Annotated[str, _checked(_text), _PATH]
"""A file path; relative values are resolved against the folder of the file that wrote them."""
NameOrPath = Annotated[str, _checked(_text), _NAME_OR_PATH]
"""A built-in file's bare name (`mocap`), or a path resolved as a `PathStr` is."""


def Choice(*choices: str) -> Any:
    """One of the given strings."""
    def check(value: Any) -> str:
        if not isinstance(value, str) or value not in choices:
            raise expect("one of " + "|".join(choices))
        return value
    return Annotated[str, _checked(check)]


def Vec(n: int, lo: float = -math.inf, hi: float = math.inf) -> Any:
    """A list of n finite numbers in [lo, hi], as a tuple of floats."""
    want = f"a list of {n} numbers in [{lo:g}, {hi:g}]"

    def check(value: Any) -> tuple[float, ...]:
        if not isinstance(value, (list, tuple)) or len(value) != n or not all(
                _is_number(v) and lo <= v <= hi for v in value):
            raise expect(want)
        return tuple(float(v) for v in value)
    return Annotated[tuple[float, ...], _checked(check), Range(lo, hi)]


def NumOrVec(n: int, lo: float = -math.inf, hi: float = math.inf) -> Any:
    """One finite number in [lo, hi] for every axis (a float), or a list of n of them (a tuple
    of floats), as a per-axis figure that most files give once."""
    want = f"a number, or a list of {n} numbers, in [{lo:g}, {hi:g}]"

    def check(value: Any) -> float | tuple[float, ...]:
        if _is_number(value) and lo <= value <= hi:
            return float(value)
        if isinstance(value, (list, tuple)) and len(value) == n and all(
                _is_number(v) and lo <= v <= hi for v in value):
            return tuple(float(v) for v in value)
        raise expect(want)
    return Annotated[float | tuple[float, ...], _checked(check), Range(lo, hi)]


def Items(n: int) -> BeforeValidator:
    """A list of exactly n mappings (put on a `tuple[Model, ...]` field), as a tuple."""
    def check(value: Any) -> tuple[Any, ...]:
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise expect(f"a list of {n} mappings")
        return tuple(value)
    return _checked(check)
