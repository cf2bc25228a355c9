"""The runs of docs/decisions/2026-12-05-spin-nmpc.md in the plant, in one process (truth state,
motor 1 off): the spinning controller with its inner LQR and with its inner NMPC (spin.inner
nmpc, horizon 20, and 40 with three SQP iterations a period), the same flights paired.
    transition  hover commands held 0-100 ms after the failure, then the controller, 3 s, 3 seeds
    landing     held 20 ms, then to touchdown, 10 seeds
    step        CPU time per step against trq_nmpc_eso's (step_time_ratio)"""
import dataclasses
import json
import sys
from dataclasses import asdict

from trq_lab.analysis.spin_flight import CONTROLLER_FILE, fly, step_time_ratio
from trq_offboard.config import load_vehicle_model
from trq_offboard.spin import SpinController, load_spin_config

cfg = load_spin_config(CONTROLLER_FILE)
vm = load_vehicle_model(cfg.vehicle_file)
inner = {"lqr": SpinController(dataclasses.replace(cfg, inner="lqr"), vm, 1),
         "nmpc20": SpinController(dataclasses.replace(cfg, inner="nmpc", horizon_steps=20), vm, 1),
         "nmpc40x3": SpinController(dataclasses.replace(cfg, inner="nmpc", horizon_steps=40),
                                    vm, 1)}
inner["nmpc40x3"]._nmpc.iterations = 3
part = sys.argv[1]


def out(**kw):
    r = kw.pop("r")
    print(json.dumps({**kw, **{k: (round(v, 3) if isinstance(v, float) else v)
                               for k, v in asdict(r).items()}}), flush=True)


if part == "transition":
    for d in (0.0, 0.02, 0.05, 0.08, 0.1):
        for name, c in inner.items():
            for seed in range(3):
                out(inner=name, delay=d, r=fly("hover", seed=seed, seconds=3.0,
                                               switch_delay_s=d, controller=c))
elif part == "landing":
    for name in ("lqr", "nmpc20"):
        for seed in range(10):
            out(inner=name, r=fly("hover", seed=seed, seconds=14.0, switch_delay_s=0.02,
                                  land=True, controller=inner[name]))
elif part == "step":
    for name in ("lqr", "nmpc20"):
        for rep in range(3):
            print(json.dumps({"inner": name, "repeat": rep,
                              **step_time_ratio(controller=inner[name])}), flush=True)
