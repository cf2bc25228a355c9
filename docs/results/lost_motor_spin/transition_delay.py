"""(b) Hover at 5 m on the hover commands, motor 1 off at 0, the commands held until the switch
(0 to 100 ms later); 3 seeds, 3 s each."""
import json
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); c = SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1)
for d in (0.0, 0.01, 0.02, 0.03, 0.05, 0.08, 0.1):
    for seed in range(3):
        r = fly("hover", seed=seed, seconds=3.0, switch_delay_s=d, controller=c)
        print(json.dumps({"delay": d, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
