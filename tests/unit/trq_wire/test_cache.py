"""The cache of compiled code shared by both daemons (trq_wire.cache): where it is, which
compiler is found, and how a library lands in it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from trq_wire import cache


def test_cache_dir_from_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("TRQ_CACHE_DIR", str(tmp_path / "c"))
    assert cache.cache_dir() == tmp_path / "c"
    monkeypatch.setenv("TRQ_CACHE_DIR", "~/elsewhere")
    assert cache.cache_dir() == Path.home() / "elsewhere"


def test_cache_dir_default(monkeypatch):
    monkeypatch.delenv("TRQ_CACHE_DIR", raising=False)
    assert cache.cache_dir() == Path.home() / ".cache" / "trq-ftc"
    monkeypatch.setenv("TRQ_CACHE_DIR", "")                    # empty: as if unset
    assert cache.cache_dir() == Path.home() / ".cache" / "trq-ftc"


def _fake_compiler(folder: Path, name: str) -> Path:
    path = folder / name
    path.write_text("#!/bin/sh\nexit 1\n")
    path.chmod(0o755)
    return path


def test_find_compiler_order(monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("CC", raising=False)
    assert cache.find_compiler() is None
    clang = _fake_compiler(tmp_path, "clang")
    assert cache.find_compiler() == str(clang)
    gcc = _fake_compiler(tmp_path, "gcc")
    assert cache.find_compiler() == str(gcc)                   # gcc before clang
    mine = _fake_compiler(tmp_path, "mycc")
    monkeypatch.setenv("CC", "mycc")
    assert cache.find_compiler() == str(mine)                  # $CC first
    monkeypatch.setenv("CC", "no-such-compiler")
    assert cache.find_compiler() == str(gcc)                   # a missing $CC is skipped


def test_build_library_reports_a_compiler_error(tmp_path):
    cc = _fake_compiler(tmp_path, "failcc")
    lib = tmp_path / "cache" / "x_0123.so"
    error = cache.build_library(str(cc), ["-shared"], "int x;", lib, [])
    assert error is not None and not lib.exists()
    assert list((tmp_path / "cache").iterdir()) == []          # no temporary left behind


def test_build_library_reports_an_unwritable_folder(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    error = cache.build_library("cc", [], "int x;", blocker / "cache" / "x.so", [])
    assert error is not None and str(blocker / "cache") in error


@pytest.mark.skipif(cache.find_compiler() is None, reason="no C compiler")
def test_build_library_lands_the_library(tmp_path):
    lib = tmp_path / "cache" / "answer_0123.so"
    error = cache.build_library(cache.find_compiler(), ["-O1", "-fPIC", "-shared"],
                                "int answer(void) { return 42; }\n", lib, [])
    assert error is None and lib.is_file() and os.access(lib, os.R_OK)
    import ctypes
    assert ctypes.CDLL(str(lib)).answer() == 42
    assert [p.name for p in lib.parent.iterdir()] == [lib.name]


def test_a_build_is_kept_for_its_key_its_folder_and_its_compiler(monkeypatch, tmp_path):
    monkeypatch.setenv("TRQ_CACHE_DIR", str(tmp_path / "a"))
    calls = []

    def build(tag):
        calls.append(tag)
        return object()

    first, fresh = cache.built_once(("test", 1), lambda: build(1))
    again, fresh_again = cache.built_once(("test", 1), lambda: build(1))
    assert fresh and not fresh_again and again is first and calls == [1]
    assert cache.built_once(("test", 2), lambda: build(2))[0] is not first    # another key
    monkeypatch.setenv("TRQ_CACHE_DIR", str(tmp_path / "b"))                 # another folder
    assert cache.built_once(("test", 1), lambda: build(1))[1]
    monkeypatch.setenv("TRQ_CACHE_DIR", str(tmp_path / "a"))
    monkeypatch.setenv("PATH", str(tmp_path))                                # no compiler
    monkeypatch.delenv("CC", raising=False)
    assert cache.built_once(("test", 1), lambda: build(1))[1]
    assert calls == [1, 2, 1, 1]
    cache.forget_built()
    assert cache.built_once(("test", 1), lambda: build(1))[1]


def test_the_builds_kept_are_bounded_the_oldest_dropped(monkeypatch):
    monkeypatch.setattr(cache, "BUILT_KEPT", 3)
    cache.forget_built()
    for k in range(4):
        cache.built_once(("bounded", k), object)
    assert not cache.built_once(("bounded", 3), object)[1]
    assert cache.built_once(("bounded", 0), object)[1]          # the oldest was dropped
    cache.forget_built()
