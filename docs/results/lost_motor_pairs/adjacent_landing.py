"""Two adjacent motors lost from a level hover at 5 m: the best landing a controller could fly, the
ground and the detection's delay included. A trajectory optimisation of the whole fall (CasADi +
IPOPT, direct multiple shooting, RK4, the final time free) on adjacent_upright.py's model (the
plant's rigid body, drag, rotor curves, motor and servo lags and rate limits): motors 1 and 3 stop
at t = 0 (their outputs decaying through the plant's motor lag and rate limit); the live rotors 2
and 4 hold the hover command for the detection's delay d, then are free (throttles idle..100 %,
tilts -30..30 deg; the body rates within the gyro's full scale, 2000 deg/s, so that the
estimator keeps them); the fall ends when the centre of mass is GROUND_M lower (the gear on the
ground, level). The start: a level hover with the hover command held for the detection's delay
(0: an oracle), or the true state of a flown motors13_lost at its pair detector's declaration
(adjacent_detected_states.json: trq_nmpc_eso_lost, seeds 1-3, 0.11 s after the onset, its NMPC
having answered the tumble meanwhile). Three problems from each start, per initial state:

    upright    maximise s, the smallest cosine of the tilt from vertical over the fall (s >= 0: the
               body never passes 90 deg, the issue's "upright descent"; s < 0: a tumble at the
               local optimum found)
    slowest    minimise the touchdown's down speed with the body never past 90 deg
    standing   the same with the touchdown's tilt within the gear's tip-over angle (50.2 deg,
               docs/simulator.md): a landing the plant does not call a tip-over

Each optimum is checked by rolling its commands out again at 1 ms (RK4, the commands held over
their interval): the check's largest tilt, touchdown speed and tilt are printed beside the
optimiser's. Local optima of non-convex problems (nine starts, none claimed global). The record:
docs/decisions/2026-12-06-adjacent-pair-landing.md.

    python docs/results/lost_motor_pairs/adjacent_landing.py | grep "^[{#]" > adjacent_landing.txt
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import casadi as ca
import numpy as np

import trq_params
from sil_vehicle.config import load_sim

sys.path.insert(0, str(Path(__file__).resolve().parent))
from adjacent_upright import model  # noqa: E402  (the same model, beside this script)

HEIGHT_M = 5.0
GROUND_M = HEIGHT_M - 0.10          # the feet 0.10 m below the centre of mass (trq.yaml's gear)
TIP_OVER_DEG = 50.2                 # the gear's tip-over angle (docs/simulator.md, "Crashes")
N = 80                              # shooting intervals over the free final time
DELAYS_S = (0.0, 0.01, 0.02, 0.04, 0.11)   # an oracle; 10 and 20 ms; the excess passing its
                                    # threshold; the pair
                                    # detector's 0.11-0.12 s in the flights (the record)
GYRO_RAD_S = math.radians(2000.0)   # the IMU's full scale (params/sensing, ICM-42688-P)
# the starts: the live throttles (%) and the senses of rotor 2's and rotor 4's tilts (at their
# limit): opposite senses turn the body about z (a spin), equal senses push it sideways
STARTS = {"cut": (10.0, 0, 0), "spin+ full": (100.0, 1, -1), "spin- full": (100.0, -1, 1),
          "spin+ 80": (80.0, 1, -1), "spin- 80": (80.0, -1, 1),
          "spin+ half": (55.0, 1, -1), "spin- half": (55.0, -1, 1),
          "side+ full": (100.0, 1, 1), "side- full": (100.0, -1, -1)}


class Fall:
    """The model, the dead rotors' decay and the hover, for one vehicle."""

    def __init__(self, vp):
        self.vp = vp
        self.f = model(vp)
        self.hover = vp.thrust_N.inverse(vp.mass_kg * vp.gravity_m_s2 / 4.0)
        tm, rate = vp.motor_time_constant_s, vp.motor_rate_limit_pct_s
        # the plant's lag with its rate limit from the hover output: rate-limited down to
        # rate * tm, then the lag's exponential
        self._y_sw = min(self.hover, rate * tm)
        self._t_sw = (self.hover - self._y_sw) / rate

    def dead(self, t):
        """The dead rotors' output (%) at t s after the failure (CasADi or float)."""
        vp = self.vp
        ramp = self.hover - vp.motor_rate_limit_pct_s * t
        decay = self._y_sw * ca.exp(-(t - self._t_sw) / vp.motor_time_constant_s)
        return ca.if_else(t < self._t_sw, ramp, decay)

    def rk4(self, x, u, t, h):
        """One RK4 step of the 15 states (fallen height, then the model's 14) from time t."""
        def rhs(xx, tt):
            d = self.f(xx[1:], u, self.dead(tt))[0]
            return ca.vertcat(xx[3], d)           # the fallen height's rate: v down
        k1 = rhs(x, t)
        k2 = rhs(x + h / 2 * k1, t + h / 2)
        k3 = rhs(x + h / 2 * k2, t + h / 2)
        k4 = rhs(x + h * k3, t + h)
        return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    def held(self, delay_s: float) -> np.ndarray:
        """The state at the detection: the hover command held for delay_s (1 ms steps)."""
        x = np.concatenate([[0.0], [0, 0, 0], [1, 0, 0, 0], [0, 0, 0],
                            [self.hover, self.hover], [0, 0]])
        u = np.array([self.hover, self.hover, 0.0, 0.0])
        step = ca.Function("held", [xs := ca.SX.sym("x", 15), ts := ca.SX.sym("t")],
                           [self.rk4(xs, u, ts, 1e-3)])
        for i in range(int(round(delay_s / 1e-3))):
            x = np.asarray(step(x, i * 1e-3)).ravel()
            x[4:8] /= np.linalg.norm(x[4:8])
        return x


