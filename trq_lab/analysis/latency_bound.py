#!/usr/bin/env python3
"""How well could ANY controller have flown a motor fault, given how late it can react?

    trq-latency-bound out/paper_fault50/trq_nmpc_eso --latency-ms 0,10,20,40,50

A lower bound on the position error after a fault, from a flight's logs (flight.csv and
controller.csv of a scenario run or of trq_lab.harness): the best flight an optimiser finds
for the plant from the vehicle's true state at the fault's onset, knowing the fault exactly and at
once, whose commands are frozen at the ones being flown for the first `latency` seconds (the time
a controller needs to see the fault and have its answer reach the actuators: over a link, its round
trip plus one control period) and free afterwards. Everything is in its favour:

- the plant's model without noise, with the fault's exact size and onset, the wind exactly;
- its actuators are the plant's first-order lags and rate limits: each optimiser step (10 ms)
  reaches any output that a target in the throttle or tilt range reaches through the exact lag,
  at most rate x step away, with the fault's factor on the faulted motor's range; during the
  latency the outputs follow the plant's own per-tick update; the thrust curve is not clamped at
  zero (a little more than the plant can do);
- a new target every step and no lost message; yaw within `--max-yaw-err-deg` of the reference
  (the task) and roll and pitch within 80 deg (off the Euler singularity), nothing else;
- the error counts only inside the window (`--horizon-s` from the onset); the flight's other
  after-fault samples count as zero.

So the RMSE it prints, over as many 10 ms samples as the flight had after its fault, bounds what
a controller of any kind (not only an NMPC with an observer) could have achieved on that flight
with that reaction time, up to the optimiser's reach: IPOPT, started from the flown flight, finds
a local optimum, at or above the global one. Read the other way, it is a flight the plant can fly
(with the fault known) in the window. Against it the tool prints the flown flight's own RMSE, and
its RMSE counting only the window.

With `--objective tilt` (a motor lost whole, where no controller holds yaw or the point) the same
optimiser, on the same frozen-then-free flight, minimises the largest tilt of the thrust axis
over the window instead (`--horizon-s` 1 s by default), with any yaw and no bound on the sink:
how far over the airframe must go, at least, before an answer that acts `L` after the loss can
stop it; against it the flown flight's largest tilt in that window. A dead motor's output is
not a decision: it runs down as the plant's does.

    trq-latency-bound out/motor1_lost/trq_nmpc_eso_lost --objective tilt --latency-ms 0,20,50

Pure function of the logs: no clock, no randomness.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from sil_vehicle.config import load_vehicle
from sil_vehicle.dynamics.actuators import first_order_step, lag_factor
from trq_lab import metrics as metrics_mod
from trq_offboard.config import load_vehicle_model
from trq_offboard.model.dynamics import PredictionModel, euler_rate_matrix

SAMPLE_S = 0.01      # s, the controller's sample period (the metric's samples)


class LogError(Exception):
    """A flight's logs that cannot give a bound (missing, or no fault in them)."""


@dataclass(frozen=True)
class Onset:
    """The flight at the fault's onset and what the bound needs from its logs."""
    t0_us: int
    x0: np.ndarray             # 12: position, velocity (NED), Euler ZYX, body rates
    y0: np.ndarray             # 8: tilt outputs (rad), throttle outputs (% as produced)
    cmd0: np.ndarray           # 8: the command being flown (tilts, throttles)
    factors: np.ndarray        # 4: motor factors after the onset
    wind: np.ndarray           # 3: NED, m/s
    ref_t: np.ndarray          # s from the onset, controller samples
    ref_pos: np.ndarray        # (n, 3)
    ref_yaw: np.ndarray        # (n,) rad, unwrapped
    flown_t: np.ndarray        # s from the onset, truth rows (for the optimiser's first guess)
    flown_x: np.ndarray        # (m, 20): the flown state and actuator outputs at those rows
    flown_err: np.ndarray      # position error of the flown samples after the onset

    @property
    def n_after(self) -> int:
        """Controller samples after the onset (the metric's count)."""
        return len(self.flown_err)


