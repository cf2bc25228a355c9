"""trq_lab.bench.acados_anchor: a clear word when acados is missing (CI has none), the recording
of a flight's solver calls, the controller-like shift of a solution, and (only where acados_template
is importable) that the OCP handed to acados is ours: dimensions, cost, dynamics and bounds."""

from __future__ import annotations

import sys
import types

import numpy as np
import pytest
import trq_params

from trq_lab.bench import acados_anchor as aa
from trq_lab.bench import nmpc as bench
from trq_offboard.allocation import Allocator
from trq_offboard.config import load_controller
from trq_offboard.model import PredictionModel
from trq_offboard.nmpc.base import plan_of
from trq_offboard.records import SolveInfo, SolveStatus


@pytest.fixture(scope="module")
def setup():
    cfg = load_controller(trq_params.resolve("controller", "trq_nmpc_eso"))
    model = PredictionModel(cfg.vehicle)
    al = Allocator(cfg.vehicle)
    return cfg, model, al.command_vector(al.hover())


def test_not_installed_is_said_not_raised(monkeypatch):
    monkeypatch.setitem(sys.modules, "acados_template", None)     # import raises ImportError
    ok, why = aa.available()
    assert not ok
    assert "acados not installed" in why and "acados_template" in why


def test_acados_source_dir_is_required(monkeypatch):
    monkeypatch.setitem(sys.modules, "acados_template", types.ModuleType("acados_template"))
    monkeypatch.delenv("ACADOS_SOURCE_DIR", raising=False)
    ok, why = aa.available()
    assert not ok and "ACADOS_SOURCE_DIR" in why


def test_missing_libraries_and_renderer_are_named(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "acados_template", types.ModuleType("acados_template"))
    monkeypatch.setenv("ACADOS_SOURCE_DIR", str(tmp_path))
    monkeypatch.delenv("TERA_PATH", raising=False)
    ok, why = aa.available()
    assert not ok and "libacados.so" in why
    (tmp_path / "lib").mkdir()
    for name in ("libacados.so", "libhpipm.so", "libblasfeo.so"):
        (tmp_path / "lib" / name).write_bytes(b"")
    ok, why = aa.available()
    assert not ok and "t_renderer" in why