def _cos_tilt(x) -> float:
    qw, qx, qy, qz = x[4:8]
    return 1 - 2 * (qx ** 2 + qy ** 2)


def _guess(fall: Fall, x0, t0: float, start: str):
    """A start: the guess's commands rolled out over the time a free fall from x0 takes."""
    vp = fall.vp
    thr, s2, s4 = STARTS[start]
    h0 = GROUND_M - x0[0]
    v0 = x0[3]
    T = (-v0 + math.sqrt(v0 ** 2 + 2 * vp.gravity_m_s2 * h0)) / vp.gravity_m_s2
    h = T / N
    xs, us = ca.SX.sym("x", 15), ca.SX.sym("u", 4)
    ts, hs = ca.SX.sym("t"), ca.SX.sym("h")
    step = ca.Function("s", [xs, us, ts, hs], [fall.rk4(xs, us, ts, hs)])
    X = np.zeros((15, N + 1))
    U = np.zeros((4, N))
    X[:, 0] = x0
    tm, ts_ = vp.motor_time_constant_s, vp.servo_time_constant_s
    for i in range(N):
        xi = X[:, i]
        u = np.array([thr, thr, s2 * vp.tilt_max_rad, s4 * vp.tilt_max_rad])
        # within the rate limits: the output's rate (u - y) / T at most the limit
        u[0:2] = np.clip(u[0:2], xi[11:13] - 0.999 * vp.motor_rate_limit_pct_s * tm,
                         xi[11:13] + 0.999 * vp.motor_rate_limit_pct_s * tm)
        u[2:4] = np.clip(u[2:4], xi[13:15] - 0.999 * vp.servo_rate_limit_rad_s * ts_,
                         xi[13:15] + 0.999 * vp.servo_rate_limit_rad_s * ts_)
        U[:, i] = u
        X[:, i + 1] = np.asarray(step(xi, u, t0 + i * h, h)).ravel()
        X[4:8, i + 1] /= np.linalg.norm(X[4:8, i + 1])
    return X, U, T


def solve(fall: Fall, x0, t0: float, problem: str, guess) -> dict:
    """One problem (the module docstring) from x0 at t0 s after the failure."""
    vp = fall.vp
    X0, U0, T0 = guess
    opti = ca.Opti()
    X, U, T, s = opti.variable(15, N + 1), opti.variable(4, N), opti.variable(), opti.variable()
    h = T / N
    opti.subject_to(X[:, 0] == x0)
    opti.subject_to(opti.bounded(0.2, T, 4.0))
    rate_m, rate_s = vp.motor_rate_limit_pct_s, vp.servo_rate_limit_rad_s
    tm, ts = vp.motor_time_constant_s, vp.servo_time_constant_s
    for i in range(N):
        opti.subject_to(X[:, i + 1] == fall.rk4(X[:, i], U[:, i], t0 + i * h, h))
        opti.subject_to(opti.bounded(-rate_m * tm, U[0:2, i] - X[11:13, i], rate_m * tm))
        opti.subject_to(opti.bounded(-rate_s * ts, U[2:4, i] - X[13:15, i], rate_s * ts))
        opti.subject_to(opti.bounded(vp.idle_pct, U[0:2, i], 100.0))
        opti.subject_to(opti.bounded(vp.tilt_min_rad, U[2:4, i], vp.tilt_max_rad))
        opti.subject_to(opti.bounded(-GYRO_RAD_S, X[8:11, i + 1], GYRO_RAD_S))
    cos = [1 - 2 * (X[5, i] ** 2 + X[6, i] ** 2) for i in range(N + 1)]
    for i in range(1, N):
        opti.subject_to(X[0, i] <= GROUND_M)            # in the air until the end
    opti.subject_to(X[0, N] == GROUND_M)
    for i in range(1, N + 1):
        opti.subject_to(cos[i] >= s)
    if problem == "upright":
        opti.minimize(-s)
    else:
        opti.subject_to(s >= 0.0)
        if problem == "standing":
            opti.subject_to(cos[N] >= math.cos(math.radians(TIP_OVER_DEG)))
        opti.minimize(X[3, N] + 1e-4 * ca.sumsqr(U[2:4, :]))
    opti.set_initial(X, X0)
    opti.set_initial(U, U0)
    opti.set_initial(T, T0)
    opti.set_initial(s, min(_cos_tilt(X0[:, i]) for i in range(1, N + 1)))
    opti.solver("ipopt", {"print_time": False, "expand": True},
                {"print_level": 0, "max_iter": 2000,
                 "tol": 1e-6, "acceptable_tol": 1e-4})
    try:
        sol = opti.solve()
        ok, Xv, Uv, Tv = True, sol.value(X), sol.value(U), float(sol.value(T))
    except RuntimeError:
        ok, Xv, Uv, Tv = (False, opti.debug.value(X), opti.debug.value(U),
                          float(opti.debug.value(T)))
    c = [_cos_tilt(Xv[:, i]) for i in range(N + 1)]
    chk = check(fall, x0, t0, Uv, Tv)
    return {"problem": problem, "converged": ok,
            "max_tilt_deg": round(math.degrees(math.acos(max(-1.0, min(c[1:])))), 1),
            "touchdown_m_s": round(float(Xv[3, N]), 2),
            "touchdown_tilt_deg": round(math.degrees(math.acos(max(-1.0, min(1.0, c[N])))), 1),
            "fall_s": round(t0 + Tv, 3),
            "max_spin_rad_s": round(float(np.max(np.abs(Xv[10, :]))), 1),
            "mean_throttle_pct": round(float(np.mean(Uv[0:2, :])), 1),
            **chk, "_sol": (Xv, Uv, Tv)}