def read_onset(log_dir: Path) -> Onset:
    _, truth = metrics_mod.read_csv(log_dir / "flight.csv")
    _, steps = metrics_mod.read_csv(log_dir / "controller.csv")
    fac = np.column_stack([truth[f"motor{i}_factor"] for i in range(1, 5)])
    changed = np.flatnonzero(np.any(fac < 1.0 - 1e-12, axis=1))
    if not len(changed):
        raise LogError(f"{log_dir}/flight.csv: no motor fault in this flight (every "
                       "motor*_factor is 1)")
    i0 = int(changed[0])
    if np.any(np.abs(fac[i0:] - fac[i0]) > 1e-9):
        raise LogError(f"{log_dir}/flight.csv: the motor factors change after the onset at row "
                       f"{i0} (a time-varying, cleared or second fault): the bound takes one "
                       "constant motor fault")
    stuck = [f"servo{i}_stuck" for i in range(1, 5) if np.any(truth[f"servo{i}_stuck"] > 0.5)]
    if stuck:
        raise LogError(f"{log_dir}/flight.csv: {', '.join(stuck)} set: the bound models motor "
                       "faults only")
    t_us = truth["t_us"].astype(np.int64)
    # the onset: the row before the first faulted one (a row holds the state after its tick;
    # the fault acts from the next tick on, so the state of that row is the one at the onset)
    j = max(i0 - 1, 0)
    t0 = int(t_us[j])
    sm = metrics_mod.samples(truth, steps)          # the metric's samples
    sel = sm.t_us >= t0
    if not sel.any():
        raise LogError(f"{log_dir}/controller.csv: no controller sample after the fault")
    err = np.linalg.norm(sm.pos[sel] - sm.ref[sel], axis=1)
    cols = ("pos_n_m", "pos_e_m", "pos_d_m", "vel_n_m_s", "vel_e_m_s", "vel_d_m_s", "roll_rad",
            "pitch_rad", "yaw_rad", "rate_p_rad_s", "rate_q_rad_s", "rate_r_rad_s")
    flown = np.column_stack([truth[c][j:] for c in cols]
                            + [truth[f"out_tilt{i}_rad"][j:] for i in range(1, 5)]
                            + [truth[f"out_throttle{i}_pct"][j:] for i in range(1, 5)])
    flown[:, 8] = np.unwrap(flown[:, 8])
    cmd0 = np.array([truth[f"cmd_tilt{i}_rad"][j] for i in range(1, 5)]
                    + [truth[f"cmd_throttle{i}_pct"][j] for i in range(1, 5)])
    wind = np.array([truth[f"wind_{a}_m_s"][j] for a in "ned"])
    ref_yaw = np.unwrap(steps["ref_yaw_rad"][sm.keep][sel])
    ref_yaw += 2.0 * math.pi * round((flown[0, 8] - ref_yaw[0]) / (2.0 * math.pi))   # nearest turn
    return Onset(t0, flown[0, 0:12].copy(), flown[0, 12:20].copy(), cmd0, fac[i0], wind,
                 (sm.t_us[sel] - t0) * 1e-6, sm.ref[sel], ref_yaw, (t_us[j:] - t0) * 1e-6,
                 flown, err)


def _dynamics(model: PredictionModel, h: float):
    """One RK4 step of h: F(x20, v8, wind) -> x20. The prediction model's rigid body and rotors
    with the drag on the air-relative velocity (as the plant's), and the actuator outputs y as
    states whose rates v are the decision."""
    x = ca.SX.sym("x", 20)
    v = ca.SX.sym("v", 8)
    wind = ca.SX.sym("wind", 3)
    rb, y = x[0:12], x[12:20]
    # the model's accelerations; only its drag term reads the velocity: give it the airspeed
    u = y if model.tilting else y[4:8]         # a locked airframe's model takes throttles only
    acc = model._accel(ca.vertcat(rb[0:3], rb[3:6] - wind, rb[6:12]), model.wrench(u))
    xdot = ca.vertcat(rb[3:6], acc[0:3], euler_rate_matrix(rb[6], rb[7]) @ rb[9:12], acc[3:6],
                      v)
    f = ca.Function("f", [x, v, wind], [xdot])
    k1 = f(x, v, wind)
    k2 = f(x + h / 2 * k1, v, wind)
    k3 = f(x + h / 2 * k2, v, wind)
    k4 = f(x + h * k3, v, wind)
    return ca.Function("F", [x, v, wind], [x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)])


