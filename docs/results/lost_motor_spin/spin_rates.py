"""The transition (hover, motor 1 off, switched 20 and 50 ms later) with the controller built for
other spin rates: the tilts govern the rate to the reference."""
import dataclasses as dc
import json
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg0 = load_spin_config(CONTROLLER_FILE); vm = load_vehicle_model(cfg0.vehicle_file)
for w in (17.0, 20.0, 25.0, 30.0):
    c = SpinController(dc.replace(cfg0, spin_rate_rad_s=w), vm, 1)
    for d in (0.02, 0.05):
        r = fly("hover", seed=0, seconds=3.0, switch_delay_s=d, controller=c)
        print(json.dumps({"spin_ref": w, "delay": d, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
