"""The plant heavier or weaker than the controller's model (the envelope's cases), hover, the
hover commands held 20 ms, the switch, the landing; seed 0."""
import json
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); c = SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1)
for plant in ({"mass_scale": 1.05}, {"mass_scale": 1.1}, {"thrust_scale": 0.95},
              {"thrust_scale": 0.9}, {"thrust_scale": 0.85}):
    r = fly("hover", seed=0, seconds=16.0, switch_delay_s=0.02, controller=c, land=True, plant=plant)
    print(json.dumps({"plant": plant, "delay": 0.02, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
