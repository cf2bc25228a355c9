"""The replay controller of trq_lab/bench/period_floor.py (a measurement device): it hands back
the recorded commands and StepInfos step by step, its log rows are the recording's, bad input
is named; and the daemon's injection point, `main(argv, make_controller)`, defaults to the real
controller."""

from __future__ import annotations

import inspect
import math

import numpy as np
import pytest

from trq_lab.bench import period_floor as pf
from trq_offboard import daemon
from trq_offboard.log import ControllerLog
from trq_offboard.loop import FlightError, StepRecord
from trq_offboard.records import (
    ActuatorCommand,
    CommandSource,
    PeriodTimes,
    ReferenceSample,
    SolveInfo,
    SolveStatus,
    StateEstimate,
    StepInfo,
    StepTimes,
)

META = {"controller": "trq_nmpc_eso", "frames": "world NED, body FRD"}


def _records(n: int, seed: int = 5) -> list[StepRecord]:
    """Steps as a flight would log them, full-precision floats everywhere."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        f = lambda m: tuple(float(v) for v in rng.normal(size=m))    # noqa: E731
        state = StateEstimate(f(3), f(3), f(3), f(3))
        ref = ReferenceSample(f(3), f(3), float(rng.normal()), "helix")
        cmd = ActuatorCommand(tuple(float(v) for v in rng.uniform(10, 90, 4)),
                              tuple(float(v) for v in rng.uniform(-0.5, 0.5, 4)))
        applied = ActuatorCommand(f(4), f(4))
        status = SolveStatus.FAILED if k == 2 else SolveStatus.OK
        source = CommandSource.SHIFTED_PLAN if k == 2 else CommandSource.NMPC
        solve = SolveInfo(status, int(rng.integers(1, 9)), float(rng.uniform(5e-4, 3e-3)),
                          math.nan if k == 2 else float(rng.uniform(0, 10)))
        info = StepInfo(source, solve, f(6), float(rng.uniform()), 0, 0, 0,
                        tuple(float(v) for v in rng.uniform(0.4, 1.0, 4)),
                        StepTimes(*(int(v) for v in rng.integers(10_000, 2_000_000, 4))))
        cpu = PeriodTimes(int(rng.integers(1e5, 1e6)), int(rng.integers(1e4, 1e5)),
                          int(rng.integers(1e4, 1e5)), int(rng.integers(1e6, 5e6)))
        stamp = 1_000_000 + 10_000 * k
        out.append(StepRecord((stamp - 1_000_000) * 1e-6, stamp, state, ref, cmd, applied,
                              info, cpu))
    return out


def _write(path, records, meta=META) -> None:
    log = ControllerLog(path, meta)
    for r in records:
        log(r)
    log.close()


def test_replays_the_recorded_commands_and_step_infos(tmp_path):
    recs = _records(6)
    _write(tmp_path / "controller.csv", recs)
    replay = pf.ReplayController.from_csv(tmp_path / "controller.csv")
    assert len(replay) == 6 and replay.controller == "trq_nmpc_eso"
    replay.reset(0.0, recs[0].state)
    for r in recs:
        cmd, info = replay.step(r.t_s, r.state, r.applied, None)
        assert cmd == r.cmd                          # exactly: the log carries full precision
        assert (info.source, info.solve.status) == (r.info.source, r.info.solve.status)
        assert info.solve.iterations == r.info.solve.iterations
        assert info.solve.solve_time_s * 1e3 == r.info.solve.solve_time_s * 1e3
        assert info.disturbance == r.info.disturbance
        assert info.effectiveness == r.info.effectiveness
        assert info.output_error == r.info.output_error
        assert info.cpu == r.info.cpu
        replay.prepare(None)
        assert replay.last_prepare_cpu_ns == r.cpu.prepare_ns
    # reset starts the recording over
    replay.reset(0.0, recs[0].state)
    assert replay.step(recs[0].t_s, recs[0].state, None, None)[0] == recs[0].cmd


def test_the_replays_log_is_the_recording_but_the_loops_own_columns(tmp_path):
    recs = _records(5)
    _write(tmp_path / "rec.csv", recs)
    replay = pf.ReplayController.from_csv(tmp_path / "rec.csv")
    replay.reset(0.0, recs[0].state)
    again = []
    for r in recs:
        cmd, info = replay.step(r.t_s, r.state, r.applied, None)
        replay.prepare(None)
        cpu = PeriodTimes(replay.last_prepare_cpu_ns, 1, 2, 3)    # the loop's own: others
        again.append(StepRecord(r.t_s, r.stamp_us, r.state, r.ref, cmd, r.applied, info, cpu))
    _write(tmp_path / "replayed.csv", again)
    ok, why = pf.replayed_steps(tmp_path / "rec.csv", tmp_path / "replayed.csv")
    assert ok, why
    a = (tmp_path / "rec.csv").read_text().splitlines()
    b = (tmp_path / "replayed.csv").read_text().splitlines()
    cols = a[2].split(",")
    assert b[2] == a[2]
    loop = [cols.index(c) for c in pf.LOOP_COLUMNS]
    for ra, rb in zip(a[3:], b[3:]):
        xa, xb = ra.split(","), rb.split(",")
        assert [v for i, v in enumerate(xa) if i not in loop] == \
            [v for i, v in enumerate(xb) if i not in loop]
        assert [xb[i] for i in loop] == [repr(v * 1e-6) for v in (1, 2, 3)]


def test_the_check_sees_a_changed_command(tmp_path):
    recs = _records(4)
    _write(tmp_path / "rec.csv", recs)
    changed = list(recs)
    r = recs[2]
    changed[2] = StepRecord(r.t_s, r.stamp_us, r.state, r.ref,
                            ActuatorCommand(r.cmd.throttle_pct, (0.0,) * 4), r.applied, r.info,
                            r.cpu)
    _write(tmp_path / "other.csv", changed)
    ok, why = pf.replayed_steps(tmp_path / "rec.csv", tmp_path / "other.csv")
    assert not ok and "cmd_tilt1_rad differs at row 3" in why


def test_a_step_beyond_the_recording_or_at_another_time_is_named(tmp_path):
    recs = _records(3)
    _write(tmp_path / "controller.csv", recs)
    replay = pf.ReplayController.from_csv(tmp_path / "controller.csv")
    replay.reset(0.0, recs[0].state)
    with pytest.raises(pf.ReplayDiverged, match=r"step 1 at t = 0\.005 s, the recording's"):
        replay.step(0.005, recs[0].state, None, None)
    for r in recs:
        replay.step(r.t_s, r.state, None, None)
    with pytest.raises(pf.ReplayDiverged,
                       match=r"controller\.csv: step 4 at t = 0\.03 s is beyond the "
                             r"recording's 3 steps"):
        replay.step(0.03, recs[0].state, None, None)
    # the daemon prints a FlightError as its one-line reason and exits 1
    assert issubclass(pf.ReplayDiverged, FlightError)


def test_a_missing_file_is_named(tmp_path):
    with pytest.raises(pf.RecordingError, match=r"nope\.csv: no such file"):
        pf.ReplayController.from_csv(tmp_path / "nope.csv")


@pytest.mark.parametrize("column", ["cmd_tilt3_rad", "t_s"])
def test_a_log_without_a_command_column_is_named(tmp_path, column):
    _write(tmp_path / "controller.csv", _records(2))
    lines = (tmp_path / "controller.csv").read_text().splitlines()
    names = lines[2].split(",")
    drop = names.index(column)
    cut = lines[:2] + [",".join(v for i, v in enumerate(ln.split(",")) if i != drop)
                       for ln in lines[2:]]
    (tmp_path / "cut.csv").write_text("\n".join(cut) + "\n")
    with pytest.raises(pf.RecordingError, match=rf"cut\.csv: no column {column}\b"):
        pf.ReplayController.from_csv(tmp_path / "cut.csv")


def test_a_bad_value_is_named_with_its_column_and_row(tmp_path):
    _write(tmp_path / "controller.csv", _records(3))
    text = (tmp_path / "controller.csv").read_text().replace(",ok,nmpc,", ",fine,nmpc,", 1)
    (tmp_path / "bad.csv").write_text(text)
    with pytest.raises(pf.RecordingError, match=r"bad\.csv: column status, row 1: 'fine'"):
        pf.ReplayController.from_csv(tmp_path / "bad.csv")
    lines = (tmp_path / "controller.csv").read_text().splitlines()
    col = lines[2].split(",").index("cmd_throttle2_pct")
    row = lines[4].split(",")
    row[col] = "nan"
    lines[4] = ",".join(row)
    (tmp_path / "nan.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(pf.RecordingError, match=r"column cmd_throttle2_pct, row 2: nan"):
        pf.ReplayController.from_csv(tmp_path / "nan.csv")


def test_the_replay_daemon_names_a_bad_recording(tmp_path, capsys):
    assert pf.main(["--replay", str(tmp_path / "none.csv"), "--no-log"]) == 2
    assert "none.csv: no such file" in capsys.readouterr().err
    _write(tmp_path / "controller.csv", _records(2))
    # recorded with trq_nmpc_eso, replayed with another controller file: refused before the
    # link opens
    assert pf.main(["--replay", str(tmp_path / "controller.csv"), "--controller", "trq_nmpc",
                    "--no-log"]) == 2
    err = capsys.readouterr().err
    assert "recorded with controller trq_nmpc_eso, replayed with trq_nmpc" in err


def test_the_replay_command_runs_this_module():
    cmd = pf.replay_command("x.csv", python="py")
    assert cmd == ["py", "-m", "trq_lab.bench.period_floor", "--replay", "x.csv"]


class _Built(Exception):
    """What the fake controllers raise: the daemon got this far, with this configuration."""


def test_the_injection_points_default_is_the_real_controller(monkeypatch, free_port):
    assert inspect.signature(daemon.main).parameters["make_controller"].default is None
    import trq_offboard.controller as controller_mod

    def fake_controller(cfg):
        raise _Built(cfg)
    monkeypatch.setattr(controller_mod, "Controller", fake_controller)
    with pytest.raises(_Built) as built:
        daemon.main(["--no-log", "--connect", f"udpin:127.0.0.1:{free_port()}"])
    assert built.value.args[0].name == "trq_nmpc_eso"


def test_the_injection_point_builds_the_given_controller(monkeypatch, free_port, capsys):
    import trq_offboard.controller as controller_mod

    def real_controller(cfg):
        raise AssertionError("the real controller was built")
    monkeypatch.setattr(controller_mod, "Controller", real_controller)
    seen = []

    def make(cfg):
        seen.append(cfg.name)
        return pf.ReplayController([], [], [], source="nothing")
    # no vehicle: the flight fails on its heartbeat timeout, after the controller was built
    rc = daemon.main(["--no-log", "--controller", "trq_nmpc", "--connect-timeout", "0.2",
                      "--connect", f"udpin:127.0.0.1:{free_port()}"], make_controller=make)
    assert rc == 1 and seen == ["trq_nmpc"]
    assert "no vehicle heartbeat" in capsys.readouterr().err


def _run(real_ms: float, floor_ms: float) -> dict:
    parts = {p: {"mean_ms": 0.1} for p in ("observer", "feedback", "prepare", "wire", "log",
                                             "period", "solve (wall)")}
    fig = lambda ms: {"controller_cpu_ms": ms, "vehicle_cpu_ms": 0.5,   # noqa: E731
                      "realtime_factor": 3.0, "parts": parts}
    return {"real": fig(real_ms), "floor": fig(floor_ms)}


def test_the_summary_puts_the_floor_against_acados_step():
    runs = [_run(3.0, 0.4), _run(2.0, 0.6), _run(2.5, 0.5)]
    s = pf.summary(runs, 1.0, [1.0, 1.0, 1.0])
    assert s["floor"]["controller_cpu_ms"] == 0.5 and s["real"]["controller_cpu_ms"] == 2.5
    assert set(s["floor"]["parts"]) == {"wire", "log", "period"}   # the replay's own only
    assert s["our_solver_ms"] == pytest.approx(0.2)          # solve (wall) + prepare
    assert s["best_with_acados"] == pytest.approx(1.5)
    assert s["best_with_ours"] == pytest.approx(0.7)
    assert s["floor_over_acados_runs"] == [0.4, 0.6, 0.5]
    text = pf.table(s, "measured")
    assert "1.50x acados' step (target <= 1.5x: reachable)" in text
    s = pf.summary([_run(3.0, 0.6)], 1.0)
    assert "1.60x acados' step (target <= 1.5x: out of reach)" in pf.table(s, "given")
    s = pf.summary([_run(3.0, 0.6)], None)
    s["calibration_ms"] = 4.0
    text = pf.table(s, "-")
    assert "needs acados' step to be at least 1.200 ms" in text
    assert "the floor / the calibration at the end (4.00 ms): 0.150" in text


@pytest.mark.parametrize("controller", ["trq_nmpc_eso_fused", "trq_nmpc_eso"])
def test_the_replay_asks_for_the_recorded_controllers_sensor_streams(
        tmp_path, monkeypatch, controller):
    # a recording of the fused filter asked the vehicle for raw sensors, which change what the
    # vehicle sends and when the flight starts: the replay asks for the same
    from trq_offboard.config import load_controller
    from trq_offboard.controller import sensor_streams_of

    _write(tmp_path / "controller.csv", _records(3), meta={**META, "controller": controller})
    cfg = load_controller(daemon.resolve_controller(controller))
    built = []
    monkeypatch.setattr(daemon, "main", lambda argv, make_controller: built.append(
        make_controller(cfg)) or 0)
    assert pf.replay_daemon(str(tmp_path / "controller.csv"), []) == 0
    replay = built[0]
    assert replay.sensor_streams == sensor_streams_of(cfg)
    assert bool(replay.sensor_streams) == ("HIGHRES_IMU" in replay.sensor_streams) \
        == (controller == "trq_nmpc_eso_fused")
    # the loop hands such a controller the sensors received: taken and dropped
    r = _records(3)[0]
    replay.reset(0.0, r.state)
    assert replay.step(r.t_s, r.state, None, None, object())[0] == r.cmd


def _with_column(src, dst, name, values) -> None:
    lines = src.read_text().splitlines()
    head = next(i for i, ln in enumerate(lines) if not ln.startswith("#"))
    j = lines[head].split(",").index(name)
    for k, v in enumerate(values):
        row = lines[head + 1 + k].split(",")
        row[j] = v
        lines[head + 1 + k] = ",".join(row)
    dst.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("own_filter", [True, False])
def test_a_recording_with_its_own_filter_is_checked_without_what_it_logs_of_it(
        tmp_path, own_filter):
    # the fused filter's recording logs the filter's position; its replay (no filter) logs the
    # autopilot's: the check leaves those columns out only when the recording had a filter
    recs = _records(3)
    _write(tmp_path / "base.csv", recs)
    ratio = ["0.5", "0.7", "0.2"] if own_filter else ["nan"] * 3
    _with_column(tmp_path / "base.csv", tmp_path / "rec.csv", "est_test_ratio", ratio)
    _with_column(tmp_path / "rec.csv", tmp_path / "moved.csv", "pos_n_m", ["1.5", "2.5", "3.5"])
    _with_column(tmp_path / "moved.csv", tmp_path / "replayed.csv", "est_test_ratio",
                 ["nan"] * 3)
    ok, why = pf.replayed_steps(tmp_path / "rec.csv", tmp_path / "replayed.csv")
    assert ok is own_filter, why
    if not own_filter:
        assert "pos_n_m differs at row 1" in why
    # a command still counts with a filter
    _with_column(tmp_path / "rec.csv", tmp_path / "cmd.csv", "cmd_tilt2_rad", ["0.25"] * 3)
    ok, why = pf.replayed_steps(tmp_path / "rec.csv", tmp_path / "cmd.csv")
    assert not ok and "cmd_tilt2_rad differs at row 1" in why


def test_a_runs_acados_step_is_the_median_of_its_passes_around_its_flights():
    """The bracket: acados' passes before, between and after the real controller's flights
    and the replay's; the run's step is their median."""
    run = {"real": {"brackets": [{"total_median_ms": v} for v in (0.7, 0.9, 0.8)]},
           "floor": {"brackets": [{"total_median_ms": v} for v in (1.4, 0.75, 0.85)]}}
    a = pf.bracket_step(run)
    assert a["passes_ms"] == [0.7, 0.9, 0.8, 1.4, 0.75, 0.85]
    assert a["total_median_ms"] == pytest.approx(0.825)


def test_the_anchor_brackets_every_pair_of_flights_with_one_server(monkeypatch, capsys):
    """--anchor acados: one server for the whole bench, three passes around the real
    controller's flights and three around the replay's in each run, the run's step their
    median; the ratios in the table are within each run."""
    from trq_lab.bench import acados_anchor, nmpc

    passes = iter([0.8, 0.8, 0.8, 1.2, 1.2, 1.2,      # run 1: the machine moved in between
                   0.5, 0.5, 0.5, 0.5, 0.5, 0.5])
    served = []

    class Server:
        def one_pass(self, pace_ms=0.0):
            assert pace_ms == 0.0             # the floor bench's bracket: a tight loop
            served.append(1)
            return {"total_median_ms": next(passes), "total_cpu_median_ms": 0.0,
                    "failures": 0, "steps": 1, "pass": len(served)}

    def floor_run(short_s, long_s, controller, work, bracket=None):
        run = _run(2.0, 0.5)
        for who in ("real", "floor"):
            run[who]["brackets"] = [bracket(p) for p in ("before", "between", "after")]
        run["checks"] = {f: {"controller_rc": 0, "same_flight": True, "flight": "ok",
                             "same_steps": True, "steps": "ok"} for f in ("short", "long")}
        return run

    monkeypatch.setattr(acados_anchor, "available", lambda: (True, "fake"))
    monkeypatch.setattr(pf, "acados_server", lambda stack, controller: Server())
    monkeypatch.setattr(pf, "floor_run", floor_run)
    monkeypatch.setattr(nmpc, "machine_line", lambda: "machine")
    monkeypatch.setattr(nmpc, "calibration_ms", lambda repeats=5: 1.0)
    assert pf.main(["--anchor", "acados", "--repeat", "2"]) == 0
    out = capsys.readouterr().out
    assert len(served) == 12
    assert "run 1: acados exact prep+feedback p50 1.000 ms (the median of its passes around " \
           "the run's flights: 0.800 0.800 0.800 1.200 1.200 1.200)" in out
    assert "the floor / acados' step: 0.67 (within each run: 0.50 1.00, median 0.75)" in out
