"""The whole case: the project's NMPC hovering at 5 m, motor 1 off, the NMPC on for the detection
delay, the switch, the hold, the descent and the touchdown; three seeds (yaw, perturbation)."""
import json
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); c = SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1)
for d in (0.05, 0.1):
    for seed in range(3):
        r = fly("hover", seed=seed, seconds=14.0, switch_delay_s=d, controller=c, nmpc_before_s=2.0,
                land=True)
        print(json.dumps({"delay": d, "nmpc_before": True, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
