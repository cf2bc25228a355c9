"""The lost-motor controller's NMPC inner loop (trq_offboard/spin_nmpc.py, spin.py's `inner:
nmpc`): the LQR's move where no bound is active, its bounds where the LQR clips, its fallback,
its parameters."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from trq_offboard.config import load_vehicle_model
from trq_offboard.records import ReferenceSample, StateEstimate
from trq_offboard.spin import SpinController, load_spin_config
from trq_params.loader import ConfigError

from conftest import PARAMS

CONTROLLER = PARAMS / "controller" / "trq_nmpc_eso.yaml"
HOLD = ReferenceSample((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), 0.0)


@pytest.fixture(scope="module")
def pair():
    """The LQR and the NMPC on the same `spin:` section, motor 1 dead."""
    cfg = dataclasses.replace(load_spin_config(CONTROLLER), inner="lqr")
    vm = load_vehicle_model(cfg.vehicle_file)
    return (SpinController(cfg, vm, 1),
            SpinController(dataclasses.replace(cfg, inner="nmpc"), vm, 1))


def _on_orbit(c: SpinController, rate_kick, tilt_deg=0.0) -> StateEstimate:
    """The orbit's attitude (the trim's axis on world up, leaned by tilt_deg in roll), its rates
    plus `rate_kick` (body FRD rad/s)."""
    n = np.asarray(c.trim.axis_frd)
    pitch = math.asin(n[0])
    roll = math.atan2(-n[1], -n[2]) + math.radians(tilt_deg)
    w = c.direction * c.trim.spin_rad_s * n + np.asarray(rate_kick, float)
    return StateEstimate((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), (roll, pitch, 0.0), tuple(w))


def _live(cmd, c: SpinController) -> np.ndarray:
    return np.array([cmd.throttle_pct[i] / 100.0 for i in c._live]
                    + [cmd.tilt_rad[i] for i in c._live])


def test_near_the_orbit_the_nmpc_moves_as_the_lqr(pair):
    """A small kick of the rates, no bound active: the NMPC's terminal cost is the LQR's P and
    its stage cost the LQR's, so its first command's deviation from the trim is the LQR's to
    the model's nonlinearity over the horizon (within 1 %; without the terminal cost it is 2 %
    off), and it is not the trim."""
    lqr, nmpc = pair
    est = _on_orbit(lqr, (0.02, -0.015, 0.01))
    devs = []
    for c in (lqr, nmpc):
        c.reset(est)
        devs.append(_live(c.step(est, HOLD), c) - c._a0)
    assert nmpc.info.qp_status == 0 and nmpc.info.saturated == 0
    assert np.linalg.norm(devs[0]) > 1e-3
    assert np.linalg.norm(devs[1] - devs[0]) < 0.01 * np.linalg.norm(devs[0])


def test_where_the_lqr_clips_the_nmpc_plans_within_the_bounds(pair):
    """A large tumble (1.5 rad/s about body x, the axis 20 deg off): the LQR's answer is clipped
    at the actuators' limits; the NMPC's plan is within them by construction, its QP solved, and
    its command is not the clipped LQR's."""
    lqr, nmpc = pair
    est = _on_orbit(lqr, (1.5, 0.0, 0.0), tilt_deg=20.0)
    cmds = []
    for c in (lqr, nmpc):
        c.reset(est)
        cmds.append(_live(c.step(est, HOLD), c))
    assert lqr.info.saturated > 0
    assert nmpc.info.qp_status in (0, 1) and nmpc.info.qp_iterations > 0
    assert np.all(cmds[1] >= nmpc._lo - 1e-9) and np.all(cmds[1] <= nmpc._hi + 1e-9)
    assert np.max(np.abs(cmds[1] - cmds[0])) > 1e-3


def test_a_failed_qp_flies_the_lqr(pair, monkeypatch):
    """The QP returning non-finite increments (HPIPM's status 3): that period's command is the
    LQR's, clipped, and the info says the QP failed; the next period plans afresh."""
    lqr, nmpc = pair
    est = _on_orbit(lqr, (0.3, -0.2, 0.1), tilt_deg=5.0)
    lqr.reset(est)
    want = _live(lqr.step(est, HOLD), lqr)
    qp = nmpc._nmpc._qp

    def broken(*args):
        qp.status = 3
        return qp.x, np.full_like(qp.u, np.nan), qp.pi
    monkeypatch.setattr(qp, "solve", broken)
    nmpc.reset(est)
    got = _live(nmpc.step(est, HOLD), nmpc)
    assert nmpc.info.qp_status == 3
    assert got == pytest.approx(want, abs=1e-12)
    monkeypatch.undo()
    nmpc.step(est, HOLD)
    assert nmpc.info.qp_status in (0, 1)


def test_the_inner_loop_is_named_in_the_file(tmp_path):
    """`spin.inner` takes lqr or nmpc (the schema's default lqr, the shipped file's nmpc),
    `spin.horizon_steps` 1..200; anything else is refused naming the key."""
    assert load_spin_config(CONTROLLER).inner == "nmpc"          # as shipped
    text = (PARAMS / "controller" / "trq_nmpc_eso.yaml").read_text()
    text = text.replace("extends: nmpc.yaml", f"extends: {PARAMS}/controller/nmpc.yaml")
    text = text.replace("vehicle: ../vehicle/", f"vehicle: {PARAMS}/vehicle/")
    f = tmp_path / "c.yaml"
    for old, bad in (("  inner: nmpc", "  inner: mpc"),
                     ("  horizon_steps: 20", "  horizon_steps: 0")):
        assert old in text
        f.write_text(text.replace(old, bad))
        with pytest.raises(ConfigError, match=bad.split(":")[0].strip()):
            load_spin_config(f)
    f.write_text(text.replace("  inner: nmpc", "  inner: lqr").replace("  horizon_steps: 20",
                                                                      "  horizon_steps: 30"))
    cfg = load_spin_config(f)
    assert (cfg.inner, cfg.horizon_steps) == ("lqr", 30)