def _plant_outputs(y: np.ndarray, target: np.ndarray, tau: np.ndarray, rate: np.ndarray,
                   lo: np.ndarray, hi: np.ndarray, dt: float, tick_s: float) -> np.ndarray:
    """The plant's actuator outputs after dt towards a held target: its own per-tick update
    (sil_vehicle.dynamics.actuators: exact lag, rate limit per tick, limits)."""
    y = [float(v) for v in y]
    n = int(round(dt / tick_s))
    for i in range(len(y)):
        f = lag_factor(float(tau[i]), tick_s)
        for _ in range(n):
            y[i] = first_order_step(y[i], float(target[i]), f, float(rate[i]) * tick_s,
                                    float(lo[i]), float(hi[i]))
    return np.array(y)


@dataclass
class _Problem:
    """The optimal flight's problem before its objective: the frozen part flown, the free part's
    variables and the plant's constraints on them."""
    opti: ca.Opti
    X: ca.MX                  # 20 x (m + 1): the free part's states and actuator outputs
    V: ca.MX                  # 8 x m: the outputs' rates
    frozen: np.ndarray        # (n_lat + 1, 20): the frozen part, through the plant's update
    ref: np.ndarray           # (n + 1, 3) the reference at the optimiser's steps
    yaw_ref: np.ndarray       # (n + 1,)
    rate: np.ndarray          # 8: the outputs' rate limits
    n_lat: int
    m: int
    every: int


def _problem(onset: Onset, vehicle_file: Path, latency_s: float, horizon_s: float,
             step_s: float, tick_s: float) -> _Problem:
    vm = load_vehicle_model(vehicle_file)
    model = PredictionModel(vm)
    dt = step_s
    F = _dynamics(model, dt)
    n = int(round(horizon_s / dt))
    n_lat = int(math.ceil(latency_s / dt - 1e-9))
    tau = np.array([vm.servo_time_constant_s] * 4 + [vm.motor_time_constant_s] * 4)
    rate = np.array([vm.servo_rate_limit_rad_s] * 4 + [vm.motor_rate_limit_pct_s] * 4)
    tau_step = dt / -np.expm1(-dt / tau)        # (target - y) = tau_step * (mean rate)
    t_lo, t_hi = (0.0, 0.0) if vm.tilt_locked else (vm.tilt_min_rad, vm.tilt_max_rad)
    lo = np.array([t_lo] * 4 + list(vm.idle_pct * onset.factors))
    hi = np.array([t_hi] * 4 + list(100.0 * onset.factors))
    target0 = np.concatenate([np.clip(onset.cmd0[:4], t_lo, t_hi),
                              np.clip(onset.cmd0[4:], vm.idle_pct, 100.0) * onset.factors])
    ref = np.column_stack([np.interp(np.arange(n + 1) * dt, onset.ref_t, onset.ref_pos[:, a])
                           for a in range(3)])
    yaw_ref = np.interp(np.arange(n + 1) * dt, onset.ref_t, onset.ref_yaw)
    x_init = np.concatenate([onset.x0, onset.y0])

    # the frozen part: the commands being flown, through the plant's own actuator update; the
    # optimiser's outputs move linearly within a step, at the rate that ends where the plant's do
    y_lo = np.array([t_lo] * 4 + [0.0] * 4)
    y_hi = np.array([t_hi] * 4 + [100.0] * 4)
    xs = [x_init]
    for _ in range(n_lat):
        xk = xs[-1]
        y_end = _plant_outputs(xk[12:20], target0, tau, rate, y_lo, y_hi, dt, tick_s)
        xs.append(np.asarray(F(xk, (y_end - xk[12:20]) / dt, onset.wind)).ravel())
    x_free0 = xs[-1]
    m = n - n_lat
    opti = ca.Opti()
    X = opti.variable(20, m + 1)
    V = opti.variable(8, m)
    opti.subject_to(X[:, 0] == x_free0)
    # a dead output (a motor at 0 %: its range is one point) no command moves: it follows the
    # plant's own update towards that point, rate limited, which the free part is given as is
    dead = [int(i) for i in np.flatnonzero(hi - lo <= 0.0)]
    live = [int(i) for i in np.flatnonzero(hi - lo > 0.0)]
    y_live = [12 + i for i in live]
    y_dead = [x_free0[12:20]]
    for _ in range(m if dead else 0):
        y_dead.append(_plant_outputs(y_dead[-1], hi, tau, rate, y_lo, y_hi, dt, tick_s))
    for k in range(m):
        opti.subject_to(X[:, k + 1] == F(X[:, k], V[:, k], onset.wind))
        for i in dead:
            opti.subject_to(V[i, k] == float((y_dead[k + 1][i] - y_dead[k][i]) / dt))
        # the outputs a step can reach: towards any target in [lo, hi] through the exact lag
        # (y + (target - y)(1 - exp(-dt/tau))), at most rate * dt
        opti.subject_to(opti.bounded(-rate[live], V[live, k], rate[live]))
        opti.subject_to(opti.bounded(lo[live], X[y_live, k] + tau_step[live] * V[live, k],
                                     hi[live]))
    # first guess: the flown flight (state and actuator outputs), its output rates
    t_free = (n_lat + np.arange(m + 1)) * dt
    guess = np.column_stack([np.interp(t_free, onset.flown_t, onset.flown_x[:, c])
                             for c in range(20)]).T
    guess[:, 0] = x_free0
    opti.set_initial(X, guess)
    opti.set_initial(V, np.clip(np.diff(guess[12:20], axis=1) / dt, -rate[:, None],
                                rate[:, None]))
    return _Problem(opti, X, V, np.array(xs), ref, yaw_ref, rate, n_lat, m,
                    int(round(SAMPLE_S / dt)))


