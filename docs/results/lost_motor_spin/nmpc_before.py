"""The transition with the project's NMPC (trq_nmpc_eso, its motor effectiveness observer on)
flying the hover 2 s before the failure and on through the detection delay, then the switch."""
import json
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); c = SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1)
for d in (0.0, 0.02, 0.05, 0.08, 0.1, 0.2, 0.3, 0.5):
    r = fly("hover", seed=0, seconds=3.0, switch_delay_s=d, controller=c, nmpc_before_s=2.0,
            perturb_rates_rad_s=0.0, perturb_pos_m=0.0)
    print(json.dumps({"delay": d, "nmpc_before": True, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
