#!/bin/sh
# The runs of docs/decisions/2026-12-05-lost-motor-spin-controller.md, from the repository root
# (each writes the JSON lines beside it; a few minutes in all on one core).
set -e
cd "$(dirname "$0")"
PY=${PY:-../../../.venv/bin/python}
$PY transition_delay.py > transition_delay.jsonl      # (b) held hover commands, switch delay 0-100 ms
$PY nmpc_before.py > nmpc_before.jsonl                # (b) the NMPC flying through the delay
$PY link_delay.py > link_delay.jsonl                  # a link delay, carried in the LQR
$PY orbit_hold.py > orbit_hold.jsonl                    # (a) the orbit held 3 s, 3 seeds
$PY landing.py 3 > landing.jsonl                      # (a), (b) and (c): to touchdown, 3 seeds
$PY nmpc_before_land.py > nmpc_before_land.jsonl      # (b) + (c) with the NMPC before the switch
$PY measured.py 3 land > measured.jsonl               # on the autopilot's ESKF (mocap profile)
$PY wind.py > wind.jsonl                              # 4 and 8 m/s, with and without gusts
$PY spin_rates.py > spin_rates.jsonl                  # other spin references: 17, 20, 25, 30
$PY -c "import json; from trq_lab.analysis.spin_flight import step_time_ratio; print(json.dumps(step_time_ratio()))" > step_time.json
$PY motors.py > motors.jsonl                          # each motor lost in turn
$PY seeds10.py > seeds10.jsonl                        # 10 seeds, held 20 ms and NMPC 50 ms
$PY plants.py > plants.jsonl                          # the plant heavier or weaker
