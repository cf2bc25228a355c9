"""trq-bench-cpu-budget's pieces that need no cgroup: the controller's CPU per period read from its
log, the table, the scenario's command, and trq-scenario's `--controller-args` reaching the
controller's command line (checked there by trq-offboard's own parser)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import PARAMS

from trq_lab import scenario
from trq_lab.bench import cpu_budget

HEADER = "# controller: trq_nmpc_eso\nt_s,stamp_us,solve_ms,cpu_period_ms\n"


def test_period_cpu_from_the_log(tmp_path):
    csv = tmp_path / "controller.csv"
    # 100 periods of 1..100 ms, and one row without the column's value (nan): left out
    csv.write_text(HEADER + "".join(f"{k / 100},{k * 10000},0.5,{k}\n" for k in range(1, 101))
                   + "1.01,1010000,0.5,nan\n")
    p50, p99 = cpu_budget.period_cpu_ms(csv)
    assert p50 == pytest.approx(50.5) and p99 == pytest.approx(99.01)
    assert cpu_budget.period_cpu_ms(tmp_path / "missing.csv") == (None, None)
    (tmp_path / "old.csv").write_text("# controller: x\nt_s,stamp_us,solve_ms\n0.0,0,0.5\n")
    assert cpu_budget.period_cpu_ms(tmp_path / "old.csv") == (None, None)


def test_the_table_shows_the_period_and_the_ratio_to_the_whole_core():
    rows = [cpu_budget.Row(1.0, 0, True, False, 0.004, 0.5, 1.2, 2.5, 3.25, 6.5),
            cpu_budget.Row(0.5, 0, True, False, 0.006, 0.6, 1.3, 3.5, 3.5, 9.0, 100, 40, 1.5),
            cpu_budget.Row(0.25, 1, False, True, None, 60.0, 9.0, 50.0)]
    lines = cpu_budget.table(rows).splitlines()
    assert "CPU a period p50 / p99 ms" in lines[0]
    assert "| 3.25 / 6.50 |" in lines[2] and "| 1.0 |" in lines[2]
    assert "| 1.5 |" in lines[3] and "| 40 of 100 | 1.50 |" in lines[3]
    assert "| - / - |" in lines[4] and "| no | True |" in lines[4]


def test_the_flight_is_the_scenario_command_pinned(tmp_path, monkeypatch):
    seen = []

    def run(cmd, **kwargs):
        seen.append(cmd)
        out = Path(cmd[cmd.index("--out") + 1])
        (out / "trq_nmpc_eso").mkdir(parents=True)
        (out / "trq_nmpc_eso" / "controller.csv").write_text(HEADER + "0.0,0,1.0,2.0\n")
        (out / "metrics.json").write_text(json.dumps({"runs": [
            {"controller": "trq_nmpc_eso", "crashed": False, "rmse_pos_after_fault_m": 0.003,
             "max_yaw_err_deg": 0.4, "solve_ms_p50": 1.0, "solve_ms_p99": 2.0}]}))

        class Done:
            returncode = 0
        return Done()

    monkeypatch.setattr(cpu_budget.subprocess, "run", run)
    row = cpu_budget.fly("paper_fault50", "trq_nmpc_eso", 1.0, 4000, tmp_path / "f", "x")
    (cmd,) = seen
    assert not any(c.startswith("--controller-args") for c in cmd)
    assert cmd[cmd.index("--controller-prefix") + 1] == "taskset -c 1"     # whole core: no quota
    assert row.targets_met and row.rmse_pos_after_fault_m == 0.003
    assert (row.cpu_period_ms_p50, row.cpu_period_ms_p99) == (2.0, 2.0)


def test_scenario_controller_args_reach_the_controller_only(tmp_path, monkeypatch):
    sc = scenario.load_scenario(PARAMS / "scenarios" / "smoke.yaml")
    run = scenario.Run("trq_nmpc_eso", 0, tmp_path, "trq_nmpc_eso")

    class Started(Exception):
        pass

    def popen(*args, **kwargs):
        raise Started

    monkeypatch.setattr(scenario.subprocess, "Popen", popen)
    with pytest.raises(Started):
        scenario._fly(sc, run, False, Path("c.yaml"), Path("s.yaml"), Path("v.yaml"), [],
                      "udpin:127.0.0.1:14540", 14560, None, (), (), ("--connect-timeout", "60", "-v"))
    vcmd, ccmd = (tmp_path / "command.txt").read_text().splitlines()
    assert ccmd.endswith(" --connect-timeout 60 -v") and "--connect-timeout" not in vcmd


def test_scenario_refuses_controller_args_the_controller_does_not_take(tmp_path, capsys):
    rc = scenario.main(["smoke", "--out", str(tmp_path / "out"),
                        "--controller-args=-v --bogus 3"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "--bogus" in err and "not options of trq-offboard" in err
    assert not (tmp_path / "out").exists()               # nothing flown, nothing written


@pytest.mark.parametrize("extra, named", [("--connect udpin:0.0.0.0:1", "--connect"),
                                          ("--log-d /tmp/x", "--log-dir"),   # abbreviated
                                          ("-v --no-log", "--no-log"),
                                          ("--applied-delay-s 0.1", "--applied-delay-s")])
def test_scenario_refuses_controller_args_it_sets_itself(tmp_path, capsys, extra, named):
    rc = scenario.main(["smoke", "--out", str(tmp_path / "out"), f"--controller-args={extra}"])
    assert rc == 2
    err = capsys.readouterr().err
    assert named in err and "sets itself" in err
    assert not (tmp_path / "out").exists()


def test_a_share_under_the_minimum_quota_is_refused_before_any_flight(monkeypatch, capsys):
    flown = []
    monkeypatch.setattr(cpu_budget, "fly", lambda *a, **k: flown.append(a))
    with pytest.raises(SystemExit) as exc:
        cpu_budget.main(["--shares", "1,1/3,1/5", "--period-us", "4000"])
    assert exc.value.code == 2 and not flown
    err = capsys.readouterr().err
    assert "--shares: 0.2 of --period-us 4000 is 800 us" in err and "at least 5000" in err
