"""The orbit held and the transition (20 ms) in a mean wind of 4 and 8 m/s, with and without the
simulation file's gusts; the controller's trim is calm air's."""
import json
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); c = SpinController(cfg, load_vehicle_model(cfg.vehicle_file), 1)
for wind in (4.0, 8.0):
    for gusts in (False, True):
        for scen, d in (("hover", 0.02),):
            r = fly(scen, seed=0, seconds=14.0, switch_delay_s=d, controller=c, wind_m_s=wind, gusts=gusts, land=True)
            print(json.dumps({"wind": wind, "gusts": gusts, "delay": d, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
