"""Ten seeds of the whole case, both ways the switch may come: the hover commands held 20 ms,
and the NMPC flying 50 ms; each to touchdown."""
import json
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); c = SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1)
for before, d in (("held", 0.02), ("nmpc", 0.05)):
    for seed in range(10):
        r = fly("hover", seed=seed, seconds=14.0, switch_delay_s=d, controller=c, land=True,
                nmpc_before_s=2.0 if before == "nmpc" else 0.0)
        print(json.dumps({"before": before, "delay": d, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
