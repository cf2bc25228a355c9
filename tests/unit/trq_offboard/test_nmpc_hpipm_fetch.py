"""trq-hpipm-fetch (trq_offboard/nmpc/hpipm_fetch.py): a wheel's two libraries unpacked into the
cache, bad wheels named, the check's failure reported (no network: wheels made here)."""

from __future__ import annotations

import zipfile

import pytest

from trq_offboard.nmpc import hpipm_fetch as fetch

DATA = "comma_deps_acados-0.2.2.post92.data/purelib/acados/install/lib/"


def _wheel(tmp_path, members: dict[str, bytes], name="comma_deps_acados-0.2.2.post92-py3-none-"
           "manylinux_2_28_x86_64.whl"):
    path = tmp_path / name
    with zipfile.ZipFile(path, "w") as zf:
        for member, data in members.items():
            zf.writestr(member, data)
    return path


def test_the_two_libraries_are_unpacked_into_a_folder_of_the_wheels_name(tmp_path):
    wheel = _wheel(tmp_path, {DATA + "libhpipm.so": b"hpipm", DATA + "libblasfeo.so": b"blas",
                              DATA + "libacados.so": b"not wanted",
                              "comma_deps_acados-0.2.2.post92.dist-info/METADATA": b"x"})
    path = fetch.unpack(wheel, tmp_path / "cache")
    folder = tmp_path / "cache" / wheel.name.removesuffix(".whl")
    assert path == folder / "libhpipm.so"
    assert sorted(p.name for p in folder.iterdir()) == ["libblasfeo.so", "libhpipm.so"]
    assert path.read_bytes() == b"hpipm" and (folder / "libblasfeo.so").read_bytes() == b"blas"
    assert fetch.unpack(wheel, tmp_path / "cache") == path         # again: the same, no error


def test_a_wheel_without_the_libraries_or_not_a_wheel_is_named(tmp_path):
    wheel = _wheel(tmp_path, {DATA + "libhpipm.so": b"hpipm", "other/libblasfeo.so": b"b"})
    with pytest.raises(fetch.FetchError, match=r"x86_64.whl: no libblasfeo.so under"):
        fetch.unpack(wheel, tmp_path / "cache")
    text = tmp_path / "notes.whl"
    text.write_text("not a zip")
    with pytest.raises(fetch.FetchError, match=r"notes.whl: not a wheel"):
        fetch.unpack(text, tmp_path / "cache")


def test_the_command_prints_the_path_or_why_not(tmp_path, capsys):
    wheel = _wheel(tmp_path, {DATA + "libhpipm.so": b"hpipm", DATA + "libblasfeo.so": b"blas"})
    dest = tmp_path / "cache"
    assert fetch.main(["--wheel", str(wheel), "--dest", str(dest), "--no-check"]) == 0
    out = capsys.readouterr().out.strip()
    assert out == f"export TRQ_HPIPM_LIBRARY={fetch.unpack(wheel, dest)}"
    # checked: these are not libraries, the binding cannot load them here
    assert fetch.main(["--wheel", str(wheel), "--dest", str(dest)]) == 1
    err = capsys.readouterr().err
    assert "does not load or solve here" in err and "libhpipm.so" in err