def _solve(p: _Problem) -> tuple[np.ndarray, str]:
    p.opti.solver("ipopt", {"print_time": False, "expand": True},
                  {"print_level": 0, "sb": "yes", "max_iter": 3000, "tol": 1e-8,
                   "acceptable_tol": 1e-6})
    try:
        sol = p.opti.solve()
        status = "optimal"
    except RuntimeError:
        sol = p.opti.debug
        status = f"not converged ({p.opti.stats().get('return_status')})"
    return np.asarray(sol.value(p.X)), status


def bound(onset: Onset, vehicle_file: Path, latency_s: float, horizon_s: float,
          max_yaw_err_rad: float, max_tilt_rad: float = math.radians(80.0),
          step_s: float = SAMPLE_S, tick_s: float = 0.001,
          effort_weight: float = 1e-9) -> dict:
    """The least position error after the fault: yaw held within max_yaw_err_rad of the
    reference, roll and pitch within max_tilt_rad."""
    p = _problem(onset, vehicle_file, latency_s, horizon_s, step_s, tick_s)
    opti, X, V, n_lat = p.opti, p.X, p.V, p.n_lat
    cost = 0
    for k in range(p.m):
        e = X[0:3, k + 1] - p.ref[n_lat + k + 1]
        # keep yaw (the task), and roll and pitch off the Euler singularity (80 deg: no crash)
        opti.subject_to(opti.bounded(-max_yaw_err_rad, X[8, k + 1] - p.yaw_ref[n_lat + k + 1],
                                     max_yaw_err_rad))
        opti.subject_to(opti.bounded(-max_tilt_rad, X[6:8, k + 1], max_tilt_rad))
        cost += ca.sumsqr(e) + effort_weight * ca.sumsqr(V[:, k] / p.rate)
    opti.minimize(cost)
    Xs, status = _solve(p)
    frozen = p.frozen
    traj = np.concatenate([frozen[:, 0:3], Xs[0:3, 1:].T], axis=0)   # n + 1 samples
    err = np.linalg.norm(traj - p.ref, axis=1)
    window = err[p.every::p.every]          # the samples after the onset inside the window
    down = traj[:, 2] - p.ref[:, 2]
    rmse = math.sqrt(float(np.sum(window ** 2)) / onset.n_after)
    ang = np.concatenate([frozen[:, 6:8], Xs[6:8, 1:].T], axis=0)
    return {"latency_ms": latency_s * 1e3, "status": status, "rmse_lower_bound_m": rmse,
            "max_err_m": float(window.max()), "max_sink_m": float(max(0.0, down.max())),
            "max_tilt_deg": float(np.degrees(np.abs(ang).max())),
            "iterations": int(opti.stats().get("iter_count", -1)),
            "states": Xs, "frozen": frozen}


