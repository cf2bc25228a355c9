"""Extended state observers on a double integrator with a known constant disturbance."""

from __future__ import annotations


import numpy as np
import pytest

from trq_offboard.config import load_eso
from trq_offboard.eso import ExtendedStateObserver, fal
from dataclasses import replace

from conftest import ROOT

ESO = ROOT / "params" / "controller" / "eso.yaml"
ESO_PAPER = ESO.with_name("eso_paper.yaml")     # the paper's form: position and angles
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
    cfg = replace(load_eso(ESO_PAPER), kind=kind)
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
    cfg = load_eso(ESO_PAPER)
    eso = ExtendedStateObserver(cfg, 0.02)
    roll, pitch = 0.3, -0.2
    d_omega = np.array([1.0, -2.0, 0.5])
    sr, cr, tp, cp = np.sin(roll), np.cos(roll), np.tan(pitch), np.cos(pitch)
    W = np.array([[1, sr * tp, cr * tp], [0, cr, -sr], [0, sr / cp, cr / cp]])
    eso.z[2, 3:6] = W @ d_omega
    np.testing.assert_allclose(eso.disturbance(np.array([roll, pitch, 0.0]))[3:6], d_omega,
                               atol=1e-12)


def _reduced(kind, omega_t=60.0, omega_r=300.0):
    """The observer one order lower: velocity and body-rate channels."""
    cfg = load_eso(ESO)
    return replace(cfg, kind=kind,
                   translational=replace(cfg.translational, output="velocity",
                                         omega_o_rad_s=omega_t, delta=0.2),
                   rotational=replace(cfg.rotational, output="rates", omega_o_rad_s=omega_r,
                                      delta=1.0))


@pytest.mark.parametrize("kind", ["nonlinear", "linear"])
def test_reduced_order_converges_on_constant_disturbance(kind):
    """Channels measuring a rate (velocity, body rates): x1 tracks the rate, x3 the constant
    disturbance on its derivative, x2 is the rate's derivative x3 + b0."""
    eso = ExtendedStateObserver(_reduced(kind), 0.01)
    eso.reset(np.zeros(6), np.zeros(6))
    d_true = np.array([D_X, -0.3, 0.5, 20.0, -10.0, 5.0])
    b0 = np.array([0.2, 0.0, -0.1, 3.0, 0.3, 0.0])
    rate = np.zeros(6)
    for _ in range(50):                                      # 0.5 s
        rate = rate + 0.01 * (b0 + d_true)                   # exact for a constant derivative
        eso.update(rate, b0)
    # within the explicit Euler substeps' bias (0.2 % at w h = 0.3)
    np.testing.assert_allclose(eso.z[2], d_true, rtol=1e-2)
    np.testing.assert_allclose(eso.z[1], d_true + b0, rtol=1e-2)
    np.testing.assert_allclose(eso.output_estimate, rate, rtol=1e-2)
    assert eso.output_error(rate) < 1e-3


def test_reduced_order_sees_a_step_sooner_than_the_third_order_one():
    """A step of angular acceleration (a motor losing half its thrust): the body-rate observer
    at 300 rad/s has 90 % of it within 30 ms; the paper's third-order observer on the angle at
    70 rad/s has not."""
    def seen_after(eso, measure, n):
        eso.reset(np.zeros(6), np.zeros(6))
        ang, rate = np.zeros(6), np.zeros(6)
        step = np.array([0.0, 0.0, 0.0, 80.0, -80.0, 0.0])
        sub = 100
        for _ in range(n):
            for _ in range(sub):
                rate = rate + 0.01 / sub * step
                ang = ang + 0.01 / sub * rate
            eso.update(measure(ang, rate), np.zeros(6))
        return eso.disturbance(np.zeros(3))[3:5] / step[3:5]

    fast = seen_after(ExtendedStateObserver(_reduced("nonlinear"), 0.01), lambda a, r: r, 3)
    slow = seen_after(ExtendedStateObserver(load_eso(ESO_PAPER), 0.01), lambda a, r: a, 3)
    assert np.all(fast > 0.9)
    assert np.all(slow < 0.6)


