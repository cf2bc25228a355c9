"""Each motor lost in turn: hover at 5 m, the hover commands held 20 ms, the switch, the landing."""
import json
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); vm = load_vehicle_model(cfg.vehicle_file)
for motor in (1, 2, 3, 4):
    c = SpinController(cfg, vm, motor)
    r = fly("hover", seed=0, seconds=14.0, motor=motor, switch_delay_s=0.02, controller=c, land=True)
    print(json.dumps({"motor": motor, "delay": 0.02, "trim_throttle_pct": c.trim.throttle_pct, "trim_tilt_rad": c.trim.tilt_rad, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
