"""The motor effectiveness observer (trq_offboard/effectiveness.py) against the vehicle's own
motor model (sil_vehicle: target = e x command, then the first-order lag, per 1 ms tick), and
its controller file keys."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from sil_vehicle.dynamics.actuators import first_order_step, lag_factor
from trq_offboard.config import ConfigError, EffectivenessConfig, load_controller
from trq_params.loader import read_yaml     # the loader's YAML 1.2 dialect: `off` stays a string
from trq_offboard.effectiveness import MotorEffectivenessObserver
from trq_offboard.nmpc.base import Solver

from conftest import ROOT

PARAMS = ROOT / "params"


class _NoOcp:
    """The part of an Ocp the controller uses: no lag states, throttle bounds ignored."""
    n_lag = 0

    def set_throttle_scale(self, e):
        pass


class _NoNmpc(Solver):
    """The effectiveness observer needs no NMPC; building one would cost seconds."""
    ocp = _NoOcp()

    def solve(self, x0, x_ref, d, u_prev, guess, y0=None):
        raise NotImplementedError
T = 0.03                 # params/vehicle/trq.yaml: motor time constant
DT = 0.01                # control period
TICK = 0.001             # the vehicle's physics tick
CFG = EffectivenessConfig(bandwidth_rad_s=250.0, min_effectiveness=0.1, substeps=10)


def _fly(e_of_t, c_of_t, seconds, noise=0.0, seed=0):
    """The plant's motors (4, only motor 1 varies) sampled every control period; returns the
    times, the observer's estimates of motor 1 and the true output of motor 1."""
    rng = np.random.default_rng(seed)
    obs = MotorEffectivenessObserver(CFG, T, DT)
    f = lag_factor(T, TICK)
    y = np.full(4, c_of_t(0.0))
    obs.reset(y)
    ts, es, ys = [], [], []
    ticks = int(round(DT / TICK))
    for k in range(int(round(seconds / DT))):
        t0 = k * DT
        c = np.full(4, c_of_t(t0))                    # held over the period
        for j in range(ticks):
            t = t0 + j * TICK
            e = np.array([e_of_t(t), 1.0, 1.0, 1.0])
            y = np.array([first_order_step(y[i], c[i] * e[i], f, 1e9, 0.0, 100.0)
                          for i in range(4)])
        y_meas = y + noise * rng.standard_normal(4)
        est = obs.update(y_meas, [(DT, c)], DT)
        ts.append(t0 + DT)
        es.append(est.copy())
        ys.append(y[0])
    return np.array(ts), np.array(es), np.array(ys)


def test_healthy_motors_stay_at_one():
    _, es, _ = _fly(lambda t: 1.0, lambda t: 60.0 + 20.0 * math.sin(4.0 * t), 2.0)
    assert np.all(es > 0.999)        # the plant's 1 ms ticks against the observer's lag ODE


def test_step_loss_seen_from_the_slope_before_the_output_falls():
    onset, c = 0.2, 60.0
    ts, es, ys = _fly(lambda t: 0.5 if t >= onset else 1.0, lambda t: c, 0.6)
    assert np.all(es[ts < onset, 0] == 1.0)
    # converges to the true effectiveness; the healthy motors are left alone
    assert es[-1, 0] == pytest.approx(0.5, abs=0.005)
    assert np.all(es[:, 1:] == 1.0)
    # 90 % of the step in the estimate, while the output has covered well under 90 % of its fall
    k = int(np.argmax(es[:, 0] <= 0.55))
    fallen = (c - ys[k]) / (c - 0.5 * c)
    # (measured: 0.60 after one period, 0.51 after two, with the output 28 % and 49 % down)
    assert ts[k] - onset <= 0.02 + 1e-9
    assert fallen < 0.55, (ts[k] - onset, fallen)
    # and sooner than the output itself reaches 90 % of its fall (about 2.3 time constants)
    k_out = int(np.argmax((c - ys) / (0.5 * c) >= 0.9))
    assert ts[k] < ts[k_out]


