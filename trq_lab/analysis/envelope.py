#!/usr/bin/env python3
"""The physical envelope: for an airframe, a motor fault and a wind, the hover trim and the force
and torque margin the actuators have left (an allocation problem under the actuator limits,
solved with CasADi + IPOPT on the simulator's own rotor model).

    trq-envelope [--vehicle params/vehicle/trq.yaml] [--motor 1 --eff 0.5]
                             [--wind 8 --wind-dir 0] [--plant mass_scale=1.03,thrust_scale=0.95]
                             [--json PATH]
    trq-envelope --spin --motor 1 --eff 0 [--motor 2] [--spin-rate 20] [--objective power]
                             [--simulate 2] [--sweep] [--json PATH]

--motor may be given twice (two faulty motors, both at --eff). --spin: the spinning ("relaxed
hover") equilibria instead of the static trim (trq_lab.analysis.spin_envelope).

The trim holds position at constant yaw: roll and pitch are free (a fixed-rotor quadcopter must
lean into the wind), throttles within idle..100 %, tilts within the servo range. The margins are,
for each body axis and sign, how much more force (N) or torque (N m) the actuators can add while
every other component of the wrench keeps its trim value. A negative or missing margin means the
vehicle cannot hold that axis: any reference asking for it cannot be tracked by any controller.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import casadi as ca
import numpy as np
import trq_params

from sil_vehicle.config import VehicleParams, load_vehicle
from sil_vehicle.frames import wind_from_to_ned
from trq_lab.analysis import spin_envelope

AXES = ("Fx", "Fy", "Fz", "Mx", "My", "Mz")


def wrench_expr(alpha, zeta, factors, vp: VehicleParams):
    """Body FRD wrench (6) as a CasADi MX expression (thrust curve without the idle clamp: the
    throttle is kept above idle, where the curve is positive)."""
    return spin_envelope.rotor_wrench_expr(alpha, zeta, factors, vp)


def analyse(vp: VehicleParams, factors: list[float], wind_speed: float, wind_from_deg: float,
            max_tilt_deg: float = 35.0, tilt_fixed_rad: dict[int, float] | None = None) -> dict:
    """The trim and margins (see the module docstring). `tilt_fixed_rad`: rotor index (0..3) ->
    a tilt the rotor cannot leave (a stuck servo)."""
    n_tilt = 0 if vp.tilt_locked else 4
    alpha = ca.MX.sym("alpha", 4) if n_tilt else ca.MX.zeros(4)
    zeta = ca.MX.sym("zeta", 4)
    roll, pitch = ca.MX.sym("roll"), ca.MX.sym("pitch")
    w = wrench_expr(alpha, zeta, factors, vp)
    wind = wind_from_to_ned(wind_speed, wind_from_deg)
    drag_ned = [vp.drag_N_s2_m2 * math.hypot(*wind) * c for c in wind]   # at rest in the wind
    # required body force: the rotors cancel gravity and drag, expressed in the body frame
    need_ned = ca.vertcat(-drag_ned[0], -drag_ned[1], -vp.mass_kg * vp.gravity_m_s2)
    cr, sr, cp, sp = ca.cos(roll), ca.sin(roll), ca.cos(pitch), ca.sin(pitch)
    rot_t = ca.vertcat(ca.horzcat(cp, 0, -sp), ca.horzcat(sr * sp, cr, sr * cp),
                       ca.horzcat(cr * sp, -sr, cr * cp))           # world->body at yaw 0
    need = ca.vertcat(rot_t @ need_ned, ca.MX.zeros(3))
    x = ca.vertcat(*([alpha] if n_tilt else []), zeta, roll, pitch)
    lo_tilt, hi_tilt = vp.tilt_min_rad, vp.tilt_max_rad
    mt = math.radians(max_tilt_deg)
    lbx = [lo_tilt] * n_tilt + [vp.idle_pct] * 4 + [-mt, -mt]
    ubx = [hi_tilt] * n_tilt + [100.0] * 4 + [mt, mt]
    x0 = [0.0] * n_tilt + [vp.hover_throttle_pct] * 4 + [0.0, 0.0]
    for i, angle in (tilt_fixed_rad or {}).items():
        if n_tilt:
            lbx[i] = ubx[i] = x0[i] = float(angle)
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"}
    # 1) the trim: the wrench as close as possible to the need, then the smallest effort
    resid = w - need
    # effort: throttle away from the healthy hover (1 % ~ 0.01 rad), tilts, and body attitude
    effort = (1e-4 * ca.sumsqr(zeta - vp.hover_throttle_pct) + ca.sumsqr(roll) + ca.sumsqr(pitch)
              + (ca.sumsqr(alpha) if n_tilt else 0))
    lsq = ca.nlpsol("lsq", "ipopt", {"x": x, "f": ca.sumsqr(resid) * 1e4 + 1e-3 * effort}, opts)
    sol = lsq(x0=x0, lbx=lbx, ubx=ubx)
    xt = np.array(sol["x"]).ravel()
    residual = np.array(ca.Function("r", [x], [resid])(xt)).ravel()
    feasible = bool(np.max(np.abs(residual)) < 1e-3)
    out = {"vehicle": vp.name, "motor_factors": factors, "wind_m_s": wind_speed,
           "wind_from_deg": wind_from_deg, "feasible": feasible,
           "residual": dict(zip(AXES, residual.round(4).tolist())),
           "trim": {"tilt_deg": np.degrees(xt[:n_tilt]).round(2).tolist(),
                    "throttle_pct": xt[n_tilt:n_tilt + 4].round(2).tolist(),
                    "roll_deg": round(math.degrees(xt[-2]), 2),
                    "pitch_deg": round(math.degrees(xt[-1]), 2)},
           "margin": {}}
    if not feasible:
        return out
    # 2) margins: push one axis at a time with the rest of the wrench held at the trim
    trim_w = np.array(ca.Function("w", [x], [w])(xt)).ravel()
    u_only = ca.vertcat(*([alpha] if n_tilt else []), zeta)
    w_u = ca.substitute(w, ca.vertcat(roll, pitch), ca.DM(xt[-2:]))
    # a fixed-rotor airframe has no body Fx, Fy at all: those axes are not actuated
    actuated = [2, 3, 4, 5] if vp.tilt_locked else list(range(6))
    for j, axis in enumerate(AXES):
        if j not in actuated:
            out["margin"][f"+{axis}"] = out["margin"][f"-{axis}"] = None
            continue
        others = [k for k in actuated if k != j]
        for sign in (+1, -1):
            nlp = {"x": u_only, "f": -sign * w_u[j],
                   "g": ca.vertcat(*[w_u[k] - trim_w[k] for k in others])}
            solver = ca.nlpsol("m", "ipopt", nlp, opts)
            r = solver(x0=xt[:-2], lbx=lbx[:-2], ubx=ubx[:-2], lbg=0, ubg=0)
            ok = solver.stats()["success"]
            value = float(-r["f"]) * sign if ok else math.nan
            out["margin"][f"{'+' if sign > 0 else '-'}{axis}"] = (
                round(sign * (value - trim_w[j]), 4) if ok else None)
    return out


def throttle_margins(out: dict, vp: VehicleParams) -> dict:
    """The trim's throttle margins (percentage points) of an `analyse` result: per motor, how far
    its trim throttle sits from full throttle (up) and from idle (down), and the smallest of all;
    None where there is no trim."""
    if not out["feasible"]:
        return {"up_pct": None, "down_pct": None, "min_pct": None}
    zeta = out["trim"]["throttle_pct"]
    up = [round(100.0 - z, 2) for z in zeta]
    down = [round(z - vp.idle_pct, 2) for z in zeta]
    return {"up_pct": up, "down_pct": down, "min_pct": round(min(up + down), 2)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="trq-envelope", description=__doc__.splitlines()[0])
    ap.add_argument("--vehicle", default="trq",
                    help="airframe: a built-in name (trq, quad) or a vehicle YAML path (default trq)")
    ap.add_argument("--motor", type=int, action="append", default=None,
                    help="faulty motor 1..4 (may be given twice)")
    ap.add_argument("--eff", type=float, default=1.0, help="its effectiveness 0..1")
    ap.add_argument("--wind", type=float, default=0.0, help="wind speed m/s")
    ap.add_argument("--wind-dir", type=float, default=0.0, help="wind from, deg")
    ap.add_argument("--plant", default=None,
                    help="the airframe perturbed as a campaign's plant: KEY=VALUE,... "
                         "(mass_scale, thrust_scale, idle_offset_pct, ...)")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--spin", action="store_true",
                    help="the spinning (relaxed hover) equilibria, for a motor lost")
    ap.add_argument("--objective", choices=("margin", "power"), default="margin",
                    help="--spin: the largest control margin (default) or the least power")
    ap.add_argument("--spin-rate", type=float, default=None,
                    help="--spin: hold this spin rate (rad/s); default: the best up to --max-spin")
    ap.add_argument("--max-spin", type=float, default=None,
                    help="--spin: the largest spin rate searched, rad/s (default: a 2000 deg/s "
                         "gyro's full scale)")
    ap.add_argument("--simulate", type=float, default=0.0, metavar="SECONDS",
                    help="--spin: fly the plant from the equilibrium on constant commands")
    ap.add_argument("--descent-margin", type=float, default=0.0,
                    help="--spin, where no hover exists: the slowest descent keeping every live "
                         "actuator this fraction of its range from its limits (default 0)")
    ap.add_argument("--sweep", action="store_true",
                    help="--spin: the best equilibrium at each of a range of spin rates")
    args = ap.parse_args(argv)
    vehicle_file = trq_params.resolve("vehicle", args.vehicle)
    if args.plant:
        import tempfile

        from trq_lab.overlays import PLANT_PARAMS, write_vehicle_overlay
        plant = {}
        for item in args.plant.split(","):
            key, _, value = item.partition("=")
            try:
                if key not in PLANT_PARAMS:
                    raise ValueError
                plant[key] = float(value)
            except ValueError:
                print(f"envelope: --plant: got {item!r}, expected KEY=NUMBER with KEY one of "
                      + ", ".join(PLANT_PARAMS), file=sys.stderr)
                return 2
        with tempfile.TemporaryDirectory() as tmp:
            try:
                vp = load_vehicle(write_vehicle_overlay(vehicle_file, plant, Path(tmp)))
            except trq_params.ConfigError as exc:
                print(f"envelope: --plant {args.plant}: {exc}", file=sys.stderr)
                return 2
    else:
        vp = load_vehicle(vehicle_file)
    factors = [1.0] * 4
    for motor in args.motor or []:
        if not 1 <= motor <= 4 or not 0.0 <= args.eff <= 1.0 or len(args.motor) > 2:
            print("envelope: --motor 1..4 (at most twice) and --eff 0..1", file=sys.stderr)
            return 2
        factors[motor - 1] = args.eff
    if args.spin:
        return spin_envelope.main_spin(vp, factors, args)
    out = analyse(vp, factors, args.wind, args.wind_dir)
    print(f"envelope of {vp.name}: motor factors {factors}, wind {args.wind:g} m/s from "
          f"{args.wind_dir:g} deg")
    t = out["trim"]
    print(f"  trim {'feasible' if out['feasible'] else 'INFEASIBLE'}: throttle "
          f"{t['throttle_pct']} %, tilt {t['tilt_deg']} deg, roll {t['roll_deg']} deg, "
          f"pitch {t['pitch_deg']} deg; wrench residual {out['residual']}")
    m = throttle_margins(out, vp)
    if m["min_pct"] is not None:
        print(f"  throttle margin: up {m['up_pct']} %, down {m['down_pct']} % (smallest "
              f"{m['min_pct']:g} %)")
    for key, value in out["margin"].items():
        unit = "N" if key[1] == "F" else "N m"
        print(f"  margin {key}: {'none (not actuated or not reachable)' if value is None else f'{value:.3f} {unit}'}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=2) + "\n")
    return 0 if out["feasible"] else 1


if __name__ == "__main__":
    sys.exit(main())
