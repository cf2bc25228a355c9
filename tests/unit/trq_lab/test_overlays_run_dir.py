"""Where a scenario writes each controller's flight: a built-in name as it is, a controller file
given by path as its stem, always inside the output folder."""

from pathlib import Path

from trq_lab.overlays import run_dir


def test_a_builtin_controller_flies_into_its_name(tmp_path: Path) -> None:
    assert run_dir(tmp_path, "trq_nmpc_eso") == tmp_path / "trq_nmpc_eso"


def test_a_controller_file_flies_into_its_stem_inside_the_output(tmp_path: Path) -> None:
    elsewhere = tmp_path / "mine" / "ctl_slow_observer.yaml"
    got = run_dir(tmp_path / "out", str(elsewhere))
    assert got == tmp_path / "out" / "ctl_slow_observer"
    assert got.parent == tmp_path / "out"
