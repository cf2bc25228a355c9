"""(a) Started on the relaxed hover at 5 m, perturbed (rates 0.1 rad/s and position 0.1 m, 1 sigma
per axis), the point held 3 s; three seeds."""
import json
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); c = SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1)
for seed in range(3):
    r = fly("orbit", seed=seed, seconds=3.0, controller=c)
    print(json.dumps({"delay": 0.0, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
