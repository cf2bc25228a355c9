"""Extended state observers on a double integrator with a known constant disturbance."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from trq_offboard.config import load_eso
from trq_offboard.eso import ExtendedStateObserver, fal
from dataclasses import replace

ESO = Path(__file__).resolve().parents[2] / "params" / "controller" / "eso.yaml"
D_X = 2.0 / 2.1          # 2 N on 2.1 kg, m/s^2


def test_fal_shape():
    d = np.array([0.1])
    assert fal(np.array([0.05]), 0.5, d)[0] == pytest.approx(0.05 / 0.1 ** 0.5)
    assert fal(np.array([0.4]), 0.5, d)[0] == pytest.approx(0.4 ** 0.5)
    assert fal(np.array([-0.4]), 0.25, d)[0] == pytest.approx(-(0.4 ** 0.25))
    # continuous at the band edge
    assert fal(np.array([0.1]), 0.5, d)[0] == pytest.approx(fal(np.array([0.1 + 1e-12]), 0.5, d)[0])


@pytest.mark.parametrize("kind", ["nonlinear", "linear"])
def test_converges_on_constant_disturbance_double_integrator(kind):
    cfg = replace(load_eso(ESO), kind=kind)
    dt = 0.02
    eso = ExtendedStateObserver(cfg, dt)
    eso.reset(np.zeros(6), np.zeros(6))
    d_true = np.array([D_X, -0.3, 0.5, 2.0, -1.0, 0.5])     # also the other channels
    b0 = np.array([0.2, 0.0, -0.1, 0.0, 0.3, 0.0])          # known model acceleration
    pos, vel = np.zeros(6), np.zeros(6)
    sub = 100
    for k in range(int(1.0 / dt)):
        for _ in range(sub):                                 # exact-ish plant
            vel = vel + dt / sub * (b0 + d_true)
            pos = pos + dt / sub * vel
        eso.update(pos, b0)
    est = eso.z[2]
    np.testing.assert_allclose(est, d_true, rtol=0.10)
    assert abs(est[0] - D_X) < 0.1 * D_X


def test_disturbance_conversion_to_body_rates():
    """Euler-acceleration estimate x3 = W(eta) d_omega  ->  d[3:6] = d_omega."""
    cfg = load_eso(ESO)
    eso = ExtendedStateObserver(cfg, 0.02)
    roll, pitch = 0.3, -0.2
    d_omega = np.array([1.0, -2.0, 0.5])
    sr, cr, tp, cp = np.sin(roll), np.cos(roll), np.tan(pitch), np.cos(pitch)
    W = np.array([[1, sr * tp, cr * tp], [0, cr, -sr], [0, sr / cp, cr / cp]])
    eso.z[2, 3:6] = W @ d_omega
    np.testing.assert_allclose(eso.disturbance(np.array([roll, pitch, 0.0]))[3:6], d_omega,
                               atol=1e-12)