def test_bench_refuses_the_anchor_cleanly(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "acados_template", None)
    with pytest.raises(SystemExit) as exc:
        bench.main(["--quick", "--modes", "rti-gn", "--anchor", "acados"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "--anchor acados" in err and "acados not installed" in err


def test_library_env_puts_acados_lib_first_once(tmp_path):
    env = aa.library_env({"ACADOS_SOURCE_DIR": str(tmp_path), "LD_LIBRARY_PATH": "/x"})
    assert env["LD_LIBRARY_PATH"] == f"{tmp_path / 'lib'}:/x"
    assert aa.library_env(env)["LD_LIBRARY_PATH"] == env["LD_LIBRARY_PATH"]
    assert "LD_LIBRARY_PATH" not in aa.library_env({})


def test_shift_is_the_controllers_shift():
    """States interpolated at dt + k h, inputs held (the one in force), s_0's tilt replaced."""
    N, h, dt = 4, 0.05, 0.01
    s = np.arange(N + 1, dtype=float)[:, None] * np.ones((1, 16))
    v = np.arange(N, dtype=float)[:, None] * np.ones((1, 8))
    s2, v2 = aa._shift(s, v, h, dt, np.full(4, -1.0))
    np.testing.assert_allclose(s2[:, 0], [0.2, 1.2, 2.2, 3.2, 4.0])   # the end clamped
    np.testing.assert_allclose(s2[0, 12:16], -1.0)
    np.testing.assert_allclose(s2[1:, 12], [1.2, 2.2, 3.2, 4.0])
    np.testing.assert_allclose(v2[:, 0], [0, 1, 2, 3])


class _FakeSolver:
    """An RTI solver's recorded surface: its preparation leaves the linearisation point in
    `_prepared.w` (packed, clipped), as RtiSolver's does."""

    prepares_plans = False

    def __init__(self, ocp):
        self.ocp = ocp
        self.last_prepare_s = 0.25
        self.prepared = []
        self._prepared = None

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        u, x = plan_of(guess)
        return u + 1.0, x, SolveInfo(SolveStatus.OK, 1, 1e-3, 0.0, "rti")

    def prepare(self, x_ref, d, u_prev, guess, y0=None):
        self.prepared.append(guess)
        o = self.ocp
        w = np.clip(o.pack(guess[1], guess[0], np.asarray(u_prev)[0:4]), o.lbw, o.ubw)
        self._prepared = types.SimpleNamespace(w=w)


class _FakePlanSolver(_FakeSolver):
    """The same, preparing at plans (the compiled guess): its point is whatever it made."""

    prepares_plans = True

    def prepare_plan(self, plan, elapsed_s, h_s, pv, yaw_ref, d, u_prev, y0=None):
        self.last_prepare_s = 0.125
        self._prepared = types.SimpleNamespace(w=np.full(self.ocp.lbw.size, elapsed_s))


def _recording(setup, solver_class):
    """(cfg, u_trim, the OCP, a controller with a fake solver of `solver_class`, its
    Recorder)."""
    from trq_offboard.nmpc.ocp import Ocp

    cfg, model, u_trim = setup
    ocp = Ocp.build(cfg, model)
    ctl = types.SimpleNamespace(solver=solver_class(ocp), u_trim=u_trim)
    return cfg, u_trim, ocp, ctl, aa.Recorder(ctl)


def test_recorder_keeps_the_solves_and_the_linearisation_points(setup):
    cfg, u_trim, ocp, ctl, rec = _recording(setup, _FakeSolver)
    N = cfg.horizon_steps
    rng = np.random.default_rng(3)
    u_prev = u_trim.copy()
    guesses = []
    for k in range(3):
        x0 = rng.normal(size=12) * 0.1
        guess = (np.tile(u_trim, (N, 1)) + 0.01 * k, np.tile(x0, (N + 1, 1)))
        u, _, _ = ctl.solver.solve(x0, np.zeros((N + 1, 12)), np.full(6, k), u_prev, guess)
        prep_guess = (guess[0] + 0.5, guess[1])
        ctl.solver.prepare(np.zeros((N + 1, 12)), np.zeros(6), u[0], prep_guess)
        guesses.append((guess, prep_guess))
        u_prev = u[0]
    a = rec.arrays()
    assert a["x0"].shape == (3, 12) and a["x_ref"].shape == (3, N + 1, 12)
    assert a["v_lo"].shape == (3, N, 8) and a["guess_s"].shape == (3, N + 1, 16)
    np.testing.assert_allclose(a["d"][:, 0], [0, 1, 2])
    np.testing.assert_allclose(a["u0"][0], u_trim + 1.0)
    assert a["ok"].all() and a["solver_prep_s"].tolist() == [0.25] * 3
    assert a["solve_s"].tolist() == [1e-3] * 3
    # step 0 linearised at its solve's guess; step 1 at the preceding preparation's guess
    w0 = np.clip(ocp.pack(guesses[0][0][1], guesses[0][0][0], u_trim[0:4]), ocp.lbw, ocp.ubw)
    np.testing.assert_allclose(a["guess_v"][0], w0[ocp.v_index])
    w1 = np.clip(ocp.pack(guesses[0][1][1], guesses[0][1][0], (u_trim + 1.0)[0:4]),
                 ocp.lbw, ocp.ubw)
    np.testing.assert_allclose(a["guess_v"][1], w1[ocp.v_index])


def test_recorder_keeps_the_compiled_guess_linearisation_points(setup):
    cfg, u_trim, ocp, ctl, rec = _recording(setup, _FakePlanSolver)
    N = cfg.horizon_steps
    guess = (np.tile(u_trim, (N, 1)), np.zeros((N + 1, 12)))
    for k in range(2):
        u, x, _ = ctl.solver.solve(np.zeros(12), np.zeros((N + 1, 12)), np.zeros(6), u_trim,
                                   guess)
        ctl.solver.prepare_plan((u, x), 0.5 + k, 0.05, np.zeros((N + 1, 6)), np.zeros(N + 1),
                                np.zeros(6), u[0])
    a = rec.arrays()
    assert a["solver_prep_s"].tolist() == [0.125, 0.125]
    # step 1 at the preparation's own point, as the compiled guess left it
    np.testing.assert_array_equal(a["guess_v"][1], np.full(ocp.v_index.shape, 0.5))


def test_the_problem_is_ours(setup):
    """The least-squares form of the cost is the stage cost of nmpc/ocp.py (no acados needed)."""
    cfg, model, u_trim = setup
    pb = aa.problem(cfg, model, u_trim)
    assert (pb.ns, pb.nv, pb.n_steps, pb.nx) == (16, 8, cfg.horizon_steps, 12)
    rng = np.random.default_rng(1)
    for _ in range(5):
        s, v, xr = rng.normal(size=16), rng.normal(size=8), rng.normal(size=12)
        y = pb.Vx @ s + pb.Vu @ v - pb.yref(xr)
        assert 0.5 * y @ pb.W @ y == pytest.approx(
            float(pb.stage.cost(s, v, xr, pb.u_trim_scaled)), rel=1e-12)
        e = pb.Vx_e @ s - xr
        assert 0.5 * e @ pb.W_e @ e == pytest.approx(float(pb.stage.terminal_cost(s, xr)),
                                                     rel=1e-12)
    assert pb.idxbx.tolist() == [6, 7, 9, 10, 11, 12, 13, 14, 15]
    assert pb.ubv0[0] == pytest.approx(pb.ubv[0] * cfg.control_dt_s / cfg.step_s)


def test_the_acados_ocp_is_ours(setup):
    """With acados_template importable: the AcadosOcp's dimensions, cost, dynamics and options
    are the project's (nothing generated or compiled)."""
    pytest.importorskip("acados_template")
    import casadi as ca

    cfg, model, u_trim = setup
    ocp, pb = aa.build_ocp(cfg, model, u_trim, "exact")
    m = ocp.model
    assert (m.x.shape[0], m.u.shape[0], m.p.shape[0]) == (16, 8, 6)
    assert ocp.solver_options.N_horizon == cfg.horizon_steps
    assert ocp.solver_options.hessian_approx == "EXACT"
    assert ocp.solver_options.nlp_solver_type == "SQP_RTI"
    assert ocp.solver_options.qp_solver_cond_N == cfg.horizon_steps
    np.testing.assert_array_equal(ocp.cost.W, pb.W)
    np.testing.assert_array_equal(ocp.solver_options.cost_scaling, np.ones(cfg.horizon_steps + 1))
    f = ca.Function("f", [m.x, m.u, m.p], [m.disc_dyn_expr])
    rng = np.random.default_rng(2)
    for _ in range(3):
        s, v, d = rng.normal(size=16) * 0.2, rng.normal(size=8) * 0.2, rng.normal(size=6)
        np.testing.assert_allclose(np.array(f(s, v, d)).ravel(),
                                   np.array(pb.stage.dynamics(s, v, d)).ravel(), rtol=1e-14)
    ocp_gn, _ = aa.build_ocp(cfg, model, u_trim, "gauss_newton")
    assert ocp_gn.solver_options.hessian_approx == "GAUSS_NEWTON"
    assert ocp_gn.solver_options.hpipm_mode == "SPEED_ABS"
    assert ocp.solver_options.regularize_method == "NO_REGULARIZE"       # acados' default
    ocp_r, _ = aa.build_ocp(cfg, model, u_trim, "exact", regularize="PROJECT", reg_epsilon=1e-5)
    assert ocp_r.solver_options.regularize_method == "PROJECT"
    assert ocp_r.solver_options.reg_epsilon == 1e-5
    # every method of ours is one acados_template accepts
    for method in aa.REGULARIZE_METHODS:
        ocp_r.solver_options.regularize_method = method


# --- the exact Hessian's regularisation (docs/decisions/2026-12-06-acados-exact-regularisation.md)

def test_regularize_is_checked():
    assert aa.check_regularize("NO_REGULARIZE") == ("NO_REGULARIZE", None)
    assert aa.check_regularize("MIRROR", 1e-5) == ("MIRROR", 1e-5)
    assert aa.check_regularize("PROJECT", 1) == ("PROJECT", 1.0)
    with pytest.raises(ValueError, match="one of NO_REGULARIZE, MIRROR"):
        aa.check_regularize("mirror")                      # acados spells them upper case
    with pytest.raises(ValueError, match="NO_REGULARIZE does not use one"):
        aa.check_regularize("NO_REGULARIZE", 1e-4)
    with pytest.raises(ValueError, match="PROJECT_REDUC_HESS does not use one"):
        aa.check_regularize("PROJECT_REDUC_HESS", 1e-4)
    for bad in (0.0, -1e-4, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="finite number > 0"):
            aa.check_regularize("MIRROR", bad)


def test_anchor_names_say_the_regularisation():
    assert aa.anchor_name("exact") == "acados-rti-exact"
    assert aa.anchor_name("gauss_newton") == "acados-rti-gn"
    assert aa.anchor_name("exact", "MIRROR") == "acados-rti-exact-mirror"


def test_replay_cli_refuses_a_bad_epsilon_before_acados(monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "acados_template", None)     # not needed to refuse
    with pytest.raises(SystemExit) as exc:
        aa.main(["--replay", "x.npz", "--regularize", "MIRROR", "--reg-epsilon", "-1"])
    assert exc.value.code == 2 and "finite number > 0" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        aa.main(["--replay", "x.npz", "--regularize", "SOMETHING"])
    assert exc.value.code == 2 and "invalid choice" in capsys.readouterr().err


def test_run_anchor_hands_the_regularisation_to_the_child(monkeypatch, tmp_path):
    """The child's command line carries the method and epsilon; its JSON is found though
    acados' C output follows it."""
    calls = []

    def fake_run(cmd, **kwargs):
        calls.append(cmd)
        return types.SimpleNamespace(
            returncode=0, stderr="",
            stdout='{"name": "acados-rti-exact-mirror"}\n\nSQP_RTI: QP solver returned error\n')

    monkeypatch.setattr(bench.subprocess, "run", fake_run)
    a = bench.run_anchor(tmp_path / "r.npz", "exact", "trq_nmpc_eso", "shift", "MIRROR", 1e-5)
    assert a == {"name": "acados-rti-exact-mirror"}
    cmd = calls[-1]
    assert cmd[cmd.index("--regularize") + 1] == "MIRROR"
    assert float(cmd[cmd.index("--reg-epsilon") + 1]) == 1e-5
    bench.run_anchor(tmp_path / "r.npz", "gauss_newton", "trq_nmpc_eso")
    assert calls[-1][calls[-1].index("--regularize") + 1] == "NO_REGULARIZE"
    assert "--reg-epsilon" not in calls[-1]
    with pytest.raises(ValueError, match="regularize method"):
        bench.run_anchor(tmp_path / "r.npz", "exact", "trq_nmpc_eso", regularize="BOGUS")


def _fake_bench(monkeypatch):
    """trq-bench-nmpc's main with acados 'available' and no flight flown: run_anchor's
    arguments kept, per hessian."""
    anchors = {}
    monkeypatch.setattr(aa, "available", lambda: (True, "acados (fake)"))
    flown = dict(steps=1, crashed=False, build_mode="cached", compilations_cold=0,
                 compilations_cached=0, sensing="truth", qp="-", median_ms=1.0, p99_ms=1.0,
                 period_median_ms=1.0)
    monkeypatch.setattr(bench, "run_mode", lambda mode, *a, **k: dict(flown, name=mode))

    def run_anchor(rec, hessian, controller, init="shift", regularize="NO_REGULARIZE",
                   reg_epsilon=None):
        anchors[hessian] = (regularize, reg_epsilon)
        return dict(name=aa.anchor_name(hessian, regularize), hessian=hessian, steps=1,
                    failures=0, prep_median_ms=1.0, feedback_median_ms=1.0,
                    total_median_ms=2.0, total_p99_ms=2.0)

    monkeypatch.setattr(bench, "run_anchor", run_anchor)
    for name in ("table", "anchor_table"):
        monkeypatch.setattr(bench, name, lambda *a, **k: "")
    monkeypatch.setattr(bench, "machine_line", lambda: "machine")
    monkeypatch.setattr(bench, "calibration_ms", lambda repeats=5: 0.0)
    return anchors


def test_bench_regularises_the_exact_replay_only(monkeypatch, capsys):
    anchors = _fake_bench(monkeypatch)
    assert bench.main(["--quick", "--modes", "rti-gn,rti-exact", "--anchor", "acados",
                       "--anchor-regularize", "MIRROR", "--anchor-reg-epsilon", "1e-5"]) == 0
    assert anchors == {"gauss_newton": ("NO_REGULARIZE", None), "exact": ("MIRROR", 1e-5)}
    assert "regularised by MIRROR, reg_epsilon 1e-05" in capsys.readouterr().out
    anchors.clear()
    assert bench.main(["--quick", "--modes", "rti-exact", "--anchor", "acados"]) == 0
    assert anchors == {"exact": ("NO_REGULARIZE", None)}          # the default: acados' own


@pytest.mark.parametrize("argv, said", [
    (["--anchor-regularize", "mirror"], "one of NO_REGULARIZE"),
    (["--anchor-reg-epsilon", "1e-4"], "NO_REGULARIZE does not use one"),
    (["--anchor-regularize", "MIRROR", "--anchor-reg-epsilon", "0"], "finite number > 0"),
])
def test_bench_refuses_a_bad_regularisation(monkeypatch, capsys, argv, said):
    _fake_bench(monkeypatch)
    with pytest.raises(SystemExit) as exc:
        bench.main(["--quick", "--modes", "rti-exact", "--anchor", "acados", *argv])
    assert exc.value.code == 2 and said in capsys.readouterr().err


def test_bench_regularisation_needs_the_exact_replay(monkeypatch, capsys):
    _fake_bench(monkeypatch)
    with pytest.raises(SystemExit) as exc:
        bench.main(["--quick", "--modes", "rti-exact", "--anchor-regularize", "MIRROR"])
    assert exc.value.code == 2 and "add --anchor acados" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        bench.main(["--quick", "--modes", "rti-gn", "--anchor", "acados",
                    "--anchor-regularize", "MIRROR"])
    assert exc.value.code == 2 and "add rti-exact to --modes" in capsys.readouterr().err


class _FakeReplayer:
    """What `serve` reads of a Replayer: its build, names, passes, run and summary."""

    def __init__(self):
        self.rti = types.SimpleNamespace(build_s=3.5)
        self.hessian, self.regularize, self.passes = "exact", "NO_REGULARIZE", 0
        self.split, self.paces = [], []

    def run(self, pace_s=0.0):
        self.passes += 1
        self.paces.append(pace_s)
        return np.full((2, 9), float(self.passes)), np.zeros((2, 8))

    def summary(self, rows, u0, split_s=None, pace_s=0.0):
        self.split.append(split_s)
        return {"total_median_ms": float(rows[0, 0]), "pace_ms": pace_s * 1e3}


def test_the_server_answers_each_pass_and_stops_at_quit():
    """The bench's bracketing server: built, then one pass a request, a wrong request answered
    with an error that names it (the server goes on), and nothing after quit."""
    import io
    import json

    fake, out = _FakeReplayer(), io.StringIO()
    n = aa.serve(fake, ["pass\n", "passs\n", "pass\n", "quit\n", "pass\n"], out, split_s=12.0)
    said = [json.loads(line) for line in out.getvalue().splitlines()]
    assert n == 2 and fake.split == [12.0, 12.0]
    assert said[0] == {"ready": True, "build_s": 3.5, "name": "acados-rti-exact"}
    assert said[1] == {"total_median_ms": 1.0, "pace_ms": 0.0, "pass": 1}
    assert "unknown request 'passs'" in said[2]["error"]
    assert said[3] == {"total_median_ms": 2.0, "pace_ms": 0.0, "pass": 2} and len(said) == 4
    out = io.StringIO()
    assert aa.serve(_FakeReplayer(), iter(["pass\n"]), out) == 1     # the requests' end ends it


def test_the_server_paces_a_pass_on_request_and_refuses_a_bad_pace():
    """"pass 10": one pass paced at 10 ms (the module's docstring); a pace that is not a
    time >= 0, or a word too many, is answered with an error and no pass."""
    import io
    import json

    fake, out = _FakeReplayer(), io.StringIO()
    n = aa.serve(fake, ["pass 10\n", "pass -1\n", "pass ten\n", "pass nan\n", "pass 1 2\n",
                        "pass\n"], out)
    said = [json.loads(line) for line in out.getvalue().splitlines()][1:]
    assert n == 2 and fake.paces == [0.01, 0.0]
    assert said[0] == {"total_median_ms": 1.0, "pace_ms": 10.0, "pass": 1}
    assert [("error" in a) for a in said] == [False, True, True, True, True, False]
    assert "'pass -1'" in said[1]["error"] and "a time >= 0" in said[1]["error"]


class _PacedRti:
    """What Replayer.run calls of AcadosRti, on a fake clock: each call takes 1 ms, and the
    feedbacks' start times are kept."""

    def __init__(self, clock):
        self.clock, self.feedbacks = clock, []
        self.pb = types.SimpleNamespace(step_s=0.05)
        self.solver = types.SimpleNamespace(reset=lambda: None,
                                            get_stats=lambda key: 0.0 if key != "qp_iter" else 3)

    def set_init(self, s, v):
        pass

    def set_stage_data(self, *a):
        pass

    def prepare(self):
        self.clock.t += 1e-3
        return 0, 1e-3, 1e-3

    def feedback(self, s0):
        self.feedbacks.append(self.clock.t)
        self.clock.t += 1e-3
        return 0, 1e-3, 1e-3

    def solution(self):
        return np.zeros((21, 16)), np.zeros((20, 8))

    def command(self, s, v):
        return np.zeros(8)


def test_a_paced_pass_starts_each_feedback_one_period_after_the_last():
    """Replayer.run(pace_s): the wait falls between the preparation and the feedback (where a
    control loop waits for its state), each feedback pace_s after the previous one started;
    the timed parts never include it. Unpaced, the steps follow each other at once."""
    clock = types.SimpleNamespace(t=100.0)
    slept = []

    def sleep(s):
        slept.append(s)
        clock.t += s

    r = object.__new__(aa.Replayer)
    r.rti, r.init, r.passes = _PacedRti(clock), "ours", 0
    r.cfg = types.SimpleNamespace(control_dt_s=0.01)
    K = 4
    r.rec = {"x0": np.zeros((K, 12)), "alpha_prev": np.zeros((K, 4)),
             "guess_s": np.zeros((K, 21, 16)), "guess_v": np.zeros((K, 20, 8)),
             "x_ref": np.zeros((K, 21, 12)), "d": np.zeros((K, 6)),
             "v_lo": np.zeros((K, 20, 8)), "v_hi": np.zeros((K, 20, 8))}
    rows, _ = r.run(0.01, clock=lambda: clock.t, sleep=sleep)
    starts = np.array(r.rti.feedbacks)
    np.testing.assert_allclose(np.diff(starts), 0.01)
    np.testing.assert_allclose(slept, [0.008] * (K - 1))     # 10 ms less the 2 ms of work
    np.testing.assert_allclose(rows[:, 0] + rows[:, 2], 2e-3)   # the waits are not timed
    r.rti.feedbacks.clear()
    slept.clear()
    r.run(0.0, clock=lambda: clock.t, sleep=sleep)
    assert slept == [] and np.allclose(np.diff(r.rti.feedbacks), 2e-3)
    with pytest.raises(ValueError, match="pace -1 s"):
        r.run(-1.0)


class _FakeServer:
    """bench.AnchorServer without acados: its passes counted, each a step p50 of 0.5 ms."""
    made = []

    def __init__(self, recording, hessian, controller, init="shift",
                 regularize="NO_REGULARIZE", reg_epsilon=None):
        self.name, self.build_s, self.passes = aa.anchor_name(hessian, regularize), 1.0, 0
        self.args = (hessian, regularize, reg_epsilon)
        self.closed = False
        self.paces = []
        _FakeServer.made.append(self)

    def one_pass(self, pace_ms=0.0):
        self.passes += 1
        self.paces.append(pace_ms)
        return {"total_median_ms": 0.5, "total_cpu_median_ms": 0.5, "failures": 0,
                "steps": 10, "pass": self.passes, "du_tilt_deg_max": 1.0}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.closed = True


def test_the_bench_brackets_each_daemon_run_with_acados_passes(monkeypatch, capsys, tmp_path):
    """With --daemons and --anchor acados, acados is built once per anchored mode on a flight
    of its own, stepped through it before, between and after each run's two daemon flights,
    and the target is printed against those passes; the servers end with the bench."""
    import json

    from trq_lab.bench import period

    _fake_bench(monkeypatch)
    tables = []
    monkeypatch.setattr(bench, "anchor_table", lambda *a, **k: tables.append(a) or "")
    _FakeServer.made.clear()
    monkeypatch.setattr(bench, "AnchorServer", _FakeServer)
    points = []

    def daemons_period(controller, sensing, bracket, vehicle_mode):
        assert vehicle_mode == "lockstep"
        got = [bracket(p) for p in ("before", "between", "after")]
        points.append(controller)
        part = {"mean_ms": 0.4, "p50_ms": 0.4, "p99_ms": 0.4}
        return {"controller_cpu_ms": 0.75, "vehicle_cpu_ms": 1.0, "realtime_factor": 2.0,
                "parts": {"solve (wall)": part, "prepare": part}, "brackets": got}

    monkeypatch.setattr(period, "daemons_period", daemons_period)
    monkeypatch.setattr(period, "parts_table", lambda fig: "")
    out = tmp_path / "b.json"
    assert bench.main(["--quick", "--modes", "rti-gn,rti-exact", "--anchor", "acados",
                       "--daemons", "--repeat", "2", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    servers = {s.name: s for s in _FakeServer.made}
    assert set(servers) == {"acados-rti-gn", "acados-rti-exact"}
    assert all(s.passes == 6 and s.closed for s in servers.values())     # 2 runs x 3 points
    assert "acados-rti-exact p50 0.500/0.500/0.500 ms around it" in text
    daemons = tables[0][2]                       # what the target's lines are printed from
    assert daemons["bracket_passes_ms"] == {"rti-gn": [[0.5] * 3] * 2,
                                            "rti-exact": [[0.5] * 3] * 2}
    assert bench.bracketed_to_anchor(daemons, "rti-exact") == [1.5, 1.5]
    runs = json.loads(out.read_text())["daemon_runs"]
    assert [sorted(b) for b in runs[0]["brackets"]] == [["rti-exact", "rti-gn"]] * 3
    assert "du_tilt_deg_max" not in runs[0]["brackets"][0]["rti-exact"]   # the pass's figures



def test_realtime_pacing_paces_both_the_daemons_and_the_bracket(monkeypatch, capsys):
    """--pacing realtime: the daemons fly with the vehicle on the wall clock and acados'
    bracket passes are paced at the controller's control period; without --daemons it is
    refused."""
    from trq_lab.bench import period

    _fake_bench(monkeypatch)
    _FakeServer.made.clear()
    monkeypatch.setattr(bench, "AnchorServer", _FakeServer)
    modes = []

    def daemons_period(controller, sensing, bracket, vehicle_mode):
        modes.append(vehicle_mode)
        part = {"mean_ms": 0.4, "p50_ms": 0.4, "p99_ms": 0.4}
        return {"controller_cpu_ms": 0.75, "vehicle_cpu_ms": 1.0, "realtime_factor": 1.0,
                "parts": {"solve (wall)": part, "prepare": part},
                "brackets": [bracket(p) for p in "abc"]}

    monkeypatch.setattr(period, "daemons_period", daemons_period)
    monkeypatch.setattr(period, "parts_table", lambda fig: "")
    assert bench.main(["--quick", "--modes", "rti-exact", "--anchor", "acados", "--daemons",
                       "--pacing", "realtime"]) == 0
    assert modes == ["realtime"] and _FakeServer.made[0].paces == [10.0] * 3
    assert ", realtime 1.00x real time" in capsys.readouterr().out
    modes.clear()
    _FakeServer.made.clear()
    assert bench.main(["--quick", "--modes", "rti-exact", "--anchor", "acados",
                       "--daemons"]) == 0                # the default: lockstep, tight passes
    assert modes == ["lockstep"] and _FakeServer.made[0].paces == [0.0] * 3
    with pytest.raises(SystemExit) as exc:
        bench.main(["--quick", "--modes", "rti-exact", "--pacing", "realtime"])
    assert exc.value.code == 2 and "add --daemons" in capsys.readouterr().err


_FAKE_SERVER = r"""
import json, sys
print(json.dumps({"ready": True, "build_s": 2.5, "name": "acados-rti-exact"}), flush=True)
n = 0
for line in sys.stdin:
    if line.strip() == "quit":
        break
    n += 1
    print("QP solver returned error", file=sys.stderr, flush=True)    # acados' C output
    print(json.dumps({"total_median_ms": 0.5 * n, "pass": n, "request": line.strip()}),
          flush=True)
"""


def test_the_anchor_server_process_is_driven_and_ended(monkeypatch):
    """AnchorServer without acados: a child speaking serve's protocol; its passes read in
    order, acados' C output (stderr) kept out of the answers, the child ended by close."""
    monkeypatch.setattr(bench, "_anchor_cmd", lambda *a: [sys.executable, "-c", _FAKE_SERVER])
    with bench.AnchorServer("r.npz", "exact", "trq_nmpc_eso") as server:
        assert (server.name, server.build_s) == ("acados-rti-exact", 2.5)
        assert [server.one_pass()["total_median_ms"] for _ in range(3)] == [0.5, 1.0, 1.5]
        assert server.one_pass(10.0)["request"] == "pass 10"       # paced at 10 ms
        proc = server._proc
    assert proc.poll() == 0


def test_an_anchor_server_that_dies_is_named_with_its_last_words(monkeypatch):
    script = "import sys; print('libacados.so: cannot open', file=sys.stderr); sys.exit(3)"
    monkeypatch.setattr(bench, "_anchor_cmd", lambda *a: [sys.executable, "-c", script])
    with pytest.raises(RuntimeError, match=r"(?s)ended \(exit 3\).*libacados.so: cannot open"):
        bench.AnchorServer("r.npz", "exact", "trq_nmpc_eso")
