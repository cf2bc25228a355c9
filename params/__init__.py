"""trq_params: the parameter files that ship with the toolkit, found by name.

In a checkout this is the `params/` folder; in an installed wheel it is the package `trq_params`
(the same files, package data). Nothing here reads a file's content: that is the loader's job
(`trq_params.loader`, against the schemas of `trq_params.schema`). What goes in: a kind of file and
a name, or a path. What comes out: the path of the file.

    loader    the one YAML reader: `extends:` chains, strict validation, errors naming the file,
              the key, the value and what was expected
    schema    the typed schema of every kind of file, one model per kind

    builtin("controller", "trq_nmpc_eso")   -> .../controller/trq_nmpc_eso.yaml
    resolve("vehicle", "quad")              -> the built-in quad.yaml
    resolve("vehicle", "my/airframe.yaml")  -> that path, as given (a user's own file)
    names("scenarios")                      -> ("fast_timevarying", "nominal", ...)

A bare name (no folder, no `.yaml`) is a built-in file; anything else is a path. A user's file may
`extends:` a built-in one by its path or by `builtin:KIND/NAME`.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["DIR", "KINDS", "builtin", "resolve", "exists", "names", "is_name", "ConfigError",
           "UnknownName"]

DIR = Path(__file__).resolve().parent
"""The folder of the shipped files (wheels install unzipped, so this is a real folder)."""

KINDS = ("vehicle", "sim", "controller", "scenarios", "faults", "campaigns", "sensing")


class ConfigError(ValueError):
    """A parameter file is wrong; the message names the file, key, value and expectation.
    (Defined here, beside the files, so that a wrong name and a wrong file are one error type;
    `trq_params.loader` raises it.)"""


class UnknownName(ConfigError):
    """A built-in file was asked for by a name that is not shipped."""


def _check_kind(kind: str) -> None:
    if kind not in KINDS:
        raise ValueError(f"unknown kind of parameter file {kind!r}: expected one of "
                         + ", ".join(KINDS))


def names(kind: str) -> tuple[str, ...]:
    """The names of the shipped files of one kind, sorted."""
    _check_kind(kind)
    return tuple(sorted(p.stem for p in (DIR / kind).glob("*.yaml")))


def builtin(kind: str, name: str) -> Path:
    """The shipped file `name` of `kind`; UnknownName (listing what exists) if there is none."""
    _check_kind(kind)
    path = DIR / kind / f"{name}.yaml"
    if not path.is_file():
        raise UnknownName(f"no built-in {kind} file named {name!r}: expected one of "
                          + ", ".join(names(kind)))
    return path


def is_name(text: str) -> bool:
    """True for a bare name (`quad`), false for anything that looks like a path."""
    return "/" not in text and "\\" not in text and not text.endswith((".yaml", ".yml"))


def resolve(kind: str, name_or_path: str | Path) -> Path:
    """A built-in file by bare name, or a user's file by path (returned as given)."""
    if isinstance(name_or_path, Path) or not is_name(name_or_path):
        return Path(name_or_path)
    return builtin(kind, name_or_path)


def exists(kind: str, name_or_path: str | Path) -> bool:
    """Whether `resolve` would find a file (a built-in name, or a path to a file)."""
    try:
        return resolve(kind, name_or_path).is_file()
    except UnknownName:
        return False