def test_varying_command_and_a_motor_off():
    ts, es, _ = _fly(lambda t: 0.7, lambda t: 50.0 + 30.0 * math.sin(6.0 * t), 1.0)
    assert np.all(np.abs(es[ts > 0.3, 0] - 0.7) < 0.01)
    _, es, _ = _fly(lambda t: 0.0 if t >= 0.1 else 1.0, lambda t: 70.0, 0.5)
    assert es[-1, 0] == pytest.approx(CFG.min_effectiveness)      # held at its floor


def test_noisy_outputs_keep_the_estimate_near_one():
    # half a throttle percent of white noise on the outputs read from the disturbance (in the
    # paper's flights the healthy estimates stay above 0.94)
    _, es, _ = _fly(lambda t: 1.0, lambda t: 65.0, 2.0, noise=0.5, seed=3)
    assert es.min() > 0.9 and np.median(es) > 0.99


def test_needs_a_motor_lag():
    with pytest.raises(ValueError, match="time constant"):
        MotorEffectivenessObserver(CFG, 0.0, DT)


def test_controller_keys(tmp_path):
    src = read_yaml(PARAMS / "controller/nmpc.yaml")
    src["vehicle"] = str(PARAMS / "vehicle/trq.yaml")
    src["observer"]["file"] = str(PARAMS / "controller/eso.yaml")

    def load(block, observer="nonlinear", applied_input="commanded"):
        d = dict(src, motor_effectiveness=block, applied_input=applied_input,
                 observer=dict(src["observer"], kind=observer))
        p = tmp_path / "c.yaml"
        p.write_text(yaml.safe_dump(d))
        return load_controller(p)

    good = {"estimate": "on", "bandwidth_rad_s": 250.0, "min": 0.1, "substeps": 10}
    assert load(good).effectiveness == CFG
    assert load(dict(good, estimate="off")).effectiveness is None
    with pytest.raises(ConfigError, match=r"motor_effectiveness\.estimate.*observer"):
        load(good, observer="none")
    with pytest.raises(ConfigError, match=r"motor_effectiveness\.bandwidth_rad_s.*1000"):
        load(dict(good, bandwidth_rad_s=1500.0))
    with pytest.raises(ConfigError, match=r"motor_effectiveness\.min"):
        load(dict(good, min=0.0))
    with pytest.raises(ConfigError, match=r"unknown key 'motor_effectiveness\.gain'"):
        load(dict(good, gain=2.0))
    with pytest.raises(ConfigError, match=r"applied_input.*outputs.*motor_effectiveness"):
        load(good, applied_input="outputs")


def test_a_long_gap_stays_stable():
    """Lost samples: 0.3 s without a measurement is integrated in substeps no longer than in a
    control period (30 x 10 here), not in 10 steps of 30 ms (p h = 7.5: divergent)."""
    obs = MotorEffectivenessObserver(CFG, T, DT)
    obs.reset(np.full(4, 60.0))
    e = obs.update(np.array([30.0, 60.0, 60.0, 60.0]), [(0.3, np.full(4, 60.0))], 0.3)
    # (the measurement is interpolated over the gap: a ramp, which it follows with a lag)
    assert np.all(np.isfinite(obs.y)) and e[0] == pytest.approx(0.5, abs=0.05)
    assert np.all(e[1:] == 1.0)
    for _ in range(10):
        e = obs.update(np.array([30.0, 60.0, 60.0, 60.0]), [(DT, np.full(4, 60.0))], DT)
    assert e[0] == pytest.approx(0.5, abs=0.005)


