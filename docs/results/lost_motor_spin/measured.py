"""The controller on the autopilot's ESKF (mocap profile) instead of the truth: hover, held
20 ms; `python measured.py N [land]`."""
import json, sys
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); vm = load_vehicle_model(cfg.vehicle_file)
c = SpinController(cfg, vm, 1)
land = "land" in sys.argv
for seed in range(int(sys.argv[1])):
    r = fly("hover", seed=seed, seconds=14.0 if land else 3.0, switch_delay_s=0.02, controller=c, measured=True, land=land)
    print(json.dumps({"delay": 0.02, "measured": True, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
