#!/usr/bin/env bash
# Two motors lost (issue 40), on seeds: motors12_lost (opposite) and motors13_lost (adjacent),
# trq_nmpc_eso_lost on seeds 1..20 and trq_nmpc_eso, quad_nmpc on seeds 1..3, each flight
# `trq-inprocess` on a copy of the scenario with its `seed` set (a campaign's fault is one motor).
# Out: $OUT/<scenario>/s<seed>/metrics.json (and the flights' logs); summary.py writes
# flights.csv and summary.md beside this script. Record:
# docs/decisions/2026-12-05-lost-motor-on-seeds.md.
#   nice bash docs/results/lost_motor_pairs/run.sh /tmp/l20/pairs
# SCENARIOS and SEEDS choose others (motors12_lost_wind on 5 seeds: lost_motor_pairs_wind/,
# docs/decisions/2026-12-05-lost-motor-axes.md):
#   SCENARIOS=motors12_lost_wind SEEDS="1 2 3 4 5" nice bash .../run.sh /tmp/pairs_wind \
#     docs/results/lost_motor_pairs_wind
set -euo pipefail
REPO=$(cd "$(dirname "$0")/../../.." && pwd)
OUT=${1:-/tmp/lost_motor_pairs}
DEST=${2:-$(dirname "$0")}
SCENARIOS=${SCENARIOS:-motors12_lost motors13_lost}
SEEDS=${SEEDS:-$(seq 1 20)}
PY=${PY:-$REPO/.venv/bin}
mkdir -p "$OUT"
for scenario in $SCENARIOS; do
  for seed in $SEEDS; do
    dir="$OUT/$scenario/s$seed"
    [ -f "$dir/metrics.json" ] && continue
    mkdir -p "$dir"
    sed -e "s/^seed: .*/seed: $seed/" -e "s#\.\./faults/#$REPO/params/faults/#" \
      "$REPO/params/scenarios/$scenario.yaml" > "$dir/$scenario.yaml"
    only=(--only trq_nmpc_eso_lost)
    [ "$seed" -le 3 ] && only+=(--only trq_nmpc_eso --only quad_nmpc)
    # (its exit status is 1 when a flight crashes: every one here does, by the plant's measure)
    "$PY/trq-inprocess" "$dir/$scenario.yaml" --out "$dir" "${only[@]}" > "$dir/log.txt" 2>&1 \
      || true
  done
done
"$PY/python" "$(dirname "$0")/summary.py" "$OUT" "$DEST"