@pytest.mark.parametrize("motor", [0, 1, 2, 3])
@pytest.mark.parametrize("loss", [0.3, 0.5])
def test_the_faulty_motor_is_isolated_from_the_disturbance(motor, loss):
    """d made by the model itself for one motor producing `loss` less (tilted rotors, a tilted
    body, spinning): the controller attributes it to that motor alone, to the throttle percent's
    thousandth (the secant of the quadratic thrust curve)."""
    from trq_offboard.controller import Controller


    ctl = Controller(load_controller(PARAMS / "controller/trq_nmpc_eso.yaml"), solver=_NoNmpc())
    x = np.zeros(12)
    x[6:9] = [0.1, -0.05, 0.4]
    x[9:12] = [0.2, -0.1, 0.3]
    y_nom = np.array([0.1, -0.05, 0.08, -0.12, 70.0, 80.0, 75.0, 85.0])
    y_true = y_nom.copy()
    y_true[4 + motor] *= 1.0 - loss
    acc = ctl.model.b0(x, y_true) - ctl.model.b0(x, y_nom)
    d = acc[[0, 1, 2, 6, 7, 8]]
    dz = ctl.motors.motor_deficit(x, d, y_nom)
    want = np.zeros(4)
    want[motor] = y_true[4 + motor] - y_nom[4 + motor]
    np.testing.assert_allclose(dz, want, atol=1e-3)
    # the same motor over-producing: never read as its deficit (at most as another motor's,
    # whose roll and pitch pattern it shares: the isolation's known limit, README)
    over = ctl.motors.motor_deficit(x, -d, y_nom)
    assert over[motor] == 0.0 and np.all(over <= 0.0) and np.count_nonzero(over) <= 1


def _deficit_step_by_step(ctl, x, d, y_nom):
    """The specification of MotorEffectiveness.motor_deficit in plain floats: each motor's
    least-squares deficit alone, the first with the largest share of |d[2:5]|^2 among those
    with a deficit, three Gauss-Newton steps on the quadratic curves' exact change; dots summed
    left to right."""
    nt = 4 if ctl.model.tilting else 0

    def col(u, j):
        jac = ctl.model.motor_jacobian(x, u).reshape(4, 4, order="F")
        return [float(v) for v in jac[0:3, j]]

    def dot(a, b):
        return (a[0] * b[0] + a[1] * b[1]) + a[2] * b[2]

    r = [float(v) for v in d[2:5]]
    cols = [col(y_nom, j) for j in range(4)]
    num = [dot(c, r) for c in cols]
    den = [max(dot(c, c), 1e-12) for c in cols]
    fit = [n * n / q if n < 0.0 else -1.0 for n, q in zip(num, den)]
    i = max(range(4), key=lambda j: (fit[j], -j))      # the first of the largest
    dz = np.zeros(4)
    if fit[i] > 0.0:
        delta, u_end = num[i] / den[i], y_nom.copy()
        for _ in range(3):
            u_end[nt + i] = y_nom[nt + i] + delta
            c1 = col(u_end, i)
            rho = [0.5 * (c0 + c) * delta - rk for c0, c, rk in zip(cols[i], c1, r)]
            delta -= dot(c1, rho) / max(dot(c1, c1), 1e-12)
        dz[i] = min(0.0, delta)
    return dz


def test_the_compiled_deficit_is_its_specification_bit_for_bit():
    """The compiled motor deficit against the step-by-step specification on random states,
    commands and disturbances (deficits, surpluses, and nothing to explain), bit for bit."""
    from trq_offboard.controller import Controller


    ctl = Controller(load_controller(PARAMS / "controller/trq_nmpc_eso.yaml"), solver=_NoNmpc())
    rng = np.random.default_rng(18)
    picked = set()
    for k in range(300):
        x = np.zeros(12)
        x[6:12] = rng.normal(0.0, 0.2, 6)
        y_nom = np.concatenate([rng.uniform(-0.3, 0.3, 4), rng.uniform(30.0, 90.0, 4)])
        d = rng.normal(0.0, 1.0, 6) if k % 10 else np.zeros(6)
        got = ctl.motors.motor_deficit(x, d, y_nom)
        want = _deficit_step_by_step(ctl, x, d, y_nom)
        assert np.array_equal(got, want), (k, got, want)
        picked.update(np.flatnonzero(got).tolist())
    assert picked == {0, 1, 2, 3}           # every motor was found in some draw
