#!/bin/sh
# The figures of docs/decisions/2026-12-05-lost-motor-envelope.md: every trq-envelope --spin run,
# its JSON beside this file, the printed lines in summary.txt. Run from this folder:
#   sh run.sh > summary.txt 2>&1
set -u
E="${TRQ_ENVELOPE:-trq-envelope}"
$E --spin --motor 1 --eff 0 --sweep --simulate 2 --json motor1_best.json
$E --spin --motor 1 --eff 0 --spin-rate 20 --simulate 2 --json motor1_spin20.json
$E --spin --motor 1 --eff 0 --spin-rate 15 --simulate 2 --json motor1_spin15.json
$E --spin --motor 1 --eff 0 --spin-rate 0 --json motor1_static.json
$E --spin --motor 1 --eff 0 --objective power --json motor1_power.json
for w in 4 8; do
  $E --spin --motor 1 --eff 0 --spin-rate 20 --wind $w --simulate 2 --json motor1_spin20_wind$w.json
  $E --spin --motor 1 --eff 0 --wind $w --simulate 2 --json motor1_best_wind$w.json
done
$E --spin --motor 1 --motor 3 --eff 0 --sweep --simulate 2 --json motors13_adjacent.json
$E --spin --motor 1 --motor 3 --eff 0 --descent-margin 0.1 --json motors13_adjacent_margin10.json
$E --spin --motor 1 --motor 2 --eff 0 --sweep --simulate 2 --json motors12_opposite.json
$E --spin --motor 1 --motor 2 --eff 0 --descent-margin 0.1 --json motors12_opposite_margin10.json
$E --vehicle quad --spin --motor 1 --eff 0 --sweep --json quad_motor1.json
for m in 2 3 4; do $E --spin --motor $m --eff 0 --spin-rate 20 --json motor${m}_spin20.json; done
# the plant perturbed as a campaign's plants are (trq_lab/overlays.py)
for p in mass_scale=1.05 mass_scale=1.1 thrust_scale=0.95 thrust_scale=0.9 thrust_scale=0.85; do
  $E --spin --motor 1 --eff 0 --plant $p --json motor1_best_$(echo $p | tr '=' '_').json
done
