"""Shared fixtures of the test suite: paths to the parameter files (from this file, never from the
working directory), loaded parameter records, a free UDP port finder, and `daemons` (with
`module_daemons`): the one way a test starts `python -m sil_vehicle` and `python -m trq_offboard`
(free ports, output to a file in the test's tmp folder, its tail in every failure message, and
a guaranteed stop: SIGTERM, then SIGKILL after a timeout); `examples(n)`, a property test's
number of examples: n in the whole suite, a fifth of it in the fast tier (`-m "not slow"`), which
is for the turn-around of an edit; CI runs them all."""

from __future__ import annotations

import ast
import contextlib
import functools
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import trq_params

from trq_lab import procs

ROOT = Path(__file__).resolve().parent.parent
PARAMS = trq_params.DIR
SIM_DEFAULT = PARAMS / "sim" / "default.yaml"
TRQ_YAML = PARAMS / "vehicle" / "trq.yaml"
QUAD_YAML = PARAMS / "vehicle" / "quad.yaml"
FAST_TIER_MARKEXPR = "not slow"
FAST_TIER_EXAMPLES = 0.2                # of a property test's examples, in the fast tier
_fast_tier = False


def pytest_configure(config) -> None:
    global _fast_tier
    _fast_tier = config.getoption("markexpr", "").strip() == FAST_TIER_MARKEXPR


@functools.lru_cache(maxsize=None)
def source_tree(path: Path) -> ast.Module:
    """A source file's syntax tree, parsed once per test process (the meta tests each walk
    every file of the project; none of them changes a tree)."""
    return ast.parse(path.read_text(encoding="utf-8"), filename=str(path))


def examples(n: int) -> int:
    """A property test's max_examples: n, or a fifth of it (at least 20) in the fast tier."""
    return max(20, round(n * FAST_TIER_EXAMPLES)) if _fast_tier else n


class Ticks:
    """A fake CPU clock (ns): each reading 1000 ns after the last."""

    def __init__(self) -> None:
        self.t = 0

    def __call__(self) -> int:
        self.t += 1000
        return self.t



def feed_imu(f, t_us: int, accel_ned_at, euler, bias_frd, rng, std: float, g: float) -> None:
    """Two accelerometer messages a control period (at t_us - 6 ms and - 2 ms, time_usec) into
    a fused filter `f` (trq_offboard.fused.FusedFilter): the specific force of the NED
    acceleration `accel_ned_at(t_s)` seen at the attitude `euler`, plus the body bias and
    white noise."""
    import numpy as np
    from trq_offboard.frames import rotation_ned_frd

    rot = rotation_ned_frd(*euler)
    for s in (t_us - 6000, t_us - 2000):
        f_frd = rot.T @ (accel_ned_at(s * 1e-6) - np.array([0.0, 0.0, g])) + np.asarray(bias_frd)
        f.add_imu(s, f_frd + rng.normal(0.0, std, 3))

def cli(command: str) -> list[str]:
    """The argv prefix of an installed console script (trq-scenario, ...): the one beside this
    interpreter, as a user of this environment runs it."""
    path = Path(sys.executable).parent / command
    assert path.is_file(), f"{command} is not installed beside {sys.executable}: pip install -e ."
    return [str(path)]


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nobody was bound to a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def free_port():
    """Call it to get a fresh free UDP port on 127.0.0.1."""
    return free_udp_port


@pytest.fixture(scope="session")
def sim():
    """The default simulation settings (trq, lockstep, 1 kHz physics) under `truth` (no sensor,
    no estimator: the tests of the plant, the link and the commands; the sim file's own default
    is `mocap`); frozen, so shared."""
    from sil_vehicle.config import load_sim, sensing_profile
    sim = load_sim(SIM_DEFAULT)
    return sim.with_changes(sensing=sensing_profile("truth", sim.physics_rate_hz, "conftest"))


@pytest.fixture(scope="session")
def trq():
    from sil_vehicle.config import load_vehicle
    return load_vehicle(TRQ_YAML)


