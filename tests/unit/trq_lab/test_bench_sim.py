"""trq-bench-sim's arithmetic (trq_lab.bench.sim): the daemon's CPU without start-up."""

from __future__ import annotations

import pytest

from trq_lab.bench.sim import steady_cpu_per_s


def test_start_up_is_taken_off():
    # 0.5 s of start-up and 0.06 s per simulated second: 20 s -> 1.7 s, 2 s -> 0.62 s
    startup, per_s = 0.5, 0.06
    got = steady_cpu_per_s((startup + 20 * per_s) / 20, 20.0, (startup + 2 * per_s) / 2, 2.0)
    assert got == pytest.approx(per_s, rel=1e-12)


def test_the_long_run_must_be_longer():
    with pytest.raises(ValueError, match="longer"):
        steady_cpu_per_s(0.1, 2.0, 0.2, 2.0)


@pytest.mark.slow
def test_the_sitl_bench_flies_under_a_sensing_profile():
    """(2) under mocap measures a flying vehicle (its estimator aligns in the air; the estimate
    loss failsafe leaves a vehicle armed before it had a position alone), not a crash."""
    from trq_lab.bench.sim import bench_sitl
    steps_per_s, msgs_per_s = bench_sitl(20000, "auto", runs=1, sensing="mocap")
    assert steps_per_s > 0 and msgs_per_s > 0
