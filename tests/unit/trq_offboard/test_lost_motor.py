"""The lost-motor detector on synthetic effectiveness streams, and the switch to the failed
configuration (trq_offboard/lost_motor.py)."""

from __future__ import annotations

import numpy as np
import pytest

from trq_offboard.config import EffectivenessConfig, LostMotorConfig, load_controller
from trq_offboard.effectiveness import MotorEffectivenessObserver
from trq_offboard.lost_motor import LostMotorDetector, failed_config, status_text

from conftest import ROOT

PARAMS = ROOT / "params"
DT = 0.01                                   # the control period
CFG = LostMotorConfig(below=0.2, hold_s=0.1, min_command_pct=20.0, yaw_weight=0.0,
                      max_body_rate_rad_s=30.0, descent_speed_m_s=1.0)
CMD = np.array([80.0, 60.0, 60.0, 60.0])    # the commands in effect (%)


def _detect(stream, cmd=CMD):
    """Feed (n, 4) estimates every control period from t = 0: (motor, time) or (None, None)."""
    det = LostMotorDetector(CFG)
    for k, e in enumerate(stream):
        lost = det.update(k * DT, e, cmd)
        if lost is not None:
            return lost, det.detected_s
    return None, None


def _observed(factor, seconds=1.0, onset_s=0.2, c=80.0, T=0.03):
    """The effectiveness observer's estimates (n, 4) of motors whose motor 2 drops to `factor`
    of its command at onset_s: outputs through the motor's lag, sampled per control period."""
    obs = MotorEffectivenessObserver(EffectivenessConfig(250.0, 0.1, 10), T, DT, codegen=False)
    y = np.full(4, c)
    obs.reset(y)
    out = []
    cmd = np.full(4, c)
    for k in range(int(round(seconds / DT))):
        t = k * DT
        e = np.array([1.0, factor if t >= onset_s else 1.0, 1.0, 1.0])
        for _ in range(10):                              # the plant's lag, 1 ms ticks
            y = y + (1.0 - np.exp(-0.001 / T)) * (e * cmd - y)
        out.append(obs.update(y, [(DT, cmd)], DT))
    return np.array(out)


def test_a_stopped_motor_is_detected_within_the_stated_time():
    """The observer's estimate of a motor at 0 % (held at its floor) declared lost within
    hold_s plus three control periods of the onset (the estimate's fall)."""
    stream = _observed(0.0)
    lost, t = _detect(stream)
    assert lost == 2
    assert 0.2 + CFG.hold_s - 1e-9 <= t <= 0.2 + CFG.hold_s + 3 * DT + 1e-9


def test_half_a_motor_is_not_lost():
    """The paper's fault: the estimate near 0.5, never at the threshold."""
    stream = _observed(0.5)
    assert stream[-1, 1] == pytest.approx(0.5, abs=0.05)
    assert _detect(stream) == (None, None)


