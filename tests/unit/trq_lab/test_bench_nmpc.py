"""trq-bench-nmpc's choices (trq_lab.bench.nmpc): the in-process flights' sensing profile, the
second controller over the daemons (--against) and its paired ratio, the options refused."""

from __future__ import annotations

import pytest

from trq_lab.bench import nmpc


def test_a_controller_on_the_autopilots_estimate_flies_truth():
    assert nmpc.inprocess_sensing({}, "mocap") == "truth"


def test_a_controller_asking_for_sensors_flies_the_benchs_profile():
    streams = {"HIGHRES_IMU": 125, "ATT_POS_MOCAP": 100}
    assert nmpc.inprocess_sensing(streams, "mocap") == "mocap"
    assert nmpc.inprocess_sensing(streams, "rtk") == "rtk"


@pytest.mark.slow
def test_the_fused_controller_asks_for_its_streams():
    """What inprocess_sensing is handed: the fused controller's streams, none for the
    autopilot's estimate (built controllers: the shipped files)."""
    import trq_params
    from trq_offboard.config import load_controller
    from trq_offboard.controller import Controller

    fused = Controller(load_controller(trq_params.resolve("controller", "trq_nmpc_eso_fused")))
    plain = Controller(load_controller(trq_params.resolve("controller", "trq_nmpc_eso")))
    assert nmpc.inprocess_sensing(fused.sensor_streams, "mocap") == "mocap"
    assert nmpc.inprocess_sensing(plain.sensor_streams, "mocap") == "truth"


def test_the_daemons_alternate_the_order_of_the_two_controllers():
    order = [nmpc.daemon_order("a", "b", k) for k in range(4)]
    assert order == [["a", "b"], ["b", "a"], ["a", "b"], ["b", "a"]]
    assert nmpc.daemon_order("a", None, 1) == ["a"]


def test_the_ratio_is_paired_run_by_run():
    runs = [{"controller_cpu_ms": v} for v in (2.0, 3.0, 6.0)]
    against = [{"controller_cpu_ms": v} for v in (1.0, 2.0, 4.0)]
    assert nmpc.paired_ratios(runs, against) == [2.0, 1.5, 1.5]
    with pytest.raises(ValueError, match="3 runs against 2"):
        nmpc.paired_ratios(runs, against[:2])


# a mode's row and acados' replay of it, as anchor_table reads them
MODE = {"name": "rti-exact", "prep_median_ms": 1.0, "median_ms": 1.0, "total_median_ms": 2.0,
        "total_p99_ms": 3.0, "period_cpu_median_ms": 2.5}
ANCHOR = {"name": "acados exact", "hessian": "exact", "prep_median_ms": 0.5,
          "feedback_median_ms": 0.5, "feedback_p99_ms": 0.8, "total_median_ms": 1.0,
          "total_p99_ms": 1.5, "total_cpu_median_ms": 1.0, "internal_total_median_ms": 0.9,
          "qp_iterations_median": 5, "qp_iterations_max": 9, "failures": 0, "build_s": 1.0}


def test_the_anchor_table_sets_both_daemon_controllers_against_acados():
    mode, anchor = MODE, ANCHOR
    text = nmpc.anchor_table([mode], {"rti-exact": anchor}, {"controller_cpu_ms": 1.6},
                             {"controller_cpu_ms": 1.2, "controller": "trq_nmpc_eso"},
                             controller="trq_nmpc_eso_fused")
    assert "(trq_nmpc_eso_fused) / acados exact's step p50 (target <= 1.5): 1.60" in text
    assert "(trq_nmpc_eso) / acados exact's step p50 (target <= 1.5): 1.20" in text
    assert "paired" not in text                  # without the runs' figures


