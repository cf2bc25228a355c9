"""(a) and (b) + (c): from the orbit, and from hover with the commands held 20 and 50 ms, to
touchdown; `python landing.py N` for N seeds."""
import json, sys
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); c = SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1)
for scen, d in (("orbit", 0.0), ("hover", 0.02), ("hover", 0.05)):
    for seed in range(int(sys.argv[1]) if len(sys.argv) > 1 else 3):
        r = fly(scen, seed=seed, seconds=16.0, land=True, switch_delay_s=d, controller=c)
        print(json.dumps({"delay": d, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
