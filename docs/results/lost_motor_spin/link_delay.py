"""The commands applied 10, 20, 30 ms after the state they answer, the controller built with
`delay_s` equal to it: the orbit, and the transition (held 20 ms)."""
import json, sys
from dataclasses import asdict
from trq_lab.analysis.spin_flight import fly, CONTROLLER_FILE
from trq_offboard.spin import SpinController, load_spin_config
from trq_offboard.config import load_vehicle_model
cfg = load_spin_config(CONTROLLER_FILE); vm = load_vehicle_model(cfg.vehicle_file)
for cd in (0.01, 0.02, 0.03):
  c = SpinController(cfg, vm, 1, delay_s=cd)
  for scen, d in (("orbit", 0.0), ("hover", 0.02)):
    r = fly(scen, seed=0, seconds=3.0, switch_delay_s=d, controller=c, command_delay_s=cd)
    print(json.dumps({"delay": d, "command_delay": cd, **{k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(r).items()}}), flush=True)
