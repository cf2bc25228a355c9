"""trq-bench-fused (trq_lab/bench/fused.py): what it feeds the filters and what it prints; its
figures are the machine's, so only their presence and shape are checked here."""

from __future__ import annotations

import json

import pytest

from trq_lab.bench import fused as bench
from trq_offboard.config import load_controller
from trq_offboard.fused import FusedFilter
from trq_offboard.nmpc import cache
from trq_params import resolve

needs_compiler = pytest.mark.skipif(cache.find_compiler() is None, reason="no C compiler")


def test_the_feed_drives_a_filter_through_a_hover_on_every_pose():
    cfg = load_controller(resolve("controller", "trq_nmpc_eso_fused")).fused
    f = FusedFilter(cfg, bench.G, codegen=False)
    assert bench.feed(f, 40, cfg) > 0.0
    # one pose a period, none rejected; the estimate where the poses are
    assert f.t_us == 400_000 and f.rejected == 0 and f.dropped == 0
    assert abs(f.x[2] + 1.0) < 0.01


@needs_compiler
def test_the_bench_prints_both_paths_and_their_paired_ratio(tmp_path, capsys):
    out = tmp_path / "fused.json"
    assert bench.main(["--repeat", "2", "--steps", "20", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "core " in text and "reference " in text and "paired repeat by repeat" in text
    figures = json.loads(out.read_text())
    assert set(figures["us_per_period"]) == {"core", "reference"}
    assert all(len(v) == 2 and min(v) > 0.0 for v in figures["us_per_period"].values())


def test_a_controller_without_the_fused_filter_is_refused_by_name(capsys):
    with pytest.raises(SystemExit):
        bench.main(["--controller", "trq_nmpc_eso"])
    assert "--controller trq_nmpc_eso: its estimator is not the fused filter" in \
        capsys.readouterr().err