def test_reduced_order_selects_rates_and_body_accelerations():
    """measurement() and b0_of() pick each channel's output from the state (12) and the
    model's accelerations (9: NED, Euler, body); body-rate channels hand x3 over unconverted."""
    eso = ExtendedStateObserver(_reduced("linear"), 0.01)
    x = np.arange(12, dtype=float)
    np.testing.assert_array_equal(eso.measurement(x), [3, 4, 5, 9, 10, 11])
    acc = np.arange(9, dtype=float) + 100.0
    np.testing.assert_array_equal(eso.b0_of(acc), [100, 101, 102, 106, 107, 108])
    eso.z[2] = [0.1, 0.2, 0.3, 1.0, -2.0, 0.5]
    np.testing.assert_array_equal(eso.disturbance(np.array([0.3, -0.2, 0.0])), eso.z[2])
    paper = ExtendedStateObserver(load_eso(ESO_PAPER), 0.01)
    np.testing.assert_array_equal(paper.measurement(x), [0, 1, 2, 6, 7, 8])
    np.testing.assert_array_equal(paper.b0_of(acc), [100, 101, 102, 103, 104, 105])


@pytest.mark.parametrize("group,value", [("translational", "rates"), ("rotational", "velocity"),
                                         ("rotational", "gyro")])
def test_output_key_is_checked(tmp_path, group, value):
    import yaml
    from trq_offboard.config import ConfigError
    data = yaml.safe_load(ESO.read_text())
    data[group]["output"] = value
    bad = tmp_path / "eso.yaml"
    bad.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=rf"{group}\.output.*{value}"):
        load_eso(bad)


def test_observer_too_fast_for_its_substeps_is_refused(tmp_path):
    """w h <= 1 on the explicit Euler substeps: 300 rad/s at 100 Hz needs at least 3 substeps;
    the error names the observer file, the key, the value and the bound."""
    import yaml
    from trq_offboard.config import ConfigError, load_controller
    data = yaml.safe_load(ESO.read_text())
    data["rotational"]["omega_o_rad_s"] = 300.0
    data["substeps"] = 2
    eso = tmp_path / "eso.yaml"
    eso.write_text(yaml.safe_dump(data))
    ctrl = tmp_path / "c.yaml"
    ctrl.write_text(f"extends: {ESO.with_name('trq_nmpc_eso.yaml')}\n"
                    f"vehicle: {ESO.parents[1] / 'vehicle' / 'trq.yaml'}\n"
                    f"observer: {{kind: nonlinear, file: {eso}}}\n")
    with pytest.raises(ConfigError, match=r"eso\.yaml: key 'rotational\.omega_o_rad_s': got "
                                          r"300\.0, expected at most .* 200 rad/s"):
        load_controller(ctrl)
    data["substeps"] = 3
    eso.write_text(yaml.safe_dump(data))
    assert load_controller(ctrl).eso.substeps == 3


def _run(eso, n=60, seed=3):
    """The observer over n control periods of a wandering output with a known b0: its z."""
    rng = np.random.default_rng(seed)
    eso.reset(np.zeros(6), np.zeros(6))
    y = np.zeros(6)
    for _ in range(n):
        y = y + rng.normal(0.0, 0.002, 6)
        eso.update(y, rng.normal(0.0, 0.5, 6))
    return eso.z.copy()


@pytest.mark.parametrize("codegen", [False, True])
def test_a_bandwidth_per_axis_moves_only_its_channel(codegen):
    """omega_o_rad_s per axis (roll, pitch, yaw): the same three figures are the group's one
    figure to the bit; the yaw's alone changed changes the yaw channel and no other."""
    base = load_eso(ESO_PAPER)
    w = base.rotational.omega_o_rad_s
    one = ExtendedStateObserver(base, 0.01, codegen=codegen)
    same = ExtendedStateObserver(replace(base, rotational=replace(base.rotational,
                                                                  omega_o_rad_s=(w, w, w))),
                                 0.01, codegen=codegen)
    yaw = ExtendedStateObserver(replace(base, rotational=replace(base.rotational,
                                                                 omega_o_rad_s=(w, w, 1.2 * w))),
                                0.01, codegen=codegen)
    z_one, z_same, z_yaw = _run(one), _run(same), _run(yaw)
    assert np.array_equal(z_one, z_same)
    assert np.array_equal(z_one[:, 0:5], z_yaw[:, 0:5])
    assert not np.array_equal(z_one[:, 5], z_yaw[:, 5])
