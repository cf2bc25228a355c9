"""trq-bench-instructions: callgrind's output read per object, the period's count as the
difference of two flights, the groups, and its errors (tests/integration does not run valgrind:
the flights take minutes)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from trq_lab.bench import instructions as ins

# a callgrind output as valgrind 3.19 writes it: compressed names, a call whose inclusive cost
# (the line after calls=) is the callee's and must not count twice, relative positions
CALLGRIND = """\
# callgrind format
version: 1
creator: callgrind-3.19.0
pid: 4242
cmd:  python -m trq_offboard
part: 1

desc: I1 cache:
desc: Timerange: Basic block 0 - 1000
positions: line
events: Ir
summary: {total}

ob=(1) /usr/lib/libpython3.11.so.1.0
fl=(1) ???
fn=(1) _PyEval_EvalFrameDefault
0 {py1}
cob=(2) /home/u/.venv/lib/python3.11/site-packages/numpy/_core/_multiarray_umath.so
cfi=(2) ???
cfn=(2) array_dot
calls=3 0
0 {np}
+2 {py2}

ob=(2)
fl=(2)
fn=(2)
0 {np}

ob=(3) /root/.cache/trq-ftc/hpipm/wheel/libblasfeo.so
fl=(3) ???
fn=(3) kernel_dgemm_nt_4x4_lib4
* {qp}

ob=(4) /root/.cache/trq-ftc/observer_period_51_0914.so
fl=(4) ???
fn=(4) observer_period
0 {kern}