@pytest.fixture(scope="session")
def quad():
    from sil_vehicle.config import load_vehicle
    return load_vehicle(QUAD_YAML)


# --- daemon processes ------------------------------------------------------------------------

STOP_TIMEOUT_S = 10.0           # SIGTERM, then this long before SIGKILL


class Process:
    """One daemon started by `Daemons`: its Popen, its output file (stdout and stderr, or stderr
    apart in <name>.err) and the ports the manager gave it."""

    def __init__(self, name: str, argv: list[str], out_dir: Path, *, cwd: Path,
                 split_stderr: bool = False, **ports) -> None:
        self.name, self.argv = name, argv
        self.out_path = out_dir / f"{name}.out"
        self.err_path = out_dir / f"{name}.err" if split_stderr else None
        self.port: int | None = None
        self.log_dir: Path | None = None
        self.__dict__.update(ports)
        with contextlib.ExitStack() as files:
            out = files.enter_context(open(self.out_path, "wb"))
            err = files.enter_context(open(self.err_path, "wb")) if split_stderr \
                else subprocess.STDOUT
            self.popen = subprocess.Popen(argv, cwd=cwd, env=dict(os.environ), stdout=out,
                                          stderr=err)

    @property
    def returncode(self) -> int | None:
        return self.popen.poll()

    def alive(self) -> bool:
        return self.popen.poll() is None

    def text(self) -> str:
        return self.out_path.read_text(errors="replace") if self.out_path.exists() else ""

    def err(self) -> str:
        return self.err_path.read_text(errors="replace") if self.err_path else ""

    def why(self, chars: int = 2000) -> str:
        """The tail of the output, for an assertion message."""
        tail = f"--- {self.name} (rc {self.popen.poll()}): {' '.join(self.argv[1:4])} ...\n"
        tail += self.text()[-chars:]
        if self.err_path:
            tail += f"\n--- {self.name} stderr\n" + self.err()[-chars:]
        return tail

    def send_signal(self, sig: int) -> None:
        if self.popen.poll() is None:
            self.popen.send_signal(sig)

    def kill(self) -> int:
        """SIGKILL (no goodbye) and reap it."""
        self.send_signal(signal.SIGKILL)
        return self.popen.wait(timeout=STOP_TIMEOUT_S)

    def wait(self, timeout_s: float, what: str = "") -> int:
        """The exit code, or an AssertionError with the output's tail after timeout_s."""
        try:
            return self._exited(self.popen.wait(timeout=max(timeout_s, 0.1)))
        except subprocess.TimeoutExpired:
            raise AssertionError(f"{self.name} did not exit within {timeout_s:.0f} s"
                                 f"{' ' + what if what else ''}\n{self.why()}") from None

    def stop(self, sig: int = signal.SIGTERM, timeout_s: float = STOP_TIMEOUT_S) -> int:
        """sig (SIGTERM), wait up to timeout_s, then SIGKILL; the exit code."""
        if self.popen.poll() is None:
            self.popen.send_signal(sig)
            try:
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait(timeout=STOP_TIMEOUT_S)
        return self._exited(self.popen.returncode)

    def _exited(self, code: int) -> int:
        """A controller daemon's log on the ground once it has exited: its controller.ulg
        written as controller.csv (trq_lab.procs.controller_csv), as the lab's runners do."""
        if self.log_dir is not None:
            procs.controller_csv(self.log_dir)
        return code

    def wait_bound(self, port: int | None = None, timeout_s: float = 60.0) -> None:
        """Until this process is bound to UDP 127.0.0.1:port (its own port by default)."""
        port = self.port if port is None else port
        if procs.wait_bound(port, self.popen, timeout_s):
            return
        raise AssertionError(f"{self.name} did not listen on {port} within {timeout_s} s\n"
                             f"{self.why()}")


