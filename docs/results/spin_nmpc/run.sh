#!/bin/sh
# The runs of docs/decisions/2026-12-05-spin-nmpc.md, from the repository root (each writes its
# JSON lines beside it). The campaign: trq-campaign docs/decisions/studies/spin_nmpc.yaml.
set -e
cd "$(dirname "$0")"
PY=${PY:-../../../.venv/bin/python}
$PY flights.py transition > transition.jsonl
$PY flights.py landing > landing.jsonl
$PY flights.py step > step.jsonl