totals: {total}
"""


def write(path: Path, py1=100, py2=20, np=300, qp=5000, kern=40, total=None) -> Path:
    total = py1 + py2 + np + qp + kern if total is None else total
    path.write_text(CALLGRIND.format(py1=py1, py2=py2, np=np, qp=qp, kern=kern, total=total))
    return path


def test_self_cost_per_object_names_expanded_and_calls_not_counted_twice(tmp_path):
    costs, total = ins.callgrind_costs(write(tmp_path / "callgrind.out.1"))
    cost = ins.by_object(costs)
    assert total == 5460
    assert cost["/usr/lib/libpython3.11.so.1.0"] == 120          # not the call's 300
    assert cost["/home/u/.venv/lib/python3.11/site-packages/numpy/_core/"
                "_multiarray_umath.so"] == 300
    assert cost["/root/.cache/trq-ftc/hpipm/wheel/libblasfeo.so"] == 5000
    assert sum(cost.values()) == total


def test_self_cost_per_function_keyed_by_its_object(tmp_path):
    costs, total = ins.callgrind_costs(write(tmp_path / "callgrind.out.1"))
    cost = ins.by_function(costs)
    assert cost == {"libpython3.11.so.1.0: _PyEval_EvalFrameDefault": 120,
                    "_multiarray_umath.so: array_dot": 300,
                    "libblasfeo.so: kernel_dgemm_nt_4x4_lib4": 5000,
                    "observer_period_51_0914.so: observer_period": 40}
    assert sum(cost.values()) == total


def test_a_file_whose_costs_miss_its_total_is_refused_by_name(tmp_path):
    path = write(tmp_path / "callgrind.out.2", total=9999)
    with pytest.raises(ValueError, match=re.escape(str(path)) + ".*9999"):
        ins.callgrind_costs(path)


@pytest.mark.parametrize("obj, group", [
    ("/root/.pyenv/versions/3.11.7/lib/libpython3.11.so.1.0", "interpreter (libpython)"),
    ("/x/site-packages/casadi/libblasfeo.so.0", "QP solver (HPIPM, BLASFEO)"),
    ("/root/.cache/trq-ftc/hpipm/comma/libhpipm.so", "QP solver (HPIPM, BLASFEO)"),
    ("/x/site-packages/numpy/_core/_multiarray_umath.cpython-311-x86_64-linux-gnu.so", "NumPy"),
    ("/x/site-packages/numpy.libs/libscipy_openblas64_-32a4b2a6.so", "NumPy"),
    ("/x/site-packages/casadi/libcasadi.so.3.7", "CasADi's library"),
    ("/w/acados/lib/libacados.so", "acados"),
    ("/usr/lib/x86_64-linux-gnu/libffi.so.8.1.2",
     "C called through ctypes (our C cores; counted under libffi)"),
    ("/r/lib/python3.11/lib-dynload/_ctypes.cpython-311-x86_64-linux-gnu.so",
     "interpreter's extension modules"),
    ("/r/lib/python3.11/lib-dynload/_struct.cpython-311-x86_64-linux-gnu.so",
     "interpreter's extension modules"),
    ("/usr/lib/x86_64-linux-gnu/libc.so.6", "C and C++ runtime"),
    ("/usr/lib/x86_64-linux-gnu/libm.so.6", "C and C++ runtime"),
    ("/root/.cache/trq-ftc/rti_lin_trq_20f41eb45f32e8c5b872.so",
     "compiled kernels (the cache: CasADi-generated, our C cores)"),
    ("???", ins.OTHER),
])
def test_objects_are_grouped_by_what_they_are(obj, group):
    assert ins.group_of(obj) == group


def test_the_period_is_the_difference_of_the_two_flights_over_their_periods(monkeypatch,
                                                                            tmp_path):
    """the controller runs under callgrind (its output file where fly_daemons' command says),
    with PYTHONHASHSEED fixed and the long start-up allowed; the short flight's count is
    subtracted object by object."""
    from trq_lab.bench import period

    seen = []

    def fly(seconds, controller, log_dir, controller_cmd=None, sensing=None,
            listen_timeout_s=60.0, controller_env=None):
        seen.append((seconds, controller_cmd, sensing, listen_timeout_s, controller_env))
        assert Path(controller_cmd[0]).name == "valgrind" and "--tool=callgrind" in controller_cmd
        out = next(a for a in controller_cmd if a.startswith("--callgrind-out-file="))
        path = Path(out.split("=", 1)[1].replace("%p", "77"))
        # start-up (1000 of libpython) plus, per second of flight, one period's worth x100
        write(path, py1=1000 + int(seconds * 100 * 10), py2=0, np=int(seconds * 100 * 3),
              qp=int(seconds * 100 * 50), kern=7)
        return {"controller_rc": 0}

    monkeypatch.setattr(ins, "valgrind", lambda: "/usr/bin/valgrind")
    monkeypatch.setattr(period, "fly_daemons", fly)
    fig = ins.period_count("trq_nmpc_eso", 2.0, 6.0, tmp_path, sensing="mocap")
    assert [s[0] for s in seen] == [2.0, 6.0]
    assert all(s[2] == "mocap" and s[3] == ins.LISTEN_TIMEOUT_S
               and s[4] == {"PYTHONHASHSEED": "0", "OPENBLAS_NUM_THREADS": "1"} for s in seen)
    assert seen[0][1][-3:] == [ins.sys.executable, "-m", "trq_offboard"]
    assert fig["periods"] == 400
    assert fig["total"] == pytest.approx(63.0)
    assert fig["groups"]["interpreter (libpython)"] == pytest.approx(10.0)
    assert fig["groups"]["NumPy"] == pytest.approx(3.0)
    assert fig["groups"]["QP solver (HPIPM, BLASFEO)"] == pytest.approx(50.0)
    assert fig["groups"]["compiled kernels (the cache: CasADi-generated, our C cores)"] == 0.0


def test_the_table_lists_each_group_per_process_in_thousands_largest_first():
    rows = {"ctl": {"groups": {"NumPy": 503_400.0, "QP solver (HPIPM, BLASFEO)": 2_417_000.0},
                    "total": 4_847_076.0},
            "floor": {"groups": {"NumPy": 91_000.0}, "total": 700_000.0}}
    lines = ins.table(rows).splitlines()
    assert lines[0] == "| thousand instructions a period | ctl | floor |"
    assert lines[2] == "| QP solver (HPIPM, BLASFEO) | 2417 | 0 |"
    assert lines[3] == "| NumPy | 503 | 91 |"
    assert lines[4] == "| **all** | **4847** | **700** |"


def test_without_valgrind_it_says_so_and_flies_nothing(monkeypatch, capsys):
    monkeypatch.setattr(ins.shutil, "which", lambda name: None)
    monkeypatch.setattr(ins, "period_count", lambda *a, **k: pytest.fail("flew"))
    assert ins.main([]) == 2
    assert "valgrind not found" in capsys.readouterr().err


def test_flights_of_the_wrong_lengths_are_refused(capsys):
    with pytest.raises(SystemExit):
        ins.main(["--short-s", "6", "--long-s", "2"])
    assert "--short-s 6 and --long-s 2" in capsys.readouterr().err


SIMULATED = """events: Ir I1mr ILmr DLmr DLmw
ob=(1) /usr/lib/libpython3.11.so.1.0
fl=(1) ???
fn=(1) _PyEval_EvalFrameDefault
0 {ir} {i1} {il} {dr} {dw}
totals: {ir} {i1} {il} {dr} {dw}
"""


def test_the_totals_per_event_come_with_the_costs(tmp_path):
    assert ins.callgrind_file(write(tmp_path / "a.out", total=5460))[1] == {"Ir": 5460}
    path = tmp_path / "b.out"
    path.write_text(SIMULATED.format(ir=100, i1=7, il=3, dr=2, dw=1))
    costs, totals = ins.callgrind_file(path)
    assert totals == {"Ir": 100, "I1mr": 7, "ILmr": 3, "DLmr": 2, "DLmw": 1}
    assert sum(costs.values()) == 100                   # the costs are the first event's, Ir
    assert ins.callgrind_costs(path)[1] == 100
    path.write_text("fn=(1) f\n0 3\n")                 # no totals line: the costs' sum
    assert ins.callgrind_file(path)[1] == {"Ir": 3}


def test_with_the_cache_simulated_the_misses_are_per_period_too(monkeypatch, tmp_path):
    """--cache: callgrind runs with CACHE_SIM's options and each event's total is taken per
    period as the instructions are; the table prints them in thousands."""
    from trq_lab.bench import period

    def fly(seconds, controller, log_dir, controller_cmd=None, sensing=None,
            listen_timeout_s=60.0, controller_env=None):
        assert all(opt in controller_cmd for opt in ins.CACHE_SIM)
        out = next(a for a in controller_cmd if a.startswith("--callgrind-out-file="))
        path = Path(out.split("=", 1)[1].replace("%p", "77"))
        n = int(seconds * 100)                    # periods flown, each 2 M Ir, 30 k I1 misses
        path.write_text(SIMULATED.format(ir=500 + 2_000_000 * n, i1=50 + 30_000 * n,
                                         il=4000 * n, dr=1000 * n, dw=2000 * n))
        return {"controller_rc": 0}

    monkeypatch.setattr(ins, "valgrind", lambda: "/usr/bin/valgrind")
    monkeypatch.setattr(period, "fly_daemons", fly)
    fig = ins.period_count("trq_nmpc_eso", 2.0, 6.0, tmp_path, cache=True)
    assert fig["cache"] == {"Ir": 2e6, "I1mr": 3e4, "ILmr": 4e3, "DLmr": 1e3, "DLmw": 2e3}
    text = ins.cache_table({"ours": fig})
    assert text.splitlines()[0].startswith("| thousands a period (a step for acados) | "
                                           "instructions | L1 instruction misses |")
    assert text.splitlines()[2] == "| ours | 2000.0 | 30.0 | 4.0 | 1.0 | 2.0 |"