def wait_until(predicate, timeout_s: float, what: str, why=lambda: "") -> None:
    """Until predicate() holds, or an AssertionError naming what (and why())."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}\n{why()}")


class Daemons:
    """Starts the daemons of one test (or module) on free ports; `close()` stops them all."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.procs: list[Process] = []
        self._ports: set[int] = set()

    def port(self) -> int:
        """A free UDP port, never one this manager handed out before."""
        while (p := free_udp_port()) in self._ports:
            pass
        self._ports.add(p)
        return p

    def start(self, name: str, argv: list[str], *, out_dir: Path | None = None,
              cwd: Path | None = None, split_stderr: bool = False, **ports) -> Process:
        out_dir = self.tmp if out_dir is None else out_dir
        out_dir.mkdir(parents=True, exist_ok=True)
        proc = Process(name, argv, out_dir, cwd=out_dir if cwd is None else cwd,
                       split_stderr=split_stderr, **ports)
        self.procs.append(proc)
        return proc

    def vehicle(self, *args: str, log_dir: Path | None = None, offboard_target: int | None = None,
                gcs_target: int | None = None, name: str = "vehicle", **kw) -> Process:
        """`python -m sil_vehicle` with its four ports (binds from the manager, targets given or
        free) and --log-dir when log_dir is given; args follow. Under `--sensing truth` unless
        the args name a profile or a sim file (the daemon's own default is `mocap`): these tests
        are of the plant, the link and the commands, not of the sensing."""
        if "--sensing" not in args and "--sim" not in args:
            args = ("--sensing", "truth", *args)
        gcs, off = self.port(), self.port()
        gcs_target = self.port() if gcs_target is None else gcs_target
        offboard_target = self.port() if offboard_target is None else offboard_target
        argv = [sys.executable, "-m", "sil_vehicle",
                "--gcs-bind", f"127.0.0.1:{gcs}", "--gcs-target", f"127.0.0.1:{gcs_target}",
                "--offboard-bind", f"127.0.0.1:{off}",
                "--offboard-target", f"127.0.0.1:{offboard_target}"]
        if log_dir is not None:
            log_dir.mkdir(parents=True, exist_ok=True)
            argv += ["--log-dir", str(log_dir)]
        proc = self.start(name, [*argv, *args], gcs_port=gcs, offboard_port=off,
                          gcs_target=gcs_target, offboard_target=offboard_target, **kw)
        proc.log_dir = log_dir
        return proc

    def controller(self, *args: str, log_dir: Path | None = None, port: int | None = None,
                   name: str = "controller", **kw) -> Process:
        """`python -m trq_offboard --connect udpin:127.0.0.1:<port>` (a free port unless given)
        and --log-dir when log_dir is given; args follow."""
        port = self.port() if port is None else port
        argv = [sys.executable, "-m", "trq_offboard", "--connect", f"udpin:127.0.0.1:{port}"]
        if log_dir is not None:
            argv += ["--log-dir", str(log_dir)]
        proc = self.start(name, [*argv, *args], port=port, **kw)
        proc.log_dir = log_dir
        return proc

    def close(self) -> None:
        """Stop every process still running (the last started first); print each one's tail,
        which pytest shows with a failing test."""
        for proc in reversed(self.procs):
            try:
                proc.stop()
            finally:
                print(proc.why(800))


@pytest.fixture
def daemons(tmp_path):
    """A `Daemons` for this test; every process it started is stopped at teardown."""
    manager = Daemons(tmp_path)
    try:
        yield manager
    finally:
        manager.close()


@pytest.fixture(scope="module")
def module_daemons(tmp_path_factory):
    """A `Daemons` shared by a module's tests (a vehicle several tests talk to)."""
    manager = Daemons(tmp_path_factory.mktemp("daemons"))
    try:
        yield manager
    finally:
        manager.close()


@pytest.fixture
def temporary_cache(tmp_path_factory, monkeypatch):
    """Compiled kernels built into a temporary cache ($TRQ_CACHE_DIR), never the user's."""
    monkeypatch.setenv("TRQ_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "trq-cache"))
