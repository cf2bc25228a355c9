"""Writing a command's outputs all at once: each file goes to a temporary name beside its target
and is renamed into place only when every one is written, so a failure leaves nothing
half-written (the files already there stay as they were)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

__all__ = ["write_all", "write_file"]


def write_all(folder: Path, files: dict[str, bytes]) -> None:
    """Write `files` (name -> bytes) into `folder` (created if missing)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    staged: list[tuple[str, Path]] = []
    try:
        for name, data in files.items():
            fd, tmp = tempfile.mkstemp(prefix=f".{name}.", dir=folder)
            with os.fdopen(fd, "wb") as fh:
                fh.write(data)
            staged.append((tmp, folder / name))
    except BaseException:
        for tmp, _ in staged:
            os.unlink(tmp)
        raise
    for tmp, target in staged:
        os.replace(tmp, target)


def write_file(path: Path, data: bytes) -> None:
    """One file, written to a temporary name beside it and renamed into place."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_all(path.parent, {path.name: data})
