"""Two motors lost (issue 40), flown by trq_nmpc_eso_lost in one process (trq_lab.harness; about
10 s of wall time each): the pair detector names the pair within 0.2 s of the onset and the failed
NMPC flies the two rotors left. Opposite (motors12_lost, seed 7): an upright descent, touchdown
at no more than the issue's 5.7 m/s (the physics allows 4.12 from 5 m: the plant's 2.5 m/s impact
crash is met by every such flight, and stated as such). Adjacent (motors13_lost): named 1-3; the
vehicle tumbles whatever flies it (docs/decisions/2026-12-05-lost-motor-on-seeds.md)."""

from __future__ import annotations

import csv
import json
import os
import subprocess

import pytest

from conftest import PARAMS, ROOT, cli

pytestmark = pytest.mark.slow      # flies: the full run only

ENV = dict(os.environ)


def _fly(tmp_path, scenario):
    out = tmp_path / scenario
    r = subprocess.run([*cli("trq-inprocess"), str(PARAMS / "scenarios" / f"{scenario}.yaml"),
                        "--out", str(out), "--only", "trq_nmpc_eso_lost"],
                       cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=600)
    assert r.returncode in (0, 1), r.stderr[-3000:]      # 1: the plant's crash, a target missed
    (run,) = json.loads((out / "metrics.json").read_text())["runs"]
    with open(out / "trq_nmpc_eso_lost" / "controller.csv", encoding="ascii") as f:
        codes = {int(row["lost_motor"]) for row in csv.DictReader(
            line for line in f if not line.startswith("#"))}
    return run, codes, r.stdout + r.stderr


def test_two_opposite_motors_lost_descend_upright(tmp_path):
    run, codes, text = _fly(tmp_path, "motors12_lost")
    assert codes == {0, 12}
    assert run["detection_s"] is not None and run["detection_s"] <= 0.2, run
    assert "motors 1 and 2 lost" in text
    assert run["max_thrust_tilt_after_fault_deg"] < 30.0, run
    assert run["touchdown_speed_m_s"] is not None and run["touchdown_speed_m_s"] <= 5.7, run
    assert run["crashed"] is True            # the plant's impact crash: above 2.5 m/s


def test_two_adjacent_motors_lost_are_named(tmp_path):
    run, codes, _ = _fly(tmp_path, "motors13_lost")
    assert codes == {0, 13}
    assert run["detection_s"] is not None and run["detection_s"] <= 0.2, run