def euler_tilt_deg(roll: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """The body z axis' angle from the vertical (deg) for ZYX Euler roll and pitch: yaw-free,
    the quantity of trq_lab.metrics.thrust_tilt_deg (which reads a truth log's quaternion), for
    the optimiser's Euler states."""
    return np.degrees(np.arccos(np.clip(np.cos(roll) * np.cos(pitch), -1.0, 1.0)))


def tilt_bound(onset: Onset, vehicle_file: Path, latency_s: float, horizon_s: float,
               max_euler_rad: float = math.radians(85.0), step_s: float = SAMPLE_S,
               tick_s: float = 0.001, drift_weight: float = 1e-3) -> dict:
    """The least largest tilt of the thrust axis after the fault, any yaw (a lost motor's
    answer gives yaw up): maximise the smallest cos(roll) cos(pitch) over the window, with a
    small weight on the drift from the onset's point that picks, among the flights with that
    peak, one that stays near. Roll and pitch within max_euler_rad (off the Euler singularity):
    a bound that needs more is reported not converged."""
    p = _problem(onset, vehicle_file, latency_s, horizon_s, step_s, tick_s)
    opti, X = p.opti, p.X
    c = opti.variable()                        # cos of the largest tilt in the free part
    drift = 0
    for k in range(p.m):
        opti.subject_to(ca.cos(X[6, k + 1]) * ca.cos(X[7, k + 1]) >= c)
        opti.subject_to(opti.bounded(-max_euler_rad, X[6:8, k + 1], max_euler_rad))
        drift += ca.sumsqr(X[0:2, k + 1] - onset.x0[0:2]) / p.m
    opti.minimize(-c + drift_weight * drift)
    frozen_cos = np.cos(p.frozen[:, 6]) * np.cos(p.frozen[:, 7])
    opti.set_initial(c, float(frozen_cos.min()))
    Xs, status = _solve(p)
    ang = np.concatenate([p.frozen[:, 6:8], Xs[6:8, 1:].T], axis=0)
    tilt = euler_tilt_deg(ang[:, 0], ang[:, 1])
    traj = np.concatenate([p.frozen[:, 0:3], Xs[0:3, 1:].T], axis=0)
    drift_m = np.linalg.norm(traj[:, 0:2] - onset.x0[0:2], axis=1)
    return {"latency_ms": latency_s * 1e3, "status": status,
            "max_tilt_deg": float(tilt.max()),
            "tilt_at_answer_deg": float(tilt[p.n_lat]),
            "peak_s": float(np.argmax(tilt) * step_s),
            "max_drift_m": float(drift_m.max()),
            "sink_m": float(traj[-1, 2] - onset.x0[2]),
            "yaw_rate_end_rad_s": float(Xs[11, -1]),
            "iterations": int(opti.stats().get("iter_count", -1)),
            "states": Xs, "frozen": p.frozen, "tilt_deg": tilt}


# the command's numeric options: (default, what it sets)
NUMBER_OPTIONS = {
    "--max-yaw-err-deg": (5.0, "the yaw error the optimal flight may not exceed (without it a "
                               "spinning vehicle is the best answer to a motor loss)"),
    "--step-ms": (10.0, "the optimiser's RK4 step, a divisor of 10 ms"),
    "--horizon-s": (None, "window after the onset the optimiser flies (default 4 s for the "
                          "position, 1 s for the tilt)"),
}
HORIZON_S = {"position": 4.0, "tilt": 1.0}


def _print_tilt(args, onset: Onset, vehicle_file: Path, lat: list[float], tick_s: float) -> None:
    """The tilt objective's table, against the flown flight's largest tilt in the window."""
    rows = onset.flown_t <= args.horizon_s + 1e-9
    flown = euler_tilt_deg(onset.flown_x[rows, 6], onset.flown_x[rows, 7])
    print(f"flight {args.log_dir}: fault at {onset.t0_us * 1e-6:.3f} s, motor factors "
          f"{onset.factors.tolist()}, wind {onset.wind.round(2).tolist()} m/s")
    print(f"flown: largest tilt of the thrust axis in the first {args.horizon_s:g} s "
          f"{flown.max():.1f} deg, at {onset.flown_t[rows][int(np.argmax(flown))]:.2f} s")
    print("| latency ms | lower bound on the largest tilt deg | at s | tilt when the answer "
          "acts deg | its drift m | its sink m | IPOPT |")
    print("|---|---|---|---|---|---|---|")
    for L in lat:
        r = tilt_bound(onset, vehicle_file, L, args.horizon_s, step_s=args.step_ms * 1e-3,
                       tick_s=tick_s)
        print(f"| {r['latency_ms']:.0f} | {r['max_tilt_deg']:.1f} | {r['peak_s']:.2f} | "
              f"{r['tilt_at_answer_deg']:.1f} | {r['max_drift_m']:.2f} | {r['sink_m']:.2f} | "
              f"{r['status']}, {r['iterations']} it |", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="trq-latency-bound", description=__doc__.splitlines()[0])
    ap.add_argument("log_dir", type=Path, help="a flight's directory (flight.csv, controller.csv)")
    ap.add_argument("--latency-ms", default="0,10,20,30,40,50",
                    help="comma-separated reaction latencies (default %(default)s)")
    ap.add_argument("--objective", choices=sorted(HORIZON_S), default="position",
                    help="position: the least position RMSE after the fault, yaw held; tilt: "
                         "the least largest tilt of the thrust axis, any yaw (a lost motor) "
                         "(default %(default)s)")
    for flag, (default, text) in NUMBER_OPTIONS.items():
        ap.add_argument(flag, type=float, default=default,
                        help=text if default is None else f"{text} (default %(default)s)")
    args = ap.parse_args(argv)
    if args.horizon_s is None:
        args.horizon_s = HORIZON_S[args.objective]
    try:
        lat = [float(s) * 1e-3 for s in args.latency_ms.split(",") if s.strip()]
    except ValueError:
        print(f"latency_bound: --latency-ms {args.latency_ms!r}: expected numbers in ms, "
              "comma-separated", file=sys.stderr)
        return 2
    per_sample = SAMPLE_S * 1e3 / args.step_ms if args.step_ms > 0 else 0.0
    if per_sample < 1.0 or abs(per_sample - round(per_sample)) > 1e-9:
        print(f"latency_bound: --step-ms {args.step_ms:g}: expected a divisor of "
              f"{SAMPLE_S * 1e3:g} ms (10, 5, 2, ...)", file=sys.stderr)
        return 2
    if not 0.0 < args.horizon_s <= 60.0:
        print(f"latency_bound: --horizon-s {args.horizon_s:g}: expected a window in (0, 60] s",
              file=sys.stderr)
        return 2
    if any(v < 0 or v >= args.horizon_s for v in lat) or not lat:
        print(f"latency_bound: --latency-ms {args.latency_ms!r}: each must be in "
              f"[0, {args.horizon_s * 1e3:.0f}) ms (the window)", file=sys.stderr)
        return 2
    try:
        for name in ("flight.csv", "controller.csv"):
            if not (args.log_dir / name).is_file():
                raise LogError(f"{args.log_dir / name}: not found (a flight's directory from "
                               "trq-scenario or trq_lab.harness is expected)")
        meta, _ = metrics_mod.read_csv(args.log_dir / "flight.csv")
        vehicle_file = Path(load_vehicle(meta["vehicle_file"]).file)
        onset = read_onset(args.log_dir)
    except LogError as exc:
        print(f"latency_bound: {exc}", file=sys.stderr)
        return 2
    tick_s = 1.0 / float(meta["physics_rate_hz"])
    if args.objective == "tilt":
        _print_tilt(args, onset, vehicle_file, lat, tick_s)
        return 0
    win = onset.ref_t <= args.horizon_s + 1e-9
    flown = math.sqrt(float(np.mean(onset.flown_err ** 2)))
    flown_win = math.sqrt(float(np.sum(onset.flown_err[win] ** 2)) / onset.n_after)
    print(f"flight {args.log_dir}: fault at {onset.t0_us * 1e-6:.3f} s, motor factors "
          f"{onset.factors.tolist()}, wind {onset.wind.round(2).tolist()} m/s, "
          f"{onset.n_after} samples after the onset")
    print(f"flown: RMSE after the fault {flown:.4f} m; counting only the first "
          f"{args.horizon_s:g} s: {flown_win:.4f} m")
    print("| latency ms | lower bound on the RMSE after the fault m | max error m | max sink m "
          "| max roll/pitch deg | IPOPT |")
    print("|---|---|---|---|---|---|")
    for L in lat:
        r = bound(onset, vehicle_file, L, args.horizon_s, math.radians(args.max_yaw_err_deg),
                  step_s=args.step_ms * 1e-3, tick_s=tick_s)
        print(f"| {r['latency_ms']:.0f} | {r['rmse_lower_bound_m']:.4f} | {r['max_err_m']:.3f} | "
              f"{r['max_sink_m']:.3f} | {r['max_tilt_deg']:.1f} | {r['status']}, "
              f"{r['iterations']} it |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