_CHECK: dict = {}


def check(fall: Fall, x0, t0: float, U, T: float) -> dict:
    """The commands U (4 x N, each held T / N s) rolled out from x0 at t0 in 1 ms RK4 steps until
    the fall's end: the largest tilt, the touchdown's speed and tilt (interpolated at the
    ground), or the tilt and height when the commands run out in the air."""
    if "step" not in _CHECK:
        xs, us, ts = ca.SX.sym("x", 15), ca.SX.sym("u", 4), ca.SX.sym("t")
        _CHECK["step"] = ca.Function("c", [xs, us, ts], [fall.rk4(xs, us, ts, 1e-3)])
    step = _CHECK["step"]
    x = np.asarray(x0, float)
    worst, h = 1.0, T / N
    for i in range(int(math.ceil(T / 1e-3)) + 200):
        k = min(int(i * 1e-3 / h), N - 1)
        x_new = np.asarray(step(x, U[:, k], t0 + i * 1e-3)).ravel()
        x_new[4:8] /= np.linalg.norm(x_new[4:8])
        worst = min(worst, _cos_tilt(x_new))
        if x_new[0] >= GROUND_M:
            a = (GROUND_M - x[0]) / (x_new[0] - x[0])
            xt = x + a * (x_new - x)
            xt[4:8] /= np.linalg.norm(xt[4:8])
            return {"check_max_tilt_deg": round(math.degrees(math.acos(max(-1.0, worst))), 1),
                    "check_touchdown_m_s": round(float(xt[3]), 2),
                    "check_touchdown_tilt_deg": round(math.degrees(math.acos(
                        max(-1.0, min(1.0, _cos_tilt(xt))))), 1)}
        x = x_new
    return {"check_max_tilt_deg": round(math.degrees(math.acos(max(-1.0, worst))), 1),
            "check_touchdown_m_s": None, "check_height_left_m": round(GROUND_M - x[0], 2)}


def initial_states(fall: Fall):
    """(name, x0, t0): the held hovers, then the flown states at the detection."""
    for delay in DELAYS_S:
        yield f"held {delay:.2f} s", fall.held(delay), delay
    flown = json.loads((Path(__file__).resolve().parent
                        / "adjacent_detected_states.json").read_text())
    for st in flown["states"]:
        yield f"flown seed {st['seed']}", np.asarray(st["x"], float), float(st["t_s"])


def main() -> None:
    vp = load_sim(trq_params.DIR / "sim" / "default.yaml").vehicle
    fall = Fall(vp)
    for name, x0, t0 in initial_states(fall):
        w = np.linalg.norm(x0[8:11])
        print(f"# {name}: at {t0:.2f} s tilted {math.degrees(math.acos(_cos_tilt(x0))):.1f} deg, "
              f"turning {w:.2f} rad/s, falling {x0[3]:.2f} m/s", flush=True)
        best = None
        for start in STARTS:
            up = solve(fall, x0, t0, "upright", _guess(fall, x0, t0, start))
            print({"state": name, "start": start,
                   **{k: v for k, v in up.items() if not k.startswith("_")}}, flush=True)
            if up["converged"] and (best is None or up["max_tilt_deg"] < best["max_tilt_deg"]):
                best = up
        if best is not None and best["max_tilt_deg"] <= 90.0:
            for p in ("slowest", "standing"):
                r = solve(fall, x0, t0, p, best["_sol"])
                print({"state": name, "start": "the best upright",
                       **{k: v for k, v in r.items() if not k.startswith("_")}}, flush=True)


if __name__ == "__main__":
    main()