def test_a_lossy_link_like_estimate_is_not_lost():
    """0.5 with noise and dips to the floor of one or two control periods, every half second
    (what paper_fault50_lossy's estimate does: the record): nothing declared."""
    rng = np.random.default_rng(7)
    stream = np.ones((1000, 4))
    stream[:, 0] = np.clip(0.5 + 0.04 * rng.standard_normal(1000), 0.1, 1.0)
    for k in range(20, 1000, 50):
        stream[k:k + 1 + (k // 50) % 2, 0] = 0.1
    assert _detect(stream) == (None, None)
    # the same dips held for hold_s: lost
    stream[500:500 + int(CFG.hold_s / DT) + 1, 0] = 0.1
    assert _detect(stream)[0] == 1


WITHIN = LostMotorConfig(below=0.2, hold_s=0.05, min_command_pct=20.0, yaw_weight=0.0,
                         max_body_rate_rad_s=30.0, descent_speed_m_s=1.0, within_s=0.1)


def _detect_with(cfg, stream, cmd=CMD):
    det = LostMotorDetector(cfg)
    for k, e in enumerate(stream):
        if det.update(k * DT, e, cmd) is not None:
            return det.lost, det.detected_s
    return None, None


def test_within_a_window_a_lost_motor_thrown_back_up_still_counts():
    """A lost motor's estimate on a lossy link (the tilt-bound record's flight): at the floor,
    thrown back above `below` for one or two periods by late commands. Without a break the
    count restarts at each; counted within the window it is declared once its steps at or
    below add up to hold_s."""
    stream = np.ones((60, 4))
    # from 0.20 s: floor, floor, up, up, floor, floor, up, floor, floor, floor, ...
    pattern = [0.1, 0.1, 0.41, 0.32, 0.1, 0.1, 0.35, 0.1, 0.1, 0.1, 0.1, 0.1]
    stream[20:20 + len(pattern), 0] = pattern
    stream[20 + len(pattern):, 0] = 0.1
    lost, t = _detect_with(WITHIN, stream)
    # five steps at or below (0.05 s): 0.20, 0.21, 0.24, 0.25, 0.27
    assert lost == 1 and t == pytest.approx(0.27)
    # the shipped controller's detector counts so
    shipped = load_controller(PARAMS / "controller/trq_nmpc_eso_lost.yaml").lost_motor
    assert _detect_with(shipped, stream) == (1, pytest.approx(0.27))
    no_break = LostMotorConfig(**{**WITHIN.__dict__, "within_s": None})
    lost, t_no_break = _detect_with(no_break, stream)
    # without a break: from 0.27 on, 0.05 s later
    assert lost == 1 and t_no_break == pytest.approx(0.32)


def test_within_a_window_isolated_dips_are_not_lost():
    """The 50 % fault's estimate on the lossy link: dips of one to three periods, the next one
    more than a window later: never declared with the window's count; three more periods after
    a dip of two, inside the window, are."""
    rng = np.random.default_rng(3)
    stream = np.ones((1000, 4))
    stream[:, 0] = np.clip(0.5 + 0.04 * rng.standard_normal(1000), 0.1, 1.0)
    for k in range(20, 1000, 50):
        stream[k:k + 1 + (k // 50) % 3, 0] = 0.1          # 1, 2 or 3 periods
    assert _detect_with(WITHIN, stream) == (None, None)
    assert stream[520:522, 0].max() == 0.1 and stream[522, 0] > 0.2   # a dip of 2 at 0.2 s
    stream[525:528, 0] = 0.1                              # 3 more: 5 periods within 0.08 s
    assert _detect_with(WITHIN, stream) == (1, pytest.approx(5.27))


def test_within_a_window_one_step_after_a_gap_does_not_decide_alone():
    """Telemetry lost for 0.3 s, then steps at the floor: the first counts half of hold_s at
    most, and the steps after it make up the rest (0.025 + 0.01 + 0.01 + 0.01)."""
    det = LostMotorDetector(WITHIN)
    low = np.array([0.1, 1.0, 1.0, 1.0])
    assert det.update(0.0, np.ones(4), CMD) is None
    assert det.update(0.3, low, CMD) is None
    assert det.update(0.31, low, CMD) is None
    assert det.update(0.32, low, CMD) is None
    assert det.update(0.33, low, CMD) == 1


def test_the_window_must_hold_the_hold(tmp_path):
    from params import schema
    from trq_offboard.config import loader
    f = tmp_path / "c.yaml"
    f.write_text(f"extends: {PARAMS / 'controller/trq_nmpc_eso_lost.yaml'}\n"
                 "lost_motor: {hold_s: 0.1, within_s: 0.05}\n")
    with pytest.raises(loader.ConfigError, match="lost_motor.within_s"):
        loader.load(f, schema.ControllerFile)
    f.write_text(f"extends: {PARAMS / 'controller/trq_nmpc_eso_lost.yaml'}\n"
                 "lost_motor: {hold_s: 0.05, within_s: 0.1}\n")
    assert load_controller(f).lost_motor.within_s == 0.1


def test_a_motor_commanded_near_idle_is_not_judged():
    stream = np.ones((100, 4))
    stream[:, 3] = 0.1
    assert _detect(stream, cmd=np.array([60.0, 60.0, 60.0, 12.0])) == (None, None)
    assert _detect(stream)[0] == 4


def test_the_detection_is_latched():
    det = LostMotorDetector(CFG)
    e = np.array([1.0, 0.1, 1.0, 1.0])
    for k in range(20):
        det.update(k * DT, e, CMD)
    assert det.lost == 2
    assert det.update(1.0, np.ones(4), CMD) == 2
    det.reset()
    assert det.lost is None


def test_the_status_text_fits_a_statustext():
    assert len(status_text(4)) <= 50 and status_text(1).startswith("motor 1 lost")


def test_the_switch_removes_the_rotor_from_the_allocation():
    """On a detection the controller flies the failed configuration's NMPC, whose OCP bounds
    the dead rotor's throttle to 0 at every stage, and commands that motor idle."""
    from trq_offboard.controller import Controller
    from trq_offboard.records import StateEstimate

    cfg = load_controller(PARAMS / "controller/trq_nmpc_eso_lost.yaml")
    assert cfg.lost_motor is not None
    failed = failed_config(cfg)
    assert failed.weights.euler[2] == 0.0 and failed.weights.rates[2] == 0.0
    assert failed.weights.euler[:2] == cfg.weights.euler[:2]
    assert failed.max_rate_rad_s == cfg.lost_motor.max_body_rate_rad_s
    ctl = Controller(cfg)
    assert ctl.detector is not None and ctl.solver is ctl._nominal_solver
    state = StateEstimate((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    ctl.reset(0.0, state)
    ctl._scale[ctl._nt:] = [0.1, 1.0, 1.0, 1.0]        # the estimate at its floor ...
    ctl._last_u[ctl._nt:] = 70.0                        # ... while commanded
    for k in range(12):
        ctl._detect(k * DT, state.as_vector())
    assert ctl.lost_motor == 1 and ctl.solver is ctl._failed_solver
    ocp = ctl.solver.ocp
    idx, lo, hi = ocp._c_bounds
    assert np.all(ocp.lbw[idx[:, 0]] == 0.0) and np.all(ocp.ubw[idx[:, 0]] == 0.0)
    assert np.all(ocp.ubw[idx[:, 1:]] > 0.9)
    u = ctl._command_of_plan(np.concatenate([np.zeros(4), [0.0, 60.0, 60.0, 60.0]]))
    assert u[ctl._nt] == ctl._u_lo[ctl._nt] and np.all(u[ctl._nt + 1:] == 60.0)
    # the reference: down at descent_speed_m_s from where it was detected, yaw free
    xr = ctl._reference_states(1.0, state.as_vector(), None)
    assert xr[0, 2] == pytest.approx(-5.0 + (1.0 - ctl._descent[0]))
    assert np.all(xr[:, 5] == cfg.lost_motor.descent_speed_m_s)


def test_the_failed_configuration_may_have_its_own_horizon():
    import dataclasses

    cfg = load_controller(PARAMS / "controller/trq_nmpc_eso_lost.yaml")
    assert (failed_config(cfg).horizon_steps, failed_config(cfg).step_s) == \
        (cfg.horizon_steps, cfg.step_s)
    own = dataclasses.replace(cfg, lost_motor=dataclasses.replace(
        cfg.lost_motor, horizon_steps=50, horizon_step_s=0.02))
    assert (failed_config(own).horizon_steps, failed_config(own).step_s) == (50, 0.02)


def test_the_spin_may_be_governed():
    import dataclasses

    cfg = load_controller(PARAMS / "controller/trq_nmpc_eso_lost.yaml")
    assert cfg.lost_motor.spin_weight is None
    assert failed_config(cfg).weights.rates[2] == cfg.lost_motor.yaw_weight
    gov = dataclasses.replace(cfg, lost_motor=dataclasses.replace(
        cfg.lost_motor, spin_weight=0.2, spin_rate_rad_s=15.0))
    assert failed_config(gov).weights.rates[2] == 0.2
    assert failed_config(gov).weights.euler[2] == cfg.lost_motor.yaw_weight


def test_the_response_key_validates(tmp_path):
    """lost_motor.response: nmpc (the default) or spin; spin needs the file's `spin:` section
    (clear errors naming the key otherwise)."""
    from trq_params import loader, schema

    base = PARAMS / "controller/trq_nmpc_eso_lost.yaml"
    assert load_controller(base).lost_motor.response in ("nmpc", "spin")

    def write(body):
        p = tmp_path / "c.yaml"
        p.write_text(f"extends: {base}\n{body}")
        return p
    assert load_controller(write("lost_motor: {response: spin}\n")).lost_motor.response == "spin"
    assert load_controller(write("lost_motor: {response: nmpc}\n")).lost_motor.response == "nmpc"
    with pytest.raises(loader.ConfigError, match="lost_motor.response"):
        loader.load(write("lost_motor: {response: tumble}\n"), schema.ControllerFile)
    with pytest.raises(loader.ConfigError, match="lost_motor.response"):
        loader.load(write("lost_motor: {response: spin}\nspin: null\n"), schema.ControllerFile)


def test_the_switch_hands_over_to_the_spinning_controller():
    """response spin: the four spinning controllers built with the controller; a synthetic
    detection of motor 1 hands the steps to motor 1's (source spin, holding where it was
    declared, the dead rotor idle, the STATUSTEXT saying so); two motors at the threshold keep
    the failed NMPC."""
    import dataclasses

    from trq_offboard.controller import Controller
    from trq_offboard.records import CommandSource, ReferenceSample, StateEstimate
    from trq_offboard.reference import ConstantReference

    cfg = load_controller(PARAMS / "controller/trq_nmpc_eso_lost.yaml")
    cfg = dataclasses.replace(cfg, lost_motor=dataclasses.replace(cfg.lost_motor,
                                                                  response="spin"))
    ctl = Controller(cfg)
    assert sorted(ctl._spins) == [(m, d) for m in (1, 2, 3, 4) for d in (-1, 1)]
    assert ctl.spin is None
    assert ctl.lost_motor_response == "nmpc"
    state = StateEstimate((1.0, -2.0, -5.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))

    def declare(scale, wind_acc=(0.0, 0.0)):
        ctl.reset(0.0, state)
        ctl._wind_acc = np.array(wind_acc)       # the low-pass of the observer's d (N, E)
        ctl._scale[ctl._nt:] = scale
        ctl._last_u[ctl._nt:] = 70.0
        for k in range(12):
            ctl._detect(k * DT, state.as_vector())

    declare([0.1, 0.1, 1.0, 1.0])               # two motors down: today's failed NMPC
    assert ctl.lost_motor == 1 and ctl.spin is None and ctl.solver is ctl._failed_solver
    declare([0.1, 1.0, 1.0, 1.0], wind_acc=(-0.95, 0.2))    # 8 m/s from the north
    assert ctl.lost_motor == 1 and ctl.spin is ctl._spins[(1, 1)]     # no spin yet: +1
    # the wind the observer learnt is where the spinning controller's position integral starts
    assert ctl.spin._integral == pytest.approx([0.95, -0.2, 0.0])
    assert ctl.lost_motor_response == "spin"
    assert status_text(1, "spin") == "motor 1 lost: spinning, holding position, landing"
    assert len(status_text(4, "spin")) <= 50
    assert ctl.spin.hold_pos_ned_m == (1.0, -2.0, -5.0)
    ref = ConstantReference(ReferenceSample((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), 0.0, "hover"))
    cmd, info = ctl.step(0.12, state, None, ref)
    assert info.source is CommandSource.SPIN and info.lost_motor == 1
    assert cmd.throttle_pct[0] == ctl._u_lo[ctl._nt]            # the dead rotor idle
    # the live ones: the spinning controller's own command for this estimate
    spin = ctl._spins[(1, 1)]
    assert max(cmd.throttle_pct[1:]) > 50.0 and spin.info.force_N > 15.0
    assert np.all(np.isfinite(cmd.throttle_pct + cmd.tilt_rad))
    ctl.prepare(ref)                              # a no-op while spinning
    ctl.reset(0.0, state)
    assert ctl.spin is None and ctl.lost_motor == 0


def test_over_a_delay_the_spin_takes_the_yaw_predicted_for_when_it_acts():
    """The spin's sense is the body's yaw when the spinning controller's first command acts:
    in lockstep the yaw rate measured; over a delayed link (applied_delay_s) the one the NMPC's
    predictor gives for then. Here the body yaws slowly one way, and the observer's d says the
    rotors left turn it hard the other way: 40 ms later it yaws that other way (the tilt-bound
    record: a flight that took the measured sense tumbled)."""
    import dataclasses

    from trq_offboard.controller import Controller
    from trq_offboard.records import StateEstimate
    from trq_offboard.spin import spin_sense

    base = load_controller(PARAMS / "controller/trq_nmpc_eso_lost.yaml")
    state = StateEstimate((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, -0.05))
    d = np.zeros(6)
    d[5] = 20.0                                   # rad/s^2 about body z (FRD)

    def declared_sense(delay_s):
        cfg = dataclasses.replace(base, applied_delay_s=delay_s, lost_motor=dataclasses.replace(
            base.lost_motor, response="spin"))
        ctl = Controller(cfg)
        ctl.reset(0.0, state)
        ctl._scale[ctl._nt:] = [0.1, 1.0, 1.0, 1.0]
        ctl._last_u[ctl._nt:] = 70.0
        for k in range(12):
            ctl._detect(k * DT, state.as_vector(), d=d)
        assert ctl.lost_motor == 1 and ctl.spin is not None
        return ctl.spin.direction, ctl._spins[(1, 1)].trim.axis_frd

    now, axis = declared_sense(0.0)
    assert now == spin_sense((0.0, 0.0, -0.05), axis)
    late, _ = declared_sense(0.04)
    assert late == spin_sense((0.0, 0.0, -0.05 + 0.04 * 20.0), axis) == -now


# --- two motors lost (PairLossDetector) ------------------------------------------------------

PAIR_CFG = LostMotorConfig(below=0.2, hold_s=0.1, min_command_pct=20.0, yaw_weight=0.0,
                           max_body_rate_rad_s=30.0, descent_speed_m_s=1.0,
                           pair_excess_m_s2=1.5, pair_angular_scale_rad_s2=5.0)


def _contributions(throttle_pct=100.0, tilts_rad=(0.0, 0.0, 0.0, 0.0)):
    """motor_contributions on the TRQ's prediction model, level, every motor at throttle_pct."""
    from trq_offboard.config import load_vehicle_model
    from trq_offboard.lost_motor import motor_contributions
    from trq_offboard.model import PredictionModel

    model = PredictionModel(load_vehicle_model(PARAMS / "vehicle/trq.yaml"))
    y = np.concatenate([tilts_rad, [throttle_pct] * 4])
    return model, motor_contributions(model.accel, np.zeros(12), y)


def _pair_detect(d4, contrib, cmd=(100.0,) * 4, seconds=0.3, onset_s=0.05, noise=0.0):
    """Feed d4 (the loss's d, from onset_s; 0 before) every control period: (pair, time)."""
    from trq_offboard.lost_motor import PairLossDetector

    det = PairLossDetector(PAIR_CFG)
    rng = np.random.default_rng(3)
    for k in range(int(round(seconds / DT))):
        t = k * DT
        d = (np.asarray(d4) if t >= onset_s else np.zeros(4)) + noise * rng.standard_normal(4) \
            * np.array([1.0, 2.0, 2.0, 2.0])
        pair = det.update(t, d, contrib, np.asarray(cmd))
        if pair is not None:
            return pair, det.detected_s
    return None, None


def test_a_motor_s_contribution_is_its_thrust_and_torques():
    """Level, untilted, 100 %: each motor lifts (f(100) - f(0)) / m (the model's curve: f(0) =
    c0), the opposite pairs' roll and pitch accelerations cancel, and yaw tells 1-2 (ccw) from
    3-4 (cw)."""
    model, c = _contributions()
    vm = model.vehicle
    f = vm.thrust_N.c2 * 1e4 + vm.thrust_N.c1 * 100.0
    assert np.allclose(c[0], -f / vm.mass_kg, rtol=1e-9)
    assert np.allclose((c[:, 0] + c[:, 1])[1:3], 0.0, atol=1e-9)
    assert np.allclose((c[:, 2] + c[:, 3])[1:3], 0.0, atol=1e-9)
    assert (c[:, 0] + c[:, 1])[3] > 0.0 > (c[:, 2] + c[:, 3])[3]


@pytest.mark.parametrize("pair", [(1, 2), (3, 4), (1, 3), (2, 4), (1, 4), (2, 3)])
def test_two_motors_lost_are_told_apart(pair):
    """d of two motors stopped whole (their shares removed), with the observer's kind of noise:
    the pair declared within hold_s of the onset (the window's mean: sooner as the excess
    grows)."""
    _, c = _contributions()
    d4 = -(c[:, pair[0] - 1] + c[:, pair[1] - 1])
    got, t = _pair_detect(d4, c, noise=0.5)
    assert got == pair
    assert 0.05 < t <= 0.05 + PAIR_CFG.hold_s + 1e-9


def test_one_motor_lost_or_half_a_motor_is_not_a_pair():
    """One motor stopped whole (its share), or the paper's half: no excess, no pair."""
    _, c = _contributions()
    for m in range(4):
        assert _pair_detect(-c[:, m], c, noise=0.5)[0] is None
        assert _pair_detect(-0.5 * c[:, m], c, noise=0.5)[0] is None


def test_a_pair_commanded_near_idle_is_not_judged():
    _, c = _contributions()
    d4 = -(c[:, 0] + c[:, 1])
    assert _pair_detect(d4, c, cmd=(10.0, 100.0, 100.0, 100.0))[0] is None


def test_the_pair_status_text_fits_a_statustext():
    from trq_offboard.lost_motor import pair_code

    text = status_text(pair_code((1, 2)))
    assert len(text) <= 50 and text.startswith("motors 1 and 2 lost")


def test_a_pair_flies_the_failed_nmpc_with_both_rotors_out():
    """Before any loss the controller's pair detector reads the observer's d against the
    motors' shares: two opposite motors' d declares 12, the failed NMPC flies with both rotors'
    throttles bounded to 0; the single-motor detector is not consulted after it."""
    from trq_offboard.controller import Controller
    from trq_offboard.lost_motor import motor_contributions
    from trq_offboard.records import StateEstimate

    cfg = load_controller(PARAMS / "controller/trq_nmpc_eso_lost.yaml")
    assert cfg.lost_motor.pair_excess_m_s2 is not None
    ctl = Controller(cfg)
    assert ctl.pair_detector is not None
    state = StateEstimate((0.0, 0.0, -5.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    ctl.reset(0.0, state)
    x = state.as_vector()
    nt = ctl._nt
    y = ctl._last_u.copy()
    y[nt:] = 100.0
    ctl._last_u[nt:] = 100.0
    c = motor_contributions(ctl.model.accel, x, y)
    d = np.zeros(6)
    d[2:6] = -(c[:, 0] + c[:, 1])
    for k in range(12):
        ctl._detect(k * DT, x, d, y)
    assert ctl.lost_motor == 12 and ctl.solver is ctl._failed_solver and ctl.spin is None
    assert ctl._scale[nt] == 0.0 and ctl._scale[nt + 1] == 0.0
    ocp = ctl.solver.ocp
    idx, lo, hi = ocp._c_bounds
    assert np.all(ocp.ubw[idx[:, 0:2]] == 0.0) and np.all(ocp.ubw[idx[:, 2:]] > 0.9)
    ctl._scale[nt:] = [0.1, 0.1, 0.1, 1.0]          # a single detection would latch motor 1
    ctl._detect(0.2, x, d, y)
    assert ctl.lost_motor == 12 and ctl.detector.lost is None