def test_the_target_is_also_paired_run_by_run_against_the_replay():
    """Each run's flight over the same run's replay, beside the ratio of the medians (which
    may set one run's fast spell against another's slow one)."""
    mode, anchor = MODE, {**ANCHOR, "total_median_runs_ms": [1.0, 2.0, 0.5]}
    daemons = {"controller_cpu_ms": 1.6, "controller_cpu_runs_ms": [1.5, 2.0, 1.0]}
    assert nmpc.paired_to_anchor(daemons, anchor) == [1.5, 1.0, 2.0]
    text = nmpc.anchor_table([mode], {"rti-exact": anchor}, daemons,
                             controller="trq_nmpc_eso_fused")
    assert "(trq_nmpc_eso_fused) / acados exact's step p50 (target <= 1.5): 1.60" in text
    assert "paired run by run (the flight and the replay of one run): median 1.50; " \
           "runs 1.50, 1.00, 2.00" in text
    assert nmpc.paired_to_anchor(daemons, {**anchor, "total_median_runs_ms": [1.0]}) == []


@pytest.mark.parametrize("argv, message", [
    (["--against", "trq_nmpc_eso"], "add --daemons"),
    (["--daemons", "--against", "no_such_controller"], "no params/controller"),
    (["--daemons", "--against", "trq_nmpc_eso"], "the same file"),
])
def test_against_is_refused_where_it_cannot_compare(argv, message, capsys):
    with pytest.raises(SystemExit):
        nmpc.main(argv)
    assert message in capsys.readouterr().err


def test_the_header_names_a_controller_file_as_it_was_given():
    """A built-in by its file under params/controller, a user's file by its path (not wrapped
    into params/controller/<path>.yaml)."""
    from trq_lab.bench.nmpc import _controller_file

    assert _controller_file("trq_nmpc_eso") == "params/controller/trq_nmpc_eso.yaml"
    assert _controller_file("/tmp/ctl.yaml") == "/tmp/ctl.yaml"
    assert _controller_file("studies/fa_0.4.yaml") == "studies/fa_0.4.yaml"


def test_the_target_is_bracketed_by_acados_passes_around_each_run():
    """Each run's flight over the median of acados' passes taken right before, between and
    after its two flights; the passes' range printed, so that a machine that moved shows."""
    mode, anchor = MODE, ANCHOR
    runs = [{"controller_cpu_ms": c, "vehicle_cpu_ms": 1.0, "realtime_factor": 2.0,
             "parts": {"solve (wall)": {"mean_ms": 0.5}, "prepare": {"mean_ms": 0.5}},
             "brackets": [{"rti-exact": {"total_median_ms": t}} for t in ts]}
            for c, ts in ((1.5, (1.0, 3.0, 1.2)), (2.0, (0.8, 0.9, 1.0)))]
    daemons = nmpc._daemons_summary(runs)
    assert daemons["bracket_passes_ms"] == {"rti-exact": [[1.0, 3.0, 1.2], [0.8, 0.9, 1.0]]}
    assert nmpc.bracketed_to_anchor(daemons, "rti-exact") == [1.25, 2.0 / 0.9]
    assert nmpc.bracketed_to_anchor(daemons, "rti-gn") == []
    text = nmpc.anchor_table([mode], {"rti-exact": anchor}, daemons,
                             controller="trq_nmpc_eso_fused")
    assert "bracketed (acados stepped through rti-exact's flight right before, between and " \
           "right after each run's two flights; its step p50 0.800-3.000 ms over 6 passes): " \
           "median 1.74; runs 1.25, 2.22" in text
    unbracketed = nmpc._daemons_summary([{k: v for k, v in r.items() if k != "brackets"}
                                         for r in runs])
    assert "bracket_passes_ms" not in unbracketed
    assert "bracketed" not in nmpc.anchor_table([mode], {"rti-exact": anchor}, unbracketed)
    assert "only the bracket paces both alike" not in text          # lockstep: as before
    paced = nmpc.anchor_table([mode], {"rti-exact": anchor}, {**daemons, "pacing": "realtime"})
    assert "(the daemons paced in real time, acados' replay a tight loop: only the bracket " \
           "paces both alike)" in paced


def test_the_daemons_period_calls_its_bracket_around_the_flights(monkeypatch, tmp_path):
    """before the short flight, between the two, after the long one, with neither daemon
    flying; what the bracket returns kept in that order."""
    from trq_lab.bench import period

    events = []

    def fly(seconds, controller, log_dir, controller_cmd=None, sensing=None,
            vehicle_mode="lockstep"):
        events.append(f"fly {seconds:g} {vehicle_mode}")
        return {"controller_cpu_s": seconds * 1e-3, "vehicle_cpu_s": seconds * 2e-3,
                "wall_s": seconds / 2}

    monkeypatch.setattr(period, "fly_daemons", fly)
    monkeypatch.setattr(period, "cpu_parts", lambda *a: {})
    monkeypatch.setattr(period, "_WARM", {("trq_nmpc_eso", None)})    # flown already
    fig = period.daemons_period(5.0, 35.0, log_root=tmp_path,
                                bracket=lambda point: events.append(point) or point.upper())
    assert events == ["before", "fly 5 lockstep", "between", "fly 35 lockstep", "after"]
    assert fig["brackets"] == ["BEFORE", "BETWEEN", "AFTER"]
    assert fig["controller_cpu_ms"] == pytest.approx(30e-3 / 3000 * 1e3)
    events.clear()
    assert "brackets" not in period.daemons_period(5.0, 35.0, log_root=tmp_path,
                                                   vehicle_mode="realtime")
    assert events == ["fly 5 realtime", "fly 35 realtime"]      # both flights so paced


def test_a_flight_in_an_unknown_vehicle_mode_is_refused_before_it_starts(tmp_path):
    from trq_lab.bench import period

    with pytest.raises(ValueError, match="vehicle mode 'fast': expected lockstep or realtime"):
        period.fly_daemons(1.0, "trq_nmpc_eso", tmp_path, vehicle_mode="fast")
    assert list(tmp_path.iterdir()) == []


def test_a_controller_flies_a_warm_up_first_once_a_process(monkeypatch, tmp_path):
    """the first flight on a fresh machine builds and caches the compiled parts: a warm-up
    flight takes it, before the bracket, once per controller and sensing (a replay's command not again); its CPU is
    not in the figures."""
    from trq_lab.bench import period

    events = []

    def fly(seconds, controller, log_dir, controller_cmd=None, sensing=None,
            vehicle_mode="lockstep"):
        events.append((seconds, controller, sensing))
        cost = 100.0 if not any(e[1:] == (controller, sensing) for e in events[:-1]) else 0.0
        return {"controller_cpu_s": seconds * 1e-3 + cost, "vehicle_cpu_s": 0.0,
                "wall_s": seconds / 2}

    monkeypatch.setattr(period, "fly_daemons", fly)
    monkeypatch.setattr(period, "cpu_parts", lambda *a: {})
    monkeypatch.setattr(period, "_WARM", set())
    fig = period.daemons_period(5.0, 35.0, log_root=tmp_path, sensing="mocap",
                                bracket=lambda point: events.append(point))
    assert events == [(1.0, "trq_nmpc_eso", "mocap"), "before", (5.0, "trq_nmpc_eso", "mocap"),
                      "between", (35.0, "trq_nmpc_eso", "mocap"), "after"]
    assert fig["controller_cpu_ms"] == pytest.approx(30e-3 / 3000 * 1e3)
    events.clear()
    period.daemons_period(5.0, 35.0, log_root=tmp_path, sensing="mocap")
    period.daemons_period(5.0, 35.0, log_root=tmp_path, sensing="mocap", warm_s=0.0,
                          controller="trq_nmpc_eso_fused")
    assert [e[0] for e in events] == [5.0, 35.0, 5.0, 35.0]
    period.daemons_period(5.0, 35.0, log_root=tmp_path, controller="trq_nmpc_eso_fused")
    assert [e[0] for e in events[4:]] == [1.0, 5.0, 35.0]
    period.daemons_period(5.0, 35.0, log_root=tmp_path, controller="trq_nmpc_eso_fused",
                          controller_cmd=["python", "-m", "replay", "x.csv"])
    assert [e[0] for e in events[7:]] == [5.0, 35.0]
